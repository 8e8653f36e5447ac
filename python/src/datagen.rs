//! `datagen`: RPNN training records as numpy arrays, or the checksummed shards of
//! `nimbus datagen` in a folder — the same library calls ([`nimbus_rpnn::data::dataset`]), so
//! the same settings and seed give the same records.

use std::path::PathBuf;

use nimbus_rpnn::data::datagen::LightSampling;
use nimbus_rpnn::data::dataset::{self, DatagenOptions, Part};
use nimbus_rpnn::descriptor::DESCRIPTOR_LEN;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::call;

/// The CLI's ranges of the flags (crates/cli/src/flags.rs).
const MAX_RECORDS: usize = 1 << 40;
const MAX_DENSITY_SCALE: f64 = 1e30;

fn bad(field: &str, msg: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(format!("datagen: field `{field}`: {msg}"))
}

fn records_in(field: &str, v: Option<usize>) -> PyResult<Option<usize>> {
    match v {
        Some(n) if n > MAX_RECORDS => Err(bad(field, format!("{n} is above 2^40"))),
        v => Ok(v),
    }
}

fn samples_in(field: &str, v: Option<u64>) -> PyResult<u64> {
    match v {
        Some(n) if !(1..=1 << 24).contains(&n) => Err(bad(field, format!("{n} not in 1..=2^24"))),
        v => Ok(v.unwrap_or(0)),
    }
}

