//! RPNN (Kallweit 2017 §4.4): Monte Carlo direct light, the network's indirect light. The
//! density pyramid, majorant grid and network backend are built once per density; the image
//! is a running sum of samples. With the network on the GPU the whole sample runs there
//! ([`nimbus_rpnn::gpu_sample`]) where the scene allows it; otherwise (ONNX Runtime, the
//! paper's sky directions, a tabulated phase function, or `cpu_shading`) camera rays,
//! tracking and direct light run on the CPU ([`nimbus_rpnn::render`]).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use nimbus_gpu::Gpu;
use nimbus_rpnn::Pyramid;
use nimbus_rpnn::gpu_mlp::{NetOptions, Precision, Tiles};
use nimbus_rpnn::gpu_sample::GpuSampler;
use nimbus_rpnn::model::Rpnn;
use nimbus_rpnn::ort_backend::{Cores, OrtModel};
use nimbus_rpnn::render::{Backend, RpnnOptions, RpnnSums, SkySh, StageTimes};
use nimbus_scene::volume::MajorantGrid;
use nimbus_scene::{Cancel, Scene};

use super::{Change, Engine, Rendered, Step};
use crate::{GpuSource, Method, NetBackend};

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
    /// Spherical-harmonic degree (0 … 4) of the sky the sky head's transfer is contracted
    /// with ([`Method::Rpnn`] with a sky and a model with a sky head).
    pub sky_degree: usize,
    /// With the network on the GPU: camera rays, tracking and direct light on the CPU anyway
    /// (the hybrid path, for comparison); off: the whole sample on the GPU where the scene
    /// allows it ([`nimbus_rpnn::gpu_sample`]).
    pub cpu_shading: bool,
    /// With the network on the GPU: how its weights and hidden activations are stored (f32,
    /// or f16 with f32 accumulation).
    pub precision: nimbus_rpnn::gpu_mlp::Precision,
    /// With the network on the GPU: its kernel (the same products, tiled differently).
    pub tiles: nimbus_rpnn::gpu_mlp::Tiles,
    /// Bounces traced before the network is asked (0: the paper;
    /// [`nimbus_rpnn::render::RpnnOptions::traced_bounces`]). More than 0 shades on the CPU.
    pub traced_bounces: u32,
    /// One sample in every `query_every` of a pixel asks the network (1: every sample, the
    /// paper; [`nimbus_rpnn::render::RpnnOptions::query_every`]).
    pub query_every: u32,
}

impl RpnnSettings {
    /// Whether camera rays, tracking and direct light run on the CPU: asked for, or traced
    /// bounces (the GPU sample asks the network at the first vertex).
    pub fn shades_on_cpu(&self) -> bool {
        self.cpu_shading || self.traced_bounces > 0
    }

    /// How the WGSL network is built.
    pub fn net(&self) -> nimbus_rpnn::gpu_mlp::NetOptions {
        nimbus_rpnn::gpu_mlp::NetOptions {
            precision: self.precision,
            tiles: self.tiles,
        }
    }
}

impl Default for RpnnSettings {
    fn default() -> Self {
        Self {
            model: None,
            backend: NetBackend::Auto,
            sky_dirs: 4,
            strict: false,
            sky_degree: nimbus_rpnn::sky::SH_DEGREE,
            cpu_shading: false,
            precision: Default::default(),
            tiles: Default::default(),
            traced_bounces: 0,
            query_every: 1,
        }
    }
}

/// The model `--method rpnn` / `rpnn-dirs` loads: `explicit` (`--model`) when given; under a
/// sky with `rpnn` the shipped sky-head model for the phase function where it is there
/// ([`nimbus_rpnn::model::sky_model_path_for`]); else the shipped model for the phase function
/// ([`nimbus_rpnn::model::model_path_for`]). Without a sky never the sky head.
pub fn rpnn_model_path(
    explicit: Option<&std::path::Path>,
    method: Method,
    phase_desc: &str,
    has_sky: bool,
) -> PathBuf {
    if let Some(p) = explicit {
        return p.to_path_buf();
    }
    let sky = (method == Method::Rpnn && has_sky)
        .then(|| nimbus_rpnn::model::sky_model_path_for(phase_desc))
        .flatten();
    sky.unwrap_or_else(|| nimbus_rpnn::model::model_path_for(phase_desc))
}

