//! The clock every estimator times itself with: `std::time::Instant` on native targets, the
//! page's `performance.now()` in a browser (`std::time::Instant::now` panics on
//! `wasm32-unknown-unknown`). The crates a web page runs (scene, gpu, trace, photon, render)
//! take time from here only; `tests/tests/layout.rs` checks it.

pub use web_time::Instant;
