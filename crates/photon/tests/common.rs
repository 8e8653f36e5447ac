//! Scenes shared by the test files.

use glam::DVec3;
use nimbus_scene::Scene;
use nimbus_scene::build::{self, SceneBuilder};

/// A 24×18×24 generated cumulus under sun and sky, seen at 32×24 pixels.
pub fn small_cloud() -> Scene {
    SceneBuilder::new(
        build::generated(nimbus_scene::CloudKind::Cumulus, 3, [24, 18, 24], 20.0).unwrap(),
    )
    .sun(DVec3::new(1.0, 0.6, 0.3), DVec3::new(1.0, 0.9, 0.8))
    .sky(DVec3::new(0.1, 0.15, 0.3))
    .look(DVec3::new(0.3, 0.3, 3.0), DVec3::ZERO, 40.0, 32, 24)
    .build()
    .unwrap()
}
