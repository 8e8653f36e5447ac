//! The estimators Nimbus can render with: one enum for the command line, the evaluation and
//! the viewer.

use std::fmt;
use std::str::FromStr;

/// An estimator of light transport in the cloud.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The CPU reference path tracer (f64; delta/ratio tracking, NEE + MIS).
    Pt,
    /// The WGSL path tracer (f32; HG/isotropic phase, a constant sky or an environment map).
    PtGpu,
    /// Photon mapping with final gathering (the default): the photon map of the default
    /// variant ([`nimbus_photon::PmVariant::default`]), read at the end of k phase-sampled
    /// bounces after exact next-event estimation of the sun (`nimbus_photon::mapper` gather.rs);
    /// progressive, one sample per pixel per frame.
    Pm,
    /// Temporally-coherent photon mapping (Elek 2012) ray marched through the upsampled cache,
    /// converged ring of m frames, in the default variant: the estimator before final
    /// gathering.
    PmMarch,
    /// Photon mapping exactly as the paper publishes it (`--pm-variant elek2012`), so the
    /// default's improvements are measured against the paper.
    PmElek2012,
    /// Radiance-predicting neural network (Kallweit 2017): Monte Carlo direct light, network
    /// indirect light; a sky through the model's sky head, one query per shading point for sun
    /// and sky (`nimbus_rpnn::sky`), where the model has one.
    Rpnn,
    /// RPNN with the paper's sky: `--sky-dirs` network queries per shading point, each a sky
    /// direction (Kallweit 2017 §4.4), so the sky head is measured against it.
    RpnnDirs,
}

impl Method {
    pub const ALL: [Method; 7] = [
        Method::Pt,
        Method::PtGpu,
        Method::Pm,
        Method::PmMarch,
        Method::PmElek2012,
        Method::Rpnn,
        Method::RpnnDirs,
    ];

    /// The name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Method::Pt => "pt",
            Method::PtGpu => "pt-gpu",
            Method::Pm => "pm",
            Method::PmMarch => "pm-march",
            Method::PmElek2012 => "pm-elek2012",
            Method::Rpnn => "rpnn",
            Method::RpnnDirs => "rpnn-dirs",
        }
    }

    /// A phrase for messages ("photon mapping").
    pub fn describe(self) -> &'static str {
        match self {
            Method::Pt => "path tracing",
            Method::PtGpu => "GPU path tracing",
            Method::Pm => "photon mapping with final gathering",
            Method::PmMarch => "photon mapping (ray marched)",
            Method::PmElek2012 => "photon mapping (Elek 2012 as published)",
            Method::Rpnn => "RPNN",
            Method::RpnnDirs => "RPNN (the paper's sky directions)",
        }
    }

    /// What a budget counts: samples per pixel, or the ray-marched photon map's ring frames.
    pub fn budget_unit(self) -> &'static str {
        if self.budget_is_ring() {
            "frames"
        } else {
            "spp"
        }
    }

    /// The default evaluation sweep: four times the work per step for the Monte Carlo methods
    /// (RMSE halves per step when unbiased; every budget even, so it splits into two halves),
    /// ring sizes up to the paper's m = 100 for photon mapping.
    pub fn default_budgets(self) -> Vec<u32> {
        match self {
            Method::Pt => vec![2, 8, 32, 128],
            Method::PtGpu => vec![4, 16, 64, 256],
            Method::Pm => vec![2, 8, 32],
            Method::PmMarch | Method::PmElek2012 => vec![4, 16, 100],
            Method::Rpnn | Method::RpnnDirs => vec![2, 8, 32],
        }
    }

    /// Whether each render reports a per-pixel variance (Monte Carlo estimators do; the photon
    /// map's error is mostly low-frequency bias and is measured against a reference only).
    pub fn has_variance(self) -> bool {
        !self.budget_is_ring()
    }

    pub fn is_photon_mapping(self) -> bool {
        matches!(self, Method::Pm | Method::PmMarch | Method::PmElek2012)
    }

    /// Whether a budget is the photon map's ring size m (the ray-marched estimators), not
    /// samples per pixel.
    pub fn budget_is_ring(self) -> bool {
        matches!(self, Method::PmMarch | Method::PmElek2012)
    }

    /// Whether the method takes a sky given as an environment map (photon mapping takes a
    /// constant sky only).
    pub fn supports_env_map(self) -> bool {
        matches!(
            self,
            Method::Pt | Method::PtGpu | Method::Rpnn | Method::RpnnDirs
        )
    }

    pub fn is_rpnn(self) -> bool {
        matches!(self, Method::Rpnn | Method::RpnnDirs)
    }

    /// Whether the method always needs a GPU adapter (RPNN uses one only when its backend
    /// runs the network in WGSL).
    pub fn needs_gpu(self) -> bool {
        matches!(
            self,
            Method::PtGpu | Method::Pm | Method::PmMarch | Method::PmElek2012
        )
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s.trim())
            .ok_or_else(|| {
                format!(
                    "unknown method `{s}` (expected pt, pt-gpu, pm, pm-march, pm-elek2012, rpnn or rpnn-dirs)"
                )
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every name parses back to its method; an unknown name lists the known ones.
    #[test]
    fn names_round_trip() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>().unwrap(), m);
            assert_eq!(m.to_string(), m.name());
        }
        let e = "pm-elek".parse::<Method>().unwrap_err();
        assert!(e.contains("pm-elek2012"), "{e}");
        assert!(Method::PmElek2012.is_photon_mapping() && !Method::PmElek2012.has_variance());
        assert_eq!(Method::PmElek2012.budget_unit(), "frames");
        assert_eq!(Method::Rpnn.budget_unit(), "spp");
        assert!(Method::PtGpu.needs_gpu() && !Method::Pt.needs_gpu() && !Method::Rpnn.needs_gpu());
    }
}
