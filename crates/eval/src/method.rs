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

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use nimbus_gpu::Gpu;
use nimbus_scene::{Image, Scene};

/// An estimator.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The CPU reference path tracer (f64).
    Pt,
    /// The WGSL path tracer (f32; HG/isotropic phase, constant sky).
    PtGpu,
    /// Temporally-coherent photon mapping (Elek 2012), converged ring of m frames, in the
    /// default variant ([`nimbus_photon::PmVariant::default`]).
    Pm,
    /// Photon mapping exactly as the paper publishes it (`--pm-variant elek2012`), so the
    /// default's improvements are measured against the paper.
    PmElek2012,
    /// Radiance-predicting neural network (Kallweit 2017).
    Rpnn,
}

impl Method {
    pub const ALL: [Method; 5] = [
        Method::Pt,
        Method::PtGpu,
        Method::Pm,
        Method::PmElek2012,
        Method::Rpnn,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Method::Pt => "pt",
            Method::PtGpu => "pt-gpu",
            Method::Pm => "pm",
            Method::PmElek2012 => "pm-elek2012",
            Method::Rpnn => "rpnn",
        }
    }

    /// What the budget counts.
    pub fn budget_unit(self) -> &'static str {
        match self {
            Method::Pm | Method::PmElek2012 => "frames",
            _ => "spp",
        }
    }

    /// The default sweep: four times the work per step for the Monte Carlo methods (RMSE
    /// halves per step when unbiased; every budget even, so it splits into two halves), ring
    /// sizes up to the paper's m = 100 for photon mapping.
    pub fn default_budgets(self) -> Vec<u32> {
        match self {
            Method::Pt => vec![2, 8, 32, 128],
            Method::PtGpu => vec![4, 16, 64, 256],
            Method::Pm | Method::PmElek2012 => vec![4, 16, 100],
            Method::Rpnn => vec![2, 8, 32],
        }
    }

    /// Whether each run reports a per-pixel variance (Monte Carlo estimators do; the photon
    /// map's error is mostly low-frequency bias and is measured against the reference only).
    pub fn has_variance(self) -> bool {
        !self.is_photon_mapping()
    }

    pub fn is_photon_mapping(self) -> bool {
        matches!(self, Method::Pm | Method::PmElek2012)
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s.trim())
            .with_context(|| {
                format!("unknown method `{s}` (expected pt, pt-gpu, pm, pm-elek2012 or rpnn)")
            })
    }
}

