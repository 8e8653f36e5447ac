//! The hierarchical stencil descriptor of Kallweit 2017 §4.2 — CPU reference implementation.
//! `shaders/rpnn_descriptor.wgsl` computes the same numbers on the GPU (test: agreement to
//! 10⁻⁵ relative).
//!
//! ## Layout (the contract with `training/`)
//! One descriptor is [`DESCRIPTOR_LEN`] = 2 251 f32, **level-major**:
//! `z[(k − 1) · 225 + p]` is ρ at point p of stencil level k = 1 … 10, and `z[2250]` is
//! γ = acos(ω · ω_l) in radians (computed as atan2(|ω × ω_l|, ω · ω_l)). Point p = ix + 5 iy + 25 iz (ix, iy ∈ 0..5, iz ∈ 0..9) sits at
//! local coordinates (−1 + ix/2, −1 + iy/2, −1 + iz/2) · 2^(k−1) mean free paths, i.e. the 5×5×9
//! grid spanning [−1, −1, −1] … [1, 1, 3], scaled per level.
//!
//! ## Frame
//! z points towards the light (ω_l); x = normalize(z × ω) is perpendicular to the plane of z and
//! the view direction ω; y = z × x. When ω ∥ ω_l (|z × ω| < 10⁻⁶, including ω = ±ω_l) the
//! x-axis is the deterministic perpendicular of `nimbus_scene::frame::orthonormal_basis(z)`.
//!
//! ## Conventions
//! ω is the direction of the camera ray (from the eye into the cloud), as in the path tracer;
//! γ = 0 therefore means looking straight towards the light (back-lit, forward scattering).
//! ρ = σ_t / σ̄ with σ̄ the mean σ_t of the non-zero voxels, and distances in mean free paths
//! 1/σ̄ (Kallweit §4.2). Stencil level k reads pyramid level [`Pyramid::level_for`]`(k)`.

use glam::Vec3;

use crate::pyramid::Pyramid;

/// Stencil levels, points per level (5 × 5 × 9) and descriptor length: one definition shared
/// with `shaders/rpnn_descriptor.wgsl` (`nimbus_gpu::consts`).
pub const LEVELS: usize = nimbus_gpu::consts::STENCIL_LEVELS as usize;
pub const POINTS: usize = nimbus_gpu::consts::STENCIL_POINTS as usize;
pub const DESCRIPTOR_LEN: usize = nimbus_gpu::consts::DESCRIPTOR_LEN as usize;

/// Local stencil coordinates (unscaled, in mean free paths) of point `p`.
pub fn stencil_point(p: usize) -> Vec3 {
    let (ix, iy, iz) = (p % 5, (p / 5) % 5, p / 25);
    Vec3::new(
        -1.0 + ix as f32 * 0.5,
        -1.0 + iy as f32 * 0.5,
        -1.0 + iz as f32 * 0.5,
    )
}

/// The local frame (x, y, z) for view direction `view` and direction to the light `to_light`.
pub fn frame(view: Vec3, to_light: Vec3) -> (Vec3, Vec3, Vec3) {
    let z = to_light.normalize();
    let c = z.cross(view.normalize());
    let x = if c.length() < 1e-6 {
        let (t, _) = nimbus_scene::frame::orthonormal_basis(z.as_dvec3());
        t.as_vec3().normalize()
    } else {
        c.normalize()
    };
    (x, z.cross(x), z)
}

/// Writes the descriptor of the shading configuration (x, ω, ω_l) into `out`
/// (len [`DESCRIPTOR_LEN`]).
pub fn descriptor(pyr: &Pyramid, x: Vec3, view: Vec3, to_light: Vec3, out: &mut [f32]) {
    descriptor_scaled(pyr, x, view, to_light, 1.0, out)
}

/// [`descriptor`] with the stencil scaled by `s` (every level's points `s` times as far apart,
/// read from the pyramid level [`Pyramid::level_for_scaled`] picks); `s` = 1 is the paper's
/// stencil, bit for bit. For experiments with the descriptor's scale
/// (`training/experiments/stencil_ab.py`). With `s` < 1 the stencil reads finer levels than
/// [`Pyramid::new`] stores: use [`Pyramid::with_every_level`] (a missing level panics).
pub fn descriptor_scaled(
    pyr: &Pyramid,
    x: Vec3,
    view: Vec3,
    to_light: Vec3,
    s: f32,
    out: &mut [f32],
) {
    assert_eq!(out.len(), DESCRIPTOR_LEN);
    let (ex, ey, ez) = frame(view, to_light);
    let mfp = (1.0 / pyr.mean_sigma) as f32;
    for k in 1..=LEVELS {
        let level = pyr.level_for_scaled(k as u32, s as f64);
        assert!(
            s == 1.0 || pyr.levels[level].is_stored(),
            "stencil scale {s}: pyramid level {level} is not stored (Pyramid::with_every_level)"
        );
        let scale = (1u32 << (k - 1)) as f32 * mfp * s;
        // Point p at x + (ex·sx + ey·sy + ez·sz) · scale, (sx, sy, sz) = stencil_point(p).
        pyr.sampler(level).stencil_into(
            x,
            [ex, ey, ez],
            scale,
            &mut out[(k - 1) * POINTS..k * POINTS],
        );
    }
    // γ = angle between ω and ω_l, as atan2(|ω × ω_l|, ω · ω_l): accurate near 0 and π, where
    // acos loses digits (and GPU acos approximations differ).
    let (v, l) = (view.normalize(), to_light.normalize());
    out[LEVELS * POINTS] = v.cross(l).length().atan2(v.dot(l));
}

/// Descriptors of many configurations (rows of [`DESCRIPTOR_LEN`]), in parallel.
pub fn descriptors(pyr: &Pyramid, configs: &[Config]) -> Vec<f32> {
    let mut out = Vec::new();
    descriptors_into(pyr, configs, &mut out);
    out
}

/// [`descriptors`] into `out` (resized to fit; every value overwritten), for a caller that
/// keeps one buffer across batches: a fresh one of megabytes is fresh pages for the kernel to
/// zero every time. (The ONNX Runtime renderer writes rows piece by piece into buffers of its
/// own: `ort_backend::OrtModel::predict_rows`.)
pub fn descriptors_into(pyr: &Pyramid, configs: &[Config], out: &mut Vec<f32>) {
    use rayon::prelude::*;
    out.resize(configs.len() * DESCRIPTOR_LEN, 0.0);
    out.par_chunks_mut(DESCRIPTOR_LEN)
        .zip(configs)
        .for_each(|(row, c)| descriptor(pyr, c.x, c.view, c.to_light, row));
}

/// A shading configuration: position, view (camera-ray) direction, direction to the light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Config {
    pub x: Vec3,
    pub view: Vec3,
    pub to_light: Vec3,
}
