//! Impostor caching (Elek 2012 §4.4): reuse the last ray-marched image of the cloud until one of
//! four empirical criteria says it is stale:
//! 1. angle — the direction from the cloud to the camera turned by more than 5°;
//! 2. distance — the camera's distance to the cloud changed by more than 20 %;
//! 3. illumination — the photon map was updated by more than 4 % of its ring (m) since;
//! 4. animation — the density changed by more than a tunable relative L1 amount (default 2 %).

use glam::DVec3;
use nimbus_scene::{Camera, Image};

/// Thresholds of the four criteria.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImpostorCriteria {
    pub angle_deg: f64,
    pub distance_rel: f64,
    pub illumination_frac: f64,
    pub density_rel: f64,
}

impl Default for ImpostorCriteria {
    fn default() -> Self {
        Self {
            angle_deg: 5.0,
            distance_rel: 0.2,
            illumination_frac: 0.04,
            density_rel: 0.02,
        }
    }
}

/// Why the impostor was (re)rendered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refresh {
    First,
    Angle,
    Distance,
    Illumination,
    Animation,
}

impl Refresh {
    pub fn name(self) -> &'static str {
        match self {
            Refresh::First => "first",
            Refresh::Angle => "angle",
            Refresh::Distance => "distance",
            Refresh::Illumination => "illumination",
            Refresh::Animation => "animation",
        }
    }
}

/// State of the impostor: what it was rendered for, and what changed since.
#[derive(Debug, Clone)]
pub struct ImpostorState {
    pub criteria: ImpostorCriteria,
    view_dir: Option<DVec3>,
    distance: f64,
    frames_traced: u32,
    density_change: f64,
    /// Counts of refreshes per reason and of reuses.
    pub refreshes: [u32; 5],
    pub reuses: u32,
}

impl ImpostorState {
    pub fn new(criteria: ImpostorCriteria) -> Self {
        Self {
            criteria,
            view_dir: None,
            distance: 0.0,
            frames_traced: 0,
            density_change: 0.0,
            refreshes: [0; 5],
            reuses: 0,
        }
    }

    /// Records a traced frame (one generation of the ring replaced).
    pub fn traced(&mut self) {
        self.frames_traced += 1;
    }

    /// Records a density change of relative L1 size `rel` (Σ|D − D_prev| / Σ D_prev).
    pub fn density_changed(&mut self, rel: f64) {
        self.density_change += rel;
    }

    /// Decides for this frame: `Some(reason)` to re-render, `None` to reuse the impostor.
    /// `ring` is m; camera and cloud centre give the view criteria.
    pub fn check(&mut self, camera: DVec3, cloud_center: DVec3, ring: u32) -> Option<Refresh> {
        let v = camera - cloud_center;
        let dist = v.length();
        let dir = v / dist.max(1e-300);
        let c = self.criteria;
        let reason = match self.view_dir {
            None => Some(Refresh::First),
            Some(d0) if d0.dot(dir).clamp(-1.0, 1.0).acos().to_degrees() > c.angle_deg => {
                Some(Refresh::Angle)
            }
            Some(_) if (dist / self.distance - 1.0).abs() > c.distance_rel => {
                Some(Refresh::Distance)
            }
            Some(_) if self.frames_traced as f64 > c.illumination_frac * ring as f64 => {
                Some(Refresh::Illumination)
            }
            Some(_) if self.density_change > c.density_rel => Some(Refresh::Animation),
            Some(_) => None,
        };
        match reason {
            Some(r) => {
                self.view_dir = Some(dir);
                self.distance = dist;
                self.frames_traced = 0;
                self.density_change = 0.0;
                self.refreshes[r as usize] += 1;
            }
            None => self.reuses += 1,
        }
        reason
    }
}

