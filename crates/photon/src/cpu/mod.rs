//! CPU twins of the photon-mapping GPU stages, one file per stage, each function named after
//! the WGSL entry point it mirrors and computing what one invocation of it computes, in the
//! same f32 arithmetic (Vello's `src/cpu/<stage>.rs` arrangement). Tests run a stage either
//! way and compare (`crates/photon/tests/gpu.rs`).
//!
//! | WGSL entry point | one invocation | CPU twin |
//! |---|---|---|
//! | `photon_sun.wgsl` `sun_transmittance` | one density voxel | [`sun_transmittance()`] |
//! | `photon_trace.wgsl` `trace` | one beam (Elek 2012 §4.1) | [`trace()`] |
//! | `photon_update.wgsl` `update` | one cache word of the ring (§4.2) | [`update()`] |
//! | `photon_upsample.wgsl` `cells` | one coarse cell | [`cells()`] |
//! | `photon_upsample.wgsl` `upsample` | one fine voxel (§4.3): J, and the flux lobes | [`upsample()`], [`upsample_dirs()`] |
//! | `photon_raymarch.wgsl` `raymarch` | one pixel (§4.4, Appendix C) | [`raymarch()`] |
//! | `photon_gather.wgsl` `gather` | one pixel's samples of the final gathering | [`gather()`], [`gather_sample()`] |

use glam::{Vec3, Vec4};
use nimbus_gpu::params::VolumeParams;
use nimbus_scene::phase::hg::eval_f32 as hg;

mod cells;
mod gather;
mod raymarch;
mod sun_transmittance;
mod trace;
mod update;
mod upsample;

pub use cells::{CellValue, cell_mean_density, cells};
pub use gather::{GatherInputs, gather, gather_sample};
pub use raymarch::{in_scattered, perturb, raymarch, single_scattered, sun_in_scatter};
pub use sun_transmittance::sun_transmittance;
pub use trace::{Rng, trace};
pub use update::update;
pub use upsample::{f_exp, f_exp_paper, upsample, upsample_dirs};

/// u32 words per cache cell (`CELL_WORDS` in photon_trace.wgsl and photon_upsample.wgsl):
/// Σw sun, Σw sky, Σw (d + 1)/2 (3), Σ order, deposit count, Σw, Σw (d + 1)/2 (3) of the
/// high-order sun deposits, and Σw p(d · ω_view) of the sun and of the sky deposits.
pub use crate::cache_layout::CELL_WORDS;

pub(crate) fn v3(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}

/// Centre of density voxel `idx` in world space (the shaders' voxel position).
pub(crate) fn voxel_centre(p: &VolumeParams, idx: usize) -> Vec3 {
    let res = p.d_res;
    let v = coords(idx, res);
    let ext = v3(p.aabb_max) - v3(p.aabb_min);
    let resf = Vec3::new(res[0] as f32, res[1] as f32, res[2] as f32);
    v3(p.aabb_min)
        + (Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32) + Vec3::splat(0.5)) / resf * ext
}

/// Grid coordinates of linear index `i` (x fastest), the inverse of [`index`].
pub(crate) fn coords(i: usize, res: [u32; 3]) -> [u32; 3] {
    let i = i as u32;
    [i % res[0], (i / res[0]) % res[1], i / (res[0] * res[1])]
}

pub(crate) fn index(x: u32, y: u32, z: u32, res: [u32; 3]) -> usize {
    ((z * res[1] + y) * res[0] + x) as usize
}

