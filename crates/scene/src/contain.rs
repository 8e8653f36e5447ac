//! Panics of third-party decoders on damaged input, turned into errors.
//!
//! The `exr` crate's B44 decoder, for one, overflows on some damaged blocks
//! (`tests/exr.rs`). Nimbus' own readers check every length and never need this.

use std::cell::Cell;
use std::panic::{self, AssertUnwindSafe};
use std::sync::Once;

thread_local! {
    static QUIET: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` on this thread; a panic inside it becomes `Err(its message)`, and is not printed.
/// Panics of other threads, and of this one outside `f`, print as before. `f` must not hand
/// work to other threads (a panic there is not caught: run decoders single-threaded).
pub fn contain<T>(f: impl FnOnce() -> T) -> Result<T, String> {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = panic::take_hook();
        panic::set_hook(Box::new(move |info| {
            if !QUIET.with(Cell::get) {
                previous(info)
            }
        }));
    });
    let was = QUIET.with(|q| q.replace(true));
    let r = panic::catch_unwind(AssertUnwindSafe(f));
    QUIET.with(|q| q.set(was));
    r.map_err(|p| {
        p.downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".into())
    })
}

#[cfg(test)]
mod tests {
    use super::contain;

    #[test]
    fn a_panic_becomes_its_message_and_values_pass_through() {
        assert_eq!(contain(|| 7), Ok(7));
        let e = contain(|| -> u32 { panic!("damaged block {}", 3) }).unwrap_err();
        assert_eq!(e, "damaged block 3");
        let e = contain(|| -> u32 { panic!("static") }).unwrap_err();
        assert_eq!(e, "static");
        // Nested: the inner one is caught, the outer stays quiet until its own end.
        let r = contain(|| contain(|| -> u8 { panic!("inner") }));
        assert_eq!(r, Ok(Err("inner".to_string())));
    }
}