/// Prepares RPNN (Kallweit 2017 §4–5) on `scene`: the model (checked against the scene's
/// medium: a warning, or an error with `strict`), the density pyramid, the sky head's
/// projection of the sky and the network's runner. What the user should know goes to
/// `warnings`. Returns the engine and where it runs.
pub(crate) fn prepare<'g>(
    scene: &Scene,
    method: Method,
    r: &RpnnSettings,
    gpu: impl GpuSource<'g>,
    label: &str,
    warnings: &mut Vec<String>,
) -> Result<(Box<dyn Engine + Send + 'g>, String)> {
    if scene.sky.is_some() && !(1..=1024).contains(&r.sky_dirs) {
        bail!(
            "--sky-dirs must lie in 1..=1024 for a scene with a sky (0 would drop the sky's multiple scattering), got {}",
            r.sky_dirs
        );
    }
    // Before the model and the pyramid are made.
    nimbus_rpnn::render::check_query_every(r.query_every)?;
    let want_sky = method == Method::Rpnn && scene.sky.is_some();
    let model_path = rpnn_model_path(
        r.model.as_deref(),
        method,
        &scene.phase_desc,
        scene.sky.is_some(),
    );
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
    let pyramid =
        Pyramid::for_rendering(&scene.volume).map_err(|e| anyhow::anyhow!("{label}: {e}"))?;
    let adapter = match r.backend {
        NetBackend::Ort | NetBackend::OrtInt8 => None,
        NetBackend::Wgpu => Some(gpu.get()?),
        NetBackend::Auto => gpu.try_get(),
    };
    // The sky head runs on either backend (ONNX Runtime, or the WGSL network's sky
    // layers).
    let sky_sh = if want_sky && model.sky_coeffs() > 0 {
        nimbus_rpnn::render::SkySh::of(scene, r.sky_degree, 64)
    } else {
        if want_sky && r.model.is_none() {
            warnings.push(format!(
                "warning: {}: no sky head; the sky is sampled in --sky-dirs directions",
                model_path.display()
            ));
        }
        None
    };
    let cpu_shading = r.shades_on_cpu();
    let (runner, device, note) = runner(
        r.backend,
        cpu_shading,
        r.net(),
        adapter,
        &model_path,
        &model,
        &pyramid,
        scene,
        sky_sh.as_ref(),
        r.sky_dirs,
        r.query_every,
    )?;
    if let Some(n) = note
        && !cpu_shading
    {
        warnings.push(format!("note: {label}: {n}"));
    }
    // Settings of a path this render does not take, said instead of ignored.
    let defaults = RpnnSettings::default();
    if !runner.network_in_wgsl() {
        let gpu_only: Vec<&str> = [
            (r.cpu_shading, "--cpu-shading"),
            (r.precision != defaults.precision, "--net-precision"),
            (r.tiles != defaults.tiles, "--net-tiles"),
        ]
        .into_iter()
        .filter_map(|(set, flag)| set.then_some(flag))
        .collect();
        if !gpu_only.is_empty() {
            warnings.push(format!(
                "warning: {label}: {} are settings of the WGSL network (--backend \
                 wgpu); ignored: the network runs on {device}",
                gpu_only.join(", ")
            ));
        }
    }
    if sky_sh.is_none() && r.sky_degree != defaults.sky_degree {
        warnings.push(format!(
            "warning: {label}: --sky-degree applies to a sky head's sky \
             (--method rpnn, a model with one, a scene with a sky); ignored"
        ));
    }
    Ok((
        Box::new(RpnnEngine::new(
            scene,
            Network {
                path: model_path,
                model,
                runner,
                adapter,
            },
            pyramid,
            r,
            sky_sh,
        )),
        device,
    ))
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
    net: nimbus_rpnn::gpu_mlp::NetOptions,
) -> Result<(Backend<'g>, String)> {
    if choice.uses_wgpu(adapter.map(Gpu::is_software)) {
        let Some(g) = adapter else {
            bail!(
                "the RPNN network on wgpu needs a GPU adapter (--backend ort runs it on the CPU)"
            );
        };
        match nimbus_rpnn::gpu_mlp::GpuRpnn::with_options(
            g,
            pyramid,
            model,
            nimbus_rpnn::gpu_mlp::DEFAULT_BATCH,
            net,
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
                let b = OrtModel::load(model_path, Cores::Workers(0))?;
                let cpu = ort_cpu(&b);
                return Ok((Backend::Ort(b), format!("ort ({cpu}; not the GPU: {e})")));
            }
            Err(e) => return Err(e.into()),
        }
    }
    if choice == NetBackend::OrtInt8 {
        let b = OrtModel::load_int8(model_path, Cores::Workers(0))?;
        let cpu = ort_cpu(&b);
        return Ok((Backend::Ort(b), format!("ort int8 ({cpu})")));
    }
    let b = OrtModel::load(model_path, Cores::Workers(0))?;
    let cpu = ort_cpu(&b);
    Ok((Backend::Ort(b), format!("ort ({cpu})")))
}

