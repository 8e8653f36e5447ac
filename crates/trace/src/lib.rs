//! # nimbus-trace
//!
//! The reference estimator of Nimbus: a CPU volumetric path tracer for heterogeneous,
//! high-albedo, strongly forward-scattering media — delta tracking for free flights, ratio
//! tracking for shadow rays, next-event estimation to the sun and sky with multiple importance
//! sampling, empty-space skipping through a majorant grid. See [`integrator`] for the estimator,
//! [`tracking`] for the free-flight machinery and [`render`](mod@render) for image rendering. The error
//! metrics against the Mitsuba 3 references and the camera optical depth that masks the cloud
//! are the image's and the scene's: `nimbus_scene::{compare, tau}`.

pub mod gpu;
pub mod integrator;
mod progress;
pub mod render;
pub mod rng;
pub mod tracking;

pub use integrator::PathTracer;
pub use render::{
    RenderOptions, RenderOutput, RenderStats, Sums, accumulate, accumulate_cancellable, render,
    render_with,
};
pub use rng::Pcg32;
