//! Lorenz–Mie phase function of water droplets (Kallweit 2017 §3.1 and Fig. 3/4).
//!
//! - Single-sphere amplitudes S1, S2 by the Bohren–Huffman series (BHMIE: logarithmic derivative
//!   Dₙ(mx) by downward recurrence, Riccati–Bessel functions ψₙ, χₙ by upward recurrence, angular
//!   functions πₙ, τₙ by recurrence, nₘₐₓ = x + 4x^{1/3} + 2).
//! - Integrated over a gamma droplet-size distribution with effective radius r_eff and effective
//!   variance v_eff (Hansen & Travis 1974): n(r) ∝ r^{(1−3v)/v} exp(−r / (r_eff v)), weighting each
//!   size by its scattering cross section, i.e. p(θ) ∝ ∫ n(r) (|S1|² + |S2|²)/2 dr.
//! - Tabulated on an angle grid that is fine near 0° (diffraction peak) and 180° (glory), then
//!   sampled by inverse CDF ([`TabulatedPhase`]).
//! - Optional chopped diffraction peak (Kallweit §3.1, after Bouthors et al. 2008): inside the
//!   cone θ < θ_c the peak is flattened to p(θ_c); the removed fraction f of scattered energy is
//!   treated as unscattered, so the medium after the first bounce uses σ_t' = σ_t (1 − f α),
//!   albedo α' = α (1 − f)/(1 − f α) and the renormalised chopped table. The first bounce keeps the
//!   full function (Kallweit Fig. 3e) so silver lining survives.
//!
//! Grey: one wavelength (default 550 nm) stands for the visible band.

use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::{Arc, Mutex, OnceLock};

use num_complex::Complex64;
use rayon::prelude::*;

use super::tabulated::TabulatedPhase;
use crate::error::FieldError;

/// Parameters of a Mie cloud phase function.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MieParams {
    /// Effective radius of the gamma droplet-size distribution, micrometres.
    pub effective_radius_um: f64,
    /// Effective variance of the distribution (dimensionless, typically 0.05–0.2).
    pub effective_variance: f64,
    /// Wavelength in nanometres.
    pub wavelength_nm: f64,
    /// Real part of the droplets' refractive index relative to air (water: 1.333).
    pub refractive_index: f64,
    /// Half-angle of the chopped diffraction peak in degrees; 0 keeps the full function everywhere.
    pub chop_deg: f64,
}

impl Default for MieParams {
    fn default() -> Self {
        Self {
            effective_radius_um: 8.0,
            effective_variance: 0.1,
            wavelength_nm: 550.0,
            refractive_index: 1.333,
            chop_deg: 0.0,
        }
    }
}

impl MieParams {
    pub fn validate(&self) -> Result<(), FieldError> {
        let check = |name: &str, v: f64, lo: f64, hi: f64| {
            if v.is_finite() && v >= lo && v <= hi {
                Ok(())
            } else {
                Err(FieldError::new(
                    name,
                    format!("must lie in [{lo}, {hi}], got {v}"),
                ))
            }
        };
        check("effective_radius_um", self.effective_radius_um, 0.1, 30.0)?;
        check("effective_variance", self.effective_variance, 0.01, 0.3)?;
        check("wavelength_nm", self.wavelength_nm, 300.0, 1000.0)?;
        check("refractive_index", self.refractive_index, 1.01, 2.0)?;
        check("chop_deg", self.chop_deg, 0.0, 20.0)?;
        Ok(())
    }
}

/// The chopped form of a Mie function.
#[derive(Debug, Clone, PartialEq)]
pub struct ChoppedPeak {
    pub phase: TabulatedPhase,
    /// Fraction f of scattered energy inside the removed peak.
    pub peak_fraction: f64,
}

/// A tabulated Mie phase function with its optional chopped form.
#[derive(Debug, Clone, PartialEq)]
pub struct MiePhase {
    pub params: MieParams,
    pub full: TabulatedPhase,
    pub chopped: Option<ChoppedPeak>,
    /// Mean cosine from the Mie series (size-averaged, weighted by scattering cross section):
    /// an independent check of the table's [`TabulatedPhase::mean_cosine`].
    pub series_g: f64,
}