/// How ONNX Runtime runs, for the device line: `cpu: 2 sessions` (one single-threaded session
/// per core, [`Cores::Workers`]). No comma: the line is a field of `report.csv`.
fn ort_cpu(b: &OrtModel) -> String {
    match b.workers() {
        1 => "cpu: 1 session".to_string(),
        n => format!("cpu: {n} sessions"),
    }
}

/// Where a sample runs: shading on the CPU with a network backend, or all of it on the GPU.
pub(crate) enum Runner<'g> {
    Cpu(Backend<'g>),
    Gpu(Box<GpuSampler<'g>>),
}

impl Runner<'_> {
    /// Whether the network runs in WGSL (the whole sample on the GPU, or CPU shading with the
    /// WGSL network), where its precision and kernel apply.
    pub(crate) fn network_in_wgsl(&self) -> bool {
        matches!(self, Runner::Gpu(_) | Runner::Cpu(Backend::Wgpu(_)))
    }

    fn name(&self) -> &'static str {
        match self {
            Runner::Cpu(b) => b.name(),
            Runner::Gpu(_) => "wgpu, whole sample on the GPU",
        }
    }
}

/// The runner for `model` on `scene`: the whole sample on the GPU when the network runs in
/// WGSL ([`NetBackend::uses_wgpu`]), `cpu_shading` is off and the scene allows it
/// ([`nimbus_rpnn::gpu_sample::unsupported`]); else CPU shading with [`rpnn_backend`]. Returns
/// it with where it runs and, when the GPU network falls back to CPU shading, why.
#[allow(clippy::too_many_arguments)]
pub(crate) fn runner<'g>(
    choice: NetBackend,
    cpu_shading: bool,
    net_opts: NetOptions,
    adapter: Option<&'g Gpu>,
    model_path: &std::path::Path,
    model: &Rpnn,
    pyramid: &Pyramid,
    scene: &Scene,
    sky_sh: Option<&SkySh>,
    sky_dirs: u32,
    query_every: u32,
) -> Result<(Runner<'g>, String, Option<String>)> {
    let mut note = None;
    if let Some(g) = adapter
        && choice.uses_wgpu(Some(g.is_software()))
    {
        match nimbus_rpnn::gpu_sample::unsupported(scene, model, sky_sh, sky_dirs) {
            None if !cpu_shading => {
                let settings = nimbus_rpnn::gpu_sample::SamplerSettings {
                    precision: net_opts.precision,
                    tiles: net_opts.tiles,
                    sky_dirs,
                    query_every,
                    ..Default::default()
                };
                match GpuSampler::with_settings(g, scene, pyramid, model, sky_sh, &settings) {
                    Ok(s) => {
                        return Ok((
                            Runner::Gpu(Box::new(s)),
                            format!("wgpu on {} (whole sample)", g.describe()),
                            None,
                        ));
                    }
                    // Beyond the adapter's bindings: CPU shading (its own checks decide
                    // between the GPU network and ONNX Runtime).
                    Err(nimbus_rpnn::render::RenderError::Gpu(e)) => {
                        note = Some(format!("CPU shading: {e}"));
                    }
                    Err(e) => return Err(e.into()),
                }
            }
            None => {}
            Some(why) => note = Some(format!("CPU shading: {why}")),
        }
    }
    // The WGSL network leaves out a sky head nothing contracts with (ONNX Runtime runs the
    // file as it is; the renderer reads the sun's columns).
    let sun_only;
    let net = if sky_sh.is_none() && model.sky_coeffs() > 0 {
        sun_only = model.without_sky_head();
        &sun_only
    } else {
        model
    };
    let (b, device) = rpnn_backend(choice, adapter, model_path, net, pyramid, net_opts)?;
    Ok((Runner::Cpu(b), device, note))
}

