//! `render`, `Estimator` and `Image`: [`nimbus_render::prepare`] and the estimator's calls, with
//! the settings by the CLI flags' names ([`nimbus_render::settings`]), on one GPU per process.

use std::path::PathBuf;
use std::sync::Mutex;

use glam::DVec3;
use nimbus_render::{Change, Estimator as RustEstimator, GpuSlot, Method, Options, Rendered};
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use crate::call;
use crate::scene::{Camera, Scene};
use crate::volume::{Volume, grid_from_numpy};

/// One GPU device per process, opened by the first method that needs one and reused by every
/// later call.
static GPU: GpuSlot = GpuSlot::new();

/// A rendered image: `rgb` float32 (H, W, 3) linear radiance, row 0 at the top; `variance`
/// (H, W) of each pixel's mean luminance (Monte Carlo methods), `seconds` of rendering.
#[pyclass(module = "nimbus", frozen)]
pub(crate) struct Image {
    pub(crate) image: nimbus_scene::Image,
    variance: Option<Vec<f32>>,
    #[pyo3(get)]
    seconds: f64,
    /// One line: what ran, on what, how fast.
    #[pyo3(get)]
    summary: String,
    /// Samples per pixel (or ring frames) the image holds.
    #[pyo3(get)]
    samples: u32,
}

impl Image {
    fn new(r: Rendered, samples: u32) -> Self {
        Self {
            image: r.image,
            variance: r.variance,
            seconds: r.seconds,
            summary: r.summary,
            samples,
        }
    }
}

pub(crate) fn rgb_array<'py>(
    py: Python<'py>,
    img: &nimbus_scene::Image,
) -> PyResult<Bound<'py, PyArray3<f32>>> {
    let flat: Vec<f32> = img.pixels.iter().flatten().copied().collect();
    PyArray1::from_vec(py, flat).reshape([img.height, img.width, 3])
}

#[pymethods]
impl Image {
    /// Reads an EXR as `nimbus compare` does (its variance channel is not read).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        let image = nimbus_scene::Image::read_exr(&path).map_err(call::scene_err)?;
        Ok(Self {
            image,
            variance: None,
            seconds: 0.0,
            summary: path.display().to_string(),
            samples: 0,
        })
    }

    /// Linear RGB, float32 (height, width, 3), row 0 at the top (a new array each call).
    #[getter]
    fn rgb<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        rgb_array(py, &self.image)
    }

    /// Per-pixel variance of the mean luminance, float32 (height, width), or None.
    #[getter]
    fn variance<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyArray2<f32>>>> {
        self.variance
            .as_ref()
            .map(|v| PyArray1::from_slice(py, v).reshape([self.image.height, self.image.width]))
            .transpose()
    }

    #[getter]
    fn width(&self) -> usize {
        self.image.width
    }

    #[getter]
    fn height(&self) -> usize {
        self.image.height
    }

    /// Writes `.exr` (linear RGB and the variance channel, as `nimbus render`) or `.png`
    /// (tone-mapped; `exposure` default: the 99th-percentile luminance maps to 0.9).
    #[pyo3(signature = (path, exposure=None))]
    fn save(&self, path: PathBuf, exposure: Option<f64>) -> PyResult<()> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("exr") => self
                .image
                .write_exr(&path, self.variance.as_deref())
                .map_err(call::scene_err),
            Some("png") => {
                let e = exposure.unwrap_or_else(|| self.image.auto_exposure());
                if !(e.is_finite() && e > 0.0) {
                    return Err(PyValueError::new_err(format!(
                        "Image.save: exposure must be a finite number > 0, got {e}"
                    )));
                }
                self.image.write_png(&path, e).map_err(call::scene_err)
            }
            _ => Err(PyValueError::new_err(format!(
                "Image.save: {}: write .exr or .png",
                path.display()
            ))),
        }
    }

    /// The tone-mapped PNG (Jupyter shows it inline).
    fn _repr_png_<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let px = self.image.to_srgb8(self.image.auto_exposure());
        let mut out = Vec::new();
        image::write_buffer_with_format(
            &mut std::io::Cursor::new(&mut out),
            &px,
            self.image.width as u32,
            self.image.height as u32,
            image::ColorType::Rgb8,
            image::ImageFormat::Png,
        )
        .map_err(|e| pyo3::exceptions::PyRuntimeError::new_err(e.to_string()))?;
        Ok(PyBytes::new(py, &out))
    }

    fn __repr__(&self) -> String {
        format!(
            "Image({}x{}, {:.3} s: {})",
            self.image.width, self.image.height, self.seconds, self.summary
        )
    }
}

