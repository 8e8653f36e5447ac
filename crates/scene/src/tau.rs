//! Camera optical depth per pixel: the geometric cloud mask of the evaluation.
//!
//! τ(pixel) = mean over 3 × 3 sub-pixel rays of ∫ σ_t(o + t d) dt through the volume's box,
//! integrated by the midpoint rule with a step of a quarter of the smallest cell (the trilinear
//! σ_t is piecewise smooth on that scale). This is the quantity the Mitsuba references store as
//! `<case>_tau.npy` ("camera optical depth, 3×3 rays/pixel"); a pixel belongs to the cloud when
//! τ ≥ [`CLOUD_TAU`]. Unlike a brightness threshold it does not depend on the lighting: with a
//! sky every pixel is bright, but only the ones that see the medium are cloud.

use crate::Scene;
use rayon::prelude::*;

/// Optical depth from which a pixel counts as cloud (as in `shared/refs`).
pub const CLOUD_TAU: f32 = 0.1;

/// τ of every pixel, row-major (`[y * width + x]`, pixel (0, 0) top-left).
pub fn optical_depth_image(scene: &Scene) -> Vec<f32> {
    let cam = &scene.camera;
    let (w, h) = (cam.width, cam.height);
    let vol = &scene.volume;
    let aabb = *vol.aabb();
    let cell = vol.cell_size();
    let step = 0.25 * cell.x.min(cell.y).min(cell.z);
    let origin = cam.origin;
    let ray_tau = |px: f64, py: f64| -> f64 {
        let d = cam.ray_dir(px, py);
        let Some((t0, t1)) = aabb.intersect(origin, d) else {
            return 0.0;
        };
        let t0 = t0.max(0.0);
        if t1 <= t0 {
            return 0.0;
        }
        let n = ((t1 - t0) / step).ceil().max(1.0);
        // Bounded: a box of res voxels is crossed in ≤ 4·√3·max(res) steps.
        let dt = (t1 - t0) / n;
        (0..n as usize)
            .map(|i| vol.sigma_t(origin + d * (t0 + (i as f64 + 0.5) * dt)))
            .sum::<f64>()
            * dt
    };
    (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (x, y) = ((i % w) as f64, (i / w) as f64);
            let mut s = 0.0;
            for sy in 0..3 {
                for sx in 0..3 {
                    s += ray_tau(x + (sx as f64 + 0.5) / 3.0, y + (sy as f64 + 0.5) / 3.0);
                }
            }
            (s / 9.0) as f32
        })
        .collect()
}

/// The cloud mask τ ≥ [`CLOUD_TAU`] of a τ image.
pub fn cloud_mask(tau: &[f32]) -> Vec<bool> {
    tau.iter().map(|&t| t >= CLOUD_TAU).collect()
}
