//! The estimator interface that front ends drive from other threads: an `Estimator<'static>`
//! (over a process-wide `static` GPU slot) moves to another thread and renders the same pixels
//! there; a live cancellation token changes no pixel; a cancel during a render of every method
//! returns within a second with an error `is_cancelled` recognises, and the estimator renders
//! correctly afterwards.

mod common;

use std::time::{Duration, Instant};

use common::{options, scene};
use nimbus_render::{Cancel, Estimator, GpuSlot, Method, is_cancelled, prepare};

/// One device for the test binary, as a Python process has one.
static GPU: GpuSlot = GpuSlot::new();

/// The methods of a build with a GPU adapter (all), or without one (the CPU's).
fn methods() -> Vec<Method> {
    let mut m = vec![Method::Pt, Method::Rpnn];
    if nimbus_gpu::testing::has_adapter("cancel: the GPU methods") {
        m.extend([
            Method::PtGpu,
            Method::Pm,
            Method::PmMarch,
            Method::PmElek2012,
        ]);
    }
    m
}

/// A small budget for pixel comparisons (the ray-marched photon maps: ring frames).
fn small(m: Method) -> u32 {
    if m.budget_is_ring() { 4 } else { 3 }
}

fn est(m: Method) -> Estimator<'static> {
    prepare(&scene(), m, &options(), &GPU).unwrap()
}

#[test]
fn estimators_are_send_and_the_gpu_slot_is_sync() {
    fn send<T: Send>() {}
    fn sync<T: Sync>() {}
    send::<Estimator<'static>>();
    sync::<GpuSlot>();
    send::<Cancel>();
    sync::<Cancel>();
}

/// Rendered on this thread with no token, on another thread with a live one: the same pixels
/// (colour and variance, bit for bit).
#[test]
fn another_thread_and_a_live_token_render_the_same_pixels() {
    for m in methods() {
        let mut here = est(m);
        let a = here.render(small(m), 5).unwrap();
        let mut there = est(m);
        let b = std::thread::spawn(move || {
            let token = Cancel::new();
            there.render_with(small(m), 5, &token).map(|r| (r, there))
        })
        .join()
        .unwrap()
        .unwrap()
        .0;
        assert_eq!(a.image.pixels, b.image.pixels, "{m}: colour");
        assert_eq!(a.variance, b.variance, "{m}: variance");
    }
}

/// A budget no test machine finishes within the cancel's delay (lavapipe included).
fn huge(m: Method) -> u32 {
    match m {
        // Ring frames: each allocates a cache slot; 48 generations of 2^16 beams take seconds
        // on lavapipe and on a hardware GPU well over the 50 ms before the cancel.
        Method::PmMarch | Method::PmElek2012 => 48,
        _ => 1_000_000,
    }
}

/// A cancel during each method's render returns within 1 s with a cancellation error; the
/// estimator then renders the same pixels as a fresh one.
#[test]
fn a_cancel_stops_every_method_within_a_second() {
    for m in methods() {
        let reference = est(m).render(small(m), 7).unwrap();
        let mut e = est(m);
        let token = Cancel::new();
        let setter = token.clone();
        let delay = Duration::from_millis(if m.budget_is_ring() { 50 } else { 300 });
        let t0 = Instant::now();
        let cancel_at = std::thread::spawn(move || {
            std::thread::sleep(delay);
            setter.cancel();
            Instant::now()
        });
        let r = e.render_with(huge(m), 7, &token);
        let returned = Instant::now();
        let cancelled = cancel_at.join().unwrap();
        let err = match r {
            Ok(_) => panic!("{m}: the render of {} finished before the cancel", huge(m)),
            Err(e) => e,
        };
        assert!(is_cancelled(&err), "{m}: {err:#}");
        let late = returned.saturating_duration_since(cancelled);
        // The bound: the longest unit of work between checks (one pixel's samples,
        // one dispatch, one generation, one RPNN sample of a 24×16 image) is far below it.
        assert!(
            late < Duration::from_secs(1),
            "{m}: returned {late:?} after the cancel"
        );
        assert!(returned.duration_since(t0) >= delay, "{m}");
        // Usable afterwards: a new render is the fresh estimator's image.
        let again = e.render(small(m), 7).unwrap();
        assert_eq!(again.image.pixels, reference.image.pixels, "{m}");
        // A token set before the call stops it at once, in accumulation too.
        e.restart(1).unwrap();
        let set = Cancel::new();
        set.cancel();
        let err = e.accumulate_with(2, &set).unwrap_err();
        assert!(is_cancelled(&err), "{m}: {err:#}");
    }
}
