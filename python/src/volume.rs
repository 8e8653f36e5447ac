//! `Volume`: a density grid from a numpy array (any real dtype, any layout, copied once into
//! the renderer's storage), a file (every format the CLI reads) or a generator.

use std::path::PathBuf;

use glam::DVec3;
use nimbus_scene::{CloudKind, DensityGrid, generate, io};
use numpy::{Element, PyArray3, PyArrayMethods, PyUntypedArray, PyUntypedArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::call;

type Vec3 = (f64, f64, f64);

/// Where a volume's grid came from (how a saved scene names it).
#[derive(Clone, Debug)]
pub(crate) enum Source {
    Memory,
    File { path: PathBuf, grid: Option<String> },
    Generated { kind: CloudKind, seed: u64 },
}

/// A density grid, indexed `[z][y][x]` as a numpy array (x fastest in memory), with the box it
/// fills when its source gives one. The grid is held once, whichever scenes use it.
#[pyclass(module = "nimbus", frozen)]
#[derive(Clone)]
pub(crate) struct Volume {
    pub(crate) grid: DensityGrid,
    pub(crate) bounds: Option<(DVec3, DVec3)>,
    pub(crate) source: Source,
}

fn triple(v: Option<[f64; 3]>) -> Option<DVec3> {
    v.map(DVec3::from_array)
}

/// The box from `aabb_min`/`aabb_max`, both or neither.
pub(crate) fn bounds_of(
    what: &str,
    lo: Option<[f64; 3]>,
    hi: Option<[f64; 3]>,
) -> PyResult<Option<(DVec3, DVec3)>> {
    match (triple(lo), triple(hi)) {
        (Some(a), Some(b)) => {
            nimbus_scene::Aabb::new(a, b).map_err(|e| call::field(what, e))?;
            Ok(Some((a, b)))
        }
        (None, None) => Ok(None),
        _ => Err(PyValueError::new_err(format!(
            "{what}: field `aabb_max`: give both aabb_min and aabb_max, or neither"
        ))),
    }
}

/// The values of `a` as f32, x fastest, in one allocation (checked against the memory budget,
/// made fallibly).
fn values<T: Element + Copy>(
    a: &Bound<'_, PyArray3<T>>,
    to: impl Fn(T) -> f32,
) -> PyResult<Vec<f32>> {
    let ro = a.readonly();
    let view = ro.as_array();
    let n = view.len();
    nimbus_scene::memory::check(n as u128 * 4, "density", &format!("a grid of {n} voxels"))
        .map_err(|e| call::field("Volume.from_numpy", e))?;
    let mut out = Vec::new();
    out.try_reserve_exact(n).map_err(|_| {
        pyo3::exceptions::PyMemoryError::new_err(format!(
            "Volume.from_numpy: cannot allocate {n} voxels"
        ))
    })?;
    match view.as_slice() {
        Some(s) => out.extend(s.iter().map(|&v| to(v))),
        // Any other layout (a transposed or strided view) in logical order, [z][y][x].
        None => out.extend(view.iter().map(|&v| to(v))),
    }
    Ok(out)
}

/// A grid from a numpy array (or anything `numpy.asarray` takes), copied once.
pub(crate) fn grid_from_numpy(obj: &Bound<'_, PyAny>) -> PyResult<DensityGrid> {
    let py = obj.py();
    let arr = match obj.cast::<PyUntypedArray>() {
        Ok(a) => a.clone(),
        Err(_) => py
            .import("numpy")?
            .call_method1("asarray", (obj,))?
            .cast_into::<PyUntypedArray>()?,
    };
    let shape = arr.shape().to_vec();
    if shape.len() != 3 {
        return Err(PyValueError::new_err(format!(
            "Volume.from_numpy: field `density`: expected a 3-D array indexed [z][y][x], got \
             shape {shape:?} ({} dimensions)",
            shape.len()
        )));
    }
    if let Some(axis) = shape.iter().position(|&n| n == 0) {
        return Err(PyValueError::new_err(format!(
            "Volume.from_numpy: field `density`: shape {shape:?} is empty along axis {axis} \
             ({}); every axis needs at least one voxel",
            ["z", "y", "x"][axis]
        )));
    }
    let data = if let Ok(a) = arr.cast::<PyArray3<f32>>() {
        values(a, |v| v)?
    } else if let Ok(a) = arr.cast::<PyArray3<f64>>() {
        values(a, |v| v as f32)?
    } else if let Ok(a) = arr.cast::<PyArray3<half::f16>>() {
        values(a, |v| v.to_f32())?
    } else if let Ok(a) = arr.cast::<PyArray3<u8>>() {
        values(a, |v| v as f32)?
    } else if let Ok(a) = arr.cast::<PyArray3<u16>>() {
        values(a, |v| v as f32)?
    } else if let Ok(a) = arr.cast::<PyArray3<u32>>() {
        values(a, |v| v as f32)?
    } else if let Ok(a) = arr.cast::<PyArray3<u64>>() {
        values(a, |v| v as f32)?
    } else if let Ok(a) = arr.cast::<PyArray3<i8>>() {
        values(a, |v| v as f32)?
    } else if let Ok(a) = arr.cast::<PyArray3<i16>>() {
        values(a, |v| v as f32)?
    } else if let Ok(a) = arr.cast::<PyArray3<i32>>() {
        values(a, |v| v as f32)?
    } else if let Ok(a) = arr.cast::<PyArray3<i64>>() {
        values(a, |v| v as f32)?
    } else {
        return Err(PyTypeError::new_err(format!(
            "Volume.from_numpy: field `density`: dtype {} is not a real number type (give \
             floats or integers)",
            arr.dtype()
        )));
    };
    let res = [shape[2], shape[1], shape[0]];
    DensityGrid::new(res, data).map_err(|e| {
        // The grid names a voxel [x,y,z]; a numpy user indexes [z, y, x].
        let idx: Vec<&str> = e
            .field
            .strip_prefix("voxel[")
            .and_then(|r| r.strip_suffix(']'))
            .map(|r| r.split(',').collect())
            .unwrap_or_default();
        if let [x, y, z] = idx.as_slice() {
            PyValueError::new_err(format!(
                "Volume.from_numpy: field `density[{z}, {y}, {x}]` (x = {x}, y = {y}, z = {z}): {}",
                e.msg
            ))
        } else {
            call::field("Volume.from_numpy", e)
        }
    })
}

#[pymethods]
impl Volume {
    /// A volume from a 3-D array indexed `[z][y][x]` (as the CLI reads `.npy` files): any real
    /// dtype and memory layout, copied once into float32. NaN, infinite or negative voxels,
    /// another rank or an empty axis raise ValueError naming the index or the field.
    /// `aabb_min`/`aabb_max`: the world box it fills (or give them to `Scene`).
    #[staticmethod]
    #[pyo3(signature = (density, aabb_min=None, aabb_max=None))]
    fn from_numpy(
        density: &Bound<'_, PyAny>,
        aabb_min: Option<[f64; 3]>,
        aabb_max: Option<[f64; 3]>,
    ) -> PyResult<Self> {
        let bounds = bounds_of("Volume.from_numpy", aabb_min, aabb_max)?;
        Ok(Self {
            grid: grid_from_numpy(density)?,
            bounds,
            source: Source::Memory,
        })
    }

    /// Reads a volume file as the CLI does (`.vol`, `.npy`, `.vdb`, `.nvdb`); `grid` names the
    /// float grid of a `.vdb`/`.nvdb` (default `density`).
    #[staticmethod]
    #[pyo3(signature = (path, grid=None))]
    fn load(py: Python<'_>, path: PathBuf, grid: Option<String>) -> PyResult<Self> {
        let f = {
            let (path, grid) = (path.clone(), grid.clone());
            call::run(py, move |_| {
                Ok(io::read_grid_named(&path, grid.as_deref())?)
            })?
        };
        Ok(Self {
            grid: f.grid,
            bounds: f.bounds,
            source: Source::File { path, grid },
        })
    }

    /// The grid's shape as a numpy array's, `(z, y, x)`.
    #[getter]
    fn shape(&self) -> (usize, usize, usize) {
        let r = self.grid.res();
        (r[2], r[1], r[0])
    }

    /// `(aabb_min, aabb_max)` when the source gives a box, else None.
    #[getter]
    fn aabb(&self) -> Option<(Vec3, Vec3)> {
        self.bounds.map(|(a, b)| (a.into(), b.into()))
    }

    /// Whether the grid is stored as 8³ bricks (`.vdb`, `.nvdb`, large `.vol`).
    #[getter]
    fn sparse(&self) -> bool {
        self.grid.as_bricks().is_some()
    }

    /// min, max, mean and the fraction of non-zero voxels.
    fn stats(&self) -> std::collections::BTreeMap<&'static str, f64> {
        let s = self.grid.stats();
        [
            ("min", s.min as f64),
            ("max", s.max as f64),
            ("mean", s.mean),
            ("nonzero_fraction", s.nonzero_fraction),
        ]
        .into_iter()
        .collect()
    }

    /// The grid as a new float32 array `[z][y][x]` (a sparse grid densified).
    fn to_numpy<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray3<f32>>> {
        let [nx, ny, nz] = self.grid.res();
        nimbus_scene::memory::check((nx * ny * nz) as u128 * 4, "volume", "the grid's copy")
            .map_err(|e| call::field("Volume.to_numpy", e))?;
        let mut data = vec![0.0f32; nx * ny * nz];
        for (z, plane) in data.chunks_mut(nx * ny).enumerate() {
            self.grid.plane(z, plane);
        }
        let a = numpy::PyArray1::from_vec(py, data);
        a.reshape([nz, ny, nx])
    }

    /// Writes the grid as `.vol` (with its box) or `.npy`.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let bounds = self.bounds.unwrap_or((DVec3::ZERO, DVec3::ONE));
        let grid = self.grid.clone();
        call::run(py, move |_| Ok(io::write_grid(&path, &grid, bounds)?))
    }

    pub(crate) fn __repr__(&self) -> String {
        let (z, y, x) = self.shape();
        let src = match &self.source {
            Source::Memory => "numpy".to_string(),
            Source::File { path, .. } => path.display().to_string(),
            Source::Generated { kind, seed } => format!("{} seed {seed}", kind.name()),
        };
        format!("Volume(shape=(z={z}, y={y}, x={x}), source={src})")
    }
}

/// A procedural cloud (`nimbus generate`): `kind` cumulus, congestus, stratus or cirrus;
/// `res` (x, y, z), default the kind's proportions at 128 along x; the box is the generator's
/// (2 units wide, centred, cubic voxels).
#[pyfunction]
#[pyo3(name = "generate", signature = (kind, seed=0, res=None))]
fn generate_volume(
    py: Python<'_>,
    kind: &str,
    seed: u64,
    res: Option<[i64; 3]>,
) -> PyResult<Volume> {
    let kind: CloudKind = kind.parse().map_err(|e| call::field("generate", e))?;
    let res = match res {
        Some(r) => generate::check_generator_resolution(r, false, "res")
            .map_err(|e| call::field("generate", e))?,
        None => kind.default_resolution(128),
    };
    let grid = call::run(py, move |_| Ok(generate::generate(kind, seed, res)?))?;
    Ok(Volume {
        grid,
        bounds: Some(generate::default_aabb(res)),
        source: Source::Generated { kind, seed },
    })
}

pub(crate) fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<Volume>()?;
    m.add_function(wrap_pyfunction!(generate_volume, m)?)?;
    Ok(())
}