/// Angle nodes (radians): 0.01° steps to 2°, 0.05° to 10°, 0.2° to 170°, 0.05° to 180°.
pub fn angle_grid() -> Vec<f64> {
    let mut deg = Vec::new();
    let mut push_range = |a: f64, b: f64, step: f64| {
        let n = ((b - a) / step).round() as usize;
        for i in 0..n {
            deg.push(a + i as f64 * step);
        }
    };
    push_range(0.0, 2.0, 0.01);
    push_range(2.0, 10.0, 0.05);
    push_range(10.0, 170.0, 0.2);
    push_range(170.0, 180.0, 0.05);
    deg.push(180.0);
    deg.into_iter().map(f64::to_radians).collect()
}

/// Mie scattering of one homogeneous sphere: for size parameter `x` and relative refractive index
/// `m`, writes i(μ) = (|S1(μ)|² + |S2(μ)|²)/2 for each μ in `mus` into `out` and returns
/// (Q_sca, g) — g from the series of Bohren & Huffman Eq. 4.62, independent of the angle grid.
/// With this normalisation ∫ i dω = π x² Q_sca.
#[allow(clippy::needless_range_loop)] // n is the series index, not just a position
pub fn bhmie(x: f64, m: Complex64, mus: &[f64], out: &mut [f64]) -> (f64, f64) {
    assert_eq!(mus.len(), out.len());
    let nstop = (x + 4.0 * x.cbrt() + 2.0).floor() as usize;
    let y = m * x;
    let nmx = (nstop as f64).max(y.norm()).ceil() as usize + 15;
    // Logarithmic derivative D_n(y) by downward recurrence.
    let mut d = vec![Complex64::new(0.0, 0.0); nmx + 1];
    for n in (1..=nmx).rev() {
        let nf = Complex64::new(n as f64, 0.0) / y;
        d[n - 1] = nf - 1.0 / (d[n] + nf);
    }
    let mut psi0 = x.cos();
    let mut psi1 = x.sin();
    let mut chi0 = -x.sin();
    let mut chi1 = x.cos();
    let mut xi1 = Complex64::new(psi1, -chi1);
    let mut s1 = vec![Complex64::new(0.0, 0.0); mus.len()];
    let mut s2 = vec![Complex64::new(0.0, 0.0); mus.len()];
    let mut pi_prev = vec![0.0f64; mus.len()];
    let mut pi_cur = vec![1.0f64; mus.len()];
    let mut qsca = 0.0;
    let mut gsca = 0.0;
    let (mut an1, mut bn1) = (Complex64::new(0.0, 0.0), Complex64::new(0.0, 0.0));
    for n in 1..=nstop {
        let nf = n as f64;
        let fnn = (2.0 * nf + 1.0) / (nf * (nf + 1.0));
        let psi = (2.0 * nf - 1.0) * psi1 / x - psi0;
        let chi = (2.0 * nf - 1.0) * chi1 / x - chi0;
        let xi = Complex64::new(psi, -chi);
        let da = d[n] / m + nf / x;
        let db = d[n] * m + nf / x;
        let an = (da * psi - psi1) / (da * xi - xi1);
        let bn = (db * psi - psi1) / (db * xi - xi1);
        qsca += (2.0 * nf + 1.0) * (an.norm_sqr() + bn.norm_sqr());
        if n > 1 {
            gsca += (nf - 1.0) * (nf + 1.0) / nf * (an1 * an.conj() + bn1 * bn.conj()).re;
        }
        gsca += (2.0 * nf + 1.0) / (nf * (nf + 1.0)) * (an * bn.conj()).re;
        an1 = an;
        bn1 = bn;
        for (j, &mu) in mus.iter().enumerate() {
            let p = pi_cur[j];
            let tau = nf * mu * p - (nf + 1.0) * pi_prev[j];
            s1[j] += fnn * (an * p + bn * tau);
            s2[j] += fnn * (an * tau + bn * p);
            let next = ((2.0 * nf + 1.0) * mu * p - (nf + 1.0) * pi_prev[j]) / nf;
            pi_prev[j] = p;
            pi_cur[j] = next;
        }
        psi0 = psi1;
        psi1 = psi;
        chi0 = chi1;
        chi1 = chi;
        xi1 = Complex64::new(psi1, -chi1);
    }
    for j in 0..mus.len() {
        out[j] = 0.5 * (s1[j].norm_sqr() + s2[j].norm_sqr());
    }
    (2.0 / (x * x) * qsca, 2.0 * gsca / qsca)
}

