//! [`prepare`] an estimator once per scene, then [`Estimator::render`] it for any budget.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use nimbus_gpu::Gpu;
use nimbus_photon::{PhotonMapper, PmSettings, PmVariant};
use nimbus_rpnn::render::{Backend, RpnnOptions};
use nimbus_rpnn::{Pyramid, model::Rpnn};
use nimbus_scene::{Image, Scene};
use nimbus_trace::{PathTracer, RenderOptions, gpu::GpuPathTracer};

use crate::{GpuSlot, Method, NetBackend};

/// RPNN's settings.
#[derive(Debug, Clone)]
pub struct RpnnSettings {
    /// The ONNX model (default: the shipped `models/rpnn-hg.onnx`).
    pub model: Option<PathBuf>,
    /// Where the network runs.
    pub backend: NetBackend,
    /// Sky directions per shading point and sample (network queries for sky light).
    pub sky_dirs: u32,
    /// Refuse, instead of warning, when the scene's phase function or albedo differs from the
    /// model's training data.
    pub strict: bool,
}

impl Default for RpnnSettings {
    fn default() -> Self {
        Self {
            model: None,
            backend: NetBackend::Auto,
            sky_dirs: 4,
            strict: false,
        }
    }
}

/// Settings of every estimator (each reads its own).
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// CPU path tracer: a progress bar on stderr.
    pub progress: bool,
    /// Photon mapping (the ring size and seed come from each render's budget and seed; the
    /// variant from the method for [`Method::PmElek2012`]).
    pub pm: PmSettings,
    /// Photon mapping: ray march at half resolution and upsample the image.
    pub pm_half_res: bool,
    /// RPNN.
    pub rpnn: RpnnSettings,
}

/// One image and what it cost.
pub struct Rendered {
    pub image: Image,
    /// Per-pixel variance of the mean luminance (Monte Carlo estimators).
    pub variance: Option<Vec<f32>>,
    /// Wall time of the render itself.
    pub seconds: f64,
    /// Set-up done inside this render that a budget sweep books apart (the photon map is
    /// built anew for each ring size).
    pub setup_s: f64,
    /// GPU time from timestamp queries, when the adapter has them (photon mapping).
    pub gpu_ms: Option<f64>,
    /// One line: what ran, on what, how fast (without the scene's name).
    pub summary: String,
    /// Per-stage timings, one line each (`--timings`).
    pub timing_lines: Vec<String>,
}

/// A prepared estimator: the work a scene needs once is done, renders are cheap to repeat.
pub struct Estimator<'a> {
    method: Method,
    scene: &'a Scene,
    opts: Options,
    /// Seconds [`prepare`] took.
    pub prepare_s: f64,
    /// Where it runs (`cpu (2 threads)`, the adapter, `ort (cpu)`, …).
    pub device: String,
    /// Warnings for the user (an RPNN model trained for another medium).
    pub warnings: Vec<String>,
    state: State<'a>,
}

