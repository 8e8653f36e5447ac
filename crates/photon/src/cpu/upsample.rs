//! Twin of `upsample` in `shaders/photon_upsample.wgsl`: physically based upsampling (Elek
//! 2012 §4.3) of the coarse cache to one fine voxel.
//!
//! ## The stable truncated exponential (Elek 2012 §4.3)
//! The paper's f_exp(d | λ, r) = max((f'(d) − f'(r)) / (1 − r f'(r)), 0) with
//! f'(d) = λ e^{−λd} / (1 − e^{−λr}) is 0/0 when λ → 0 or λr → 0, and λ = σ_s (D(p) − D(q))/2 is
//! negative whenever D(p) < D(q). With y = λr, u = d/r, v = 1 − u it simplifies exactly to
//!
//!   f_exp = (y / r) · expm1(y v) / (expm1(y) − y),
//!
//! which is positive for every y ≠ 0 and u < 1 (numerator and denominator share the sign of y)
//! and tends to the triangle filter 2(1 − u)/r as y → 0. Evaluation:
//! - |y| < 0.05: series (2/r) v (1 + yv/2 + y²v²/6) / (1 + y/3 + y²/12), error O(y³) < 10⁻⁴;
//! - y > 0: multiplied through by e^{−y} — (y/r) e^{−yu}(1 − e^{−yv}) / (1 − (1 + y) e^{−y}) —
//!   so large y cannot overflow;
//! - y < 0: the expm1 form directly (both exponentials are < 1);
//! - d ≥ r: 0.
//!
//! Each form integrates to one over [0, r] (tested numerically).

use super::*;

/// Stable truncated exponential filter (see the module docs).
pub fn f_exp(d: f32, lambda: f32, r: f32) -> f32 {
    if d >= r {
        return 0.0;
    }
    let y = lambda * r;
    let u = d / r;
    let v = 1.0 - u;
    if y.abs() < 0.05 {
        return 2.0 / r * v * (1.0 + y * v / 2.0 + y * y * v * v / 6.0)
            / (1.0 + y / 3.0 + y * y / 12.0);
    }
    if y > 0.0 {
        let num = (-y * u).exp() * (1.0 - (-y * v).exp());
        let den = 1.0 - (1.0 + y) * (-y).exp();
        return (y / r * num / den).max(0.0);
    }
    let num = (y * v).exp() - 1.0;
    let den = y.exp() - 1.0 - y;
    (y / r * num / den).max(0.0)
}

/// The paper's formula, written as printed (for tests away from its singularities).
pub fn f_exp_paper(d: f64, lambda: f64, r: f64) -> f64 {
    let fp = |x: f64| lambda * (-lambda * x).exp() / (1.0 - (-lambda * r).exp());
    (((fp(d) - fp(r)) / (1.0 - r * fp(r))).max(0.0)) * if d < r { 1.0 } else { 0.0 }
}

/// J at fine voxel `idx` (the upsampling of `photon_upsample.wgsl`).
pub fn upsample(p: &VolumeParams, density: &[f32], total: &[u32], idx: usize) -> [f32; 4] {
    if p.filtered == 0 {
        let cv = cells(p, density, total, idx);
        return [cv.sun, cv.sky, cv.g, cv.gamma];
    }
    if !near_density(p, density, idx) {
        return [0.0; 4];
    }
    let pos = voxel_centre(p, idx);
    let gp = interp(p, pos, p.i_res, |i| cells(p, density, total, i).gamma);
    let lng = p.g.abs().max(1e-30).ln();
    let (mut sw, mut s_sun, mut s_sky, mut swg, mut s_g) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for_each_neighbour(p, density, idx, |qi, wl| {
        let cv = cells(p, density, total, qi);
        sw += wl;
        s_sun += wl * cv.sun;
        s_sky += wl * cv.sky;
        if cv.has_sun {
            let wg = if p.g.abs() >= 1e-6 {
                ((gp - cv.gamma) * lng).clamp(-60.0, 60.0).exp()
            } else {
                1.0
            };
            swg += if p.upsample_g_extrapolate != 0 {
                wl
            } else {
                wg * wl
            };
            s_g += wg * wl * cv.g;
        }
    });
    let mut out = if sw > 0.0 {
        [s_sun / sw, s_sky / sw, 0.0, gp]
    } else {
        let f = interp(p, pos, p.i_res, |i| {
            let cv = cells(p, density, total, i);
            glam::Vec2::new(cv.sun, cv.sky)
        });
        [f.x, f.y, 0.0, gp]
    };
    if swg > 0.0 {
        out[2] = (s_g / swg).clamp(-0.999, 0.999);
    }
    out
}