/// Parses `pt,pm,rpnn` (no duplicates).
pub fn parse_methods(list: &str) -> Result<Vec<Method>> {
    let mut out: Vec<Method> = Vec::new();
    for m in list.split(',').filter(|s| !s.trim().is_empty()) {
        let m: Method = m.parse()?;
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
    let (m, list) = spec
        .split_once('=')
        .with_context(|| format!("--budgets `{spec}`: expected METHOD=B1,B2,… (e.g. pt=1,4,16)"))?;
    let m: Method = m.parse()?;
    let mut b = Vec::new();
    for v in list.split(',') {
        let n: u32 = v
            .trim()
            .parse()
            .with_context(|| format!("--budgets `{spec}`: `{v}` is not a whole number"))?;
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
    /// RPNN: the ONNX model (default: the shipped one).
    pub model: Option<PathBuf>,
    /// RPNN: network on the GPU (`Some(true)`), in ONNX Runtime (`Some(false)`), or the
    /// renderer's automatic choice (wgpu on hardware, ort on a software rasteriser).
    pub rpnn_gpu: Option<bool>,
    /// RPNN: sky directions per shading point and sample.
    pub sky_dirs: u32,
}

impl Default for RunSettings {
    fn default() -> Self {
        Self {
            seed: 1,
            pm_beams: 8192,
            model: None,
            rpnn_gpu: None,
            sky_dirs: 4,
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

/// A lazily created GPU, shared by the GPU methods of one evaluation.
#[derive(Default)]
pub struct GpuSlot(Option<Gpu>);

impl GpuSlot {
    pub fn get(&mut self) -> Result<&Gpu> {
        if self.0.is_none() {
            self.0 = Some(Gpu::new().context("no GPU adapter for a GPU method")?);
        }
        Ok(self.0.as_ref().expect("set above"))
    }
}

/// Runs `method` on `scene` for each budget (ascending), calling `each` after every run.
pub fn sweep(
    scene: &Scene,
    method: Method,
    budgets: &[u32],
    settings: &RunSettings,
    gpu: &mut GpuSlot,
    each: &mut dyn FnMut(&Run),
) -> Result<Vec<Run>> {
    let label = scene.source.display().to_string();
    let mut runs = Vec::new();
    let t_setup = Instant::now();
    match method {
        Method::Pt => {
            let tracer = nimbus_trace::PathTracer::new(scene);
            let setup_s = t_setup.elapsed().as_secs_f64();
            for &spp in budgets {
                let (image, half_diff, time_s) = halves(spp, settings.seed, |spp, seed| {
                    let out = nimbus_trace::render_with(
                        &tracer,
                        &nimbus_trace::RenderOptions {
                            spp,
                            seed,
                            progress: false,
                        },
                    );
                    Ok((out.image, out.stats.seconds))
                })?;
                runs.push(Run {
                    method,
                    budget: spp,
                    image,
                    variance: variance_of(&half_diff),
                    half_diff,
                    time_s,
                    gpu_ms: None,
                    setup_s,
                    device: format!("cpu ({} threads)", rayon_threads()),
                });
                each(runs.last().expect("pushed"));
            }
        }
        Method::PtGpu => {
            let gpu = gpu.get()?;
            let mut gpt = nimbus_trace::gpu::GpuPathTracer::new(gpu, scene)
                .with_context(|| format!("{label}: GPU path tracer"))?;
            let setup_s = t_setup.elapsed().as_secs_f64();
            for &spp in budgets {
                let (image, half_diff, time_s) = halves(spp, settings.seed, |spp, seed| {
                    let t0 = Instant::now();
                    let (image, _) = gpt.render(spp, seed)?;
                    Ok((image, t0.elapsed().as_secs_f64()))
                })?;
                runs.push(Run {
                    method,
                    budget: spp,
                    image,
                    variance: variance_of(&half_diff),
                    half_diff,
                    time_s,
                    gpu_ms: None,
                    setup_s,
                    device: gpu.describe(),
                });
                each(runs.last().expect("pushed"));
            }
        }
        Method::Pm | Method::PmElek2012 => {
            let gpu = gpu.get()?;
            for &frames in budgets {
                let t0 = Instant::now();
                let pm_settings = nimbus_photon::PmSettings {
                    beams_per_frame: settings.pm_beams,
                    ring: frames,
                    seed: settings.seed as u32,
                    variant: if method == Method::PmElek2012 {
                        nimbus_photon::PmVariant::Elek2012
                    } else {
                        nimbus_photon::PmVariant::default()
                    },
                    ..Default::default()
                };
                let mut pm = nimbus_photon::PhotonMapper::new(gpu, scene, pm_settings)
                    .with_context(|| format!("{label}: photon mapper"))?;
                let setup_s = t0.elapsed().as_secs_f64();
                let t1 = Instant::now();
                let mut gpu_ms = 0.0;
                while !pm.ring_full() {
                    pm.trace_frame(None);
                    gpu_ms += stage_sum(&pm.last_times);
                }
                pm.upsample();
                gpu_ms += stage_sum(&pm.last_times);
                let image = pm.raymarch(&scene.camera)?;
                gpu_ms += stage_sum(&pm.last_times);
                runs.push(Run {
                    method,
                    budget: frames,
                    image,
                    variance: None,
                    half_diff: None,
                    time_s: t1.elapsed().as_secs_f64(),
                    gpu_ms: gpu.has_timestamps().then_some(gpu_ms).filter(|&v| v > 0.0),
                    setup_s,
                    device: gpu.describe(),
                });
                each(runs.last().expect("pushed"));
            }
        }
        Method::Rpnn => {
            use nimbus_rpnn::render::{Backend, RpnnOptions};
            let path = settings
                .model
                .clone()
                .unwrap_or_else(nimbus_rpnn::model::default_model_path);
            let model = nimbus_rpnn::model::Rpnn::load(&path)?;
            let pyr = nimbus_rpnn::Pyramid::for_rendering(&scene.volume)?;
            let use_gpu = match settings.rpnn_gpu {
                Some(v) => v,
                None => gpu.get().is_ok_and(|g| !g.is_software()),
            };
            let (mut backend, device) = if use_gpu {
                let g = gpu.get()?;
                let b = nimbus_rpnn::gpu_mlp::GpuRpnn::new(
                    g,
                    &pyr,
                    &model,
                    nimbus_rpnn::gpu_mlp::DEFAULT_BATCH,
                )?;
                (
                    Backend::Wgpu(Box::new(b)),
                    format!("wgpu on {}", g.describe()),
                )
            } else {
                let b = nimbus_rpnn::ort_backend::OrtModel::load(&path, 0)?;
                (Backend::Ort(b), "ort (cpu)".to_string())
            };
            let setup_s = t_setup.elapsed().as_secs_f64();
            for &spp in budgets {
                let (image, half_diff, time_s) = halves(spp, settings.seed, |spp, seed| {
                    let opts = RpnnOptions {
                        spp,
                        seed,
                        sky_dirs: settings.sky_dirs,
                    };
                    let out = nimbus_rpnn::render::render(scene, &pyr, &mut backend, &opts)
                        .with_context(|| format!("{label}: RPNN render"))?;
                    Ok((out.image, out.times.total_ms / 1e3))
                })?;
                runs.push(Run {
                    method,
                    budget: spp,
                    image,
                    variance: variance_of(&half_diff),
                    half_diff,
                    time_s,
                    gpu_ms: None,
                    setup_s,
                    device: device.clone(),
                });
                each(runs.last().expect("pushed"));
            }
        }
    }
    Ok(runs)
}

fn stage_sum(t: &[(&'static str, f64)]) -> f64 {
    t.iter().map(|(_, v)| v).sum()
}

fn rayon_threads() -> usize {
    rayon::current_num_threads()
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
