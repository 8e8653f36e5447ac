//! CPU reference implementations of the deterministic GPU stages — the upsampling filter
//! (`shaders/photon_upsample.wgsl`) and ray marching with HG reconstruction
//! (`shaders/photon_raymarch.wgsl`) — in the same f32 arithmetic, so tests can check GPU = CPU.
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

use glam::{Vec3, Vec4};
use nimbus_scene::phase::hg::eval_f32 as hg;

use nimbus_gpu::params::VolumeParams;

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

/// u32 words per cache cell (`CELL_WORDS` in photon_trace.wgsl and photon_upsample.wgsl):
/// Σw sun, Σw sky, Σw (d + 1)/2 (3), Σ order, deposit count, and Σw, Σw (d + 1)/2 (3) of the
/// high-order sun deposits.
pub use crate::cache_layout::CELL_WORDS;

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

pub fn cell_value(p: &VolumeParams, density: &[f32], total: &[u32], i: usize) -> CellValue {
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
    CellValue {
        sun: w_sun * p.sun_norm * scale,
        sky: w_sky * p.sky_norm * scale,
        g,
        gamma,
        has_sun: w_sun > 0.0,
        dir,
        has_lo: lo_u > 0,
        sun_hi: hi_u as f32 * p.sun_norm * scale,
        dir_hi,
    }
}

fn v3(a: [f32; 3]) -> Vec3 {
    Vec3::from_array(a)
}

/// Centre of density voxel `idx` in world space (the shaders' voxel position).
fn voxel_centre(p: &VolumeParams, idx: usize) -> Vec3 {
    let res = p.d_res;
    let v = coords(idx, res);
    let ext = v3(p.aabb_max) - v3(p.aabb_min);
    let resf = Vec3::new(res[0] as f32, res[1] as f32, res[2] as f32);
    v3(p.aabb_min)
        + (Vec3::new(v[0] as f32, v[1] as f32, v[2] as f32) + Vec3::splat(0.5)) / resf * ext
}

/// Grid coordinates of linear index `i` (x fastest), the inverse of [`index`].
fn coords(i: usize, res: [u32; 3]) -> [u32; 3] {
    let i = i as u32;
    [i % res[0], (i / res[0]) % res[1], i / (res[0] * res[1])]
}

fn index(x: u32, y: u32, z: u32, res: [u32; 3]) -> usize {
    ((z * res[1] + y) * res[0] + x) as usize
}

/// (i0, i1, fraction) of the cell-centred trilinear lookup at p in a grid of `res`.
fn trilinear(p: &VolumeParams, pos: Vec3, res: [u32; 3]) -> ([u32; 3], [u32; 3], Vec3) {
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

fn inside(p: &VolumeParams, x: Vec3) -> bool {
    x.cmpge(v3(p.aabb_min)).all() && x.cmple(v3(p.aabb_max)).all()
}

fn lerp<T>(a: T, b: T, t: f32) -> T
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
fn interp<T>(p: &VolumeParams, pos: Vec3, res: [u32; 3], f: impl Fn(usize) -> T) -> T
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

/// J at fine voxel `idx` (the upsampling of `photon_upsample.wgsl`).
pub fn upsample_voxel(p: &VolumeParams, density: &[f32], total: &[u32], idx: usize) -> [f32; 4] {
    if p.filtered == 0 {
        let cv = cell_value(p, density, total, idx);
        return [cv.sun, cv.sky, cv.g, cv.gamma];
    }
    let pos = voxel_centre(p, idx);
    let gp = interp(p, pos, p.i_res, |i| cell_value(p, density, total, i).gamma);
    let lng = p.g.abs().max(1e-30).ln();
    let (mut sw, mut s_sun, mut s_sky, mut swg, mut s_g) = (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0.0f32);
    for_each_neighbour(p, density, idx, |qi, wl| {
        let cv = cell_value(p, density, total, qi);
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
            let cv = cell_value(p, density, total, i);
            glam::Vec2::new(cv.sun, cv.sky)
        });
        [f.x, f.y, 0.0, gp]
    };
    if swg > 0.0 {
        out[2] = (s_g / swg).clamp(-0.999, 0.999);
    }
    out
}

/// `interp` over the per-voxel flux entries (`interp_dir` in photon_raymarch.wgsl).
fn interp_dir(p: &VolumeParams, j_dirs: &[[Vec4; 2]], pos: Vec3, hi: bool) -> Vec4 {
    interp(p, pos, p.d_res, |i| j_dirs[i][hi as usize])
}

/// HG(· | g·|v|) for the lobe v (axis × g') towards the camera (−d) (`lobe_phase`).
fn lobe_phase(p: &VolumeParams, v: Vec3, d: Vec3) -> f32 {
    let gl = v.length();
    let mu = if gl > 1e-6 { (-d).dot(v / gl) } else { 0.0 };
    hg(p.g * gl.min(0.999), mu)
}

