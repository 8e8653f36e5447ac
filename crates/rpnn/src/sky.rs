//! The whole sky in one network query (Kallweit 2017 §7 names it as future work): real
//! spherical harmonics up to degree [`SH_DEGREE`], the sky's projection onto them, and their
//! rotation into the descriptor's frame.
//!
//! The indirect radiance due to a sky of radiance L(ω') is linear in L:
//! L_i^sky(x, ω) = ∫ T(x, ω, ω') L(ω') dω', where T is the radiance per unit radiance arriving
//! from direction ω' after at least one scattering beyond x. Expanded in real spherical
//! harmonics in the descriptor's frame (`crate::descriptor::frame`: z towards the light,
//! x ⟂ the view), T(ω') ≈ Σ t_lm Y_lm(ω'_local), and L_i^sky = Σ t_lm L_lm, the coefficients of
//! the sky rotated into that frame. The network's sky head predicts t_lm from the same
//! descriptor as the sun's (so one query gives both), the renderer projects the sky once and
//! rotates it per shading point. The product is exact for the sky's band-limited part: what a
//! degree keeps of real skies is measured by [`kept_energy`].
//!
//! Convention: a sky direction ω' is the direction a path leaves along (the sky radiance seen
//! looking along it, as `nimbus_scene::Sky` returns it), in the world, or in the descriptor's
//! frame as (ω'·x, ω'·y, ω'·z).

use std::sync::OnceLock;

use glam::DVec3;

/// Highest spherical-harmonic degree of the sky transfer.
pub const SH_DEGREE: usize = 4;
/// Coefficients up to [`SH_DEGREE`]: (L + 1)².
pub const SH_COEFFS: usize = (SH_DEGREE + 1) * (SH_DEGREE + 1);

/// Coefficients up to degree `l`.
pub const fn coeffs(l: usize) -> usize {
    (l + 1) * (l + 1)
}

/// The real, orthonormal spherical harmonics Y_lm of degree ≤ 4 at the unit vector `d`, in the
/// order (l, m) = (0, 0), (1, −1), (1, 0), (1, 1), (2, −2), … (index l² + l + m).
pub fn eval(d: DVec3) -> [f64; SH_COEFFS] {
    let (x, y, z) = (d.x, d.y, d.z);
    let (x2, y2, z2) = (x * x, y * y, z * z);
    [
        0.282_094_791_773_878_1,
        0.488_602_511_902_919_9 * y,
        0.488_602_511_902_919_9 * z,
        0.488_602_511_902_919_9 * x,
        1.092_548_430_592_079 * x * y,
        1.092_548_430_592_079 * y * z,
        0.315_391_565_252_520_05 * (3.0 * z2 - 1.0),
        1.092_548_430_592_079 * x * z,
        0.546_274_215_296_039_5 * (x2 - y2),
        0.590_043_589_926_643_5 * y * (3.0 * x2 - y2),
        2.890_611_442_640_554 * x * y * z,
        0.457_045_799_464_465_8 * y * (5.0 * z2 - 1.0),
        0.373_176_332_590_115_4 * z * (5.0 * z2 - 3.0),
        0.457_045_799_464_465_8 * x * (5.0 * z2 - 1.0),
        1.445_305_721_320_277 * z * (x2 - y2),
        0.590_043_589_926_643_5 * x * (x2 - 3.0 * y2),
        2.503_342_941_796_704_5 * x * y * (x2 - y2),
        1.770_130_769_779_930_5 * y * z * (3.0 * x2 - y2),
        0.946_174_695_757_560_1 * x * y * (7.0 * z2 - 1.0),
        0.669_046_543_557_289_2 * y * z * (7.0 * z2 - 3.0),
        0.105_785_546_915_204_22 * (35.0 * z2 * z2 - 30.0 * z2 + 3.0),
        0.669_046_543_557_289_2 * x * z * (7.0 * z2 - 3.0),
        0.473_087_347_878_780 * (x2 - y2) * (7.0 * z2 - 1.0),
        1.770_130_769_779_930_5 * x * z * (x2 - 3.0 * y2),
        0.625_835_735_449_176_1 * (x2 * (x2 - 3.0 * y2) - y2 * (3.0 * x2 - y2)),
    ]
}

