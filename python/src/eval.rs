//! Evaluation: `compare` (the metrics of `nimbus compare TEST.exr REF.exr`), `tau` (the camera
//! optical depth whose τ ≥ 0.1 is the cloud mask) and `compare_scene` (`nimbus compare
//! SCENE`).

use std::collections::BTreeMap;
use std::path::PathBuf;

use nimbus_eval::{CompareOptions, RefDevice, ReferenceSettings, RunSettings};
use numpy::{
    PyArray1, PyArray2, PyArrayDescrMethods, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::call;
use crate::render::Image;
use crate::scene::{Scene, image_from_numpy};

/// An image given as an `Image`, an (H, W, 3) array or an EXR path.
fn image_of(
    obj: &Bound<'_, PyAny>,
    what: &str,
) -> PyResult<(nimbus_scene::Image, Option<PathBuf>)> {
    if let Ok(i) = obj.cast::<Image>() {
        return Ok((i.get().image.clone(), None));
    }
    if let Ok(p) = obj.extract::<PathBuf>() {
        let img = nimbus_scene::Image::read_exr(&p).map_err(call::scene_err)?;
        return Ok((img, Some(p)));
    }
    Ok((image_from_numpy(obj, what)?, None))
}

/// The cloud mask of `mask`: a bool array (H, W), an optical-depth array (cloud: τ ≥ 0.1) or
/// a `.npy` path of one.
fn mask_of(obj: &Bound<'_, PyAny>, w: usize, h: usize) -> PyResult<Vec<bool>> {
    if let Ok(p) = obj.extract::<PathBuf>() {
        return nimbus_scene::compare::tau_mask(&p, w, h).map_err(call::scene_err);
    }
    let np = obj.py().import("numpy")?;
    let a = np
        .call_method1("asarray", (obj,))?
        .cast_into::<PyUntypedArray>()?;
    if a.shape() != [h, w] {
        return Err(PyValueError::new_err(format!(
            "compare: field `mask`: expected shape ({h}, {w}), got {:?}",
            a.shape()
        )));
    }
    if a.dtype().kind() == b'b' {
        let a = a.into_any().cast_into::<PyArray2<bool>>()?;
        return Ok(a.readonly().as_array().iter().copied().collect());
    }
    let tau = np
        .call_method1("asarray", (obj, "float32"))?
        .cast_into::<PyArray2<f32>>()?;
    let tau: Vec<f32> = tau.readonly().as_array().iter().copied().collect();
    Ok(nimbus_scene::tau::cloud_mask(&tau))
}

/// The error metrics of `test` against `reference` (each an `Image`, an (H, W, 3) array or an
/// EXR path), as `nimbus compare TEST.exr REF.exr` prints them: `cloud_pixels`, `rmse_rgb`,
/// `rel_rmse_cloud`, `rel_rmse_cloud_4x4` (4×4 cloud blocks), `mean_lum_ratio`, `nonfinite`.
/// `mask`: the cloud pixels (a bool array, an optical-depth array or its `.npy`); default the
/// reference's `<name>_tau.npy` beside an EXR, else reference luminance > 10⁻³ × max.
#[pyfunction]
#[pyo3(signature = (test, reference, mask=None))]
fn compare(
    test: &Bound<'_, PyAny>,
    reference: &Bound<'_, PyAny>,
    mask: Option<&Bound<'_, PyAny>>,
) -> PyResult<BTreeMap<&'static str, f64>> {
    let (t, _) = image_of(test, "compare: field `test`")?;
    let (r, rpath) = image_of(reference, "compare: field `reference`")?;
    if (t.width, t.height) != (r.width, r.height) {
        return Err(PyValueError::new_err(format!(
            "compare: test is {}x{} but reference is {}x{}",
            t.width, t.height, r.width, r.height
        )));
    }
    let m = match mask {
        Some(m) => Some(mask_of(m, r.width, r.height)?),
        None => match rpath {
            Some(p) => {
                let auto = PathBuf::from(format!("{}_tau.npy", p.with_extension("").display()));
                if auto.exists() {
                    Some(
                        nimbus_scene::compare::tau_mask(&auto, r.width, r.height)
                            .map_err(call::scene_err)?,
                    )
                } else {
                    None
                }
            }
            None => None,
        },
    };
    let res = nimbus_scene::compare::compare(&t, &r, m.as_deref());
    if res.cloud_pixels == 0 || !res.mean_lum_ratio.is_finite() && res.nonfinite == 0 {
        return Err(PyValueError::new_err(
            "compare: the reference has no cloud pixels with positive luminance; relative \
             metrics are undefined",
        ));
    }
    Ok([
        ("cloud_pixels", res.cloud_pixels as f64),
        ("rmse_rgb", res.rmse_rgb),
        ("rel_rmse_cloud", res.rel_rmse_cloud),
        ("rel_rmse_cloud_4x4", res.rel_rmse_cloud_4x4),
        ("mean_lum_ratio", res.mean_lum_ratio),
        ("nonfinite", res.nonfinite as f64),
    ]
    .into_iter()
    .collect())
}