enum State<'a> {
    Pt(PathTracer<'a>),
    PtGpu(Box<GpuPathTracer<'a>>),
    Pm(&'a Gpu),
    Rpnn {
        model_path: PathBuf,
        pyramid: Pyramid,
        backend: Backend<'a>,
    },
}

/// The range of coordinates and box extents (`F32_SCALE`) and of the largest extinction
/// (`F32_SIGMA`) the 32-bit estimators are given: pt-gpu, pm and RPNN's descriptors compute in
/// f32. Measured on one cloud rescaled by 10^E (box ±10^E, density scale 10^−E, so the largest
/// extinction is 5·10^−(E+1); the same image in f64): correct for −38 ≤ E ≤ 33, pt-gpu 64 % dark
/// at E = 34 and black from 35, pm 27 % dark from 34. The bounds keep margins of 10³ and more.
const F32_SCALE: [f64; 2] = [1e-30, 1e30];
const F32_SIGMA: [f64; 2] = [1e-32, 1e32];

/// Refuses a scene modelled at a scale the f32 estimators cannot represent (it would render
/// black or without its cloud, without a word); `pt` (f64) renders it.
pub fn check_f32_scale(scene: &Scene, method: Method) -> Result<()> {
    let [lo, hi] = F32_SCALE;
    let [slo, shi] = F32_SIGMA;
    let aabb = scene.volume.aabb();
    let coord = |v: glam::DVec3| v.abs().max_element();
    let sigma = scene.volume.max_sigma_t();
    let box_coord = coord(aabb.min).max(coord(aabb.max));
    let bad = if box_coord > hi {
        Some(("volume.aabb_min/aabb_max", "a coordinate", box_coord))
    } else if aabb.extent().min_element() < lo {
        Some((
            "volume.aabb_min/aabb_max",
            "the box's smallest extent",
            aabb.extent().min_element(),
        ))
    } else if coord(scene.camera.origin) > hi {
        Some(("camera.origin", "a coordinate", coord(scene.camera.origin)))
    } else if sigma > 0.0 && !(slo..=shi).contains(&sigma) {
        Some((
            "volume.density_scale",
            "the largest extinction (density scale × the grid's maximum)",
            sigma,
        ))
    } else {
        None
    };
    if let Some((field, what, v)) = bad {
        bail!(
            "{}: field `{field}`: {what} is {v:e}; {method} computes in 32-bit floats and needs \
             coordinates and extents within [{lo:e}, {hi:e}] and extinctions within \
             [{slo:e}, {shi:e}] (rescale the scene, or render it with pt, which computes in \
             64-bit floats)",
            scene.source.display()
        );
    }
    Ok(())
}

/// Prepares `method` on `scene`: the majorant grid (path tracer), the GPU pipelines and
/// buffers (GPU path tracer), the device (photon mapping), or the model, density pyramid and
/// network backend (RPNN). A GPU is opened through `gpu` only when the method needs one.
pub fn prepare<'a>(
    scene: &'a Scene,
    method: Method,
    opts: &Options,
    gpu: &'a GpuSlot,
) -> Result<Estimator<'a>> {
    let t0 = Instant::now();
    let label = scene.source.display().to_string();
    let mut warnings = Vec::new();
    if let Some(d) = scene.render.max_depth
        && !matches!(method, Method::Pt | Method::PtGpu)
    {
        warnings.push(format!(
            "warning: {label}: render.max_depth = {d} is honoured by pt and pt-gpu only; \
             {method} computes every order of scattering"
        ));
    }
    if method != Method::Pt {
        check_f32_scale(scene, method)?;
    }
    let (state, device) = match method {
        Method::Pt => (
            State::Pt(PathTracer::new(scene)),
            format!("cpu ({} threads)", rayon::current_num_threads()),
        ),
        Method::PtGpu => {
            let g = gpu.get()?;
            let t = GpuPathTracer::new(g, scene)
                .with_context(|| format!("{label}: GPU path tracer"))?;
            (State::PtGpu(Box::new(t)), g.describe())
        }
        Method::Pm | Method::PmElek2012 => {
            let g = gpu.get()?;
            (State::Pm(g), g.describe())
        }
        Method::Rpnn => {
            let r = &opts.rpnn;
            if scene.sky.is_some() && !(1..=1024).contains(&r.sky_dirs) {
                bail!(
                    "--sky-dirs must lie in 1..=1024 for a scene with a sky (0 would drop the sky's multiple scattering), got {}",
                    r.sky_dirs
                );
            }
            let model_path = r
                .model
                .clone()
                .unwrap_or_else(|| nimbus_rpnn::model::model_path_for(&scene.phase_desc));
            let model = Rpnn::load(&model_path)?;
            let mismatches = [
                nimbus_rpnn::render::phase_mismatch(scene, &model.phase),
                nimbus_rpnn::render::albedo_mismatch(scene, model.albedo),
            ];
            for w in mismatches.into_iter().flatten() {
                if r.strict {
                    bail!(
                        "{}: {} (--strict)",
                        model_path.display(),
                        w.trim_start_matches("warning: ")
                    );
                }
                warnings.push(w);
            }
            // The pyramid's errors carry their cause in their message: formatted once.
            let pyramid = Pyramid::for_rendering(&scene.volume)
                .map_err(|e| anyhow::anyhow!("{label}: {e}"))?;
            let adapter = match r.backend {
                NetBackend::Ort => None,
                NetBackend::Wgpu => Some(gpu.get()?),
                NetBackend::Auto => gpu.try_get(),
            };
            let (backend, device) =
                rpnn_backend(r.backend, adapter, &model_path, &model, &pyramid)?;
            (
                State::Rpnn {
                    model_path,
                    pyramid,
                    backend,
                },
                device,
            )
        }
    };
    Ok(Estimator {
        method,
        scene,
        opts: opts.clone(),
        prepare_s: t0.elapsed().as_secs_f64(),
        device,
        warnings,
        state,
    })
}