/// Directions for band l's rotation (any 2l + 1 in general position; these are a Fibonacci
/// set) and the inverse of the band's values there, B⁻¹ with B_im = Y_lm(n_i).
struct Band {
    dirs: Vec<DVec3>,
    inv: Vec<f64>,
}

fn bands() -> &'static [Band] {
    static BANDS: OnceLock<Vec<Band>> = OnceLock::new();
    BANDS.get_or_init(|| {
        (0..=SH_DEGREE)
            .map(|l| {
                let n = 2 * l + 1;
                // Fibonacci points, offset per band so no two bands share a set.
                let dirs: Vec<DVec3> = (0..n)
                    .map(|i| {
                        let t = (i as f64 + 0.37 + 0.11 * l as f64) / n as f64;
                        let z = 1.0 - 2.0 * t;
                        let r = (1.0 - z * z).max(0.0).sqrt();
                        let phi = std::f64::consts::PI * (3.0 - 5f64.sqrt()) * i as f64 + 0.3;
                        DVec3::new(r * phi.cos(), r * phi.sin(), z)
                    })
                    .collect();
                let mut b = vec![0.0; n * n];
                for (i, d) in dirs.iter().enumerate() {
                    let y = eval(*d);
                    b[i * n..(i + 1) * n].copy_from_slice(&y[l * l..l * l + n]);
                }
                let inv =
                    invert(&b, n).expect("the band's sample directions are in general position");
                Band { dirs, inv }
            })
            .collect()
    })
}

/// The inverse of the n×n row-major matrix `a` (Gauss–Jordan, partial pivoting); `None` when
/// singular.
fn invert(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut m = a.to_vec();
    let mut inv = vec![0.0; n * n];
    for i in 0..n {
        inv[i * n + i] = 1.0;
    }
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| m[i * n + c].abs().total_cmp(&m[j * n + c].abs()))?;
        if m[p * n + c].abs() < 1e-12 {
            return None;
        }
        for k in 0..n {
            m.swap(c * n + k, p * n + k);
            inv.swap(c * n + k, p * n + k);
        }
        let s = 1.0 / m[c * n + c];
        for k in 0..n {
            m[c * n + k] *= s;
            inv[c * n + k] *= s;
        }
        for r in 0..n {
            if r != c {
                let f = m[r * n + c];
                if f != 0.0 {
                    for k in 0..n {
                        m[r * n + k] -= f * m[c * n + k];
                        inv[r * n + k] -= f * inv[c * n + k];
                    }
                }
            }
        }
    }
    Some(inv)
}

/// The rotation of coefficients into a frame, band by band (see [`rotate_to_frame`]).
pub struct Rotation {
    /// Per band l, D (row-major, (2l + 1)²).
    d: Vec<Vec<f64>>,
}

impl Rotation {
    /// For the frame with columns `ex`, `ey`, `ez` (local → world): coefficients of
    /// f_local(ω) = f(M ω) are D c.
    pub fn new((ex, ey, ez): (DVec3, DVec3, DVec3)) -> Self {
        let d = bands()
            .iter()
            .enumerate()
            .map(|(l, band)| {
                let n = 2 * l + 1;
                let o = l * l;
                let mut a = vec![0.0; n * n];
                for (i, d) in band.dirs.iter().enumerate() {
                    let w = ex * d.x + ey * d.y + ez * d.z;
                    a[i * n..(i + 1) * n].copy_from_slice(&eval(w)[o..o + n]);
                }
                let mut dm = vec![0.0; n * n];
                for m in 0..n {
                    for mp in 0..n {
                        dm[m * n + mp] = (0..n).map(|i| band.inv[m * n + i] * a[i * n + mp]).sum();
                    }
                }
                dm
            })
            .collect();
        Self { d }
    }

    /// D c for one channel of coefficients (any length up to [`SH_COEFFS`]: whole bands).
    pub fn apply(&self, c: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; c.len()];
        for (l, dm) in self.d.iter().enumerate() {
            let (n, o) = (2 * l + 1, l * l);
            if o + n > c.len() {
                break;
            }
            for m in 0..n {
                out[o + m] = (0..n).map(|mp| dm[m * n + mp] * c[o + mp]).sum();
            }
        }
        out
    }
}