/// Training records for RPNN, as `nimbus datagen` makes them (keywords are its flags' names).
///
/// Without `out`: a dict of numpy arrays per split, `{"train": {"x", "y", "meta"}, "val": …,
/// "test": …}` — descriptors float32 `(n, 2251)` (float16 with `f16=True`), labels `(n,)`,
/// metadata `(n, 15)` (columns `meta_names`) — the rows of the CLI's shards in order, with
/// `seconds`, `records_per_second`, `converged`. With `out`: writes (or resumes) the same
/// checksummed shards and manifest as the CLI and returns the run's summary.
#[pyfunction]
#[pyo3(signature = (records, out=None, clouds="gen:40".to_string(), test_records=None, val_records=None, samples=None, eval_samples=None, eval_noise=None, light="sphere".to_string(), density_range=(10.0, 80.0), phase="hg".to_string(), seed=0, shard_size=1000, shard=None, f16=false, sky_transfer=false, max_samples=1 << 18, density_scale=30.0, device=None, progress=false))]
#[allow(clippy::too_many_arguments)]
fn datagen<'py>(
    py: Python<'py>,
    records: usize,
    out: Option<PathBuf>,
    clouds: String,
    test_records: Option<usize>,
    val_records: Option<usize>,
    samples: Option<u64>,
    eval_samples: Option<u64>,
    eval_noise: Option<f64>,
    light: String,
    density_range: (f64, f64),
    phase: String,
    seed: u64,
    shard_size: usize,
    shard: Option<String>,
    f16: bool,
    sky_transfer: bool,
    max_samples: u64,
    density_scale: f64,
    device: Option<String>,
    progress: bool,
) -> PyResult<Bound<'py, PyDict>> {
    records_in("records", Some(records))?;
    let test_records = records_in("test_records", test_records)?.unwrap_or(records / 4);
    let val_records = records_in("val_records", val_records)?.unwrap_or(test_records);
    if records == 0 && test_records == 0 && val_records == 0 {
        return Err(bad("records", "a set of no records"));
    }
    let samples = samples_in("samples", samples)?;
    let eval_samples_set = eval_samples.is_some();
    let eval_samples = samples_in("eval_samples", eval_samples)?;
    let eval_noise = eval_noise.unwrap_or(0.0);
    if !(0.0..1.0).contains(&eval_noise) {
        return Err(bad("eval_noise", format!("{eval_noise} not in [0, 1)")));
    }
    if eval_noise > 0.0 && !eval_samples_set {
        return Err(bad(
            "eval_noise",
            "needs eval_samples (the pilot's sample count)",
        ));
    }
    let (lo, hi) = density_range;
    if !(lo > 0.0 && lo <= hi && hi <= MAX_DENSITY_SCALE) {
        return Err(bad(
            "density_range",
            format!("({lo}, {hi}): needs 0 < lo <= hi <= 1e30"),
        ));
    }
    if !(density_scale > 0.0 && density_scale <= MAX_DENSITY_SCALE) {
        return Err(bad(
            "density_scale",
            format!("{density_scale} not in (0, 1e30]"),
        ));
    }
    if !(1..=1 << 30).contains(&shard_size) {
        return Err(bad("shard_size", format!("{shard_size} not in 1..=2^30")));
    }
    if max_samples == 0 {
        return Err(bad("max_samples", "must be at least 1"));
    }
    let light = match light.as_str() {
        "sphere" => LightSampling::Sphere,
        "uniform-gamma" => LightSampling::UniformGamma,
        other => {
            return Err(bad(
                "light",
                format!("{other}: expected sphere or uniform-gamma"),
            ));
        }
    };
    let part = shard
        .map(|s| Part::parse(&s).map_err(|e| bad("shard", e)))
        .transpose()?;
    if part.is_some() && out.is_none() {
        return Err(bad(
            "shard",
            "a part of a set is written to a folder: give out=",
        ));
    }
    let device = match device.as_deref() {
        None => None,
        Some("cpu") => Some(false),
        Some("gpu") => Some(true),
        Some(other) => return Err(bad("device", format!("{other}: expected cpu or gpu"))),
    };
    let set = dataset::cloud_set(&clouds, seed, [lo, hi], density_scale)
        .map_err(|e| call::to_py(e.into()))?;
    let opts = DatagenOptions {
        records,
        test_records,
        val_records,
        samples,
        eval_samples,
        eval_noise,
        light,
        shard_size,
        seed,
        max_samples,
        albedo: 1.0,
        // As the CLI: the sky's transfer is estimated on the CPU only.
        gpu: if sky_transfer && device.is_none() {
            false
        } else {
            dataset::datagen_on_gpu(device, &phase)
        },
        phase,
        progress,
        part,
        f16_descriptors: f16,
        sky_transfer,
    };
    let d = PyDict::new(py);
    if let Some(out) = out {
        let r = call::run(py, |c| Ok(dataset::run_cancellable(&set, &opts, &out, c)?))?;
        d.set_item("records", r.records)?;
        d.set_item("computed", r.computed)?;
        d.set_item("converged", r.converged)?;
        d.set_item("seconds", r.seconds)?;
        d.set_item(
            "records_per_second",
            r.computed as f64 / r.seconds.max(1e-9),
        )?;
        d.set_item("manifest", out.join("manifest.json"))?;
        return Ok(d);
    }
    let (splits, r) = call::run(py, |c| Ok(dataset::in_memory(&set, &opts, c)?))?;
    for s in splits {
        let a = s.arrays;
        let n = s.records;
        let sd = PyDict::new(py);
        let x = PyArray1::from_vec(py, a.x).reshape([n, DESCRIPTOR_LEN])?;
        if f16 {
            sd.set_item("x", x.call_method1("astype", ("float16",))?)?;
        } else {
            sd.set_item("x", x)?;
        }
        sd.set_item("y", PyArray1::from_vec(py, a.y))?;
        sd.set_item(
            "meta",
            PyArray1::from_vec(py, a.meta).reshape([n, a.width])?,
        )?;
        sd.set_item("converged", a.converged)?;
        d.set_item(s.split, sd)?;
    }
    let mut names: Vec<&str> = dataset::META_NAMES.to_vec();
    if sky_transfer {
        names.extend(dataset::SKY_META_NAMES);
    }
    d.set_item("meta_names", names)?;
    d.set_item("records", r.records)?;
    d.set_item("converged", r.converged)?;
    d.set_item("seconds", r.seconds)?;
    d.set_item("records_per_second", r.records as f64 / r.seconds.max(1e-9))?;
    Ok(d)
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(datagen, m)?)?;
    Ok(())
}
