//! # nimbus-eval
//!
//! Measures the three estimators of Nimbus against each other: "how wrong, for how long?" and
//! "does it hold up on extreme inputs?".
//!
//! - [`compare`]: a cached high-spp path-traced [`reference`](mod@reference), budget sweeps of each
//!   [`method`], the [`metrics`] of Kallweit et al. 2017 §6 (relative RMSE, mean ratio, TTUV,
//!   speed-up, bias of converged images) and the [`report`] files with a log–log [`plot`];
//! - [`suite`]: the analogue of Kallweit's Table 1 on held-out generated clouds;
//! - [`stress`]: the stiff-case matrix (phase asymmetry, density, albedo, sun placement,
//!   degenerate grids, invalid voxels) with per-case time limits and physical bounds.

pub mod blocks;
pub mod compare;
pub mod method;
pub mod metrics;
pub mod plot;
pub mod reference;
pub mod report;
pub mod stress;
pub mod suite;

pub use compare::{CompareOptions, Comparison, compare_scene};
pub use method::{GpuSlot, Method, Run, RunSettings};
pub use reference::{RefDevice, Reference, ReferenceSettings};
