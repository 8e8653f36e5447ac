//! GPU tests on machines with and without an adapter.
//!
//! A test that needs a GPU asks for one with [`gpu`] (or [`has_adapter`] when it runs the
//! `nimbus` binary): where no adapter exists it prints why it is skipped and returns early.
//! A skipped test cannot fail, so CI must not skip: `scripts/test.sh` sets
//! [`REQUIRE_ENV`], and a missing adapter then fails the test with the install hint.
//! Other errors (an adapter that exists but cannot open a device) always fail.
//!
//! wgpu's `WGPU_BACKEND` environment variable limits the backends searched (e.g.
//! `WGPU_BACKEND=vulkan`); a backend this platform lacks (`WGPU_BACKEND=dx12` on Linux) hides
//! every adapter, which is how the skipping itself is exercised.

use crate::{Gpu, GpuError};

/// Set (to anything but `0`) to turn a missing GPU adapter into a test failure.
pub const REQUIRE_ENV: &str = "NIMBUS_REQUIRE_GPU";

fn required() -> bool {
    std::env::var(REQUIRE_ENV).is_ok_and(|v| v != "0")
}

fn skip(test: &str) {
    let why = GpuError::NoAdapter;
    if required() {
        panic!("{test}: {why} ({REQUIRE_ENV} is set, so GPU tests may not be skipped)");
    }
    eprintln!("skipped {test}: {why} (set {REQUIRE_ENV}=1 to make this a failure)");
}

/// The GPU for test `test`, or `None` (after saying so on stderr) when there is no adapter
/// and [`REQUIRE_ENV`] is not set.
///
/// # Panics
/// When the adapter cannot be opened, or there is none and [`REQUIRE_ENV`] is set.
pub fn gpu(test: &str) -> Option<Gpu> {
    match Gpu::new() {
        Ok(g) => Some(g),
        Err(GpuError::NoAdapter) => {
            skip(test);
            None
        }
        Err(e) => panic!("{test}: {e}"),
    }
}

/// Whether GPU work can run for test `test` (e.g. a `nimbus render --method pm` it is about
/// to start); `false` after saying so on stderr, under the same rule as [`gpu`].
pub fn has_adapter(test: &str) -> bool {
    let any = !crate::list_adapters().is_empty();
    if !any {
        skip(test);
    }
    any
}