/// The camera optical depth of each pixel, float32 (H, W); `tau(scene) >= 0.1` is the cloud
/// mask `compare` and the references use.
#[pyfunction]
fn tau<'py>(py: Python<'py>, scene: &Scene) -> PyResult<Bound<'py, PyArray2<f32>>> {
    let s = &scene.scene;
    let t = call::run(py, |_| Ok(nimbus_scene::tau::optical_depth_image(s)))?;
    PyArray1::from_vec(py, t).reshape([s.camera.height, s.camera.width])
}

/// Runs what `nimbus compare SCENE` runs: a cached path-traced reference, each method's
/// budget sweep, the metrics (errors over 4×4 cloud blocks, bias with its floor, speed-ups)
/// and the report files in `out`; returns the report's rows as dicts. `methods`: names or a
/// comma-separated string; `budgets`: {method: [budgets]}; other keywords are the settings of
/// `render` (the CLI flags' names).
#[pyfunction]
#[pyo3(signature = (scene, methods=None, out=PathBuf::from("report"), budgets=None, ref_spp=512, ref_noise=0.01, ref_time_cap=600.0, cache=Some(PathBuf::from("out/cache/reference")), seed=None, **settings))]
#[allow(clippy::too_many_arguments)]
fn compare_scene<'py>(
    py: Python<'py>,
    scene: &Scene,
    methods: Option<&Bound<'py, PyAny>>,
    out: PathBuf,
    budgets: Option<BTreeMap<String, Vec<u32>>>,
    ref_spp: u32,
    ref_noise: f64,
    ref_time_cap: f64,
    cache: Option<PathBuf>,
    seed: Option<u64>,
    settings: Option<&Bound<'py, PyDict>>,
) -> PyResult<Bound<'py, PyAny>> {
    let s = &scene.scene;
    let list = match methods {
        None => if s.sky.is_some() {
            "pt,pm,rpnn,rpnn-dirs"
        } else {
            "pt,pm,rpnn"
        }
        .to_string(),
        Some(m) => match m.extract::<String>() {
            Ok(t) => t,
            Err(_) => m.extract::<Vec<String>>()?.join(","),
        },
    };
    let bad = |e: anyhow::Error| PyValueError::new_err(format!("compare_scene: {e:#}"));
    let methods = nimbus_eval::method::parse_methods(&list).map_err(bad)?;
    let mut b = BTreeMap::new();
    for (m, list) in budgets.unwrap_or_default() {
        let spec = format!(
            "{m}={}",
            list.iter()
                .map(|x| x.to_string())
                .collect::<Vec<_>>()
                .join(",")
        );
        let (m, l) = nimbus_eval::method::parse_budgets(&spec).map_err(bad)?;
        b.insert(m, l);
    }
    if !(1..=1 << 20).contains(&ref_spp) {
        return Err(PyValueError::new_err(format!(
            "compare_scene: field `ref_spp`: must lie in 1..=1048576, got {ref_spp}"
        )));
    }
    if !(ref_noise.is_finite() && (0.0..1.0).contains(&ref_noise)) {
        return Err(PyValueError::new_err(format!(
            "compare_scene: field `ref_noise`: must lie in [0, 1), got {ref_noise}"
        )));
    }
    if !(ref_time_cap.is_finite() && ref_time_cap >= 0.0) {
        return Err(PyValueError::new_err(format!(
            "compare_scene: field `ref_time_cap`: must be seconds ≥ 0, got {ref_time_cap}"
        )));
    }
    let seed = seed.unwrap_or(s.render.seed);
    let mut o = nimbus_render::settings::defaults(seed);
    if let Some(st) = settings {
        for (k, v) in st.iter() {
            let name: String = k.extract()?;
            let text = match v.extract::<bool>() {
                Ok(x) => x.to_string(),
                Err(_) => v.str()?.to_string(),
            };
            nimbus_render::settings::set(&mut o, &name, &text).map_err(PyValueError::new_err)?;
        }
    }
    let opts = CompareOptions {
        methods,
        budgets: b,
        run: RunSettings {
            seed,
            pm_beams: o.pm.beams_per_frame,
            pm_gather: o.pm_gather,
            model: o.rpnn.model.clone(),
            rpnn_backend: o.rpnn.backend,
            sky_dirs: o.rpnn.sky_dirs,
            sky_degree: o.rpnn.sky_degree,
            cpu_shading: o.rpnn.cpu_shading,
            rpnn_precision: o.rpnn.precision,
            rpnn_tiles: o.rpnn.tiles,
            traced_bounces: o.rpnn.traced_bounces,
            query_every: o.rpnn.query_every,
        },
        reference: ReferenceSettings {
            spp: ref_spp,
            target_rel_noise: ref_noise,
            time_cap_s: ref_time_cap,
            seed: CompareOptions::reference_seed(seed),
            device: RefDevice::Auto,
            cache_dir: cache,
            cached_only: false,
        },
    };
    let name = s
        .source
        .file_stem()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| "scene".into());
    let rows = call::run(py, |_| {
        let mut gpu = nimbus_eval::GpuSlot::new();
        let c = nimbus_eval::compare_scene(s, &name, &opts, &out, &mut gpu, &mut |_| {})?;
        Ok(serde_json::to_string(&c.report.rows)?)
    })?;
    py.import("json")?.call_method1("loads", (rows,))
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(compare, m)?)?;
    m.add_function(wrap_pyfunction!(tau, m)?)?;
    m.add_function(wrap_pyfunction!(compare_scene, m)?)?;
    Ok(())
}