pub(crate) struct RpnnEngine<'g> {
    model_path: PathBuf,
    model: Rpnn,
    pyramid: Pyramid,
    runner: Runner<'g>,
    /// The adapter the backend was chosen with (rebuilt on a new density).
    adapter: Option<&'g Gpu>,
    choice: NetBackend,
    cpu_shading: bool,
    net: NetOptions,
    /// The sky's degree for the sky head (its coefficients follow a moved sun's sky).
    sky_degree: usize,
    majorants: MajorantGrid,
    sums: RpnnSums,
    seed: u64,
    sky_dirs: u32,
    /// Bounces traced before the network is asked (CPU shading).
    traced_bounces: u32,
    /// One sample in every this many asks the network.
    query_every: u32,
    /// The sky through the sky head (`None`: the paper's directions).
    sky_sh: Option<SkySh>,
    /// Stage times since the last restart.
    times: StageTimes,
}

/// The network an [`RpnnEngine`] runs: the model, its file, where it runs and on which
/// adapter it was chosen.
pub(crate) struct Network<'g> {
    pub path: PathBuf,
    pub model: Rpnn,
    pub runner: Runner<'g>,
    pub adapter: Option<&'g Gpu>,
}

impl<'g> RpnnEngine<'g> {
    pub(crate) fn new(
        scene: &Scene,
        net: Network<'g>,
        pyramid: Pyramid,
        settings: &RpnnSettings,
        sky_sh: Option<SkySh>,
    ) -> Self {
        Self {
            model_path: net.path,
            model: net.model,
            pyramid,
            runner: net.runner,
            adapter: net.adapter,
            choice: settings.backend,
            cpu_shading: settings.shades_on_cpu(),
            net: settings.net(),
            sky_degree: settings.sky_degree,
            majorants: nimbus_rpnn::render::majorants(scene),
            sums: RpnnSums::new(scene.camera.width, scene.camera.height),
            seed: scene.render.seed,
            sky_dirs: settings.sky_dirs,
            traced_bounces: settings.traced_bounces,
            query_every: settings.query_every,
            sky_sh,
            times: StageTimes::default(),
        }
    }

    /// Adds `spp` samples; with a live `cancel`, one sample at a time (the samples are
    /// independent and summed one by one either way: the same pixels), checking it between
    /// them and waiting for the device after each.
    fn add_cancellable(&mut self, scene: &Scene, spp: u32, cancel: &Cancel) -> Result<()> {
        if !cancel.is_live() {
            return self.add(scene, spp);
        }
        for _ in 0..spp {
            cancel.check()?;
            self.add(scene, 1)?;
            if let Some(g) = self.adapter {
                let _ = g.device.poll(wgpu::PollType::wait_indefinitely());
            }
        }
        Ok(cancel.check()?)
    }

