//! Henyey–Greenstein phase function (Elek 2012 §3.1, Eq. 1; Kallweit 2017 Fig. 4).
//!
//! Convention: `cos_theta` is the cosine between the propagation direction before and after
//! scattering, so g > 0 scatters forward. Stable for every |g| < 1: |g| < 1e-4 uses the
//! first-order expansion of the inverse CDF (error O(g²)), and the denominator
//! 1 + g² − 2gμ is evaluated as (1 − g)² + 2g(1 − μ) so that g → ±1 keeps full precision near
//! the peak.

use std::f64::consts::PI;

use crate::error::FieldError;

/// Below this |g| the closed-form inverse CDF loses digits to cancellation; a Taylor expansion is
/// used instead (error O(g²) = 1e-8, against f64 cancellation of ≈ 1e-16 / 2|g|). The f32 twin
/// in `shaders/lib/hg.wgsl` switches at 1e-3 for the same balance in single precision.
const SMALL_G: f64 = 1e-4;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HenyeyGreenstein {
    g: f64,
}

impl HenyeyGreenstein {
    /// Requires a finite g with |g| < 1.
    pub fn new(g: f64) -> Result<Self, FieldError> {
        if !g.is_finite() || g.abs() >= 1.0 {
            return Err(FieldError::new(
                "g",
                format!("Henyey–Greenstein needs |g| < 1 (e.g. 0.999), got {g}"),
            ));
        }
        Ok(Self { g })
    }

    pub fn g(&self) -> f64 {
        self.g
    }

    /// Phase function value per steradian.
    #[inline]
    pub fn eval(&self, cos_theta: f64) -> f64 {
        eval(self.g, cos_theta)
    }

    /// Samples cos θ proportionally to the phase function from a uniform `u` in [0, 1).
    #[inline]
    pub fn sample_cos(&self, u: f64) -> f64 {
        sample_cos(self.g, u)
    }

    /// CDF of cos θ: P(μ' ≤ μ).
    pub fn cdf(&self, mu: f64) -> f64 {
        let g = self.g;
        if g.abs() < SMALL_G {
            // ∫ (1/2)(1 + 3gμ') dμ' from −1 to μ (first order in g).
            let mu = mu.clamp(-1.0, 1.0);
            return (0.5 * (mu + 1.0) + 0.75 * g * (mu * mu - 1.0)).clamp(0.0, 1.0);
        }
        let mu = mu.clamp(-1.0, 1.0);
        let denom = |m: f64| ((1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - m)).sqrt();
        // ∫_{-1}^{μ} (1−g²)/(2 (1+g²−2gμ')^{3/2}) dμ' = (1−g²)/(2g) [1/√(…μ) − 1/(1+g)]
        ((1.0 - g * g) / (2.0 * g) * (1.0 / denom(mu) - 1.0 / (1.0 + g))).clamp(0.0, 1.0)
    }
}

#[inline]
pub fn eval(g: f64, cos_theta: f64) -> f64 {
    let denom = (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - cos_theta);
    (1.0 - g * g) / (4.0 * PI * denom * denom.sqrt())
}

/// [`eval`] in single precision, operation for operation as `hg_eval` in
/// `shaders/lib/hg.wgsl`: for the CPU twins of GPU stages, which must round as the GPU does.
#[inline]
pub fn eval_f32(g: f32, cos_theta: f32) -> f32 {
    let denom = (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - cos_theta);
    (1.0 - g * g) / (4.0 * std::f32::consts::PI * denom * denom.sqrt())
}

/// [`sample_cos`] in single precision as `hg_sample_cos` in `shaders/lib/hg.wgsl` (its
/// small-|g| branch starts at 1e-3, the f32 balance documented there), for CPU twins.
#[inline]
pub fn sample_cos_f32(g: f32, u: f32) -> f32 {
    let s = 2.0 * u - 1.0;
    if g.abs() < 1.0e-3 {
        return (s + 1.5 * g * (1.0 - s * s)).clamp(-1.0, 1.0);
    }
    let t = (1.0 - g * g) / (1.0 + g * s);
    ((1.0 + g * g - t * t) / (2.0 * g)).clamp(-1.0, 1.0)
}

#[inline]
pub fn sample_cos(g: f64, u: f64) -> f64 {
    let s = 2.0 * u - 1.0;
    if g.abs() < SMALL_G {
        return (s + 1.5 * g * (1.0 - s * s)).clamp(-1.0, 1.0);
    }
    let t = (1.0 - g * g) / (1.0 + g * s);
    ((1.0 + g * g - t * t) / (2.0 * g)).clamp(-1.0, 1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The single-precision twin agrees with the f64 form to f32 rounding. For g < 0 the
    /// denominator (1 − g)² + 2g(1 − μ) is a difference of terms ≈ 4 that cancels towards
    /// (1 + g)² at μ → −1 (1e-4 at g = −0.99), so the bound scales with (sum of the terms'
    /// magnitudes) / denominator: a few f32 ulps of the terms, amplified by the cancellation and
    /// the power 3/2; elsewhere it is 1e-5.
    #[test]
    fn f32_twin_matches_f64() {
        for gi in -99..=99 {
            let g = gi as f64 / 100.0;
            for mi in -20..=20 {
                let mu = mi as f64 / 20.0;
                let (a, b) = (eval(g, mu), eval_f32(g as f32, mu as f32) as f64);
                let denom = (1.0 - g) * (1.0 - g) + 2.0 * g * (1.0 - mu);
                let terms = (1.0 - g) * (1.0 - g) + 2.0 * g.abs() * (1.0 - mu);
                let tol = 1e-5 + 4.0 * f32::EPSILON as f64 * 1.5 * terms / denom;
                assert!((a - b).abs() <= tol * a, "g {g} mu {mu}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn rejects_invalid_g() {
        for g in [1.0, -1.0, 1.5, f64::NAN, f64::INFINITY] {
            assert!(HenyeyGreenstein::new(g).is_err(), "{g}");
        }
        assert!(HenyeyGreenstein::new(0.999).is_ok());
    }

    #[test]
    fn sampling_inverts_cdf() {
        for g in [-0.999, -0.5, 0.0, 1e-6, 5e-5, 0.3, 0.857, 0.999] {
            let hg = HenyeyGreenstein::new(g).unwrap();
            for i in 0..=20 {
                let u = i as f64 / 20.0;
                let mu = hg.sample_cos(u);
                assert!((-1.0..=1.0).contains(&mu));
                // The CDF at the sampled value returns u (to the Taylor order for tiny g).
                assert!((hg.cdf(mu) - u).abs() < 1e-7, "g={g} u={u}");
            }
        }
    }

    #[test]
    fn tiny_g_matches_isotropic_limit() {
        for g in [0.0, 1e-8, -3e-5] {
            let v = eval(g, 0.3);
            assert!((v - 1.0 / (4.0 * PI)).abs() < 1e-3 / (4.0 * PI));
        }
    }
}
