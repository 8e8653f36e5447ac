//! Cancellation of long work: a token that a front end (Ctrl-C in the CLI, KeyboardInterrupt in
//! Python, a button in a page) sets and that the estimators check between chunks of work (tiles
//! of the path tracer, generations and gather dispatches of the photon map, samples of RPNN). A
//! cancelled call returns [`Cancelled`] and leaves its estimator usable.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

/// A cancellation token: clones share one flag. [`Cancel::never`] (the default) is never set
/// and costs nothing to check.
#[derive(Debug, Clone, Default)]
pub struct Cancel(Option<Arc<AtomicBool>>);

/// The error of a cancelled call.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("cancelled")]
pub struct Cancelled;

impl Cancel {
    /// A token that [`Cancel::cancel`] can set.
    pub fn new() -> Self {
        Self(Some(Arc::new(AtomicBool::new(false))))
    }

    /// A token that is never set (calls that cannot be cancelled).
    pub fn never() -> Self {
        Self(None)
    }

    /// Whether this token can be set at all (work may then wait for the device between chunks
    /// so that a cancel is seen promptly; a `never` token changes nothing).
    pub fn is_live(&self) -> bool {
        self.0.is_some()
    }

    /// Sets the token: work that checks it stops at its next check.
    pub fn cancel(&self) {
        if let Some(f) = &self.0 {
            f.store(true, Ordering::Relaxed);
        }
    }

    /// Clears the token, so that it can serve the next call.
    pub fn reset(&self) {
        if let Some(f) = &self.0 {
            f.store(false, Ordering::Relaxed);
        }
    }

    pub fn is_cancelled(&self) -> bool {
        self.0.as_ref().is_some_and(|f| f.load(Ordering::Relaxed))
    }

    /// `Err(Cancelled)` once the token is set.
    pub fn check(&self) -> Result<(), Cancelled> {
        if self.is_cancelled() {
            Err(Cancelled)
        } else {
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clones_share_the_flag_and_never_is_never_set() {
        let c = Cancel::new();
        let d = c.clone();
        assert!(c.check().is_ok() && c.is_live());
        d.cancel();
        assert_eq!(c.check(), Err(Cancelled));
        c.reset();
        assert!(!d.is_cancelled());
        let n = Cancel::never();
        n.cancel();
        assert!(n.check().is_ok() && !n.is_live());
    }
}