/// Droplet radii (µm) and weights for the gamma distribution, trapezoidal rule.
fn radius_quadrature(p: &MieParams, n: usize) -> Vec<(f64, f64)> {
    let v = p.effective_variance;
    let re = p.effective_radius_um;
    let a = (1.0 - 3.0 * v) / v;
    let b = 1.0 / (re * v);
    // Gamma(shape a+1, rate b): mean (a+1)/b, sd √(a+1)/b. Cover mean ± 8 sd (clipped at 0).
    let mean = (a + 1.0) / b;
    let sd = (a + 1.0).sqrt() / b;
    let lo = (mean - 8.0 * sd).max(0.02 * re);
    let hi = mean + 8.0 * sd;
    let h = (hi - lo) / (n - 1) as f64;
    let logw: Vec<f64> = (0..n)
        .map(|i| {
            let r = lo + i as f64 * h;
            a * r.ln() - b * r
        })
        .collect();
    let lmax = logw.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    (0..n)
        .map(|i| {
            let r = lo + i as f64 * h;
            let trap = if i == 0 || i == n - 1 { 0.5 } else { 1.0 };
            (r, (logw[i] - lmax).exp() * h * trap)
        })
        .collect()
}

/// Number of droplet radii in the size integral: enough that the single-size ripple structure
/// averages out (Δx ≈ 0.3 at r_eff = 8 µm).
const RADII: usize = 600;

/// Computes (uncached) the Mie phase function for `p`.
pub fn compute(p: &MieParams) -> Result<MiePhase, FieldError> {
    p.validate()?;
    let theta = angle_grid();
    let mus: Vec<f64> = theta.iter().map(|t| t.cos()).collect();
    let k = 2.0 * PI / (p.wavelength_nm * 1e-3); // per µm
    let m = Complex64::new(p.refractive_index, 0.0);
    let radii = radius_quadrature(p, RADII);
    // Per radius: (weighted i(μ), weighted C_sca, weighted C_sca·g), C_sca ∝ x² Q_sca.
    let (sum, csca, cg) = radii
        .par_iter()
        .map(|&(r, w)| {
            let x = k * r;
            let mut i = vec![0.0; mus.len()];
            let (q, g) = bhmie(x, m, &mus, &mut i);
            i.iter_mut().for_each(|v| *v *= w);
            let c = w * PI * x * x * q;
            (i, c, c * g)
        })
        .reduce(
            || (vec![0.0; mus.len()], 0.0, 0.0),
            |mut a, b| {
                a.0.iter_mut().zip(b.0).for_each(|(x, y)| *x += y);
                (a.0, a.1 + b.1, a.2 + b.2)
            },
        );
    let full = TabulatedPhase::from_angles(&theta, &sum);
    let chopped = (p.chop_deg > 0.0).then(|| {
        let tc = p.chop_deg.to_radians();
        let cap = sum[theta.partition_point(|&t| t < tc).min(theta.len() - 1)];
        let chopped_vals: Vec<f64> = theta
            .iter()
            .zip(&sum)
            .map(|(&t, &v)| if t < tc { v.min(cap) } else { v })
            .collect();
        // Fraction of the (normalised) full function removed by flattening the peak.
        let full_mass = mass(&theta, &sum);
        let chopped_mass = mass(&theta, &chopped_vals);
        ChoppedPeak {
            phase: TabulatedPhase::from_angles(&theta, &chopped_vals),
            peak_fraction: 1.0 - chopped_mass / full_mass,
        }
    });
    Ok(MiePhase {
        params: *p,
        full,
        chopped,
        series_g: cg / csca,
    })
}

/// ∫ v dω with the same bin rule as [`TabulatedPhase::from_angles`].
fn mass(theta: &[f64], v: &[f64]) -> f64 {
    theta
        .windows(2)
        .zip(v.windows(2))
        .map(|(t, v)| 0.5 * (v[0] + v[1]) * (t[0].cos() - t[1].cos()) * 2.0 * PI)
        .sum()
}