/// (i0, i1, fraction) of the cell-centred trilinear lookup at p in a grid of `res`.
pub(crate) fn trilinear(p: &VolumeParams, pos: Vec3, res: [u32; 3]) -> ([u32; 3], [u32; 3], Vec3) {
    let resf = Vec3::new(res[0] as f32, res[1] as f32, res[2] as f32);
    let u = (pos - v3(p.aabb_min)) / (v3(p.aabb_max) - v3(p.aabb_min)) * resf - Vec3::splat(0.5);
    let b = u.floor();
    let hi = resf - Vec3::ONE;
    let i0 = b.clamp(Vec3::ZERO, hi);
    let i1 = (b + Vec3::ONE).clamp(Vec3::ZERO, hi);
    (
        [i0.x as u32, i0.y as u32, i0.z as u32],
        [i1.x as u32, i1.y as u32, i1.z as u32],
        u - b,
    )
}

pub(crate) fn inside(p: &VolumeParams, x: Vec3) -> bool {
    x.cmpge(v3(p.aabb_min)).all() && x.cmple(v3(p.aabb_max)).all()
}

pub(crate) fn lerp<T>(a: T, b: T, t: f32) -> T
where
    T: std::ops::Mul<f32, Output = T>
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + Copy,
{
    // mix(a, b, t) = a * (1 − t) + b * t, as WGSL computes it.
    a * (1.0 - t) + b * t
}

/// Trilinear interpolation of `f(index)` over a grid (same arithmetic order as the shaders).
pub(crate) fn interp<T>(p: &VolumeParams, pos: Vec3, res: [u32; 3], f: impl Fn(usize) -> T) -> T
where
    T: std::ops::Mul<f32, Output = T>
        + std::ops::Add<Output = T>
        + std::ops::Sub<Output = T>
        + Copy,
{
    let (i0, i1, t) = trilinear(p, pos, res);
    let c00 = lerp(
        f(index(i0[0], i0[1], i0[2], res)),
        f(index(i1[0], i0[1], i0[2], res)),
        t.x,
    );
    let c10 = lerp(
        f(index(i0[0], i1[1], i0[2], res)),
        f(index(i1[0], i1[1], i0[2], res)),
        t.x,
    );
    let c01 = lerp(
        f(index(i0[0], i0[1], i1[2], res)),
        f(index(i1[0], i0[1], i1[2], res)),
        t.x,
    );
    let c11 = lerp(
        f(index(i0[0], i1[1], i1[2], res)),
        f(index(i1[0], i1[1], i1[2], res)),
        t.x,
    );
    lerp(lerp(c00, c10, t.y), lerp(c01, c11, t.y), t.z)
}

/// Unscaled density at x (0 outside the box).
pub fn density_at(p: &VolumeParams, density: &[f32], x: Vec3) -> f32 {
    if !inside(p, x) {
        return 0.0;
    }
    interp(p, x, p.d_res, |i| density[i])
}

/// Whether a voxel within `p.near_radius` (at least 1) of voxel `idx` (the block clamped to
/// the grid) holds density (`near_density` in grid.wgsl): the sun pass and the upsampling skip
/// the others.
pub fn near_density(p: &VolumeParams, density: &[f32], idx: usize) -> bool {
    let r = p.d_res;
    let v = coords(idx, r);
    let k = p.near_radius.max(1);
    let near = |a: usize| v[a].saturating_sub(k)..=(v[a] + k).min(r[a] - 1);
    near(2).any(|z| near(1).any(|y| near(0).any(|x| density[index(x, y, z, r)] > 0.0)))
}

pub(crate) fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747796405).wrapping_add(2891336453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277803737);
    (word >> 22) ^ word
}

