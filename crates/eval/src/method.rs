//! The estimators under evaluation and how one budget of each is run.
//!
//! A *budget* is the knob that trades time for error: samples per pixel for the path tracers
//! and RPNN (Kallweit 2017 §6 compares them at equal time), ring frames m for photon mapping
//! (each frame traces n_g beams, so the photon count is m · n_g; Elek 2012 §5). Every run is
//! timed from the first sample to the finished image; one-time setup (pipelines, density
//! upload, density pyramid, model loading) is reported separately as `setup_s`.
//!
//! A Monte Carlo budget of b ≥ 2 samples per pixel is rendered as two independent halves of
//! b/2 (seeds `seed` and `seed ^ HALF_B`); the image is their mean and its noise is estimated
//! from their difference, E[(A − B)²/4] = Var((A + B)/2), which — unlike a per-pixel sample
//! variance — holds for the heavy-tailed samples of a delta sun through an HG lobe. The metrics
//! subtract it to measure bias ([`crate::metrics`]).

use std::path::PathBuf;

use anyhow::{Result, bail};
use nimbus_render::{NetBackend, Options, RpnnSettings};
use nimbus_scene::{Image, Scene};

pub use nimbus_render::{GpuSlot, Method};

/// Parses `pt,pm,rpnn` (no duplicates).
pub fn parse_methods(list: &str) -> Result<Vec<Method>> {
    let mut out: Vec<Method> = Vec::new();
    for m in list.split(',').filter(|s| !s.trim().is_empty()) {
        let m: Method = m.parse().map_err(anyhow::Error::msg)?;
        if out.contains(&m) {
            bail!("--methods lists `{m}` twice");
        }
        out.push(m);
    }
    if out.is_empty() {
        bail!("--methods is empty");
    }
    Ok(out)
}

/// Parses a budget override `method=b1,b2,…` (each budget 1 ..= 65 536).
pub fn parse_budgets(spec: &str) -> Result<(Method, Vec<u32>)> {
    let (m, list) = spec.split_once('=').ok_or_else(|| {
        anyhow::anyhow!("--budgets `{spec}`: expected METHOD=B1,B2,… (e.g. pt=1,4,16)")
    })?;
    let m: Method = m.parse().map_err(anyhow::Error::msg)?;
    let mut b = Vec::new();
    for v in list.split(',') {
        let n: u32 = v.trim().parse().map_err(|_| {
            anyhow::anyhow!("--budgets `{spec}`: `{v}` is not a whole number in 1..=65536")
        })?;
        if !(1..=65_536).contains(&n) {
            bail!("--budgets `{spec}`: {n} lies outside 1..=65536");
        }
        b.push(n);
    }
    b.sort_unstable();
    b.dedup();
    Ok((m, b))
}

/// Settings shared by every run of an evaluation.
#[derive(Debug, Clone)]
pub struct RunSettings {
    /// Seed of the method runs (the reference uses an independent stream).
    pub seed: u64,
    /// Photon mapping: beams per frame n_g.
    pub pm_beams: u32,
    /// Photon mapping with final gathering: bounces and the sun's shadows.
    pub pm_gather: nimbus_photon::GatherSettings,
    /// RPNN: the ONNX model (default: the shipped one).
    pub model: Option<PathBuf>,
    /// RPNN: where the network runs.
    pub rpnn_backend: NetBackend,
    /// RPNN: sky directions per shading point and sample.
    pub sky_dirs: u32,
    /// RPNN with a sky head: the sky's spherical-harmonic degree.
    pub sky_degree: usize,
    /// RPNN with the network on the GPU: shade on the CPU anyway (the hybrid path).
    pub cpu_shading: bool,
    /// RPNN with the network on the GPU: f32 or f16 weights and activations.
    pub rpnn_precision: nimbus_rpnn::gpu_mlp::Precision,
    /// RPNN with the network on the GPU: its kernel.
    pub rpnn_tiles: nimbus_rpnn::gpu_mlp::Tiles,
    /// RPNN: bounces traced before the network is asked (0: the paper).
    pub traced_bounces: u32,
    /// RPNN: one sample in every this many asks the network (1: the paper).
    pub query_every: u32,
}

impl Default for RunSettings {
    fn default() -> Self {
        Self {
            seed: 1,
            pm_beams: 8192,
            pm_gather: Default::default(),
            model: None,
            rpnn_backend: NetBackend::Auto,
            sky_dirs: 4,
            sky_degree: nimbus_rpnn::sky::SH_DEGREE,
            cpu_shading: false,
            rpnn_precision: Default::default(),
            rpnn_tiles: Default::default(),
            traced_bounces: 0,
            query_every: 1,
        }
    }
}

/// One finished run.
#[derive(Debug, Clone)]
pub struct Run {
    pub method: Method,
    pub budget: u32,
    pub image: Image,
    /// Variance of each pixel's mean luminance, (A − B)²/4 from the two halves (Monte Carlo
    /// methods with ≥ 2 samples per pixel; one sample has no noise estimate).
    pub variance: Option<Vec<f32>>,
    /// Luminance of half A − half B per pixel (block-level noise estimates).
    pub half_diff: Option<Vec<f32>>,
    /// Wall time from the first sample to the finished image.
    pub time_s: f64,
    /// GPU time from timestamp queries, when the adapter has them.
    pub gpu_ms: Option<f64>,
    /// One-time setup before the first budget (shared by the sweep).
    pub setup_s: f64,
    /// Where it ran (`cpu`, the adapter, `ort`, …).
    pub device: String,
}

