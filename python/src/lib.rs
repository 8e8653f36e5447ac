//! `nimbus`, the Python module: bindings only — conversions between numpy and Nimbus' types,
//! the GIL, errors. Every estimator, reader, check and metric is the library crates' (the same
//! calls as the command line), so a render from Python is the CLI's render.
//!
//! - [`volume`]: `Volume` (numpy, files, generators);
//! - [`scene`]: `Scene` and its parts, with the scene file's field names;
//! - [`render`]: `render`, `Estimator`, `Image`;
//! - [`eval`]: `compare`, `tau`, `compare_scene`;
//! - [`datagen`]: `datagen` (RPNN training records);
//! - [`call`]: long calls on a worker thread with the GIL released, Ctrl-C as cancellation,
//!   errors and panics as Python exceptions.

use pyo3::prelude::*;

mod call;
mod datagen;
mod eval;
mod render;
mod scene;
mod volume;

/// Worker threads of the CPU estimators (the CLI's `--threads`); the first call wins, as one
/// thread pool serves the process.
#[pyfunction]
fn set_threads(n: usize) -> PyResult<()> {
    if !(1..=1024).contains(&n) {
        return Err(pyo3::exceptions::PyValueError::new_err(format!(
            "set_threads: n must lie in 1..=1024, got {n}"
        )));
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
        .map_err(|e| {
            pyo3::exceptions::PyRuntimeError::new_err(format!(
                "set_threads: the thread pool is already running ({e}); call set_threads \
                 before the first render"
            ))
        })
}

/// The worker threads the CPU estimators use.
#[pyfunction]
fn threads() -> usize {
    rayon::current_num_threads()
}

/// The memory budget for any allocation sized by input (the CLI's `--max-memory`): bytes as an
/// int, or text such as `"6G"`, `"512M"`. Returns the budget in bytes (without an argument,
/// the one in force).
#[pyfunction]
#[pyo3(signature = (size=None))]
fn max_memory(size: Option<&Bound<'_, PyAny>>) -> PyResult<u64> {
    if let Some(s) = size {
        let bytes = if let Ok(n) = s.extract::<u64>() {
            n
        } else if let Ok(t) = s.extract::<String>() {
            nimbus_scene::memory::parse_size(&t)
                .map_err(|e| pyo3::exceptions::PyValueError::new_err(format!("max_memory: {e}")))?
        } else {
            return Err(pyo3::exceptions::PyTypeError::new_err(
                "max_memory: give bytes (int) or a size such as \"6G\"",
            ));
        };
        if bytes == 0 {
            return Err(pyo3::exceptions::PyValueError::new_err(
                "max_memory: must be at least 1 byte",
            ));
        }
        nimbus_scene::memory::set_budget(bytes);
    }
    Ok(nimbus_scene::memory::budget())
}

/// The estimators' names (`method=` of `render` and `Estimator`).
#[pyfunction]
fn methods() -> Vec<&'static str> {
    nimbus_render::Method::ALL
        .iter()
        .map(|m| m.name())
        .collect()
}

/// The settings `render` and `Estimator` take by name, with one line of help each.
#[pyfunction]
fn settings() -> Vec<(&'static str, &'static str)> {
    nimbus_render::settings::all()
        .map(|s| (s.name, s.help))
        .collect()
}

#[pymodule]
fn _nimbus(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(set_threads, m)?)?;
    m.add_function(wrap_pyfunction!(threads, m)?)?;
    m.add_function(wrap_pyfunction!(max_memory, m)?)?;
    m.add_function(wrap_pyfunction!(methods, m)?)?;
    m.add_function(wrap_pyfunction!(settings, m)?)?;
    volume::register(m)?;
    scene::register(m)?;
    render::register(m)?;
    eval::register(m)?;
    datagen::register(m)?;
    Ok(())
}
