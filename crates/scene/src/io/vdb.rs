//! OpenVDB `.vdb` float grids, read through the `vdb-rs` crate.
//!
//! Supported: file versions 222–224 as written by OpenVDB 7–11, `Tree_float_5_4_3` grids stored
//! as full floats, uncompressed, zlib or Blosc compressed, uniform-scale (and translate)
//! transforms. The grid named `density` is read; a file without one is an error that lists the
//! grids it has. Active voxels and active tiles are densified over their index bounding box
//! (inactive voxels read as 0, the usual background of density grids). The world bounds are
//! `(index_min − ½, index_max + ½) × voxel_size + translation`, so voxel centres land where
//! OpenVDB puts them.
//!
//! Not supported (clear error): half-float storage (`saveFloatAsHalf`), other value types (vec3,
//! double, int), frustum or affine transforms, multi-pass point grids. `vdb-rs` may panic on corrupt input; the panic is caught and
//! reported as a malformed-file error.

use std::io::Cursor;
use std::path::Path;

use glam::DVec3;

use super::GridFile;
use crate::error::{Error, Result};
use crate::grid::{DensityGrid, check_resolution};

/// The grid name looked up in `.vdb` files.
pub const GRID_NAME: &str = "density";

/// Parses `.vdb` bytes, grid [`GRID_NAME`]; `path` only labels errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<GridFile> {
    parse_named(bytes, path, GRID_NAME)
}

/// Parses `.vdb` bytes, the float grid called `name`; `path` only labels errors.
pub fn parse_named(bytes: &[u8], path: &Path, name: &str) -> Result<GridFile> {
    let owned = bytes.to_vec();
    let name = name.to_string();
    // vdb-rs panics on malformed input ("Not supported", index errors — found by
    // `cargo fuzz run vdb`); the panic becomes an error naming the file. The default hook would
    // print the panic and a backtrace before that error, so a silent hook stands in meanwhile
    // (process-wide: a panic on another thread in this window would go unprinted).
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let result = std::panic::catch_unwind(move || parse_inner(&owned, &name));
    std::panic::set_hook(hook);
    match result {
        Ok(Ok(v)) => {
            let (res, data, bounds) = v;
            let grid = DensityGrid::new(res, data).map_err(|e| e.at(path))?;
            Ok(GridFile {
                grid,
                bounds: Some(bounds),
            })
        }
        Ok(Err((field, msg))) => Err(Error::invalid(path, field, msg)),
        Err(panic) => {
            let what = panic
                .downcast_ref::<String>()
                .cloned()
                .or_else(|| panic.downcast_ref::<&str>().map(|s| s.to_string()))
                .unwrap_or_else(|| "unknown error".into());
            Err(Error::parse(
                path,
                format!("malformed or unsupported OpenVDB file ({what})"),
            ))
        }
    }
}

type Parsed = ([usize; 3], Vec<f32>, (DVec3, DVec3));

fn parse_inner(bytes: &[u8], name: &str) -> std::result::Result<Parsed, (String, String)> {
    let err = |f: &str, m: String| (f.to_string(), m);
    if bytes.len() < 8 || bytes[0..4] != [0x20, 0x42, 0x44, 0x56] {
        return Err(err(
            "header.magic",
            "not an OpenVDB file (bad magic number)".into(),
        ));
    }
    let mut reader = vdb_rs::VdbReader::new(Cursor::new(bytes))
        .map_err(|e| err("header", format!("cannot read the OpenVDB header: {e}")))?;
    let names = reader.available_grids();
    let Some(desc) = reader.grid_descriptors.get(name).cloned() else {
        return Err(err(
            "grid",
            format!(
                "no grid named `{name}` (grids in file: {names:?}); choose one with `grid = \"…\"` in [volume] or `--grid`"
            ),
        ));
    };
    if !desc.grid_type.starts_with("Tree_float_5_4_3") {
        return Err(err(
            "grid.type",
            format!(
                "grid `{name}` has type {}; only float grids (Tree_float_5_4_3) are supported",
                desc.grid_type
            ),
        ));
    }
    if desc.meta_data.is_half_float() {
        return Err(err(
            "grid.is_saved_as_half_float",
            format!(
                "grid `{name}` is stored as half floats, which are not supported; re-save it with full floats"
            ),
        ));
    }
    let grid = reader
        .read_grid::<f32>(name)
        .map_err(|e| err("grid", format!("cannot read grid `{name}`: {e}")))?;
    let (voxel_size, translation) = match &grid.transform {
        vdb_rs::Map::UniformScaleMap { voxel_size, .. } => (
            DVec3::new(voxel_size.x, voxel_size.y, voxel_size.z),
            DVec3::ZERO,
        ),
        vdb_rs::Map::ScaleTranslateMap {
            voxel_size,
            translation,
            ..
        } => (
            DVec3::new(voxel_size.x, voxel_size.y, voxel_size.z),
            DVec3::new(translation.x, translation.y, translation.z),
        ),
    };
    if !(voxel_size.is_finite() && voxel_size.cmpgt(DVec3::ZERO).all()) {
        return Err(err(
            "transform.voxel_size",
            format!("invalid voxel size {voxel_size}"),
        ));
    }
    // Index bounding box of active voxels and tiles.
    let mut lo = [i64::MAX; 3];
    let mut hi = [i64::MIN; 3];
    let mut items = Vec::new();
    for (c, v, level) in grid.iter() {
        let s = level.scale() as i64;
        let o = [c.x as i64, c.y as i64, c.z as i64];
        for a in 0..3 {
            lo[a] = lo[a].min(o[a]);
            hi[a] = hi[a].max(o[a] + s - 1);
        }
        items.push((o, v, s));
    }
    if items.is_empty() {
        return Err(err("grid", format!("grid `{name}` has no active voxels")));
    }
    let res = check_resolution(
        [hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1],
        "grid.bounds",
    )
    .map_err(|e| (e.field, e.msg))?;
    // Active voxels and tiles fill the index box densely: its size is checked against the
    // memory budget before anything is allocated.
    let what = format!(
        "the dense {}×{}×{} grid spanning its active voxels",
        res[0], res[1], res[2]
    );
    let mut data = crate::memory::filled(res[0] * res[1] * res[2], 0.0f32, "grid.bounds", &what)
        .map_err(|e| (e.field, e.msg))?;
    for (o, v, s) in items {
        for z in o[2]..o[2] + s {
            for y in o[1]..o[1] + s {
                for x in o[0]..o[0] + s {
                    let (ix, iy, iz) = (
                        (x - lo[0]) as usize,
                        (y - lo[1]) as usize,
                        (z - lo[2]) as usize,
                    );
                    data[(iz * res[1] + iy) * res[0] + ix] = v;
                }
            }
        }
    }
    let lo_w = DVec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64) - DVec3::splat(0.5);
    let hi_w = DVec3::new(hi[0] as f64, hi[1] as f64, hi[2] as f64) + DVec3::splat(0.5);
    Ok((
        res,
        data,
        (
            lo_w * voxel_size + translation,
            hi_w * voxel_size + translation,
        ),
    ))
}

pub fn read(path: &Path) -> Result<GridFile> {
    read_named(path, GRID_NAME)
}

/// Reads the float grid called `name`.
pub fn read_named(path: &Path, name: &str) -> Result<GridFile> {
    // The file's bytes, a copy for the reader and the grid are held at once.
    crate::memory::check_file(path, 3)?;
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_named(&bytes, path, name)
}
