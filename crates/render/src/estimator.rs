//! [`prepare`] an estimator once per scene, then [`Estimator::render`] it for any budget, or
//! drive it progressively: [`Estimator::accumulate`] adds samples (or photon-map generations)
//! to the image, [`Estimator::change`] takes a new camera, sun or density and starts the image
//! again, [`Estimator::image`] reads it. The command line, the evaluation and the viewer all go
//! through this one dispatch; each estimator is one `engine/` module.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use glam::DVec3;
use nimbus_gpu::Gpu;
use nimbus_photon::PmSettings;
use nimbus_photon::impostor::{ImpostorCriteria, Refresh};
use nimbus_rpnn::ort_backend::{Cores, OrtModel};
use nimbus_rpnn::render::Backend;
use nimbus_rpnn::{Pyramid, model::Rpnn};
use nimbus_scene::volume::Volume;
use nimbus_scene::{Camera, Cancel, Cancelled, Image, Scene};

use crate::engine::{self, Engine};
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

/// Settings of every estimator (each reads its own).
#[derive(Debug, Clone, Default)]
pub struct Options {
    /// CPU path tracer: a progress bar on stderr.
    pub progress: bool,
    /// Photon mapping (the ring size and seed of a ray-marched render come from its budget and
    /// seed; the variant from the method for [`Method::PmElek2012`]).
    pub pm: PmSettings,
    /// Photon mapping: ray march at half resolution and upsample the image.
    pub pm_half_res: bool,
    /// Photon mapping with final gathering ([`Method::Pm`]): bounces and the sun's shadows.
    pub pm_gather: nimbus_photon::GatherSettings,
    /// Ray-marched photon mapping, progressively driven (the viewer): reuse the last image as
    /// an impostor while these criteria allow (Elek 2012 §4.4); `None` ray marches every frame.
    pub impostors: Option<ImpostorCriteria>,
    /// Photon mapping of an animated density: the largest value any of its frames holds, so
    /// the majorant covers them all (`None`: the scene's grid).
    pub pm_density_max: Option<f32>,
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

/// A change of the scene between images (the viewer's edits).
#[derive(Debug, Clone)]
pub enum Change {
    /// A new camera: position, orientation, field of view or image size.
    Camera(Camera),
    /// A new direction towards the sun; with `[sun] atmosphere` the sun's and sky's colours
    /// follow ([`Scene::set_sun_dir`]).
    SunDir(DVec3),
    /// A new density grid of the same resolution and box (an animation's next frame).
    Density(Arc<Volume>),
}

/// What one [`Estimator::accumulate`] did (the viewer's status line).
#[derive(Debug, Clone, Default)]
pub struct Step {
    /// Wall-clock milliseconds per stage, GPU work finished.
    pub stages: Vec<(&'static str, f64)>,
    /// Photon beams traced (sun, sky).
    pub beams: (u64, u64),
    /// Photon mapping: generations in the ring and its size m.
    pub ring: Option<(u32, u32)>,
    /// Ray-marched photon mapping with impostors: why the image was ray marched (`None`: the
    /// impostor was re-projected).
    pub refresh: Option<Refresh>,
    /// Impostor criteria's counts: refreshes per reason ([`Refresh`] order) and reuses.
    pub impostor_counts: Option<([u32; 5], u32)>,
    /// Samples per pixel in the image (progressive estimators).
    pub spp: u32,
    /// Something the user should know about this step.
    pub note: Option<String>,
}

/// A prepared estimator: the work a scene needs once is done, renders are cheap to repeat.
pub struct Estimator<'g> {
    method: Method,
    scene: Scene,
    /// Seconds [`prepare`] took.
    pub prepare_s: f64,
    /// Where it runs (`cpu (2 threads)`, the adapter, `ort (cpu: 2 sessions)`, …).
    pub device: String,
    /// Warnings for the user (an RPNN model trained for another medium).
    pub warnings: Vec<String>,
    engine: Box<dyn Engine + Send + 'g>,
    /// Seed of the progressive images and how many restarts drew from it.
    seed: u64,
    restarts: u64,
}

/// Where an estimator finds its GPU: a [`GpuSlot`] (opened on first use) or an open [`Gpu`]
/// (the viewer's, which owns the window's surface).
pub trait GpuSource<'g>: Copy {
    fn get(self) -> Result<&'g Gpu>;
    fn try_get(self) -> Option<&'g Gpu>;
}

impl<'g> GpuSource<'g> for &'g GpuSlot {
    fn get(self) -> Result<&'g Gpu> {
        GpuSlot::get(self)
    }
    fn try_get(self) -> Option<&'g Gpu> {
        GpuSlot::try_get(self)
    }
}

impl<'g> GpuSource<'g> for &'g Gpu {
    fn get(self) -> Result<&'g Gpu> {
        Ok(self)
    }
    fn try_get(self) -> Option<&'g Gpu> {
        Some(self)
    }
}