/// A setting's value as the flag's text: `True` → `true`, a sequence → `a,b,c`.
fn setting_text(v: &Bound<'_, PyAny>) -> PyResult<String> {
    if let Ok(b) = v.extract::<bool>() {
        return Ok(b.to_string());
    }
    if let Ok(s) = v.extract::<String>() {
        return Ok(s);
    }
    if let Ok(p) = v.extract::<PathBuf>() {
        return Ok(p.display().to_string());
    }
    if let Ok(items) = v.extract::<Vec<Bound<'_, PyAny>>>() {
        let parts: PyResult<Vec<String>> = items.iter().map(|i| Ok(i.str()?.to_string())).collect();
        return Ok(parts?.join(","));
    }
    Ok(v.str()?.to_string())
}

fn parse_method(method: &str) -> PyResult<Method> {
    method
        .parse()
        .map_err(|e: String| PyValueError::new_err(format!("field `method`: {e}")))
}

/// The options of `settings` (the CLI flags' names) over the CLI's defaults.
fn options(seed: u64, progress: bool, settings: Option<&Bound<'_, PyDict>>) -> PyResult<Options> {
    let mut o = nimbus_render::settings::defaults(seed);
    o.progress = progress;
    if let Some(s) = settings {
        for (k, v) in s.iter() {
            let name: String = k.extract()?;
            nimbus_render::settings::set(&mut o, &name, &setting_text(&v)?)
                .map_err(PyValueError::new_err)?;
        }
    }
    Ok(o)
}

/// Emits the estimator's warnings as Python warnings.
fn warn(py: Python<'_>, warnings: &[String]) -> PyResult<()> {
    if warnings.is_empty() {
        return Ok(());
    }
    let w = py.import("warnings")?;
    for line in warnings {
        w.call_method1("warn", (line.as_str(),))?;
    }
    Ok(())
}

/// Renders `scene` with `method` (`pt`, `pt-gpu`, `pm`, `pm-march`, `pm-elek2012`, `rpnn`,
/// `rpnn-dirs`) as `nimbus render` does: `spp` samples per pixel (default the scene's
/// `render.spp`), or for pm-march and pm-elek2012 `frames` ring frames (the CLI's `ring`);
/// `seed` (default the scene's `render.seed`); the same seed gives the CLI's pixels. Other
/// keywords are the CLI flags' names without dashes (`sky_dirs=8`, `backend="ort"`,
/// `pm_variant="elek2012"`, …; `nimbus.settings()` lists them). The GIL is released while it
/// renders; Ctrl-C stops it. `progress=True`: a tqdm bar when tqdm is installed (the
/// progressive estimator stepped per sample, see `render_stepped`), else the estimator's own
/// bar on stderr.
#[pyfunction]
#[pyo3(signature = (scene, method="pt", spp=None, seed=None, frames=None, progress=false, **settings))]
#[allow(clippy::too_many_arguments)]
fn render(
    py: Python<'_>,
    scene: &Scene,
    method: &str,
    spp: Option<i64>,
    seed: Option<u64>,
    frames: Option<i64>,
    progress: bool,
    settings: Option<&Bound<'_, PyDict>>,
) -> PyResult<Image> {
    let method = parse_method(method)?;
    let s = &scene.scene;
    let seed = seed.unwrap_or(s.render.seed);
    let spp = match spp {
        Some(v) if !(1..=nimbus_scene::scene::MAX_SPP).contains(&v) => {
            return Err(PyValueError::new_err(format!(
                "field `spp`: must lie in 1..={} (as render.spp), got {v}",
                nimbus_scene::scene::MAX_SPP
            )));
        }
        Some(v) => v as u32,
        None => s.render.spp,
    };
    let mut opts = options(seed, progress, settings)?;
    if let Some(f) = frames {
        if !method.budget_is_ring() {
            return Err(PyValueError::new_err(format!(
                "field `frames`: the budget of pm-march and pm-elek2012; {method} takes spp"
            )));
        }
        nimbus_render::settings::set(&mut opts, "ring", &f.to_string())
            .map_err(|e| PyValueError::new_err(e.replace("setting `ring`", "field `frames`")))?;
    }
    let budget = nimbus_render::settings::budget(method, &opts, spp);
    if progress && let Ok(tqdm) = py.import("tqdm") {
        opts.progress = false;
        let (r, warnings) = render_stepped(py, &tqdm, s, method, &opts, budget, seed)?;
        warn(py, &warnings)?;
        return Ok(Image::new(r, budget));
    }
    let (r, warnings) = call::run(py, |cancel| {
        let mut est = nimbus_render::prepare(s, method, &opts, &GPU)?;
        let r = est.render_with(budget, seed, cancel)?;
        Ok((r, est.warnings))
    })?;
    warn(py, &warnings)?;
    Ok(Image::new(r, budget))
}