/// RPNN's network backend: WGSL on `adapter` or ONNX Runtime, as `choice` and the adapter
/// say ([`NetBackend::uses_wgpu`]); returns it with a description of where it runs. The one
/// place that makes this choice (the estimator and the viewer call it).
pub fn rpnn_backend<'g>(
    choice: NetBackend,
    adapter: Option<&'g Gpu>,
    model_path: &std::path::Path,
    model: &Rpnn,
    pyramid: &Pyramid,
) -> Result<(Backend<'g>, String)> {
    if choice.uses_wgpu(adapter.map(Gpu::is_software)) {
        let Some(g) = adapter else {
            bail!(
                "the RPNN network on wgpu needs a GPU adapter (--backend ort runs it on the CPU)"
            );
        };
        match nimbus_rpnn::gpu_mlp::GpuRpnn::new(
            g,
            pyramid,
            model,
            nimbus_rpnn::gpu_mlp::DEFAULT_BATCH,
        ) {
            Ok(b) => {
                return Ok((
                    Backend::Wgpu(Box::new(b)),
                    format!("wgpu on {}", g.describe()),
                ));
            }
            // A pyramid beyond the adapter's binding limit (a sparse cloud's level in a huge
            // box): the automatic choice reads it on the CPU instead, and says so.
            Err(e @ (nimbus_gpu::GpuError::TooLarge { .. } | nimbus_gpu::GpuError::Memory(_)))
                if choice == NetBackend::Auto =>
            {
                let b = nimbus_rpnn::ort_backend::OrtModel::load(model_path, 0)?;
                return Ok((Backend::Ort(b), format!("ort (cpu; not the GPU: {e})")));
            }
            Err(e) => return Err(e.into()),
        }
    }
    let b = nimbus_rpnn::ort_backend::OrtModel::load(model_path, 0)?;
    Ok((Backend::Ort(b), "ort (cpu)".to_string()))
}