/// Shows an impostor rendered from camera `from` as seen from camera `to` (Elek §4.4: the
/// impostor is a billboard). The billboard is the plane through the cloud centre `center`
/// facing the impostor's camera; each pixel of `to` looks up where its ray meets that plane in
/// the impostor image (bilinear). Rays that miss the plane (parallel or behind) get the
/// impostor's corner pixel, the background.
pub fn reproject(image: &Image, from: &Camera, to: &Camera, center: DVec3) -> Image {
    use rayon::prelude::*;
    let (w0, h0) = (from.width as f64, from.height as f64);
    let (f0, r0, u0, t0) = from.basis();
    let a0 = w0 / h0;
    let n = (from.origin - center).normalize();
    let background = image.get(0, 0);
    let mut out = Image::new(to.width, to.height);
    let sample = |px: f64, py: f64| -> [f32; 3] {
        // Continuous pixel coordinates; pixel (i, j) has its centre at (i + ½, j + ½).
        let x = (px - 0.5).clamp(0.0, w0 - 1.0);
        let y = (py - 0.5).clamp(0.0, h0 - 1.0);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(from.width - 1), (y0 + 1).min(from.height - 1));
        let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
        let (a, b, c, d) = (
            image.get(x0, y0),
            image.get(x1, y0),
            image.get(x0, y1),
            image.get(x1, y1),
        );
        std::array::from_fn(|k| {
            (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy
        })
    };
    out.pixels
        .par_chunks_mut(to.width)
        .enumerate()
        .for_each(|(j, row)| {
            for (i, px) in row.iter_mut().enumerate() {
                let d = to.ray_dir(i as f64 + 0.5, j as f64 + 0.5);
                let dn = d.dot(n);
                let t = if dn.abs() > 1e-12 {
                    (center - to.origin).dot(n) / dn
                } else {
                    -1.0
                };
                let v = to.origin + d * t - from.origin;
                let z = v.dot(f0);
                *px = if t > 0.0 && z > 0.0 {
                    let x = v.dot(r0) / (z * t0 * a0);
                    let y = v.dot(u0) / (z * t0);
                    sample((x + 1.0) * 0.5 * w0, (1.0 - y) * 0.5 * h0)
                } else {
                    background
                };
            }
        });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(origin: DVec3, w: usize, h: usize) -> Camera {
        Camera::new(origin, DVec3::ZERO, DVec3::Y, 30.0, w, h).unwrap()
    }

    #[test]
    fn reprojection_to_the_same_camera_is_the_identity() {
        let cam = camera(DVec3::new(0.3, 0.2, 4.0), 40, 30);
        let mut img = Image::new(40, 30);
        for (k, p) in img.pixels.iter_mut().enumerate() {
            *p = [k as f32, (k % 7) as f32, 1.0];
        }
        let out = reproject(&img, &cam, &cam, DVec3::ZERO);
        for (a, b) in out.pixels.iter().zip(&img.pixels) {
            for c in 0..3 {
                // Pixel centres map to pixel centres up to f64 rounding of the projection.
                assert!(
                    (a[c] - b[c]).abs() < 1e-3 * b[c].abs().max(1.0),
                    "{a:?} {b:?}"
                );
            }
        }
    }

    #[test]
    fn reprojection_follows_a_pan_and_a_resize() {
        // A bright pixel at the image centre (the cloud centre) stays at the centre of a camera
        // that orbits by 3° and renders at twice the resolution.
        let from = camera(DVec3::new(0.0, 0.0, 4.0), 41, 31);
        let mut img = Image::new(41, 31);
        img.pixels[15 * 41 + 20] = [1.0; 3];
        let o = DVec3::new(
            4.0 * 3f64.to_radians().sin(),
            0.0,
            4.0 * 3f64.to_radians().cos(),
        );
        let to = camera(o, 82, 62);
        let out = reproject(&img, &from, &to, DVec3::ZERO);
        let (mut best, mut at) = (0.0, 0);
        for (k, p) in out.pixels.iter().enumerate() {
            if p[0] > best {
                (best, at) = (p[0], k);
            }
        }
        let (x, y) = (at % 82, at / 82);
        assert!(
            (x as i64 - 41).abs() <= 1 && (y as i64 - 31).abs() <= 1,
            "{x} {y}"
        );
        // Looking away from the billboard: background.
        let away = Camera::new(
            DVec3::new(0.0, 0.0, 4.0),
            DVec3::new(0.0, 0.0, 8.0),
            DVec3::Y,
            30.0,
            8,
            8,
        )
        .unwrap();
        let out = reproject(&img, &from, &away, DVec3::ZERO);
        assert!(out.pixels.iter().all(|p| *p == img.get(0, 0)));
    }

    #[test]
    fn four_criteria() {
        let mut s = ImpostorState::new(ImpostorCriteria::default());
        let c = DVec3::ZERO;
        let cam = DVec3::new(0.0, 0.0, 10.0);
        assert_eq!(s.check(cam, c, 100), Some(Refresh::First));
        assert_eq!(s.check(cam, c, 100), None);
        // 4° turn: reuse; 6°: refresh.
        let turn = |deg: f64| {
            DVec3::new(
                10.0 * deg.to_radians().sin(),
                0.0,
                10.0 * deg.to_radians().cos(),
            )
        };
        assert_eq!(s.check(turn(4.0), c, 100), None);
        assert_eq!(s.check(turn(6.0), c, 100), Some(Refresh::Angle));
        // 15 % closer: reuse; 25 %: refresh.
        let base = turn(6.0);
        assert_eq!(s.check(base * 0.85, c, 100), None);
        assert_eq!(s.check(base * 0.75, c, 100), Some(Refresh::Distance));
        // 4 of 100 generations replaced: reuse; the 5th: refresh.
        let cam = base * 0.75;
        for _ in 0..4 {
            s.traced();
        }
        assert_eq!(s.check(cam, c, 100), None);
        s.traced();
        assert_eq!(s.check(cam, c, 100), Some(Refresh::Illumination));
        s.density_changed(0.015);
        assert_eq!(s.check(cam, c, 100), None);
        s.density_changed(0.01);
        assert_eq!(s.check(cam, c, 100), Some(Refresh::Animation));
        assert_eq!(s.refreshes, [1, 1, 1, 1, 1]);
        assert_eq!(s.reuses, 5);
    }
}