/// The inverse frame's columns: for `frame` local → world, the frame world → local (an
/// orthonormal frame's transpose), so [`Rotation::new`] of it takes coefficients given in
/// `frame` back to the world.
pub fn transposed((ex, ey, ez): (DVec3, DVec3, DVec3)) -> (DVec3, DVec3, DVec3) {
    (
        DVec3::new(ex.x, ey.x, ez.x),
        DVec3::new(ex.y, ey.y, ez.y),
        DVec3::new(ex.z, ey.z, ez.z),
    )
}

/// Coefficients of f_local(ω) = f(M ω) from those of f (world), M the frame with columns
/// `ex`, `ey`, `ez` (local → world): band by band, c_local = D c with D = B⁻¹ A,
/// A_im = Y_lm(M n_i).
pub fn rotate_to_frame(
    c: &[[f64; 3]; SH_COEFFS],
    (ex, ey, ez): (DVec3, DVec3, DVec3),
) -> [[f64; 3]; SH_COEFFS] {
    let mut out = [[0.0; 3]; SH_COEFFS];
    for (l, band) in bands().iter().enumerate() {
        let n = 2 * l + 1;
        let o = l * l;
        // A: the band at the rotated sample directions.
        let mut a = vec![0.0; n * n];
        for (i, d) in band.dirs.iter().enumerate() {
            let w = ex * d.x + ey * d.y + ez * d.z;
            a[i * n..(i + 1) * n].copy_from_slice(&eval(w)[o..o + n]);
        }
        for m in 0..n {
            for mp in 0..n {
                // D_{m m'} = Σ_i B⁻¹_{m i} A_{i m'}.
                let d: f64 = (0..n).map(|i| band.inv[m * n + i] * a[i * n + mp]).sum();
                for ch in 0..3 {
                    out[o + m][ch] += d * c[o + mp][ch];
                }
            }
        }
    }
    out
}

/// Σ t_lm c'_lm up to degree `l`, c' the world coefficients `c` rotated into the frame with
/// columns `ex`, `ey`, `ez`, without forming the rotation: band by band
/// t_l · (B⁻¹ A c_l) = (B⁻ᵀ t_l) · (A c_l), and (A c_l)_i = Σ_m c_lm Y_lm(M n_i) is band l of
/// the sky seen along the rotated sample direction M n_i. The whole-sample GPU renderer
/// (`shaders/lib/rpnn_sample_core.wgsl`, `sky_product`) computes this, with [`gpu_table`]; this
/// is its CPU twin, equal to [`rotate_to_frame`] followed by [`apply`].
pub fn product_in_frame(
    t: &[f32],
    c: &[[f64; 3]; SH_COEFFS],
    (ex, ey, ez): (DVec3, DVec3, DVec3),
    l: usize,
) -> DVec3 {
    let mut out = DVec3::ZERO;
    for (band_l, band) in bands().iter().enumerate().take(l.min(SH_DEGREE) + 1) {
        let n = 2 * band_l + 1;
        let o = band_l * band_l;
        for (i, d) in band.dirs.iter().enumerate() {
            let u: f64 = (0..n).map(|m| band.inv[m * n + i] * t[o + m] as f64).sum();
            let y = eval(ex * d.x + ey * d.y + ez * d.z);
            let mut s = DVec3::ZERO;
            for m in 0..n {
                s += DVec3::from_array(c[o + m]) * y[o + m];
            }
            out += u * s;
        }
    }
    out
}

/// The sky for the GPU's contraction ([`product_in_frame`]): 75 floats of the world
/// coefficients (RGB per coefficient), 75 of the bands' sample directions (xyz, band l's at
/// l² …), then each band's B⁻¹ row-major (offsets 0, 1, 10, 35, 84; 165 floats).
pub fn gpu_table(c: &[[f64; 3]; SH_COEFFS]) -> Vec<f32> {
    let mut out: Vec<f32> = c.iter().flatten().map(|&v| v as f32).collect();
    for band in bands() {
        for d in &band.dirs {
            out.extend([d.x as f32, d.y as f32, d.z as f32]);
        }
    }
    for band in bands() {
        out.extend(band.inv.iter().map(|&v| v as f32));
    }
    out
}

