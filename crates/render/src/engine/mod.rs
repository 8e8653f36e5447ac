//! The estimators behind [`crate::Estimator`], one module each: the one place a new estimator
//! is added (with its [`crate::Method`]). Each keeps its one-time state (majorant grid, GPU
//! pipelines, photon map, density pyramid and network) and a progressive image.

use std::sync::Arc;

use anyhow::Result;
use glam::DVec3;
use nimbus_photon::PmSettings;
use nimbus_photon::impostor::{ImpostorCriteria, Refresh};
use nimbus_scene::volume::Volume;
use nimbus_scene::{Camera, Cancel, Image, Scene};

use crate::{GpuSource, Method};

pub(crate) mod pm;
pub(crate) mod pm_march;
pub(crate) mod pt;
pub(crate) mod pt_gpu;
#[cfg(feature = "rpnn")]
pub(crate) mod rpnn;

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
    #[cfg(feature = "rpnn")]
    pub rpnn: rpnn::RpnnSettings,
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

/// The engine of `method` on `scene` and where it runs: the one dispatch ([`crate::prepare`]
/// adds the checks every method shares). A new estimator is one module here and one arm.
pub(crate) fn prepare<'g>(
    scene: &Scene,
    method: Method,
    opts: &Options,
    gpu: impl GpuSource<'g>,
    label: &str,
    warnings: &mut Vec<String>,
) -> Result<(Box<dyn Engine + Send + 'g>, String)> {
    Ok(match method {
        Method::Pt => (
            Box::new(pt::PtEngine::new(scene, opts.progress)),
            format!("cpu ({} threads)", rayon::current_num_threads()),
        ),
        Method::PtGpu => {
            let g = gpu.get()?;
            (Box::new(pt_gpu::PtGpuEngine::new(g, scene)?), g.describe())
        }
        Method::Pm => {
            let g = gpu.get()?;
            (
                Box::new(pm::GatherEngine::new(g, scene, opts)?),
                g.describe(),
            )
        }
        Method::PmMarch | Method::PmElek2012 => {
            let g = gpu.get()?;
            let e = pm_march::MarchEngine::new(g, scene, method, opts);
            (Box::new(e), g.describe())
        }
        #[cfg(feature = "rpnn")]
        Method::Rpnn | Method::RpnnDirs => {
            rpnn::prepare(scene, method, &opts.rpnn, gpu, label, warnings)?
        }
        #[cfg(not(feature = "rpnn"))]
        Method::Rpnn | Method::RpnnDirs => {
            let _ = (label, warnings);
            anyhow::bail!("{method}: this build of nimbus-render has no RPNN (its `rpnn` feature)")
        }
    })
}

/// One estimator. `scene` is always the estimator's current scene (changes already in it).
/// `Send`: an estimator moves to another thread (a Python call that releases the GIL). The
/// long calls check `cancel` between chunks of their work and then return
/// [`nimbus_scene::Cancelled`], leaving the engine usable.
pub(crate) trait Engine: Send {
    /// An image of `budget` from `seed`, from scratch: what `render`, `compare` and
    /// `bench-suite` time. `device` and `prepare_s` describe the preparation for the summary.
    fn render(
        &mut self,
        scene: &Scene,
        device: &str,
        prepare_s: f64,
        budget: u32,
        seed: u64,
        cancel: &Cancel,
    ) -> Result<Rendered>;

    /// Starts the progressive image again; its samples are drawn from `seed`.
    fn restart(&mut self, scene: &Scene, seed: u64) -> Result<()>;

    /// Takes a change the scene already holds (a restart follows).
    fn apply(&mut self, scene: &Scene, change: &Change) -> Result<()>;

    /// Adds `n` samples per pixel to the progressive image (or `n` frames of a live photon
    /// map).
    fn accumulate(&mut self, scene: &Scene, n: u32, cancel: &Cancel) -> Result<Step>;

    /// The progressive image so far.
    fn image(&mut self, scene: &Scene, device: &str) -> Result<Rendered>;

    /// Samples per pixel in the progressive image.
    fn samples(&self) -> u32;
}

/// Milliseconds since `t`.
pub(crate) fn ms_since(t: nimbus_scene::clock::Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The sum of a frame's per-stage GPU milliseconds.
pub(crate) fn stage_sum(t: &[(&'static str, f64)]) -> f64 {
    t.iter().map(|(_, v)| v).sum()
}
