//! Long calls from Python: the Rust work runs on a worker thread while the calling thread,
//! without the GIL, waits for it and every 100 ms takes the GIL to look for a signal. Ctrl-C
//! (KeyboardInterrupt) cancels the work through its [`Cancel`] token, waits for it to return
//! (the estimator stays usable) and raises KeyboardInterrupt. Errors become Python exceptions
//! ([`to_py`]); a panic becomes a `RuntimeError`, never a dead interpreter.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Duration;

use nimbus_render::Cancel;
use pyo3::exceptions::{PyKeyboardInterrupt, PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

/// How often the waiting thread looks for a signal.
const POLL: Duration = Duration::from_millis(100);

/// Runs `f` with the GIL released; Ctrl-C sets the token `f` is given.
pub(crate) fn run<T: Send>(
    py: Python<'_>,
    f: impl FnOnce(&Cancel) -> anyhow::Result<T> + Send,
) -> PyResult<T> {
    let cancel = Cancel::new();
    let done = Arc::new((Mutex::new(false), Condvar::new()));
    let mut interrupted: Option<PyErr> = None;
    let result = std::thread::scope(|s| {
        let worker = {
            let (cancel, done) = (cancel.clone(), done.clone());
            s.spawn(move || {
                let r = catch_unwind(AssertUnwindSafe(|| f(&cancel)));
                let (m, c) = &*done;
                *m.lock().unwrap_or_else(|p| p.into_inner()) = true;
                c.notify_all();
                r
            })
        };
        loop {
            let finished = py.detach(|| {
                let (m, c) = &*done;
                let g = m.lock().unwrap_or_else(|p| p.into_inner());
                let (g, _) = c
                    .wait_timeout_while(g, POLL, |d| !*d)
                    .unwrap_or_else(|p| p.into_inner());
                *g
            });
            if finished {
                break;
            }
            if interrupted.is_none()
                && let Err(e) = py.check_signals()
            {
                cancel.cancel();
                interrupted = Some(e);
            }
        }
        py.detach(|| worker.join())
    });
    if let Some(e) = interrupted {
        return Err(e);
    }
    match result {
        Ok(Ok(Ok(v))) => Ok(v),
        Ok(Ok(Err(e))) => Err(to_py(e)),
        Ok(Err(panic)) | Err(panic) => Err(PyRuntimeError::new_err(format!(
            "nimbus: internal error (a Rust panic): {}",
            panic_text(&panic)
        ))),
    }
}

fn panic_text(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into())
}

/// An error of the libraries as a Python exception: invalid input (a field, a value, a file's
/// content) → `ValueError`, a file that cannot be read or written → `OSError`, a cancelled
/// call → `KeyboardInterrupt`, anything else → `RuntimeError`; the message is the whole chain,
/// as the CLI prints it.
pub(crate) fn to_py(e: anyhow::Error) -> PyErr {
    let msg = format!("{e:#}");
    if nimbus_render::is_cancelled(&e) {
        return PyKeyboardInterrupt::new_err(msg);
    }
    for cause in e.chain() {
        if let Some(se) = cause.downcast_ref::<nimbus_scene::Error>() {
            return match se {
                nimbus_scene::Error::Io { .. } => PyOSError::new_err(msg),
                _ => PyValueError::new_err(msg),
            };
        }
        if cause.downcast_ref::<nimbus_scene::FieldError>().is_some() {
            return PyValueError::new_err(msg);
        }
    }
    PyRuntimeError::new_err(msg)
}

/// A field error of `what` (a constructor's name) as a `ValueError`.
pub(crate) fn field(what: &str, e: nimbus_scene::FieldError) -> PyErr {
    PyValueError::new_err(format!("{what}: {e}"))
}

/// A scene-crate error as a Python exception.
pub(crate) fn scene_err(e: nimbus_scene::Error) -> PyErr {
    to_py(e.into())
}