/// Computes the Mie phase function once per parameter set per process (a few hundred ms).
pub fn cached(p: &MieParams) -> Result<Arc<MiePhase>, FieldError> {
    static CACHE: OnceLock<Mutex<HashMap<[u64; 5], Arc<MiePhase>>>> = OnceLock::new();
    let key = [
        p.effective_radius_um.to_bits(),
        p.effective_variance.to_bits(),
        p.wavelength_nm.to_bits(),
        p.refractive_index.to_bits(),
        p.chop_deg.to_bits(),
    ];
    let cache = CACHE.get_or_init(Default::default);
    if let Some(v) = cache.lock().unwrap().get(&key) {
        return Ok(v.clone());
    }
    let v = Arc::new(compute(p)?);
    cache.lock().unwrap().insert(key, v.clone());
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rayleigh_limit() {
        // x ≪ 1: Q_sca = 8/3 x⁴ |(m²−1)/(m²+2)|², i(μ) ∝ 1 + μ².
        let x = 0.01;
        let m = Complex64::new(1.5, 0.0);
        let mus = [1.0, 0.0, -1.0];
        let mut i = [0.0; 3];
        let (q, g) = bhmie(x, m, &mus, &mut i);
        assert!(g.abs() < 1e-3, "Rayleigh scattering is symmetric: g = {g}");
        let lk = ((m * m - 1.0) / (m * m + 2.0)).norm_sqr();
        let expected = 8.0 / 3.0 * x.powi(4) * lk;
        assert!((q / expected - 1.0).abs() < 1e-3, "{q} vs {expected}");
        assert!((i[0] / i[1] - 2.0).abs() < 1e-3 && (i[2] / i[1] - 2.0).abs() < 1e-3);
    }

    #[test]
    fn bohren_huffman_example_and_optical_theorem() {
        // Bohren & Huffman, Appendix A example: x = 2π·0.525/0.6328, m = 1.55:
        // Q_sca = Q_ext = 3.10543 (non-absorbing sphere).
        let x = 2.0 * PI * 0.525 / 0.6328;
        let m = Complex64::new(1.55, 0.0);
        let theta = angle_grid();
        let mus: Vec<f64> = theta.iter().map(|t| t.cos()).collect();
        let mut i = vec![0.0; mus.len()];
        let (q, _) = bhmie(x, m, &mus, &mut i);
        assert!((q - 3.10543).abs() < 2e-4, "Q_sca = {q}");
        // ∫ i dω = π x² Q_sca (quadrature on the table grid: 1e-3).
        let integral = mass(&theta, &i);
        assert!((integral / (PI * x * x * q) - 1.0).abs() < 1e-3);
    }

    #[test]
    fn cloud_mean_cosine() {
        // Cloud droplets with r_eff 5–10 µm have g ≈ 0.85–0.87 at visible wavelengths (0.849 at
        // 5 µm, v_eff 0.1, 550 nm, hence the 0.845 lower bound). The table's g must match the
        // independent Mie-series g to 2e-3 (angle-grid quadrature).
        for r in [5.0, 8.0, 10.0] {
            let p = MieParams {
                effective_radius_um: r,
                ..Default::default()
            };
            let mie = cached(&p).unwrap();
            let g = mie.full.mean_cosine();
            assert!((0.845..=0.875).contains(&g), "r_eff={r}: g={g}");
            assert!(
                (g - mie.series_g).abs() < 2e-3,
                "table g {g} vs series {}",
                mie.series_g
            );
        }
    }

    #[test]
    fn chopped_peak_is_consistent() {
        let p = MieParams {
            chop_deg: 5.0,
            ..Default::default()
        };
        let mie = cached(&p).unwrap();
        let c = mie.chopped.as_ref().unwrap();
        // The diffraction peak of 8 µm droplets holds about half of the scattered energy
        // (diffraction ≈ ½ of extinction); inside 5° most of it.
        assert!(
            (0.3..0.6).contains(&c.peak_fraction),
            "f = {}",
            c.peak_fraction
        );
        // Removing a forward peak lowers the mean cosine: g_full = f + (1 − f) g_chopped
        // up to the peak's own spread (cos 5° ≈ 0.996) and the table resolution.
        let gf = mie.full.mean_cosine();
        let gc = c.phase.mean_cosine();
        let f = c.peak_fraction;
        assert!(gc < gf);
        assert!(
            (f + (1.0 - f) * gc - gf).abs() < 5e-3 * f,
            "{gf} vs {}",
            f + (1.0 - f) * gc
        );
        assert!(
            MieParams {
                effective_radius_um: -1.0,
                ..p
            }
            .validate()
            .is_err()
        );
    }
}
