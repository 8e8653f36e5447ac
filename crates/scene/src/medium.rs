//! The scattering medium: albedo and phase function, with the chopped-peak switch of
//! Kallweit 2017 §3.1 (full Lorenz–Mie on the first bounce, chopped function and optically
//! thinner medium after it).

use std::sync::Arc;

use crate::error::FieldError;
use crate::phase::{MiePhase, Phase, TabulatedPhase};

/// Medium after the first scattering event when a Mie diffraction peak is chopped.
#[derive(Debug, Clone, PartialEq)]
pub struct ChoppedMedium {
    pub phase: Phase,
    /// σ_t' / σ_t = 1 − f α.
    pub density_factor: f64,
    /// α' = α (1 − f) / (1 − f α).
    pub albedo: f64,
}

/// Single-scattering albedo and phase function of the cloud.
#[derive(Debug, Clone, PartialEq)]
pub struct Medium {
    pub albedo: f64,
    pub phase: Phase,
    pub chopped: Option<ChoppedMedium>,
}

impl Medium {
    pub fn new(albedo: f64, phase: Phase) -> Result<Self, FieldError> {
        check_albedo(albedo)?;
        Ok(Self {
            albedo,
            phase,
            chopped: None,
        })
    }

    /// A Mie medium: the full function everywhere, or — when the table has a chopped form — the
    /// full function on the first bounce and the chopped one (with reduced density) after it.
    pub fn mie(albedo: f64, mie: &MiePhase) -> Result<Self, FieldError> {
        check_albedo(albedo)?;
        let full = Phase::Tabulated(Arc::new(mie.full.clone()));
        let chopped = mie.chopped.as_ref().map(|c| {
            let f = c.peak_fraction;
            let density_factor = 1.0 - f * albedo;
            ChoppedMedium {
                phase: Phase::Tabulated(Arc::new(c.phase.clone()) as Arc<TabulatedPhase>),
                density_factor,
                albedo: if density_factor > 0.0 {
                    albedo * (1.0 - f) / density_factor
                } else {
                    0.0
                },
            }
        });
        Ok(Self {
            albedo,
            phase: full,
            chopped,
        })
    }

    /// Factor on σ_t for path segments that follow `scatterings` scattering events.
    #[inline]
    pub fn density_factor(&self, scatterings: u32) -> f64 {
        match (&self.chopped, scatterings) {
            (Some(c), s) if s >= 1 => c.density_factor,
            _ => 1.0,
        }
    }

    /// Albedo and phase function of the `index`-th scattering event (1-based).
    #[inline]
    pub fn vertex(&self, index: u32) -> (f64, &Phase) {
        match (&self.chopped, index) {
            (Some(c), i) if i >= 2 => (c.albedo, &c.phase),
            _ => (self.albedo, &self.phase),
        }
    }
}

fn check_albedo(a: f64) -> Result<(), FieldError> {
    if a.is_finite() && (0.0..=1.0).contains(&a) {
        Ok(())
    } else {
        Err(FieldError::new(
            "volume.albedo",
            format!("must lie in [0, 1], got {a}"),
        ))
    }
}