/// The second half's seed offset.
pub const HALF_B: u64 = 0x5851_f42d_4c95_7f2d;

/// Renders a Monte Carlo budget of `spp` as halves (see the module docs) with `render(spp,
/// seed)`; returns (image, half difference, seconds summed over the renders).
fn halves(
    spp: u32,
    seed: u64,
    mut render: impl FnMut(u32, u64) -> Result<(Image, f64)>,
) -> Result<(Image, Option<Vec<f32>>, f64)> {
    if spp < 2 {
        let (img, t) = render(spp, seed)?;
        return Ok((img, None, t));
    }
    let (a, ta) = render(spp / 2, seed)?;
    let (b, tb) = render(spp - spp / 2, seed ^ HALF_B)?;
    let mut img = Image::new(a.width, a.height);
    let mut diff = vec![0.0f32; a.pixels.len()];
    for (i, (pa, pb)) in a.pixels.iter().zip(&b.pixels).enumerate() {
        img.pixels[i] = [0, 1, 2].map(|c| 0.5 * (pa[c] + pb[c]));
        diff[i] = (pa[0] + pa[1] + pa[2] - pb[0] - pb[1] - pb[2]) / 3.0;
    }
    Ok((img, Some(diff), ta + tb))
}

fn variance_of(diff: &Option<Vec<f32>>) -> Option<Vec<f32>> {
    diff.as_ref()
        .map(|d| d.iter().map(|v| v * v / 4.0).collect())
}

impl RunSettings {
    /// The estimators' options for these settings (everything else at its default).
    pub fn options(&self) -> Options {
        Options {
            progress: false,
            pm: nimbus_photon::PmSettings {
                beams_per_frame: self.pm_beams,
                ..Default::default()
            },
            pm_half_res: false,
            pm_gather: self.pm_gather,
            impostors: None,
            pm_density_max: None,
            rpnn: RpnnSettings {
                model: self.model.clone(),
                backend: self.rpnn_backend,
                sky_dirs: self.sky_dirs,
                strict: false,
                sky_degree: self.sky_degree,
                cpu_shading: self.cpu_shading,
                precision: self.rpnn_precision,
                tiles: self.rpnn_tiles,
                traced_bounces: self.traced_bounces,
                query_every: self.query_every,
            },
        }
    }
}

/// Runs `method` on `scene` for each budget (ascending), calling `each` after every run: one
/// [`nimbus_render::prepare`] (its time is the runs' `setup_s`), then one render per budget
/// (Monte Carlo budgets as two halves; a photon map is built per ring size, and that build is
/// its `setup_s`).
pub fn sweep(
    scene: &Scene,
    method: Method,
    budgets: &[u32],
    settings: &RunSettings,
    gpu: &mut GpuSlot,
    each: &mut dyn FnMut(&Run),
) -> Result<Vec<Run>> {
    let gpu: &GpuSlot = gpu;
    let mut est = nimbus_render::prepare(scene, method, &settings.options(), gpu)?;
    // What the estimator cannot honour (a model trained for another medium, a depth limit):
    // said, whatever the progress setting.
    for w in &est.warnings {
        eprintln!("{w}");
    }
    let mut runs = Vec::new();
    for &budget in budgets {
        let run = if method.has_variance() {
            let (image, half_diff, time_s) = halves(budget, settings.seed, |spp, seed| {
                let r = est.render(spp, seed)?;
                Ok((r.image, r.seconds))
            })?;
            Run {
                method,
                budget,
                image,
                variance: variance_of(&half_diff),
                half_diff,
                time_s,
                gpu_ms: None,
                setup_s: est.prepare_s,
                device: est.device.clone(),
            }
        } else {
            let r = est.render(budget, settings.seed)?;
            Run {
                method,
                budget,
                image: r.image,
                variance: None,
                half_diff: None,
                time_s: r.seconds,
                gpu_ms: r.gpu_ms,
                setup_s: r.setup_s,
                device: est.device.clone(),
            }
        };
        runs.push(run);
        each(runs.last().expect("pushed"));
    }
    Ok(runs)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every method's name parses back to it; the paper's photon mapping is its own method so
    /// `compare` and `bench-suite` can put it beside the default; duplicates and unknown names
    /// are refused by name.
    #[test]
    fn method_names_round_trip() {
        for m in Method::ALL {
            assert_eq!(m.name().parse::<Method>().unwrap(), m);
        }
        assert_eq!(
            parse_methods("pm,pm-elek2012").unwrap(),
            vec![Method::Pm, Method::PmElek2012]
        );
        assert!(Method::PmElek2012.is_photon_mapping() && !Method::PmElek2012.has_variance());
        assert_eq!(Method::PmElek2012.budget_unit(), "frames");
        let e = parse_methods("pm,pm").unwrap_err().to_string();
        assert!(e.contains("twice"), "{e}");
        let e = parse_methods("pm-elek").unwrap_err().to_string();
        assert!(e.contains("pm-elek2012"), "{e}");
    }
}
