//! Scenes built in code, for tests and programs that make their own clouds: one builder
//! instead of a `Scene { … }` literal or a hand-assembled [`Scene::in_memory`] per test file.
//!
//! ```
//! use glam::DVec3;
//! use nimbus_scene::{CloudKind, build};
//!
//! let scene = build::SceneBuilder::new(build::generated(CloudKind::Cumulus, 3, [24, 18, 24], 20.0)?)
//!     .hg(0.857)
//!     .sun(DVec3::new(1.0, 0.6, 0.3), DVec3::ONE)
//!     .sky(DVec3::new(0.1, 0.15, 0.3))
//!     .look(DVec3::new(0.3, 0.3, 3.0), DVec3::ZERO, 40.0, 32, 24)
//!     .build()?;
//! assert_eq!(scene.camera.width, 32);
//! # Ok::<(), nimbus_scene::FieldError>(())
//! ```

use glam::DVec3;

use crate::phase::HenyeyGreenstein;
use crate::{
    Aabb, Camera, CloudKind, DensityGrid, FieldError, Medium, Phase, Scene, Sky, Sun, Volume,
    generate,
};

/// A generated cloud in its default box ([`generate::default_aabb`]) with σ_t scale
/// `density_scale`.
pub fn generated(
    kind: CloudKind,
    seed: u64,
    res: [usize; 3],
    density_scale: f64,
) -> Result<Volume, FieldError> {
    let grid = generate::generate(kind, seed, res)?;
    let (lo, hi) = generate::default_aabb(res);
    Volume::new(grid, Aabb::new(lo, hi)?, density_scale)
}

/// A grid of `res` voxels over the box [`lo`, `hi`] with σ_t scale `density_scale`.
pub fn volume(
    grid: DensityGrid,
    lo: DVec3,
    hi: DVec3,
    density_scale: f64,
) -> Result<Volume, FieldError> {
    Volume::new(grid, Aabb::new(lo, hi)?, density_scale)
}

/// Builds a [`Scene`]: albedo 1, Henyey–Greenstein g = 0.857 (the papers' cloud), no lights and
/// a 32×24 camera at (0, 0, 4) looking at the origin unless told otherwise. Values are checked
/// by [`SceneBuilder::build`], as the scene file's are.
#[derive(Debug, Clone)]
pub struct SceneBuilder {
    label: String,
    volume: Volume,
    albedo: f64,
    phase: PhaseChoice,
    sun: Option<(DVec3, DVec3, f64)>,
    sky: Option<Sky>,
    camera: CameraChoice,
}

#[derive(Debug, Clone)]
enum PhaseChoice {
    Hg(f64),
    Given(Phase),
}

#[derive(Debug, Clone)]
enum CameraChoice {
    Look {
        origin: DVec3,
        target: DVec3,
        vfov_deg: f64,
        width: usize,
        height: usize,
    },
    Given(Camera),
}

impl SceneBuilder {
    pub fn new(volume: Volume) -> Self {
        Self {
            label: "test".into(),
            volume,
            albedo: 1.0,
            phase: PhaseChoice::Hg(0.857),
            sun: None,
            sky: None,
            camera: CameraChoice::Look {
                origin: DVec3::new(0.0, 0.0, 4.0),
                target: DVec3::ZERO,
                vfov_deg: 40.0,
                width: 32,
                height: 24,
            },
        }
    }

    /// The name the scene carries in errors and reports (default `test`).
    pub fn label(mut self, label: &str) -> Self {
        self.label = label.into();
        self
    }

    pub fn albedo(mut self, albedo: f64) -> Self {
        self.albedo = albedo;
        self
    }

    /// Henyey–Greenstein phase function with asymmetry `g`.
    pub fn hg(mut self, g: f64) -> Self {
        self.phase = PhaseChoice::Hg(g);
        self
    }

    pub fn phase(mut self, phase: Phase) -> Self {
        self.phase = PhaseChoice::Given(phase);
        self
    }

    /// A delta sun towards `direction` with `irradiance`.
    pub fn sun(self, direction: DVec3, irradiance: DVec3) -> Self {
        self.sun_disc(direction, irradiance, 0.0)
    }

    /// A sun disc of angular radius `angular_radius_deg` (0: a delta light).
    pub fn sun_disc(
        mut self,
        direction: DVec3,
        irradiance: DVec3,
        angular_radius_deg: f64,
    ) -> Self {
        self.sun = Some((direction, irradiance, angular_radius_deg));
        self
    }

    /// A constant sky of `radiance`.
    pub fn sky(mut self, radiance: DVec3) -> Self {
        self.sky = Some(Sky::Constant(radiance));
        self
    }

    /// A camera at `origin` looking at `target`, y up.
    pub fn look(
        mut self,
        origin: DVec3,
        target: DVec3,
        vfov_deg: f64,
        width: usize,
        height: usize,
    ) -> Self {
        self.camera = CameraChoice::Look {
            origin,
            target,
            vfov_deg,
            width,
            height,
        };
        self
    }

    pub fn camera(mut self, camera: Camera) -> Self {
        self.camera = CameraChoice::Given(camera);
        self
    }

    /// The scene, or the first invalid value as the scene file would report it.
    pub fn build(self) -> Result<Scene, FieldError> {
        let phase = match self.phase {
            PhaseChoice::Hg(g) => Phase::HenyeyGreenstein(HenyeyGreenstein::new(g)?),
            PhaseChoice::Given(p) => p,
        };
        let medium = Medium::new(self.albedo, phase)?;
        let sun = self.sun.map(|(d, e, r)| Sun::new(d, e, r)).transpose()?;
        let camera = match self.camera {
            CameraChoice::Look {
                origin,
                target,
                vfov_deg,
                width,
                height,
            } => Camera::new(origin, target, DVec3::Y, vfov_deg, width, height)?,
            CameraChoice::Given(c) => c,
        };
        Ok(Scene::in_memory(
            &self.label,
            self.volume,
            medium,
            sun,
            self.sky,
            camera,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Defaults are the papers' cloud medium without lights; invalid values are refused by
    /// the same checks as a scene file's.
    #[test]
    fn defaults_and_checks() {
        let v = generated(CloudKind::Stratus, 1, [8, 6, 8], 10.0).unwrap();
        let s = SceneBuilder::new(v.clone()).build().unwrap();
        assert_eq!(s.medium.albedo, 1.0);
        assert!(
            matches!(s.medium.vertex(1).1, Phase::HenyeyGreenstein(hg) if (hg.g() - 0.857).abs() < 1e-12)
        );
        assert!(s.sun.is_none() && s.sky.is_none());
        assert_eq!((s.camera.width, s.camera.height), (32, 24));
        let e = SceneBuilder::new(v.clone()).hg(1.0).build().unwrap_err();
        assert!(e.to_string().contains("g"), "{e}");
        let e = SceneBuilder::new(v.clone())
            .albedo(1.5)
            .build()
            .unwrap_err();
        assert!(e.to_string().contains("albedo"), "{e}");
        let e = SceneBuilder::new(v)
            .sun(DVec3::ZERO, DVec3::ONE)
            .build()
            .unwrap_err();
        assert!(e.to_string().contains("sun.direction"), "{e}");
    }
}