pub(crate) fn box_intersect(p: &VolumeParams, o: Vec3, d: Vec3) -> (f32, f32) {
    let (mut t0, mut t1) = (0.0f32, 3.0e38f32);
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < p.aabb_min[a] || o[a] > p.aabb_max[a] {
                return (1.0, 0.0);
            }
        } else {
            let inv = 1.0 / d[a];
            let ta = (p.aabb_min[a] - o[a]) * inv;
            let tb = (p.aabb_max[a] - o[a]) * inv;
            t0 = t0.max(ta.min(tb));
            t1 = t1.min(ta.max(tb));
        }
    }
    (t0, t1)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn f_exp_is_stable_and_normalised() {
        let r = 0.3f32;
        for lambda in [
            -400.0f32, -50.0, -3.0, -0.1, -1e-6, 0.0, 1e-7, 0.1, 3.0, 50.0, 400.0,
        ] {
            // ∫₀ʳ f dd = 1 (midpoint rule, 20 000 panels).
            let n = 20_000;
            let h = r / n as f32;
            let integral: f32 = (0..n)
                .map(|i| f_exp((i as f32 + 0.5) * h, lambda, r) * h)
                .sum();
            assert!((integral - 1.0).abs() < 2e-3, "λ={lambda}: ∫ = {integral}");
            for k in 0..=10 {
                let v = f_exp(k as f32 * r / 10.0, lambda, r);
                assert!(v.is_finite() && v >= 0.0, "λ={lambda} d={k}: {v}");
            }
        }
        // Agrees with the paper's formula where that is well conditioned.
        for lambda in [-5.0f64, -1.0, 0.5, 2.0, 10.0] {
            for k in 0..10 {
                let d = k as f64 * 0.03;
                let a = f_exp(d as f32, lambda as f32, 0.3) as f64;
                let b = f_exp_paper(d, lambda, 0.3);
                assert!(
                    (a - b).abs() < 1e-4 * b.abs().max(1.0),
                    "λ={lambda} d={d}: {a} vs {b}"
                );
            }
        }
        // The λ → 0 limit is the triangle filter; both sides of the series switch match.
        assert!((f_exp(0.0, 0.0, 1.0) - 2.0).abs() < 1e-6);
        assert!((f_exp(0.1, 0.0499, 1.0) - f_exp(0.1, 0.0501, 1.0)).abs() < 1e-4);
        assert!((f_exp(0.1, -0.0499, 1.0) - f_exp(0.1, -0.0501, 1.0)).abs() < 1e-4);
        assert_eq!(f_exp(0.3, 1.0, 0.3), 0.0);
    }

    #[test]
    fn hg_reconstruction_is_the_convolution() {
        // ∫ p_HG(ω·ω'|g) p_HG(ω'·ω_s|g') dω' = p_HG(ω·ω_s | g g'): numerical convolution on a
        // 400 × 800 (θ, φ) grid against the closed form used by the ray marcher.
        let p = VolumeParams {
            albedo: 1.0,
            density_scale: 1.0,
            g: 0.7,
            sun_irradiance: [1.0; 3],
            ..Default::default()
        };
        let gp = 0.5f32;
        let hg = nimbus_scene::phase::hg::eval;
        for view_mu in [-0.8f64, 0.0, 0.6, 0.95] {
            // ω_s = z; ω at angle acos(view_mu) in the x-z plane.
            let w = glam::DVec3::new((1.0 - view_mu * view_mu).sqrt(), 0.0, view_mu);
            let (nt, np) = (400, 800);
            let mut acc = 0.0;
            for i in 0..nt {
                let t = (i as f64 + 0.5) / nt as f64 * std::f64::consts::PI;
                for k in 0..np {
                    let ph = (k as f64 + 0.5) / np as f64 * std::f64::consts::TAU;
                    let wp = glam::DVec3::new(t.sin() * ph.cos(), t.sin() * ph.sin(), t.cos());
                    acc += hg(0.7, w.dot(wp)) * hg(gp as f64, t.cos()) * t.sin();
                }
            }
            let numeric =
                acc * (std::f64::consts::PI / nt as f64) * (std::f64::consts::TAU / np as f64);
            let closed = in_scattered(&p, 1.0, [1.0, 0.0, gp, 0.0], view_mu as f32).x as f64;
            assert!(
                (numeric / closed - 1.0).abs() < 2e-3,
                "μ={view_mu}: {numeric} vs {closed}"
            );
        }
    }
}