/// Sun fluence times the phase of its lobes towards the camera (`sun_in_scatter` in
/// photon_raymarch.wgsl): one lobe along the sun with J's g' (the paper), or per-voxel flux
/// lobes — one for all orders, or low and high orders apart (`p.lobe_split`).
pub fn sun_in_scatter(p: &VolumeParams, j_dirs: &[[Vec4; 2]], pos: Vec3, j: Vec4, d: Vec3) -> f32 {
    if p.lobe_axis == 0 {
        return j.x * lobe_phase(p, -v3(p.sun_dir) * j.z, d);
    }
    let lo = interp_dir(p, j_dirs, pos, false);
    if p.lobe_split == 0 {
        return j.x * lobe_phase(p, lo.truncate(), d);
    }
    let hi = interp_dir(p, j_dirs, pos, true);
    let f_hi = lo.w.clamp(0.0, j.x);
    (j.x - f_hi) * lobe_phase(p, lo.truncate(), d) + f_hi * lobe_phase(p, hi.truncate(), d)
}

/// The upsampled flux lobes at fine voxel `idx` (`j_dir`, `j_hi` of photon_upsample.wgsl):
/// [(low-order mean propagation vector, high-order fluence), (high-order vector, 0)], each
/// vector Σ w_L v(q) / Σ w_L over the neighbouring cells q with such light, w_L the
/// upsampling's energy weight (no penetration-depth weight: the flux is linear, its average
/// shortens where directions diverge).
pub fn upsample_dir_voxel(
    p: &VolumeParams,
    density: &[f32],
    total: &[u32],
    idx: usize,
) -> [Vec4; 2] {
    if p.filtered == 0 {
        let cv = cell_value(p, density, total, idx);
        return [cv.dir.extend(cv.sun_hi), cv.dir_hi.extend(0.0)];
    }
    let (mut s_lo, mut sw_lo, mut s_hi, mut sw_hi) = (Vec3::ZERO, 0.0f32, Vec3::ZERO, 0.0f32);
    let (mut sw, mut s_fhi) = (0.0f32, 0.0f32);
    for_each_neighbour(p, density, idx, |qi, wl| {
        let cv = cell_value(p, density, total, qi);
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
            cell_value(p, density, total, i).sun_hi
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
fn for_each_neighbour(
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

/// Henyey–Greenstein reconstruction of the in-scattered radiance (Elek Appendix C): the
/// incident lobe HG(g') convolved with the medium's HG(g) is HG(g g'); `mu` is the cosine
/// between the lobe's axis and the direction towards the camera.
pub fn in_scattered(p: &VolumeParams, dens: f32, j: [f32; 4], mu: f32) -> Vec3 {
    p.albedo
        * p.density_scale
        * dens
        * (v3(p.sun_irradiance) * (j[0] * hg(p.g * j[2], mu))
            + v3(p.sky_radiance) * (j[1] / (4.0 * std::f32::consts::PI)))
}

/// Exact first-order sun light at density `dens` with sun transmittance `t_sun`:
/// σ_s E_sun T_sun p_HG(μ | g).
pub fn single_scattered(p: &VolumeParams, dens: f32, t_sun: f32, mu: f32) -> Vec3 {
    p.albedo * p.density_scale * dens * v3(p.sun_irradiance) * (t_sun * hg(p.g, mu))
}

fn pcg_hash(v: u32) -> u32 {
    let state = v.wrapping_mul(747796405).wrapping_add(2891336453);
    let word = ((state >> ((state >> 28) + 4)) ^ state).wrapping_mul(277803737);
    (word >> 22) ^ word
}

fn box_intersect(p: &VolumeParams, o: Vec3, d: Vec3) -> (f32, f32) {
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

fn lattice(c: [i32; 3]) -> Vec3 {
    let h = pcg_hash(c[0] as u32 ^ pcg_hash(c[1] as u32 ^ pcg_hash(c[2] as u32)));
    let h2 = pcg_hash(h);
    let h3 = pcg_hash(h2);
    Vec3::new((h >> 8) as f32, (h2 >> 8) as f32, (h3 >> 8) as f32) * (2.0 / 16777216.0) - Vec3::ONE
}

fn value_noise(q: Vec3) -> Vec3 {
    let b = q.floor();
    let f = q - b;
    let s = f * f * (Vec3::splat(3.0) - 2.0 * f);
    let c = [b.x as i32, b.y as i32, b.z as i32];
    let l = |dx: i32, dy: i32, dz: i32| lattice([c[0] + dx, c[1] + dy, c[2] + dz]);
    let x00 = lerp(l(0, 0, 0), l(1, 0, 0), s.x);
    let x10 = lerp(l(0, 1, 0), l(1, 1, 0), s.x);
    let x01 = lerp(l(0, 0, 1), l(1, 0, 1), s.x);
    let x11 = lerp(l(0, 1, 1), l(1, 1, 1), s.x);
    lerp(lerp(x00, x10, s.y), lerp(x01, x11, s.y), s.z)
}

/// Three-octave vector-noise displacement of a lookup position (Elek §4.4).
pub fn perturb(p: &VolumeParams, x: Vec3) -> Vec3 {
    if p.noise_amplitude <= 0.0 {
        return x;
    }
    let q = x * p.noise_frequency;
    let n = value_noise(q) + 0.5 * value_noise(2.0 * q) + 0.25 * value_noise(4.0 * q);
    x + p.noise_amplitude * n
}

/// One pixel of `photon_raymarch.wgsl`.
/// Sun transmittance at density voxel `idx` (the pass of `photon_sun.wgsl`): midpoint rule
/// with half the smallest voxel as step from the voxel centre to the box boundary.
pub fn sun_transmittance_voxel(p: &VolumeParams, density: &[f32], idx: usize) -> f32 {
    let r = p.d_res;
    let ext = v3(p.aabb_max) - v3(p.aabb_min);
    let resf = Vec3::new(r[0] as f32, r[1] as f32, r[2] as f32);
    let x = voxel_centre(p, idx);
    let sun = v3(p.sun_dir);
    let (_, t1) = box_intersect(p, x, sun);
    let cell = ext / resf;
    let h = 0.5 * cell.x.min(cell.y.min(cell.z));
    let len = t1.max(0.0);
    let n = (len / h).ceil().max(1.0);
    let dt = len / n;
    let tau: f32 = (0..n as u32)
        .map(|i| density_at(p, density, x + sun * ((i as f32 + 0.5) * dt)))
        .sum();
    (-p.density_scale * tau * dt).exp()
}

/// The colour of pixel (x, y) (the pass of `photon_raymarch.wgsl`); `t_sun` is the
/// sun-transmittance volume (read when `p.single_scatter` is set), `j_dirs` the upsampled flux
/// lobes (read when `p.lobe_axis` is set).
pub fn raymarch_pixel(
    p: &VolumeParams,
    density: &[f32],
    j: &[[f32; 4]],
    t_sun: &[f32],
    j_dirs: &[[Vec4; 2]],
    x: u32,
    y: u32,
) -> Vec3 {
    let px = (x as f32 + 0.5) / p.width as f32 * 2.0 - 1.0;
    let py = 1.0 - (y as f32 + 0.5) / p.height as f32 * 2.0;
    let d = (v3(p.cam_forward)
        + v3(p.cam_right) * (px * p.tan_half * p.aspect)
        + v3(p.cam_up) * (py * p.tan_half))
        .normalize();
    let mut l = Vec3::ZERO;
    let mut tr = 1.0f32;
    let o = v3(p.cam_origin);
    let (t0, t1) = box_intersect(p, o, d);
    if t0 <= t1 {
        let offset = (pcg_hash(y * p.width + x) >> 8) as f32 * (1.0 / 16777216.0);
        let mut t = t0 + offset * p.step;
        let mu = d.dot(v3(p.sun_dir));
        while t < t1 && tr >= p.early_exit {
            let dt = p.step.min(t1 - t);
            let xp = perturb(p, o + d * (t + 0.5 * dt));
            let dens = density_at(p, density, xp);
            let sigma_t = p.density_scale * dens;
            if sigma_t > 0.0 {
                let jv = interp(p, xp, p.d_res, |i| glam::Vec4::from_array(j[i]));
                let mut ls = p.albedo
                    * p.density_scale
                    * dens
                    * (v3(p.sun_irradiance) * sun_in_scatter(p, j_dirs, xp, jv, d)
                        + v3(p.sky_radiance) * (jv.y / (4.0 * std::f32::consts::PI)));
                if p.single_scatter != 0 {
                    let ts = interp(p, xp, p.d_res, |i| t_sun[i]);
                    ls += single_scattered(p, dens, ts, mu);
                }
                let ts = (-sigma_t * dt).exp();
                l += tr * ls * (1.0 - ts) / sigma_t;
                tr *= ts;
            }
            t += dt;
        }
    }
    if tr >= p.early_exit {
        let mut bg = v3(p.sky_radiance);
        if p.sun_disc_radiance > 0.0 && d.dot(v3(p.sun_dir)) >= p.sun_cos_max {
            bg += v3(p.sun_irradiance) * p.sun_disc_radiance;
        }
        l += tr * bg;
    }
    l
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
