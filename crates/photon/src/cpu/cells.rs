//! Twin of `cells` in `shaders/photon_upsample.wgsl`: one coarse cell of the cache in physical units.

use super::*;

/// Cache quantities of one cell in physical units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellValue {
    pub sun: f32,
    pub sky: f32,
    pub g: f32,
    pub gamma: f32,
    pub has_sun: bool,
    /// Mean propagation vector Σ w d / Σ w of the cell's low-order sun light (orders below
    /// `lobe_split`; all orders without a split), zero without such light.
    pub dir: Vec3,
    pub has_lo: bool,
    /// Fluence of the high-order sun light (part of `sun`; 0 without a split).
    pub sun_hi: f32,
    /// Its mean propagation vector.
    pub dir_hi: Vec3,
}

/// Mean density over coarse cell `i` (4×4×4 stratified samples; `cell_mean_density` in the
/// shader): the divisor of density-weighted sums.
pub fn cell_mean_density(p: &VolumeParams, density: &[f32], i: usize) -> f32 {
    let r = p.i_res;
    let c = coords(i, r);
    let ires = Vec3::new(r[0] as f32, r[1] as f32, r[2] as f32);
    let ext = v3(p.aabb_max) - v3(p.aabb_min);
    let lo = v3(p.aabb_min) + Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) / ires * ext;
    let size = ext / ires;
    let mut s = 0.0f32;
    for k in 0..64u32 {
        let u = (Vec3::new((k % 4) as f32, ((k / 4) % 4) as f32, (k / 16) as f32)
            + Vec3::splat(0.5))
            * 0.25;
        s += density_at(p, density, lo + u * size);
    }
    s / 64.0
}

/// Coarse cell `i` of the ring total `total` (one invocation of `cells`).
pub fn cells(p: &VolumeParams, density: &[f32], total: &[u32], i: usize) -> CellValue {
    let b = i * CELL_WORDS;
    let w_sun = total[b] as f32;
    let w_sky = total[b + 1] as f32;
    let cw = Vec3::new(
        total[b + 2] as f32,
        total[b + 3] as f32,
        total[b + 4] as f32,
    );
    let ord = total[b + 5] as f32;
    let n = total[b + 6] as f32;
    let g = if w_sun > 0.0 {
        let all = 2.0 * cw / w_sun - Vec3::ONE;
        if p.lobe_axis != 0 {
            all.length().min(0.999)
        } else {
            all.dot(-v3(p.sun_dir)).clamp(-0.999, 0.999)
        }
    } else {
        0.0
    };
    // High orders (a subset of the sums) and the rest, in integers as the shader does.
    let hi_u = total[b + 7];
    let cw_hi_u = [total[b + 8], total[b + 9], total[b + 10]];
    let lo_u = total[b].wrapping_sub(hi_u);
    let cw_lo = Vec3::new(
        total[b + 2].wrapping_sub(cw_hi_u[0]) as f32,
        total[b + 3].wrapping_sub(cw_hi_u[1]) as f32,
        total[b + 4].wrapping_sub(cw_hi_u[2]) as f32,
    );
    let dir = if lo_u > 0 {
        2.0 * cw_lo / lo_u as f32 - Vec3::ONE
    } else {
        Vec3::ZERO
    };
    let dir_hi = if hi_u > 0 {
        2.0 * Vec3::new(cw_hi_u[0] as f32, cw_hi_u[1] as f32, cw_hi_u[2] as f32) / hi_u as f32
            - Vec3::ONE
    } else {
        Vec3::ZERO
    };
    let gamma = if n > 0.0 { ord / n } else { 0.0 };
    let scale = if p.density_weighted != 0 {
        let m = cell_mean_density(p, density, i) / p.d_max;
        if m > 0.0 { 1.0 / m } else { 0.0 }
    } else {
        1.0
    };
    // View mode 2: in-scattering towards the view point instead of the fluences.
    let (v_sun, v_sky) = if p.view_mode == 2 {
        (total[b + 11] as f32, total[b + 12] as f32)
    } else {
        (w_sun, w_sky)
    };
    CellValue {
        sun: v_sun * p.sun_norm * scale,
        sky: v_sky * p.sky_norm * scale,
        g,
        gamma,
        has_sun: w_sun > 0.0,
        dir,
        has_lo: lo_u > 0,
        sun_hi: hi_u as f32 * p.sun_norm * scale,
        dir_hi,
    }
}