impl Estimator<'_> {
    pub fn method(&self) -> Method {
        self.method
    }

    /// Renders with `budget` samples per pixel (Monte Carlo methods) or a ring of `budget`
    /// frames (photon mapping), from `seed`.
    pub fn render(&mut self, budget: u32, seed: u64) -> Result<Rendered> {
        let label = self.scene.source.display().to_string();
        let cam = &self.scene.camera;
        let pixels = (cam.width * cam.height) as f64;
        match &mut self.state {
            State::Pt(tracer) => {
                let out = nimbus_trace::render_with(
                    tracer,
                    &RenderOptions {
                        spp: budget,
                        seed,
                        progress: self.opts.progress,
                    },
                );
                let st = out.stats;
                Ok(Rendered {
                    image: out.image,
                    variance: Some(out.variance),
                    seconds: st.seconds,
                    setup_s: 0.0,
                    gpu_ms: None,
                    summary: format!(
                        "path tracing {}x{} at {} spp in {:.2} s ({:.3e} camera paths/s, {:.1} scatterings/path)",
                        cam.width,
                        cam.height,
                        budget,
                        st.seconds,
                        st.paths_per_second(),
                        st.scatterings as f64 / st.paths.max(1) as f64,
                    ),
                    timing_lines: Vec::new(),
                })
            }
            State::PtGpu(gpt) => {
                let t0 = Instant::now();
                let (image, variance) = gpt.render(budget, seed)?;
                let seconds = t0.elapsed().as_secs_f64();
                // As the command line has always reported it: set-up and render together.
                let total = self.prepare_s + seconds;
                Ok(Rendered {
                    image,
                    variance: Some(variance),
                    seconds,
                    setup_s: 0.0,
                    gpu_ms: None,
                    summary: format!(
                        "GPU path tracing on {} — {}x{} at {} spp in {:.2} s ({:.3e} camera paths/s)",
                        self.device,
                        cam.width,
                        cam.height,
                        budget,
                        total,
                        pixels * budget as f64 / total.max(1e-9)
                    ),
                    timing_lines: Vec::new(),
                })
            }
            State::Pm(gpu) => {
                let t0 = Instant::now();
                let mut settings = PmSettings {
                    ring: budget,
                    seed: seed as u32,
                    ..self.opts.pm.clone()
                };
                if self.method == Method::PmElek2012 {
                    settings.variant = PmVariant::Elek2012;
                }
                let beams = settings.beams_per_frame;
                let mut pm = PhotonMapper::new(gpu, self.scene, settings)
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
                let image = if self.opts.pm_half_res {
                    pm.raymarch_half(cam)?
                } else {
                    pm.raymarch(cam)?
                };
                gpu_ms += stage_sum(&pm.last_times);
                let seconds = t1.elapsed().as_secs_f64();
                let mut timing_lines = Vec::new();
                if pm.last_times.is_empty() {
                    timing_lines.push("GPU timestamps are not available on this adapter".into());
                }
                for (stage, ms) in &pm.last_times {
                    timing_lines.push(format!("  {stage:14} {ms:9.3} ms (last frame)"));
                }
                Ok(Rendered {
                    image,
                    variance: None,
                    seconds,
                    setup_s,
                    gpu_ms: gpu.has_timestamps().then_some(gpu_ms).filter(|&v| v > 0.0),
                    summary: format!(
                        "photon mapping on {} — {} frames × {} beams, cache {:?} ({}){}, {}x{} in {:.2} s",
                        self.device,
                        pm.frames(),
                        beams,
                        pm.cache_res(),
                        if pm.uses_shared_memory() {
                            "workgroup memory"
                        } else {
                            "global atomics"
                        },
                        [pm.light_note(), pm.cache_note()]
                            .into_iter()
                            .flatten()
                            .map(|n| format!(", {n}"))
                            .collect::<String>(),
                        cam.width,
                        cam.height,
                        setup_s + seconds
                    ),
                    timing_lines,
                })
            }
            State::Rpnn {
                model_path,
                pyramid,
                backend,
            } => {
                let ro = RpnnOptions {
                    spp: budget,
                    seed,
                    sky_dirs: self.opts.rpnn.sky_dirs,
                };
                let out = nimbus_rpnn::render::render(self.scene, pyramid, backend, &ro)
                    .with_context(|| format!("{label}: RPNN render"))?;
                let t = &out.times;
                let n = budget as f64;
                Ok(Rendered {
                    summary: format!(
                        "RPNN ({}, {}) {}x{} at {} spp in {:.2} s — {:.1} ms per spp, {} network queries",
                        model_path.display(),
                        backend.name(),
                        cam.width,
                        cam.height,
                        budget,
                        t.total_ms / 1e3,
                        t.total_ms / n,
                        t.queries
                    ),
                    timing_lines: vec![
                        format!("  descriptor {:9.2} ms per spp", t.descriptor_ms / n),
                        format!("  inference  {:9.2} ms per spp", t.inference_ms / n),
                        format!("  rest       {:9.2} ms per spp", t.rest_ms / n),
                    ],
                    seconds: t.total_ms / 1e3,
                    setup_s: 0.0,
                    gpu_ms: None,
                    variance: Some(out.variance),
                    image: out.image,
                })
            }
        }
    }
}

fn stage_sum(t: &[(&'static str, f64)]) -> f64 {
    t.iter().map(|(_, v)| v).sum()
}