/// The range of coordinates and box extents (`F32_SCALE`) and of the largest extinction
/// (`F32_SIGMA`) the 32-bit estimators are given: pt-gpu, pm and RPNN's descriptors compute in
/// f32. Measured on one cloud rescaled by 10^E (box ±10^E, density scale 10^−E, so the largest
/// extinction is 5·10^−(E+1); the same image in f64): correct for −38 ≤ E ≤ 33, pt-gpu 64 % dark
/// at E = 34 and black from 35, pm 27 % dark from 34. The bounds keep margins of 10³ and more.
const F32_SCALE: [f64; 2] = [1e-30, 1e30];
const F32_SIGMA: [f64; 2] = [1e-32, 1e32];

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
pub fn prepare<'g>(
    scene: &Scene,
    method: Method,
    opts: &Options,
    gpu: impl GpuSource<'g>,
) -> Result<Estimator<'g>> {
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
    // Every estimator reads an environment map as latitude–longitude (2:1); another layout
    // (a mirror ball, a cube cross) would light the cloud wrongly without a word.
    if let Some(nimbus_scene::Sky::Env(env)) = &scene.sky {
        let (w, h) = (env.image().width, env.image().height);
        if w != 2 * h {
            warnings.push(format!(
                "warning: {label}: sky.envmap is {w}×{h}, not 2:1; it is read as a \
                 latitude–longitude map (a mirror ball or a cube cross would light the cloud \
                 wrongly)"
            ));
        }
    }
    if method != Method::Pt {
        check_f32_scale(scene, method)?;
    }
    let (engine, device): (Box<dyn Engine + Send + 'g>, String) = match method {
        Method::Pt => (
            Box::new(engine::pt::PtEngine::new(scene, opts.progress)),
            format!("cpu ({} threads)", rayon::current_num_threads()),
        ),
        Method::PtGpu => {
            let g = gpu.get()?;
            (
                Box::new(engine::pt_gpu::PtGpuEngine::new(g, scene)?),
                g.describe(),
            )
        }
        Method::Pm => {
            let g = gpu.get()?;
            (
                Box::new(engine::pm::GatherEngine::new(g, scene, opts)?),
                g.describe(),
            )
        }
        Method::PmMarch | Method::PmElek2012 => {
            let g = gpu.get()?;
            (
                Box::new(engine::pm_march::MarchEngine::new(g, scene, method, opts)),
                g.describe(),
            )
        }
        Method::Rpnn | Method::RpnnDirs => {
            let r = &opts.rpnn;
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
            let pyramid = Pyramid::for_rendering(&scene.volume)
                .map_err(|e| anyhow::anyhow!("{label}: {e}"))?;
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
            let (runner, device, note) = engine::rpnn::runner(
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
            (
                Box::new(engine::rpnn::RpnnEngine::new(
                    scene,
                    engine::rpnn::Network {
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
            )
        }
    };
    Ok(Estimator {
        method,
        scene: scene.clone(),
        prepare_s: t0.elapsed().as_secs_f64(),
        device,
        warnings,
        engine,
        seed: scene.render.seed,
        restarts: 0,
    })
}

/// Whether `err` comes from a cancelled call ([`Estimator::render_with`]).
pub fn is_cancelled(err: &anyhow::Error) -> bool {
    err.chain().any(|e| e.downcast_ref::<Cancelled>().is_some())
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

impl<'g> Estimator<'g> {
    pub fn method(&self) -> Method {
        self.method
    }

    /// The scene as the estimator sees it now (after its [`Change`]s).
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Renders with `budget` samples per pixel (Monte Carlo methods and the final gathering)
    /// or a ring of `budget` frames (the ray-marched photon maps), from `seed`, from scratch.
    pub fn render(&mut self, budget: u32, seed: u64) -> Result<Rendered> {
        self.render_with(budget, seed, &Cancel::never())
    }

    /// [`Self::render`], stopped when `cancel` is set: the path tracer checks it before each
    /// pixel, the GPU path tracer after each dispatch, the photon map after each generation
    /// and gather dispatch, RPNN after each sample. A cancelled call returns an error for
    /// which [`is_cancelled`] holds, and the estimator stays usable (the next render starts
    /// from scratch). The image is the same with any token.
    pub fn render_with(&mut self, budget: u32, seed: u64, cancel: &Cancel) -> Result<Rendered> {
        let label = self.scene.source.display().to_string();
        self.engine
            .render(
                &self.scene,
                &self.device,
                self.prepare_s,
                budget,
                seed,
                cancel,
            )
            .with_context(|| format!("{label}: {}", self.method))
    }

    /// Starts the progressive image again from `seed`.
    pub fn restart(&mut self, seed: u64) -> Result<()> {
        self.seed = seed;
        self.restarts = 0;
        self.engine.restart(&self.scene, seed)
    }

    /// Takes `change` into the scene and starts the image again. Samples after a restart are
    /// independent of those before it (each restart draws from its own seed).
    pub fn change(&mut self, change: Change) -> Result<()> {
        match &change {
            Change::Camera(c) => self.scene.camera = c.clone(),
            Change::SunDir(d) => self.scene.set_sun_dir(*d),
            Change::Density(v) => self.scene.volume = v.clone(),
        }
        self.engine.apply(&self.scene, &change)?;
        self.restarts += 1;
        let seed = self
            .seed
            .wrapping_add(self.restarts.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        self.engine.restart(&self.scene, seed)
    }

    /// Adds `n` samples per pixel to the progressive image (ray-marched photon maps: traces up
    /// to `n` generations where the ring needs them, then ray marches or re-projects).
    pub fn accumulate(&mut self, n: u32) -> Result<Step> {
        self.accumulate_with(n, &Cancel::never())
    }

    /// [`Self::accumulate`], stopped when `cancel` is set (as [`Self::render_with`]); the
    /// samples added before the cancel stay in the image, which remains consistent with
    /// [`Self::samples`].
    pub fn accumulate_with(&mut self, n: u32, cancel: &Cancel) -> Result<Step> {
        self.engine.accumulate(&self.scene, n, cancel)
    }

    /// The progressive image so far.
    pub fn image(&mut self) -> Result<Rendered> {
        self.engine.image(&self.scene, &self.device)
    }

    /// Samples per pixel in the progressive image.
    pub fn samples(&self) -> u32 {
        self.engine.samples()
    }
}
