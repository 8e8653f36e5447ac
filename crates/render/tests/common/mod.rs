//! What the render test binaries share: a small lit cloud and the options with the tiny RPNN
//! model on ONNX Runtime.

use std::path::Path;

use glam::DVec3;
use nimbus_render::{NetBackend, Options, RpnnSettings};
use nimbus_scene::Scene;
use nimbus_scene::build::{self, SceneBuilder};

/// A 24×18×24 generated cumulus under a sun and a sky, seen at 24×16 pixels.
pub fn scene() -> Scene {
    SceneBuilder::new(
        build::generated(nimbus_scene::CloudKind::Cumulus, 3, [24, 18, 24], 20.0).unwrap(),
    )
    .sun(DVec3::new(1.0, 0.6, 0.3), DVec3::new(1.0, 0.9, 0.8))
    .sky(DVec3::new(0.1, 0.15, 0.3))
    .look(DVec3::new(0.3, 0.3, 3.0), DVec3::ZERO, 40.0, 24, 16)
    .build()
    .unwrap()
}

/// Default options, RPNN with the test model `rpnn-tiny.onnx` in ONNX Runtime.
pub fn options() -> Options {
    Options {
        rpnn: RpnnSettings {
            model: Some(
                Path::new(env!("CARGO_MANIFEST_DIR")).join("../rpnn/tests/data/rpnn-tiny.onnx"),
            ),
            backend: NetBackend::Ort,
            ..Default::default()
        },
        ..Default::default()
    }
}
