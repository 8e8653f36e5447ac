//! The estimators behind [`crate::Estimator`], one module each: the one place a new estimator
//! is added (with its [`crate::Method`]). Each keeps its one-time state (majorant grid, GPU
//! pipelines, photon map, density pyramid and network) and a progressive image.

use anyhow::Result;
use nimbus_scene::{Cancel, Scene};

use crate::estimator::{Change, Rendered, Step};

pub(crate) mod pm;
pub(crate) mod pm_march;
pub(crate) mod pt;
pub(crate) mod pt_gpu;
pub(crate) mod rpnn;

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
pub(crate) fn ms_since(t: std::time::Instant) -> f64 {
    t.elapsed().as_secs_f64() * 1e3
}

/// The sum of a frame's per-stage GPU milliseconds.
pub(crate) fn stage_sum(t: &[(&'static str, f64)]) -> f64 {
    t.iter().map(|(_, v)| v).sum()
}