/// The upsampled flux lobes at fine voxel `idx` (`j_dir`, `j_hi` of photon_upsample.wgsl):
/// [(low-order mean propagation vector, high-order fluence), (high-order vector, 0)], each
/// vector Σ w_L v(q) / Σ w_L over the neighbouring cells q with such light, w_L the
/// upsampling's energy weight (no penetration-depth weight: the flux is linear, its average
/// shortens where directions diverge).
pub fn upsample_dirs(p: &VolumeParams, density: &[f32], total: &[u32], idx: usize) -> [Vec4; 2] {
    if p.filtered == 0 {
        let cv = cells(p, density, total, idx);
        return [cv.dir.extend(cv.sun_hi), cv.dir_hi.extend(0.0)];
    }
    if !near_density(p, density, idx) {
        return [Vec4::ZERO; 2];
    }
    let (mut s_lo, mut sw_lo, mut s_hi, mut sw_hi) = (Vec3::ZERO, 0.0f32, Vec3::ZERO, 0.0f32);
    let (mut sw, mut s_fhi) = (0.0f32, 0.0f32);
    for_each_neighbour(p, density, idx, |qi, wl| {
        let cv = cells(p, density, total, qi);
        sw += wl;
        s_fhi += wl * cv.sun_hi;
        if cv.has_lo {
            s_lo += wl * cv.dir;
            sw_lo += wl;
        }
        if cv.sun_hi > 0.0 {
            s_hi += wl * cv.dir_hi;
            sw_hi += wl;
        }
    });
    let f_hi = if sw > 0.0 {
        s_fhi / sw
    } else {
        interp(p, voxel_centre(p, idx), p.i_res, |i| {
            cells(p, density, total, i).sun_hi
        })
    };
    let lo = if sw_lo > 0.0 {
        s_lo / sw_lo
    } else {
        Vec3::ZERO
    };
    let hi = if sw_hi > 0.0 {
        s_hi / sw_hi
    } else {
        Vec3::ZERO
    };
    [lo.extend(f_hi), hi.extend(0.0)]
}

/// Calls `f(cell index, w_L)` for each of the 3×3×3 coarse cells around fine voxel `idx` with
/// a positive energy weight, in the shader's loop order.
pub(crate) fn for_each_neighbour(
    p: &VolumeParams,
    density: &[f32],
    idx: usize,
    mut f: impl FnMut(usize, f32),
) {
    let ext = v3(p.aabb_max) - v3(p.aabb_min);
    let ires = Vec3::new(p.i_res[0] as f32, p.i_res[1] as f32, p.i_res[2] as f32);
    let pos = voxel_centre(p, idx);
    let dp = density[idx];
    let cell = ext / ires;
    let radius = 1.5 * cell.x.min(cell.y.min(cell.z));
    let uc = (pos - v3(p.aabb_min)) / ext * ires;
    let c = uc.floor().clamp(Vec3::ZERO, ires - Vec3::ONE);
    let c = [c.x as i32, c.y as i32, c.z as i32];
    let sigma_s = p.albedo * p.density_scale;
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                if (0..3).any(|a| q[a] < 0 || q[a] >= p.i_res[a] as i32) {
                    continue;
                }
                let qu = [q[0] as u32, q[1] as u32, q[2] as u32];
                let qc = v3(p.aabb_min)
                    + (Vec3::new(qu[0] as f32, qu[1] as f32, qu[2] as f32) + Vec3::splat(0.5))
                        / ires
                        * ext;
                let dq = density_at(p, density, qc);
                let lambda = if p.upsample_mean != 0 {
                    sigma_s * (dp + dq) * 0.5
                } else {
                    sigma_s * (dp - dq) * 0.5
                };
                let wl = f_exp((pos - qc).length(), lambda, radius)
                    * (1.0 - (dp - dq).abs() / p.d_max).max(0.0);
                if wl > 0.0 {
                    f(index(qu[0], qu[1], qu[2], p.i_res), wl);
                }
            }
        }
    }
}