    fn add(&mut self, scene: &Scene, spp: u32) -> Result<()> {
        let backend = match &mut self.runner {
            Runner::Gpu(g) => {
                g.sync(scene)?;
                g.add(spp)
                    .with_context(|| format!("RPNN render with {}", self.model_path.display()))?;
                // The stages are the sampler's ([`RpnnEngine::stages`]).
                self.times.total_ms = g.times.total_ms;
                return Ok(());
            }
            Runner::Cpu(b) => b,
        };
        let ro = RpnnOptions {
            sky_sh: self.sky_sh.clone(),
            sun_outputs: self.model.outputs,
            traced_bounces: self.traced_bounces,
            query_every: self.query_every,
            ..RpnnOptions::new(spp, self.seed, self.sky_dirs)
        };
        let t = nimbus_rpnn::render::accumulate(
            scene,
            &self.pyramid,
            &self.majorants,
            backend,
            &ro,
            &mut self.sums,
        )
        .with_context(|| format!("RPNN render with {}", self.model_path.display()))?;
        let a = &mut self.times;
        a.descriptor_ms += t.descriptor_ms;
        a.inference_ms += t.inference_ms;
        a.rest_ms += t.rest_ms;
        a.total_ms += t.total_ms;
        a.queries += t.queries;
        Ok(())
    }

    /// Milliseconds per stage since the restart. CPU shading: descriptors, the network
    /// (transfers included), the rest (camera rays, tracking, direct light). The whole sample
    /// on the GPU: its four passes from timestamps (zero where the adapter has none) and the
    /// rest of the wall time (submission, waiting).
    fn stages(&self) -> Vec<(&'static str, f64)> {
        match &self.runner {
            Runner::Gpu(g) => {
                let t = &g.times;
                let gpu = t.shade_ms + t.descriptor_ms + t.inference_ms + t.resolve_ms;
                vec![
                    ("shade", t.shade_ms),
                    ("descriptor", t.descriptor_ms),
                    ("inference", t.inference_ms),
                    ("resolve", t.resolve_ms),
                    ("rest", (t.total_ms - gpu).max(0.0)),
                ]
            }
            Runner::Cpu(_) => {
                let t = &self.times;
                vec![
                    ("descriptor", t.descriptor_ms),
                    ("inference", t.inference_ms),
                    ("rest", t.rest_ms),
                ]
            }
        }
    }

    /// Rebuilds the runner for the scene's density (the pyramid is new).
    fn rebuild(&mut self, scene: &Scene) -> Result<()> {
        // ONNX Runtime reads descriptors made on the CPU and keeps its session.
        if let Runner::Cpu(Backend::Ort(_)) = self.runner {
            return Ok(());
        }
        self.runner = runner(
            self.choice,
            self.cpu_shading,
            self.net,
            self.adapter,
            &self.model_path,
            &self.model,
            &self.pyramid,
            scene,
            self.sky_sh.as_ref(),
            self.sky_dirs,
            self.query_every,
        )?
        .0;
        if let Runner::Gpu(g) = &mut self.runner {
            g.reset(self.seed);
        }
        Ok(())
    }
}

