//! Phase functions as interchangeable parts: isotropic, Henyey–Greenstein and tabulated
//! (Lorenz–Mie). All are rotationally symmetric, normalised to ∫ p dω = 1, and use the
//! propagation convention: `cos_theta` is the cosine between the directions of travel before and
//! after scattering (forward scattering: cos θ = 1).

pub mod hg;
pub mod mie;
pub mod tabulated;

use std::f64::consts::{PI, TAU};
use std::sync::Arc;

use glam::DVec3;

use crate::frame::direction_around;
pub use hg::HenyeyGreenstein;
pub use mie::{MieParams, MiePhase};
pub use tabulated::TabulatedPhase;

/// A phase function.
#[derive(Debug, Clone, PartialEq)]
pub enum Phase {
    Isotropic,
    HenyeyGreenstein(HenyeyGreenstein),
    Tabulated(Arc<TabulatedPhase>),
}

/// A sampled scattering direction.
#[derive(Debug, Clone, Copy)]
pub struct PhaseSample {
    pub dir: DVec3,
    /// Density of `dir` per steradian (equal to the phase function value: perfect importance
    /// sampling).
    pub pdf: f64,
}

impl Phase {
    /// Value per steradian for the cosine between incoming and outgoing propagation directions.
    #[inline]
    pub fn eval(&self, cos_theta: f64) -> f64 {
        match self {
            Phase::Isotropic => 1.0 / (4.0 * PI),
            Phase::HenyeyGreenstein(hg) => hg.eval(cos_theta),
            Phase::Tabulated(t) => t.eval(cos_theta),
        }
    }

    /// Samples cos θ from a uniform number in [0, 1).
    #[inline]
    pub fn sample_cos(&self, u: f64) -> f64 {
        match self {
            Phase::Isotropic => 1.0 - 2.0 * u,
            Phase::HenyeyGreenstein(hg) => hg.sample_cos(u),
            Phase::Tabulated(t) => t.sample_cos(u),
        }
    }

    /// CDF of cos θ.
    pub fn cdf(&self, mu: f64) -> f64 {
        match self {
            Phase::Isotropic => 0.5 * (mu.clamp(-1.0, 1.0) + 1.0),
            Phase::HenyeyGreenstein(hg) => hg.cdf(mu),
            Phase::Tabulated(t) => t.cdf(mu),
        }
    }

    /// Samples a new propagation direction for a photon travelling along `dir`.
    #[inline]
    pub fn sample(&self, dir: DVec3, u: [f64; 2]) -> PhaseSample {
        let mu = self.sample_cos(u[0]);
        let out = direction_around(dir, mu, TAU * u[1]);
        PhaseSample {
            dir: out,
            pdf: self.eval(mu),
        }
    }

    /// Mean cosine g.
    pub fn mean_cosine(&self) -> f64 {
        match self {
            Phase::Isotropic => 0.0,
            Phase::HenyeyGreenstein(hg) => hg.g(),
            Phase::Tabulated(t) => t.mean_cosine(),
        }
    }
}

#[cfg(test)]
mod tests;
