//! Pinhole camera, Mitsuba 3 convention: `look_at(origin, target, up)`, `vfov_deg` is the full
//! vertical field of view, pixel (0, 0) is the top-left corner, image x grows to the right of the
//! view direction (right = normalize(forward × up)), each pixel integrates a box filter over its
//! square.

use glam::DVec3;

use crate::error::FieldError;

#[derive(Debug, Clone, PartialEq)]
pub struct Camera {
    pub origin: DVec3,
    pub width: usize,
    pub height: usize,
    forward: DVec3,
    right: DVec3,
    up: DVec3,
    tan_half: f64,
    vfov_deg: f64,
    target: DVec3,
    up_hint: DVec3,
}

/// Largest accepted image side; larger is almost surely a typo (and would not fit memory).
pub const MAX_IMAGE_SIDE: usize = 32768;

impl Camera {
    pub fn new(
        origin: DVec3,
        target: DVec3,
        up: DVec3,
        vfov_deg: f64,
        width: usize,
        height: usize,
    ) -> Result<Self, FieldError> {
        if !(origin.is_finite() && target.is_finite() && up.is_finite()) {
            return Err(FieldError::new(
                "camera",
                "origin, target and up must be finite",
            ));
        }
        let f = target - origin;
        if !f.is_finite() || !f.length().is_finite() {
            return Err(FieldError::new(
                "camera.target",
                "the distance from camera.origin overflows (coordinates beyond ≈ 1e154); use a smaller scene scale",
            ));
        }
        // Relative to the coordinates' size: a scene may be modelled at any scale.
        if f.length() == 0.0 || f.length() < 1e-12 * origin.length().max(target.length()) {
            return Err(FieldError::new(
                "camera.target",
                "must differ from camera.origin",
            ));
        }
        let forward = f.normalize();
        let r = forward.cross(up);
        if !r.is_finite() || !r.length().is_finite() || !up.length().is_finite() {
            return Err(FieldError::new(
                "camera.up",
                "its length overflows; use a unit vector",
            ));
        }
        if r.length() < 1e-9 * up.length().max(1e-300) || up.length() == 0.0 {
            return Err(FieldError::new(
                "camera.up",
                "must not be zero or parallel to the view direction",
            ));
        }
        if !(vfov_deg.is_finite() && vfov_deg > 0.0 && vfov_deg < 180.0) {
            return Err(FieldError::new(
                "camera.vfov_deg",
                format!("must lie in (0, 180), got {vfov_deg}"),
            ));
        }
        for (name, v) in [("camera.width", width), ("camera.height", height)] {
            if v == 0 || v > MAX_IMAGE_SIDE {
                return Err(FieldError::new(
                    name,
                    format!("must lie in 1..={MAX_IMAGE_SIDE}, got {v}"),
                ));
            }
        }
        crate::memory::check(
            width as u128 * height as u128 * 12,
            "camera.width",
            &format!("a {width}×{height} RGB float image"),
        )?;
        let right = r.normalize();
        Ok(Self {
            origin,
            width,
            height,
            forward,
            right,
            up: right.cross(forward),
            tan_half: (0.5 * vfov_deg).to_radians().tan(),
            vfov_deg,
            target,
            up_hint: up,
        })
    }

    /// Unit direction of the ray through image point (`px`, `py`) in pixel units (continuous:
    /// pixel (i, j) spans [i, i+1) × [j, j+1)).
    #[inline]
    pub fn ray_dir(&self, px: f64, py: f64) -> DVec3 {
        let aspect = self.width as f64 / self.height as f64;
        let x = (2.0 * px / self.width as f64 - 1.0) * self.tan_half * aspect;
        let y = (1.0 - 2.0 * py / self.height as f64) * self.tan_half;
        (self.forward + self.right * x + self.up * y).normalize()
    }

    /// (forward, right, up, tan(vfov/2)) — the pinhole basis, for GPU ray generation.
    pub fn basis(&self) -> (DVec3, DVec3, DVec3, f64) {
        (self.forward, self.right, self.up, self.tan_half)
    }

    pub fn forward(&self) -> DVec3 {
        self.forward
    }

    pub fn vfov_deg(&self) -> f64 {
        self.vfov_deg
    }

    pub fn target(&self) -> DVec3 {
        self.target
    }

    pub fn up_hint(&self) -> DVec3 {
        self.up_hint
    }

    /// The same view at another image size (the size is checked as in [`Camera::new`]).
    pub fn with_size(&self, width: usize, height: usize) -> Result<Self, FieldError> {
        Self::new(
            self.origin,
            self.target,
            self.up_hint,
            self.vfov_deg,
            width,
            height,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn with_size_keeps_the_view() {
        let c = Camera::new(
            DVec3::new(1.0, 2.0, 3.0),
            DVec3::ZERO,
            DVec3::Y,
            35.0,
            64,
            48,
        )
        .unwrap();
        let d = c.with_size(320, 200).unwrap();
        assert_eq!((d.width, d.height), (320, 200));
        assert_eq!(
            (d.origin, d.target(), d.up_hint(), d.vfov_deg(), d.forward()),
            (c.origin, c.target(), c.up_hint(), c.vfov_deg(), c.forward())
        );
        assert!(c.with_size(0, 10).is_err());
    }

    #[test]
    fn orientation() {
        let c = Camera::new(DVec3::new(0.0, 0.0, 5.0), DVec3::ZERO, DVec3::Y, 90.0, 4, 2).unwrap();
        let centre = c.ray_dir(2.0, 1.0);
        assert!((centre - DVec3::NEG_Z).length() < 1e-12);
        // Top-left pixel looks up and left (−x, +y).
        let tl = c.ray_dir(0.0, 0.0);
        assert!(tl.x < 0.0 && tl.y > 0.0);
        assert!(Camera::new(DVec3::ZERO, DVec3::ZERO, DVec3::Y, 40.0, 4, 4).is_err());
        assert!(Camera::new(DVec3::ZERO, DVec3::Y, DVec3::Y, 40.0, 4, 4).is_err());
        assert!(Camera::new(DVec3::ZERO, DVec3::X, DVec3::Y, 0.0, 4, 4).is_err());
        assert!(Camera::new(DVec3::ZERO, DVec3::X, DVec3::Y, 40.0, 0, 4).is_err());
    }
}