/// `render(progress=True)` with tqdm installed: the progressive estimator (as `Estimator`:
/// prepared, restarted from `seed`) stepped one sample (generation) at a time, a tqdm bar
/// advanced after each. The path tracer's pixels equal `render`'s; the photon maps and RPNN
/// draw their samples in the progressive order (`Estimator.accumulate`'s pixels).
fn render_stepped(
    py: Python<'_>,
    tqdm: &Bound<'_, PyModule>,
    s: &nimbus_scene::Scene,
    method: Method,
    opts: &Options,
    budget: u32,
    seed: u64,
) -> PyResult<(Rendered, Vec<String>)> {
    let bar = tqdm.getattr("tqdm")?.call1((budget,))?;
    let result = (|| {
        let mut est = call::run(py, |_| {
            let mut e = nimbus_render::prepare(s, method, opts, &GPU)?;
            e.restart(seed)?;
            Ok(e)
        })?;
        for _ in 0..budget {
            call::run(py, |c| est.accumulate_with(1, c))?;
            bar.call_method1("update", (1,))?;
        }
        let r = call::run(py, |_| est.image())?;
        Ok((r, est.warnings.clone()))
    })();
    bar.call_method0("close")?;
    result
}

/// A prepared estimator, driven progressively (the viewer's interface): `accumulate(n)` adds
/// samples (photon-map generations), `image()` reads the image so far, `change(...)` takes a
/// new sun direction, camera or density and starts the image again, `restart()` starts it
/// again. Settings as `render`'s.
#[pyclass(module = "nimbus", frozen)]
pub(crate) struct Estimator {
    inner: Mutex<RustEstimator<'static>>,
    #[pyo3(get)]
    method: String,
    /// Where it runs (`cpu (2 threads)`, the adapter, `ort (cpu: 2 sessions)`).
    #[pyo3(get)]
    device: String,
}

impl Estimator {
    fn with<T: Send>(
        &self,
        py: Python<'_>,
        f: impl FnOnce(&mut RustEstimator<'static>, &nimbus_render::Cancel) -> anyhow::Result<T> + Send,
    ) -> PyResult<T> {
        call::run(py, |cancel| {
            let mut e = self.inner.lock().unwrap_or_else(|p| p.into_inner());
            f(&mut e, cancel)
        })
    }
}

#[pymethods]
impl Estimator {
    #[new]
    #[pyo3(signature = (scene, method="pt", seed=None, **settings))]
    fn new(
        py: Python<'_>,
        scene: &Scene,
        method: &str,
        seed: Option<u64>,
        settings: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let method = parse_method(method)?;
        let mut s = scene.scene.clone();
        if let Some(seed) = seed {
            s.render.seed = seed;
        }
        let opts = options(s.render.seed, false, settings)?;
        let est = call::run(py, |_| nimbus_render::prepare(&s, method, &opts, &GPU))?;
        warn(py, &est.warnings)?;
        Ok(Self {
            method: method.name().to_string(),
            device: est.device.clone(),
            inner: Mutex::new(est),
        })
    }