impl Engine for RpnnEngine<'_> {
    fn render(
        &mut self,
        scene: &Scene,
        device: &str,
        _prepare_s: f64,
        budget: u32,
        seed: u64,
        cancel: &Cancel,
    ) -> Result<Rendered> {
        self.restart(scene, seed)?;
        self.add_cancellable(scene, budget, cancel)?;
        self.image(scene, device)
    }

    fn restart(&mut self, scene: &Scene, seed: u64) -> Result<()> {
        self.sums = RpnnSums::new(scene.camera.width, scene.camera.height);
        self.seed = seed;
        self.times = StageTimes::default();
        if let Runner::Gpu(g) = &mut self.runner {
            g.sync(scene)?;
            g.reset(seed);
        }
        Ok(())
    }

    fn apply(&mut self, scene: &Scene, change: &Change) -> Result<()> {
        match change {
            Change::Density(_) => {
                let label = scene.source.display();
                self.pyramid = Pyramid::for_rendering(&scene.volume)
                    .map_err(|e| anyhow::anyhow!("{label}: {e}"))?;
                self.majorants = nimbus_rpnn::render::majorants(scene);
                self.rebuild(scene)?;
            }
            // A constant sky whose colour follows the sun (`[sun] atmosphere`): new
            // coefficients. An environment map does not move with the sun: its projection
            // (every texel) is kept.
            Change::SunDir(_)
                if self.sky_sh.is_some()
                    && matches!(scene.sky, Some(nimbus_scene::Sky::Constant(_))) =>
            {
                self.sky_sh = SkySh::of(scene, self.sky_degree, 64);
                if let (Runner::Gpu(g), Some(s)) = (&mut self.runner, &self.sky_sh) {
                    g.set_sky(s);
                }
            }
            _ => {}
        }
        Ok(())
    }

    fn accumulate(&mut self, scene: &Scene, n: u32, cancel: &Cancel) -> Result<Step> {
        let before = self.stages();
        self.add_cancellable(scene, n, cancel)?;
        let stages = self
            .stages()
            .into_iter()
            .zip(before)
            .map(|((name, a), (_, b))| (name, a - b))
            .collect();
        Ok(Step {
            stages,
            spp: self.samples(),
            ..Default::default()
        })
    }

    fn image(&mut self, scene: &Scene, _device: &str) -> Result<Rendered> {
        let (image, variance, queries) = match &self.runner {
            Runner::Gpu(g) => {
                let (i, v) = g.image()?;
                (i, v, g.queries()?)
            }
            Runner::Cpu(_) => {
                let (i, v) = self.sums.image();
                (i, v, self.times.queries)
            }
        };
        let t = &self.times;
        let cam = &scene.camera;
        let budget = self.samples();
        let n = budget.max(1) as f64;
        Ok(Rendered {
            summary: format!(
                "RPNN ({}, {}{}{}{}) {}x{} at {} spp in {:.2} s — {:.1} ms per spp, {} network queries",
                self.model_path.display(),
                match &self.runner {
                    Runner::Cpu(Backend::Ort(_)) => self.runner.name().to_string(),
                    _ => format!(
                        "{}{}{}",
                        self.runner.name(),
                        match self.net.precision {
                            Precision::F32 => "",
                            Precision::F16 => ", f16 network",
                        },
                        match self.net.tiles {
                            Tiles::Square => ", 64x64 tiles",
                            Tiles::Wide => "",
                        }
                    ),
                },
                match &self.sky_sh {
                    Some(s) => format!(", sky head of degree {}", s.degree),
                    None if scene.sky.is_some() => format!(", {} sky directions", self.sky_dirs),
                    None => String::new(),
                },
                match self.traced_bounces {
                    0 => String::new(),
                    1 => ", 1 traced bounce".to_string(),
                    k => format!(", {k} traced bounces"),
                },
                match self.query_every {
                    1 => String::new(),
                    m => format!(", the network in 1 sample of {m}"),
                },
                cam.width,
                cam.height,
                budget,
                t.total_ms / 1e3,
                t.total_ms / n,
                queries
            ),
            timing_lines: self
                .stages()
                .into_iter()
                .map(|(name, ms)| format!("  {name:<10} {:9.2} ms per spp", ms / n))
                .collect(),
            seconds: t.total_ms / 1e3,
            setup_s: 0.0,
            gpu_ms: None,
            variance: Some(variance),
            image,
        })
    }

    fn samples(&self) -> u32 {
        match &self.runner {
            Runner::Gpu(g) => g.samples(),
            Runner::Cpu(_) => self.sums.samples,
        }
    }
}
