//! # nimbus-render
//!
//! One API over Nimbus' estimators, in the manner of pbrt-v4's `RenderCPU`/`RenderWavefront`
//! behind one `pbrt` command: a [`Method`] names the estimator, [`prepare`] does the one-time
//! work a scene needs (majorant grid, GPU pipelines, density pyramid, network), and
//! [`Estimator::render`] makes an image for a budget (samples per pixel, or photon-map frames)
//! with its timings. The command line, the evaluation (`nimbus-eval`) and the viewer all call
//! it, so the choice of network backend and the GPU device live in one place ([`backend`]).
//!
//! Data flow: `Scene` (nimbus-scene) → [`prepare`] → [`Estimator`] → [`Rendered`] (image,
//! variance, timings) → report (nimbus-eval) or files (the CLI). See `ARCHITECTURE.md`.

pub mod backend;
mod engine;
pub mod estimator;
pub mod method;
pub mod settings;

pub use backend::{GpuSlot, GpuSource, NetBackend};
pub use estimator::{
    Change, Estimator, Options, Rendered, Step, check_f32_scale, is_cancelled, prepare,
};
#[cfg(feature = "rpnn")]
pub use estimator::{RpnnSettings, rpnn_backend, rpnn_model_path};
pub use method::Method;
pub use nimbus_scene::{Cancel, Cancelled};
