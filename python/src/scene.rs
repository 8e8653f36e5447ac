//! `Scene` and its parts. Keywords are the scene file's field names (`density_scale`, `albedo`,
//! `phase`, `[sun] direction`, …), so one page documents both; a scene is checked by the scene
//! file's own reader ([`nimbus_scene::Scene::from_toml_in_memory`]), its arrays handed over in
//! memory.

use std::path::{Path, PathBuf};

use glam::DVec3;
use nimbus_scene::scene::InMemory;
use nimbus_scene::{Image, fsio, io};
use numpy::{PyArray3, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use toml::{Table, Value};

use crate::call;
use crate::volume::{Source, Volume, bounds_of};

fn arr(v: [f64; 3]) -> Value {
    Value::Array(v.iter().map(|&x| Value::Float(x)).collect())
}

/// An RGB value given as one number (grey) or three.
fn rgb(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Value> {
    if let Ok(x) = obj.extract::<f64>() {
        return Ok(Value::Float(x));
    }
    obj.extract::<[f64; 3]>()
        .map(arr)
        .map_err(|_| PyValueError::new_err(format!("{what}: give one number or three (r, g, b)")))
}

/// A phase function (`HenyeyGreenstein(g)`, `Isotropic()`, `Mie(...)`): the scene file's
/// `phase` value.
#[pyclass(module = "nimbus", frozen)]
#[derive(Clone)]
pub(crate) struct Phase {
    value: Value,
}

#[pymethods]
impl Phase {
    fn __repr__(&self) -> String {
        format!("Phase({})", self.value)
    }
}

/// Henyey–Greenstein phase function with asymmetry `g` in (−1, 1) (`phase = { kind = "hg", g }`).
#[pyfunction]
#[pyo3(name = "HenyeyGreenstein")]
fn henyey_greenstein(g: f64) -> PyResult<Phase> {
    nimbus_scene::phase::HenyeyGreenstein::new(g)
        .map_err(|e| call::field("HenyeyGreenstein", e))?;
    let mut t = Table::new();
    t.insert("kind".into(), Value::String("hg".into()));
    t.insert("g".into(), Value::Float(g));
    Ok(Phase {
        value: Value::Table(t),
    })
}

/// The isotropic phase function (`phase = "isotropic"`).
#[pyfunction]
#[pyo3(name = "Isotropic")]
fn isotropic() -> Phase {
    Phase {
        value: Value::String("isotropic".into()),
    }
}

/// Lorenz–Mie phase function of a droplet distribution (`phase = { kind = "mie", … }`; the
/// defaults are the scene file's).
#[pyfunction]
#[pyo3(name = "Mie", signature = (effective_radius_um=None, effective_variance=None, wavelength_nm=None, refractive_index=None, chop_deg=None))]
fn mie(
    effective_radius_um: Option<f64>,
    effective_variance: Option<f64>,
    wavelength_nm: Option<f64>,
    refractive_index: Option<f64>,
    chop_deg: Option<f64>,
) -> PyResult<Phase> {
    let mut t = Table::new();
    t.insert("kind".into(), Value::String("mie".into()));
    for (k, v) in [
        ("effective_radius_um", effective_radius_um),
        ("effective_variance", effective_variance),
        ("wavelength_nm", wavelength_nm),
        ("refractive_index", refractive_index),
        ("chop_deg", chop_deg),
    ] {
        if let Some(v) = v {
            t.insert(k.into(), Value::Float(v));
        }
    }
    let value = Value::Table(t);
    nimbus_scene::scene::parse_phase(Some(&value)).map_err(|e| call::field("Mie", e))?;
    Ok(Phase { value })
}

/// The sun (`[sun]`): `direction` towards the sun, `irradiance` one number or (r, g, b),
/// `angular_radius_deg` (0: a delta light), `atmosphere` (colour by elevation).
#[pyclass(module = "nimbus", frozen)]
#[derive(Clone)]
pub(crate) struct Sun {
    table: Table,
}

#[pymethods]
impl Sun {
    #[new]
    #[pyo3(signature = (direction, irradiance=None, angular_radius_deg=0.0, atmosphere=false))]
    fn new(
        direction: [f64; 3],
        irradiance: Option<&Bound<'_, PyAny>>,
        angular_radius_deg: f64,
        atmosphere: bool,
    ) -> PyResult<Self> {
        let irr = match irradiance {
            Some(v) => rgb(v, "Sun: field `irradiance`")?,
            None => Value::Float(1.0),
        };
        let mut t = Table::new();
        t.insert("direction".into(), arr(direction));
        t.insert("irradiance".into(), irr);
        t.insert(
            "angular_radius_deg".into(),
            Value::Float(angular_radius_deg),
        );
        t.insert("atmosphere".into(), Value::Boolean(atmosphere));
        let d = DVec3::from_array(direction);
        // The scene reader's check, now rather than at the scene.
        nimbus_scene::Sun::new(d, DVec3::ONE, angular_radius_deg)
            .map_err(|e| call::field("Sun", e))?;
        Ok(Self { table: t })
    }

    fn __repr__(&self) -> String {
        format!("Sun({})", Value::Table(self.table.clone()))
    }
}

/// The sky (`[sky]`): a constant `radiance` (one number or (r, g, b)), or an environment map
/// `envmap`: a latitude–longitude float array (H, W, 3), row 0 the zenith, or an EXR path;
/// `scale` multiplies either.
#[pyclass(module = "nimbus", frozen)]
#[derive(Clone)]
pub(crate) struct Sky {
    table: Table,
    envmap: Option<Image>,
}

#[pymethods]
impl Sky {
    #[new]
    #[pyo3(signature = (radiance=None, envmap=None, scale=1.0))]
    fn new(
        radiance: Option<&Bound<'_, PyAny>>,
        envmap: Option<&Bound<'_, PyAny>>,
        scale: f64,
    ) -> PyResult<Self> {
        let mut t = Table::new();
        t.insert("scale".into(), Value::Float(scale));
        let mut image = None;
        match (radiance, envmap) {
            (Some(_), Some(_)) => {
                return Err(PyValueError::new_err(
                    "Sky: field `sky`: give either `radiance` or `envmap`, not both",
                ));
            }
            (None, None) => {
                return Err(PyValueError::new_err(
                    "Sky: field `sky`: needs `radiance` or `envmap`",
                ));
            }
            (Some(r), None) => {
                t.insert("radiance".into(), rgb(r, "Sky: field `radiance`")?);
            }
            (None, Some(e)) => {
                if let Ok(p) = e.extract::<PathBuf>() {
                    t.insert(
                        "envmap".into(),
                        Value::String(absolute(&p).display().to_string()),
                    );
                } else {
                    image = Some(image_from_numpy(e, "Sky: field `envmap`")?);
                }
            }
        }
        Ok(Self {
            table: t,
            envmap: image,
        })
    }

    fn __repr__(&self) -> String {
        match &self.envmap {
            Some(i) => format!("Sky(envmap=<{}×{} array>)", i.width, i.height),
            None => format!("Sky({})", Value::Table(self.table.clone())),
        }
    }
}

fn absolute(p: &Path) -> PathBuf {
    std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf())
}

/// An (H, W, 3) array of any real dtype as a linear RGB image, row 0 at the top.
pub(crate) fn image_from_numpy(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Image> {
    let py = obj.py();
    let a = py
        .import("numpy")?
        .call_method1("asarray", (obj, "float32"))
        .map_err(|e| PyValueError::new_err(format!("{what}: not an array of numbers ({e})")))?
        .cast_into::<PyUntypedArray>()?;
    let shape = a.shape().to_vec();
    if shape.len() != 3 || shape[2] != 3 || shape[0] == 0 || shape[1] == 0 {
        return Err(PyValueError::new_err(format!(
            "{what}: expected an RGB image of shape (height, width, 3), got {shape:?}"
        )));
    }
    let a = a.into_any().cast_into::<PyArray3<f32>>()?;
    let ro = a.readonly();
    let v = ro.as_array();
    let (h, w) = (shape[0], shape[1]);
    let mut img = Image::new(w, h);
    for (i, p) in img.pixels.iter_mut().enumerate() {
        let (y, x) = (i / w, i % w);
        *p = [v[[y, x, 0]], v[[y, x, 1]], v[[y, x, 2]]];
    }
    Ok(img)
}

/// A pinhole camera (`[camera]`): `origin`, `target`, `up`, full vertical field of view
/// `vfov_deg`, image `width` × `height`.
#[pyclass(module = "nimbus", frozen)]
#[derive(Clone)]
pub(crate) struct Camera {
    table: Table,
    pub(crate) camera: nimbus_scene::Camera,
}

#[pymethods]
impl Camera {
    #[new]
    #[pyo3(signature = (origin, target, up=[0.0, 1.0, 0.0], vfov_deg=40.0, width=128, height=96))]
    fn new(
        origin: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        vfov_deg: f64,
        width: i64,
        height: i64,
    ) -> PyResult<Self> {
        let max = nimbus_scene::camera::MAX_IMAGE_SIDE as i64;
        for (name, v) in [("width", width), ("height", height)] {
            if !(1..=max).contains(&v) {
                return Err(PyValueError::new_err(format!(
                    "Camera: field `camera.{name}`: must lie in 1..={max}, got {v}"
                )));
            }
        }
        let camera = nimbus_scene::Camera::new(
            DVec3::from_array(origin),
            DVec3::from_array(target),
            DVec3::from_array(up),
            vfov_deg,
            width as usize,
            height as usize,
        )
        .map_err(|e| call::field("Camera", e))?;
        let mut t = Table::new();
        t.insert("origin".into(), arr(origin));
        t.insert("target".into(), arr(target));
        t.insert("up".into(), arr(up));
        t.insert("vfov_deg".into(), Value::Float(vfov_deg));
        t.insert("width".into(), Value::Integer(width));
        t.insert("height".into(), Value::Integer(height));
        Ok(Self { table: t, camera })
    }

    #[getter]
    fn width(&self) -> usize {
        self.camera.width
    }

    #[getter]
    fn height(&self) -> usize {
        self.camera.height
    }

    fn __repr__(&self) -> String {
        format!("Camera({})", Value::Table(self.table.clone()))
    }
}

/// A scene: the scene file's fields as keywords (`volume` and its `density_scale`, `albedo`,
/// `phase`, `aabb_min`/`aabb_max`; `sun`, `sky`, `camera`; the `[render]` fields `spp`,
/// `seed`, `max_depth`), checked as a scene file is.
#[pyclass(module = "nimbus", frozen)]
pub(crate) struct Scene {
    /// The scene file's table, without the volume's source (`file`/`generator`/`grid`).
    table: Table,
    volume: Volume,
    envmap: Option<Image>,
    pub(crate) scene: nimbus_scene::Scene,
}

impl Scene {
    fn build(table: Table, volume: Volume, envmap: Option<Image>) -> PyResult<Self> {
        let text = toml::to_string(&table).map_err(|e| PyValueError::new_err(e.to_string()))?;
        let memory = InMemory {
            grid: Some((volume.grid.clone(), volume.bounds)),
            envmap: envmap.clone(),
        };
        let cwd = std::env::current_dir().unwrap_or_default();
        let mut scene =
            nimbus_scene::Scene::from_toml_in_memory(&text, &cwd, Path::new("Scene"), memory)
                .map_err(call::scene_err)?;
        scene.volume_source = match &volume.source {
            Source::Memory => nimbus_scene::VolumeSource::Memory,
            Source::File { path, .. } => nimbus_scene::VolumeSource::File(path.clone()),
            Source::Generated { kind, seed } => nimbus_scene::VolumeSource::Generated {
                kind: *kind,
                seed: *seed,
            },
        };
        Ok(Self {
            table,
            volume,
            envmap,
            scene,
        })
    }

    /// The scene's table as a file at `path` would hold it (paths absolute).
    fn file_table(&self, path: &Path) -> PyResult<Table> {
        let mut t = self.table.clone();
        let vol = t
            .entry("volume")
            .or_insert_with(|| Value::Table(Table::new()))
            .as_table_mut()
            .expect("a table");
        for k in ["file", "generator", "grid"] {
            vol.remove(k);
        }
        let aabb = self.scene.volume.aabb();
        vol.insert("aabb_min".into(), arr(aabb.min.to_array()));
        vol.insert("aabb_max".into(), arr(aabb.max.to_array()));
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().to_string())
            .unwrap_or_else(|| "scene".into());
        let dir = path.parent().unwrap_or(Path::new("."));
        match &self.volume.source {
            Source::File { path: f, grid } => {
                vol.insert(
                    "file".into(),
                    Value::String(absolute(f).display().to_string()),
                );
                if let Some(g) = grid {
                    vol.insert("grid".into(), Value::String(g.clone()));
                }
            }
            Source::Generated { kind, seed } => {
                let r = self.volume.grid.res();
                let mut g = Table::new();
                g.insert("kind".into(), Value::String(kind.name().into()));
                g.insert("seed".into(), Value::Integer(*seed as i64));
                g.insert(
                    "resolution".into(),
                    Value::Array(r.iter().map(|&n| Value::Integer(n as i64)).collect()),
                );
                vol.insert("generator".into(), Value::Table(g));
            }
            Source::Memory => {
                let npy = format!("{stem}.npy");
                io::write_grid(dir.join(&npy), &self.volume.grid, (aabb.min, aabb.max))
                    .map_err(call::scene_err)?;
                vol.insert("file".into(), Value::String(npy));
            }
        }
        if let Some(env) = &self.envmap {
            let exr = format!("{stem}_sky.exr");
            env.write_exr(dir.join(&exr), None)
                .map_err(call::scene_err)?;
            if let Some(sky) = t.get_mut("sky").and_then(Value::as_table_mut) {
                sky.insert("envmap".into(), Value::String(exr));
            }
        }
        Ok(t)
    }
}

/// Makes the relative paths of a scene file's table absolute (against its folder `base`).
fn rebase(t: &mut Table, base: &Path) {
    for (section, key) in [("volume", "file"), ("sky", "envmap")] {
        if let Some(Value::String(p)) = t
            .get_mut(section)
            .and_then(Value::as_table_mut)
            .and_then(|s| s.get_mut(key))
        {
            *p = absolute(&base.join(&*p)).display().to_string();
        }
    }
}

#[pymethods]
impl Scene {
    #[new]
    #[pyo3(signature = (volume, camera, density_scale=1.0, albedo=1.0, phase=None, sun=None, sky=None, aabb_min=None, aabb_max=None, spp=None, seed=None, max_depth=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        volume: Volume,
        camera: Camera,
        density_scale: f64,
        albedo: f64,
        phase: Option<Phase>,
        sun: Option<Sun>,
        sky: Option<Sky>,
        aabb_min: Option<[f64; 3]>,
        aabb_max: Option<[f64; 3]>,
        spp: Option<i64>,
        seed: Option<u64>,
        max_depth: Option<i64>,
    ) -> PyResult<Self> {
        let mut vol = Table::new();
        vol.insert("density_scale".into(), Value::Float(density_scale));
        vol.insert("albedo".into(), Value::Float(albedo));
        if let Some(p) = phase {
            vol.insert("phase".into(), p.value);
        }
        if let Some((a, b)) = bounds_of("Scene", aabb_min, aabb_max)? {
            vol.insert("aabb_min".into(), arr(a.to_array()));
            vol.insert("aabb_max".into(), arr(b.to_array()));
        }
        let mut t = Table::new();
        t.insert("volume".into(), Value::Table(vol));
        if let Some(s) = sun {
            t.insert("sun".into(), Value::Table(s.table));
        }
        let mut envmap = None;
        if let Some(s) = sky {
            t.insert("sky".into(), Value::Table(s.table));
            envmap = s.envmap;
        }
        t.insert("camera".into(), Value::Table(camera.table));
        let mut render = Table::new();
        if let Some(v) = spp {
            render.insert("spp".into(), Value::Integer(v));
        }
        if let Some(v) = seed {
            render.insert("seed".into(), Value::Integer(v as i64));
        }
        if let Some(v) = max_depth {
            render.insert("max_depth".into(), Value::Integer(v));
        }
        if !render.is_empty() {
            t.insert("render".into(), Value::Table(render));
        }
        Self::build(t, volume, envmap)
    }

    /// Reads a scene file (`nimbus render scene.toml` reads the same).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let (scene, text) = {
            let path = path.clone();
            call::run(py, move |_| {
                let s = nimbus_scene::Scene::load(&path)?;
                let text = fsio::read_to_string(&path)?;
                Ok((s, text))
            })?
        };
        let mut table: Table = text
            .parse()
            .map_err(|e| PyValueError::new_err(format!("{}: {e}", path.display())))?;
        rebase(&mut table, path.parent().unwrap_or(Path::new(".")));
        let grid_name = table
            .get("volume")
            .and_then(|v| v.get("grid"))
            .and_then(Value::as_str)
            .map(String::from);
        let aabb = *scene.volume.aabb();
        let volume = Volume {
            grid: scene.volume.grid().clone(),
            bounds: Some((aabb.min, aabb.max)),
            source: match &scene.volume_source {
                nimbus_scene::VolumeSource::File(p) => Source::File {
                    path: absolute(p),
                    grid: grid_name,
                },
                nimbus_scene::VolumeSource::Generated { kind, seed } => Source::Generated {
                    kind: *kind,
                    seed: *seed,
                },
                nimbus_scene::VolumeSource::Memory => Source::Memory,
            },
        };
        Ok(Self {
            table,
            volume,
            envmap: None,
            scene,
        })
    }

    /// Writes the scene file; a volume from numpy is written beside it as `<name>.npy` (an
    /// environment map from numpy as `<name>_sky.exr`), files it was read from are named by
    /// their absolute paths.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        let t = self.file_table(&path)?;
        let text = toml::to_string(&t).map_err(|e| PyValueError::new_err(e.to_string()))?;
        fsio::write_bytes(&path, text.as_bytes()).map_err(call::scene_err)
    }

    /// The scene file's text (as `save` would write it, without writing arrays).
    fn to_toml(&self) -> PyResult<String> {
        toml::to_string(&self.table).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    #[getter]
    fn volume(&self) -> Volume {
        self.volume.clone()
    }

    #[getter]
    fn width(&self) -> usize {
        self.scene.camera.width
    }

    #[getter]
    fn height(&self) -> usize {
        self.scene.camera.height
    }

    /// `render.spp` and `render.seed`.
    #[getter]
    fn spp(&self) -> u32 {
        self.scene.render.spp
    }

    #[getter]
    fn seed(&self) -> u64 {
        self.scene.render.seed
    }

    /// The phase function as the reports name it (`hg g=0.857`).
    #[getter]
    fn phase(&self) -> String {
        self.scene.phase_desc.clone()
    }

    fn __repr__(&self) -> String {
        format!(
            "Scene({}x{}, {}, {:?})",
            self.scene.camera.width,
            self.scene.camera.height,
            self.scene.phase_desc,
            volume_repr(&self.volume)
        )
    }
}

fn volume_repr(v: &Volume) -> String {
    v.__repr__()
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Phase>()?;
    m.add_function(wrap_pyfunction!(henyey_greenstein, m)?)?;
    m.add_function(wrap_pyfunction!(isotropic, m)?)?;
    m.add_function(wrap_pyfunction!(mie, m)?)?;
    m.add_class::<Sun>()?;
    m.add_class::<Sky>()?;
    m.add_class::<Camera>()?;
    m.add_class::<Scene>()?;
    Ok(())
}