/// Gauss–Legendre nodes and weights on [−1, 1] (Newton's iteration on P_n).
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (0..n)
        .map(|i| {
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-15 {
                    break;
                }
            }
            (x, 2.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

/// The quadrature of [`project`] and [`kept_energy`]: `n` Gauss–Legendre nodes in cos θ from
/// the world's +y (the sky's zenith) times 2`n` equal steps in φ, with their solid angles —
/// exact for any function of degree < 2`n` (a constant sky to rounding).
fn quadrature(n: usize) -> Vec<(DVec3, f64)> {
    let n = n.max(2);
    let np = 2 * n;
    let dp = std::f64::consts::TAU / np as f64;
    let mut out = Vec::with_capacity(n * np);
    for (mu, w) in gauss_legendre(n) {
        let s = (1.0 - mu * mu).max(0.0).sqrt();
        for k in 0..np {
            let p = (k as f64 + 0.5) * dp;
            out.push((DVec3::new(s * p.cos(), mu, s * p.sin()), w * dp));
        }
    }
    out
}

/// The sky's coefficients (per RGB channel) by the quadrature of `quadrature(n)`: exact for
/// skies of degree < 2`n`; for others its error falls with `n`.
pub fn project(radiance: impl Fn(DVec3) -> DVec3, n: usize) -> [[f64; 3]; SH_COEFFS] {
    let mut c = [[0.0; 3]; SH_COEFFS];
    for (d, w) in quadrature(n) {
        let l = radiance(d);
        for (cj, yj) in c.iter_mut().zip(eval(d)) {
            for ch in 0..3 {
                cj[ch] += w * l[ch] * yj;
            }
        }
    }
    c
}

/// Texels (or parts of texels) per axis below which [`project_env`] splits each texel. The
/// midpoint rule over a part 1/256 of the way round (1.4°) integrates a spherical harmonic of
/// degree ≤ 4 across it with a relative error of about (4 Δ)²/24 ≈ 4·10⁻⁴.
const ENV_PARTS: [usize; 2] = [256, 128];

/// The solid angle of one cell of a lat-long map `columns` wide that spans v0 … v1 in the
/// map's v ∈ [0, 1] (θ = π v from the zenith): 2π / columns · (cos θ₀ − cos θ₁).
pub fn latlong_cell_solid_angle(columns: usize, v0: f64, v1: f64) -> f64 {
    let pi = std::f64::consts::PI;
    std::f64::consts::TAU / columns as f64 * ((v0 * pi).cos() - (v1 * pi).cos())
}

/// The coefficients (per RGB channel) of a lat-long environment map, as the renderers read it:
/// constant over each texel (`EnvMap::radiance` is a nearest-texel lookup). Every texel counts
/// with its solid angle Δφ (cos θ₀ − cos θ₁), split so that there are at least 256 × 128
/// parts over the sphere (`ENV_PARTS`), so a bright texel the size of the sun's disc weighs
/// what it holds:
/// c₀₀ is Y₀₀ ∫ L dω to rounding, whatever the map. A point quadrature ([`project`]) would
/// miss such a texel or count it many times over.
pub fn project_env(env: &nimbus_scene::EnvMap) -> [[f64; 3]; SH_COEFFS] {
    use rayon::prelude::*;
    let img = env.image();
    let (w, h) = (img.width, img.height);
    let sub = [
        ENV_PARTS[0].div_ceil(w).max(1),
        ENV_PARTS[1].div_ceil(h).max(1),
    ];
    let (nu, nv) = (w * sub[0], h * sub[1]);
    let scale = env.scale();
    // One row of parts at a time (θ fixed within it): the sum over its parts.
    let rows: Vec<[[f64; 3]; SH_COEFFS]> = (0..nv)
        .into_par_iter()
        .map(|j| {
            let (v0, v1) = (j as f64 / nv as f64, (j + 1) as f64 / nv as f64);
            let omega = latlong_cell_solid_angle(nu, v0, v1);
            let vc = (v0 + v1) / 2.0;
            let y = j / sub[1];
            let mut c = [[0.0; 3]; SH_COEFFS];
            for i in 0..nu {
                let p = img.get(i / sub[0], y);
                if p == [0.0; 3] {
                    continue;
                }
                let d = nimbus_scene::EnvMap::dir_of((i as f64 + 0.5) / nu as f64, vc);
                let l = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) * (scale * omega);
                for (cj, yj) in c.iter_mut().zip(eval(d)) {
                    for ch in 0..3 {
                        cj[ch] += l[ch] * yj;
                    }
                }
            }
            c
        })
        .collect();
    let mut c = [[0.0; 3]; SH_COEFFS];
    for r in rows {
        for (cj, rj) in c.iter_mut().zip(r) {
            for ch in 0..3 {
                cj[ch] += rj[ch];
            }
        }
    }
    c
}

/// Share of the sky's energy ∫ |L|² dω that degrees ≤ `l` hold: Σ |c_lm|² over them against
/// the quadrature of |L|² itself (Parseval).
pub fn kept_energy(radiance: impl Fn(DVec3) -> DVec3 + Copy, l: usize, n: usize) -> f64 {
    let c = project(radiance, n);
    let total: f64 = quadrature(n)
        .into_iter()
        .map(|(d, w)| w * radiance(d).length_squared())
        .sum();
    let kept: f64 = c[..coeffs(l)]
        .iter()
        .map(|v| v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        .sum();
    if total > 0.0 { kept / total } else { 1.0 }
}

/// Σ t_lm c_lm per channel for the first `coeffs(l)` coefficients: the indirect radiance the
/// transfer `t` gives under the sky `c` (both in the same frame).
pub fn apply(t: &[f32], c: &[[f64; 3]; SH_COEFFS], l: usize) -> DVec3 {
    let mut out = DVec3::ZERO;
    for (tj, cj) in t.iter().zip(c).take(coeffs(l)) {
        out += DVec3::from_array(*cj) * *tj as f64;
    }
    out
}

/// A clear-sky model for tests and evaluation (not a physical atmosphere): a zenith-to-horizon
/// colour gradient whose strength grows with `turbidity` (1 clear … 10 hazy), a ground below the
/// horizon (`ground` radiance), and a glow around the sun at elevation `sun_elevation_deg` and
/// azimuth `sun_azimuth_deg` (y up; azimuth about +y from +z towards +x).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkyModel {
    pub sun_elevation_deg: f64,
    pub sun_azimuth_deg: f64,
    pub turbidity: f64,
    pub zenith: DVec3,
    pub ground: DVec3,
}

impl SkyModel {
    /// The sun's direction (unit, towards the sun).
    pub fn sun_dir(&self) -> DVec3 {
        let (e, a) = (
            self.sun_elevation_deg.to_radians(),
            self.sun_azimuth_deg.to_radians(),
        );
        DVec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos())
    }

    /// The model as a `w`×`h` lat-long environment map (`nimbus_scene::EnvMap`'s layout),
    /// each texel the radiance at its centre.
    pub fn latlong(&self, w: usize, h: usize) -> nimbus_scene::Image {
        let mut img = nimbus_scene::Image::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let d = nimbus_scene::EnvMap::dir_of(
                    (x as f64 + 0.5) / w as f64,
                    (y as f64 + 0.5) / h as f64,
                );
                let l = self.radiance(d);
                img.pixels[y * w + x] = [l.x as f32, l.y as f32, l.z as f32];
            }
        }
        img
    }

    /// Radiance seen looking along `d`.
    pub fn radiance(&self, d: DVec3) -> DVec3 {
        let d = d.normalize();
        if d.y < 0.0 {
            // The ground, with a little of the horizon's haze close to it.
            return self.ground * (1.0 + 0.5 * (1.0 + d.y * 8.0).max(0.0));
        }
        let haze = (self.turbidity.clamp(1.0, 10.0) - 1.0) / 9.0;
        // Brighter and whiter towards the horizon, more so when hazy.
        let horizon = (1.0 - d.y).powi(3);
        let white = DVec3::splat(self.zenith.element_sum() / 3.0);
        let base = self.zenith.lerp(white * 1.6, horizon * (0.4 + 0.5 * haze));
        // Glow around the sun: wider and stronger when hazy.
        let c = d.dot(self.sun_dir()).clamp(-1.0, 1.0);
        let glow = (0.5 + 2.5 * haze) * ((c - 1.0) * (8.0 - 5.0 * haze)).exp();
        base * (1.0 + glow)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fib(n: usize) -> Vec<DVec3> {
        (0..n)
            .map(|i| {
                let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
                let r = (1.0 - z * z).sqrt();
                let p = std::f64::consts::PI * (3.0 - 5f64.sqrt()) * i as f64;
                DVec3::new(r * p.cos(), r * p.sin(), z)
            })
            .collect()
    }

    /// The basis is orthonormal: ∫ Y_i Y_j dω = δ_ij, by a 20 000-point quadrature (its error
    /// on polynomials of degree ≤ 8 is below 1e-3).
    #[test]
    fn basis_is_orthonormal() {
        let pts = fib(20_000);
        let w = 4.0 * std::f64::consts::PI / pts.len() as f64;
        let mut g = [[0.0f64; SH_COEFFS]; SH_COEFFS];
        for p in &pts {
            let y = eval(*p);
            for i in 0..SH_COEFFS {
                for j in 0..SH_COEFFS {
                    g[i][j] += w * y[i] * y[j];
                }
            }
        }
        for (i, gi) in g.iter().enumerate() {
            for (j, gij) in gi.iter().enumerate() {
                let want = if i == j { 1.0 } else { 0.0 };
                assert!((gij - want).abs() < 2e-3, "({i}, {j}): {gij}");
            }
        }
    }

    /// A function of degree ≤ 4 projected and evaluated in a rotated frame equals the function
    /// at the rotated point: f_local(ω) = f(M ω), to 1e-9.
    #[test]
    fn rotation_into_a_frame_is_exact_for_band_limited_functions() {
        let mut c = [[0.0; 3]; SH_COEFFS];
        for (j, v) in c.iter_mut().enumerate() {
            *v = [
                (j as f64 * 0.37).sin(),
                (j as f64 * 0.11).cos(),
                j as f64 * 0.01,
            ];
        }
        let f = |c: &[[f64; 3]; SH_COEFFS], d: DVec3| {
            let y = eval(d);
            (0..SH_COEFFS).map(|j| c[j][0] * y[j]).sum::<f64>()
        };
        let ez = DVec3::new(0.3, -0.5, 0.8).normalize();
        let ex = ez.cross(DVec3::new(0.1, 1.0, 0.2)).normalize();
        let ey = ez.cross(ex);
        let local = rotate_to_frame(&c, (ex, ey, ez));
        for d in fib(50) {
            let w = ex * d.x + ey * d.y + ez * d.z;
            assert!((f(&local, d) - f(&c, w)).abs() < 1e-9, "{d}");
        }
    }

    /// A constant sky is one coefficient, L √(4π), and keeps all its energy at degree 0.
    #[test]
    fn constant_sky_projects_exactly() {
        let c = project(|_| DVec3::new(1.0, 2.0, 3.0), 32);
        let s = (4.0 * std::f64::consts::PI).sqrt();
        assert!((c[0][1] - 2.0 * s).abs() < 1e-9, "{:?}", c[0]);
        assert!(c[1..].iter().flatten().all(|v| v.abs() < 1e-9));
        assert!((kept_energy(|_| DVec3::ONE, 0, 32) - 1.0).abs() < 1e-9);
    }

    /// The transfer product is the integral: for T and L of degree ≤ 4 given on a grid,
    /// Σ t_lm c_lm equals ∫ T L dω by quadrature to 1e-3.
    #[test]
    fn apply_is_the_integral_of_the_product() {
        let t_fn = |d: DVec3| 1.0 + 0.5 * d.z + 0.2 * d.x * d.y;
        let l_fn = |d: DVec3| DVec3::splat(2.0 + d.y - 0.3 * d.z * d.z);
        let t = project(|d| DVec3::splat(t_fn(d)), 64);
        let t: Vec<f32> = t.iter().map(|v| v[0] as f32).collect();
        let c = project(l_fn, 64);
        let pts = fib(40_000);
        let w = 4.0 * std::f64::consts::PI / pts.len() as f64;
        let want: f64 = pts.iter().map(|&d| w * t_fn(d) * l_fn(d).x).sum();
        let got = apply(&t, &c, SH_DEGREE).x;
        assert!((got / want - 1.0).abs() < 1e-3, "{got} vs {want}");
    }

    /// What each degree keeps of a clear sky (sun 30° high, turbidity 3, the bench suite's
    /// colours): the energy ∫ |L|² dω kept by degrees 0 … 4 is 0.640, 0.880, 0.898, 0.950 and
    /// 0.955 (`examples/sky_degree.rs`; docs/rpnn.md quotes them), each to ±0.003 — the
    /// quadrature is deterministic, so the bound only absorbs rounding across platforms. The sky
    /// is brighter towards the sun than away from it, and degree 4 keeps 87 % of the energy
    /// above degree 0: the rest is the sun's glow, narrower than degree 4 resolves.
    #[test]
    fn sky_model_is_smooth_enough_for_low_degrees() {
        let s = SkyModel {
            sun_elevation_deg: 30.0,
            sun_azimuth_deg: 40.0,
            turbidity: 3.0,
            zenith: DVec3::new(0.08, 0.16, 0.36),
            ground: DVec3::new(0.06, 0.055, 0.05),
        };
        assert!(s.radiance(s.sun_dir()).x > 2.0 * s.radiance(-s.sun_dir()).x);
        let e: Vec<f64> = (0..=SH_DEGREE)
            .map(|l| kept_energy(|d| s.radiance(d), l, 64))
            .collect();
        for (l, want) in [0.6405, 0.8796, 0.8982, 0.9496, 0.9550]
            .into_iter()
            .enumerate()
        {
            assert!(
                (e[l] - want).abs() < 0.003,
                "degree {l}: {} against {want}",
                e[l]
            );
        }
        let varying = (e[SH_DEGREE] - e[0]) / (1.0 - e[0]);
        assert!((varying - 0.875).abs() < 0.005, "{varying}");
    }

    /// A 1024×512 map, black but for one texel as bright as a sun's disc would be: each
    /// coefficient is that texel's radiance times ∫ Y dω over it. c₀₀ (Y₀₀ is constant) is
    /// exact to rounding (1e-12); the others within 1e-3 of Y at the texel's centre times its
    /// solid angle (Y varies by less across a texel 0.35° wide). The point quadrature of
    /// [`project`] at 64 nodes, as the renderer used it before (8 192 directions for 524 288
    /// texels: it looks at one texel in 64), gets c₀₀ wrong by more than half: the reason the
    /// map is projected texel by texel.
    #[test]
    fn project_env_weighs_each_texel_by_its_solid_angle() {
        let (w, h, tx, ty) = (1024, 512, 700, 150);
        let mut img = nimbus_scene::Image::new(w, h);
        img.pixels[ty * w + tx] = [5.0e4, 4.0e4, 3.0e4];
        let env = nimbus_scene::EnvMap::new(img, 2.0).unwrap();
        let c = project_env(&env);
        let omega = latlong_cell_solid_angle(w, ty as f64 / h as f64, (ty + 1) as f64 / h as f64);
        let centre = nimbus_scene::EnvMap::dir_of(
            (tx as f64 + 0.5) / w as f64,
            (ty as f64 + 0.5) / h as f64,
        );
        let y = eval(centre);
        for (ch, l) in [1.0e5, 8.0e4, 6.0e4].into_iter().enumerate() {
            let want0 = l * omega * y[0];
            assert!(
                (c[0][ch] / want0 - 1.0).abs() < 1e-12,
                "c00 {} against {want0}",
                c[0][ch]
            );
            for j in 1..SH_COEFFS {
                let want = l * omega * y[j];
                assert!(
                    (c[j][ch] - want).abs() < 1e-3 * l * omega,
                    "c[{j}][{ch}] {} against {want}",
                    c[j][ch]
                );
            }
        }
        let point = project(|d| env.radiance(d), 64);
        assert!(
            (point[0][0] / c[0][0] - 1.0).abs() > 0.5,
            "the point quadrature happened to hit the texel's weight: {} against {}",
            point[0][0],
            c[0][0]
        );
    }

    /// A coarse map (32×16: texels 11.25° wide) is split into 8 × 8 parts per texel: one lit
    /// texel's coefficients equal ∫ Y dω over it, here by a 256 × 256 midpoint rule with
    /// exact solid angles, to 2e-3 of its solid angle (the parts' midpoint error, about 4e-4
    /// of Y's range). Y at the texel's centre times its solid angle misses by more than that
    /// for some coefficient: without the split the test fails.
    #[test]
    fn project_env_splits_coarse_texels() {
        let (w, h, tx, ty) = (32, 16, 10, 4);
        let mut img = nimbus_scene::Image::new(w, h);
        img.pixels[ty * w + tx] = [1.0, 1.0, 1.0];
        let env = nimbus_scene::EnvMap::new(img, 1.0).unwrap();
        let c = project_env(&env);
        let k = 256;
        let mut want = [0.0; SH_COEFFS];
        for j in 0..k {
            let v0 = (ty as f64 + j as f64 / k as f64) / h as f64;
            let v1 = (ty as f64 + (j + 1) as f64 / k as f64) / h as f64;
            let omega = latlong_cell_solid_angle(w * k, v0, v1);
            for i in 0..k {
                let u = (tx as f64 + (i as f64 + 0.5) / k as f64) / w as f64;
                let y = eval(nimbus_scene::EnvMap::dir_of(u, (v0 + v1) / 2.0));
                for (wj, yj) in want.iter_mut().zip(y) {
                    *wj += omega * yj;
                }
            }
        }
        let omega = latlong_cell_solid_angle(w, ty as f64 / h as f64, (ty + 1) as f64 / h as f64);
        let centre = eval(nimbus_scene::EnvMap::dir_of(
            (tx as f64 + 0.5) / w as f64,
            (ty as f64 + 0.5) / h as f64,
        ));
        let mut centre_miss = 0.0f64;
        for j in 0..SH_COEFFS {
            assert!(
                (c[j][0] - want[j]).abs() < 2e-3 * omega,
                "c[{j}] {} against {}",
                c[j][0],
                want[j]
            );
            centre_miss = centre_miss.max((centre[j] * omega - want[j]).abs() / omega);
        }
        assert!(centre_miss > 1e-2, "{centre_miss}");
    }

    /// A smooth sky as a 256×128 map (`SkyModel::latlong`) projects onto what the function
    /// itself does: every coefficient within 1 % of the largest (the map holds the function at
    /// texel centres, 1.4° apart).
    #[test]
    fn project_env_of_a_smooth_map_is_the_function_s() {
        let s = SkyModel {
            sun_elevation_deg: 20.0,
            sun_azimuth_deg: 120.0,
            turbidity: 3.0,
            zenith: DVec3::new(0.08, 0.16, 0.36),
            ground: DVec3::new(0.06, 0.055, 0.05),
        };
        let env = nimbus_scene::EnvMap::new(s.latlong(256, 128), 1.0).unwrap();
        let a = project_env(&env);
        let b = project(|d| s.radiance(d), 64);
        let big = b.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
        for (j, (aj, bj)) in a.iter().zip(&b).enumerate() {
            for ch in 0..3 {
                assert!(
                    (aj[ch] - bj[ch]).abs() < 0.01 * big,
                    "c[{j}][{ch}]: {} against {}",
                    aj[ch],
                    bj[ch]
                );
            }
        }
    }

    /// The GPU's contraction without the rotation equals rotating the sky into the frame and
    /// contracting (f64 rounding: 1e-9 relative), for every degree and several frames.
    #[test]
    fn product_in_frame_equals_rotate_then_apply() {
        let sky = SkyModel {
            sun_elevation_deg: 25.0,
            sun_azimuth_deg: -70.0,
            turbidity: 4.0,
            zenith: DVec3::new(0.1, 0.2, 0.45),
            ground: DVec3::splat(0.05),
        };
        let c = project(|d| sky.radiance(d), 32);
        let t: Vec<f32> = (0..SH_COEFFS)
            .map(|i| ((i as f32 * 0.7).sin() + 0.2) / (1.0 + i as f32))
            .collect();
        for (view, light) in [
            (DVec3::new(0.3, -0.2, -1.0), DVec3::new(0.5, 0.7, 0.1)),
            (DVec3::new(0.0, 0.0, 1.0), DVec3::new(0.0, 1.0, 0.0)),
            (DVec3::new(-0.8, 0.1, 0.2), DVec3::new(-0.1, -0.3, 0.9)),
        ] {
            let (ex, ey, ez) =
                crate::descriptor::frame(view.normalize().as_vec3(), light.normalize().as_vec3());
            let frame = (ex.as_dvec3(), ey.as_dvec3(), ez.as_dvec3());
            for l in 0..=SH_DEGREE {
                let want = apply(&t, &rotate_to_frame(&c, frame), l);
                let got = product_in_frame(&t, &c, frame, l);
                assert!(
                    (got - want).abs().max_element() <= 1e-9 * want.abs().max_element().max(1e-3),
                    "degree {l}: {got} vs {want}"
                );
            }
        }
        assert_eq!(gpu_table(&c).len(), 75 + 75 + 165);
    }
}
