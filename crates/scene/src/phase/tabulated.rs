//! A rotationally symmetric phase function tabulated over cos θ: piecewise constant on bins in
//! μ = cos θ, sampled by inverting its exact CDF, so evaluation and sampling agree to round-off.

use std::f64::consts::TAU;

/// Piecewise-constant phase function over μ bins.
#[derive(Debug, Clone, PartialEq)]
pub struct TabulatedPhase {
    /// Bin edges in μ, ascending from −1 to 1 (len = bins + 1).
    mu_edges: Vec<f64>,
    /// Phase function value (per steradian) on each bin.
    values: Vec<f64>,
    /// CDF at the upper edge of each bin (last = 1).
    cdf: Vec<f64>,
    mean_cosine: f64,
}

impl TabulatedPhase {
    /// Builds the table from samples `values[i]` ≥ 0 at angles `theta[i]` (radians, strictly
    /// ascending from 0 to π). Each bin between two nodes takes the mean of its end values; the
    /// result is normalised so that ∫ p dω = 1.
    pub fn from_angles(theta: &[f64], values: &[f64]) -> Self {
        assert!(theta.len() >= 2 && theta.len() == values.len());
        assert!(theta.windows(2).all(|w| w[1] > w[0]));
        let n = theta.len();
        // θ ascending ↔ μ descending: walk backwards to get ascending μ.
        let mut mu_edges = Vec::with_capacity(n);
        let mut vals = Vec::with_capacity(n - 1);
        for i in (0..n).rev() {
            mu_edges.push(theta[i].cos());
            if i > 0 {
                vals.push(0.5 * (values[i] + values[i - 1]).max(0.0));
            }
        }
        mu_edges[0] = -1.0;
        mu_edges[n - 1] = 1.0;
        Self::from_bins(mu_edges, vals)
    }

    /// Builds the table from μ edges (ascending, −1 … 1) and per-bin values; normalises it.
    pub fn from_bins(mu_edges: Vec<f64>, mut values: Vec<f64>) -> Self {
        assert_eq!(mu_edges.len(), values.len() + 1);
        let mass: Vec<f64> = values
            .iter()
            .enumerate()
            .map(|(i, v)| v * (mu_edges[i + 1] - mu_edges[i]) * TAU)
            .collect();
        let total: f64 = mass.iter().sum();
        assert!(total > 0.0 && total.is_finite(), "phase table has no mass");
        let mut cdf = Vec::with_capacity(values.len());
        let mut acc = 0.0;
        let mut mean = 0.0;
        for (i, m) in mass.iter().enumerate() {
            acc += m / total;
            cdf.push(acc);
            mean += m / total * 0.5 * (mu_edges[i] + mu_edges[i + 1]);
            values[i] /= total;
        }
        *cdf.last_mut().unwrap() = 1.0;
        Self {
            mu_edges,
            values,
            cdf,
            mean_cosine: mean,
        }
    }

    /// Value per steradian at cos θ = `mu`.
    #[inline]
    pub fn eval(&self, mu: f64) -> f64 {
        let i = self.bin_of(mu);
        self.values[i]
    }

    #[inline]
    fn bin_of(&self, mu: f64) -> usize {
        let mu = mu.clamp(-1.0, 1.0);
        // First edge greater than mu, minus one.
        let k = self.mu_edges.partition_point(|&e| e <= mu);
        k.saturating_sub(1).min(self.values.len() - 1)
    }

    /// Samples cos θ from a uniform `u` in [0, 1).
    #[inline]
    pub fn sample_cos(&self, u: f64) -> f64 {
        let i = self
            .cdf
            .partition_point(|&c| c <= u)
            .min(self.values.len() - 1);
        let c0 = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        let w = self.cdf[i] - c0;
        let f = if w > 0.0 {
            ((u - c0) / w).clamp(0.0, 1.0)
        } else {
            0.5
        };
        self.mu_edges[i] + f * (self.mu_edges[i + 1] - self.mu_edges[i])
    }

    /// CDF of cos θ (exact for the table).
    pub fn cdf(&self, mu: f64) -> f64 {
        let mu = mu.clamp(-1.0, 1.0);
        let i = self.bin_of(mu);
        let c0 = if i == 0 { 0.0 } else { self.cdf[i - 1] };
        c0 + self.values[i] * (mu - self.mu_edges[i]) * TAU
    }

    /// Mean cosine g = ∫ p(ω) cos θ dω of the table.
    pub fn mean_cosine(&self) -> f64 {
        self.mean_cosine
    }

    pub fn mu_edges(&self) -> &[f64] {
        &self.mu_edges
    }

    pub fn values(&self) -> &[f64] {
        &self.values
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalised_and_invertible() {
        let theta: Vec<f64> = (0..=180).map(|d| (d as f64).to_radians()).collect();
        let vals: Vec<f64> = theta.iter().map(|t| 1.0 + t.cos().powi(2)).collect();
        let t = TabulatedPhase::from_angles(&theta, &vals);
        let integral: f64 = (0..t.values.len())
            .map(|i| t.values[i] * (t.mu_edges[i + 1] - t.mu_edges[i]) * TAU)
            .sum();
        assert!((integral - 1.0).abs() < 1e-12);
        assert!(t.mean_cosine().abs() < 1e-9); // Rayleigh-like shape is symmetric
        for k in 0..100 {
            let u = k as f64 / 100.0;
            assert!((t.cdf(t.sample_cos(u)) - u).abs() < 1e-9);
        }
    }
}