    /// Adds `n` samples per pixel (ray-marched photon maps: generations) to the image; returns
    /// the samples it holds. `progress=True`: a tqdm bar, one step per sample, when tqdm is
    /// installed. Ctrl-C stops it; the samples added so far stay.
    #[pyo3(signature = (n=1, progress=false))]
    fn accumulate(&self, py: Python<'_>, n: u32, progress: bool) -> PyResult<u32> {
        let bar = if progress {
            match py.import("tqdm") {
                Ok(t) => Some(t.getattr("tqdm")?.call1((n,))?),
                Err(_) => None,
            }
        } else {
            None
        };
        let Some(bar) = bar else {
            return self.with(py, |e, c| {
                e.accumulate_with(n, c)?;
                Ok(e.samples())
            });
        };
        let mut samples = 0;
        let result = (|| {
            for _ in 0..n {
                samples = self.with(py, |e, c| {
                    e.accumulate_with(1, c)?;
                    Ok(e.samples())
                })?;
                bar.call_method1("update", (1,))?;
            }
            Ok(samples)
        })();
        bar.call_method0("close")?;
        result
    }

    /// The image so far.
    fn image(&self, py: Python<'_>) -> PyResult<Image> {
        let (r, n) = self.with(py, |e, _| Ok((e.image()?, e.samples())))?;
        Ok(Image::new(r, n))
    }

    /// Samples per pixel in the image.
    #[getter]
    fn samples(&self, py: Python<'_>) -> u32 {
        py.detach(|| {
            self.inner
                .lock()
                .unwrap_or_else(|p| p.into_inner())
                .samples()
        })
    }

    /// Takes a new sun direction (towards the sun), camera and/or density (a `Volume` or an
    /// array of the same resolution; the box stays) and starts the image again.
    #[pyo3(signature = (sun=None, camera=None, density=None))]
    fn change(
        &self,
        py: Python<'_>,
        sun: Option<[f64; 3]>,
        camera: Option<Camera>,
        density: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<()> {
        let mut changes = Vec::new();
        let mut density_grid = None;
        if let Some(d) = sun {
            let d = DVec3::from_array(d);
            if !(d.is_finite() && d.length() > 0.0) {
                return Err(PyValueError::new_err(format!(
                    "Estimator.change: field `sun`: a direction must be finite and non-zero, got {d}"
                )));
            }
            changes.push(Change::SunDir(d));
        }
        if let Some(c) = camera {
            changes.push(Change::Camera(c.camera));
        }
        if let Some(obj) = density {
            let grid = match obj.extract::<Volume>() {
                Ok(v) => v.grid,
                Err(_) => grid_from_numpy(obj)?,
            };
            density_grid = Some(grid);
        }
        if changes.is_empty() && density_grid.is_none() {
            return Err(PyValueError::new_err(
                "Estimator.change: give sun=, camera= or density=",
            ));
        }
        self.with(py, move |e, _| {
            if let Some(g) = density_grid {
                // The density keeps the scene's box and scale; the resolution must match.
                let v = e.scene().volume.clone();
                if g.res() != v.grid().res() {
                    return Err(nimbus_scene::FieldError::new(
                        "density",
                        format!(
                            "resolution {:?} (x, y, z), the scene's is {:?}",
                            g.res(),
                            v.grid().res()
                        ),
                    )
                    .into());
                }
                let v = nimbus_scene::Volume::new(g, *v.aabb(), v.density_scale())?;
                changes.push(Change::Density(std::sync::Arc::new(v)));
            }
            for c in changes {
                e.change(c)?;
            }
            Ok(())
        })
    }

    /// Starts the image again (from `seed`, default the scene's).
    #[pyo3(signature = (seed=None))]
    fn restart(&self, py: Python<'_>, seed: Option<u64>) -> PyResult<()> {
        self.with(py, move |e, _| {
            let seed = seed.unwrap_or(e.scene().render.seed);
            e.restart(seed)
        })
    }

    /// Renders from scratch as `render` does (`budget` spp or ring frames).
    #[pyo3(signature = (budget, seed=None))]
    fn render(&self, py: Python<'_>, budget: u32, seed: Option<u64>) -> PyResult<Image> {
        if budget == 0 {
            return Err(PyValueError::new_err("field `budget`: must be at least 1"));
        }
        let r = self.with(py, move |e, c| {
            let seed = seed.unwrap_or(e.scene().render.seed);
            e.render_with(budget, seed, c)
        })?;
        Ok(Image::new(r, budget))
    }

    fn __repr__(&self) -> String {
        format!("Estimator({} on {})", self.method, self.device)
    }
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Image>()?;
    m.add_class::<Estimator>()?;
    m.add_function(wrap_pyfunction!(render, m)?)?;
    Ok(())
}
