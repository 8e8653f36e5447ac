//! Reading and writing density grids.
//!
//! | format | read | write | notes |
//! |---|---|---|---|
//! | Mitsuba `.vol` | yes | yes | version 3, encoding 1 (float32), 1 channel |
//! | NumPy `.npy` | yes | yes | float32 or float64 (converted), shape `[z][y][x]`, C order |
//! | OpenVDB `.vdb` | yes | no | the float grid named `density` unless another is named; see [`vdb`] |
//! | NanoVDB `.nvdb` | yes | no | the float (or Fp4/8/16) grid named `density` unless another is named; see [`nvdb`] |
//!
//! Every reader checks sizes against the file length before allocating, and rejects NaN, infinite
//! or negative voxels with an error naming the file and the voxel.

pub mod npy;
pub mod nvdb;
pub mod vdb;
pub mod vol;

use std::path::Path;

use glam::DVec3;

use crate::error::{Error, Result};
use crate::grid::DensityGrid;

/// A grid read from a file, with the bounding box its header stores, when it has one.
#[derive(Debug, Clone)]
pub struct GridFile {
    pub grid: DensityGrid,
    /// `(min, max)` from the file header (`.vol`) or the index-space bounds times the voxel size
    /// (`.vdb`); `None` for `.npy`.
    pub bounds: Option<(DVec3, DVec3)>,
}

/// Reads a grid, choosing the format from the extension.
pub fn read_grid(path: impl AsRef<Path>) -> Result<GridFile> {
    read_grid_named(path, None)
}

/// Like [`read_grid`]; `grid` names the grid of a `.vdb` or `.nvdb` file (default `density`). Other formats
/// hold one unnamed grid: naming one is an error.
pub fn read_grid_named(path: impl AsRef<Path>, grid: Option<&str>) -> Result<GridFile> {
    let path = path.as_ref();
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    if grid.is_some() && !matches!(ext.as_deref(), Some("vdb" | "nvdb")) {
        return Err(Error::invalid(
            path,
            "grid",
            "only .vdb and .nvdb files hold named grids",
        ));
    }
    // A pipe, device, folder or bad link is refused here, whatever the extension says.
    crate::fsio::open(path, crate::fsio::Hold::Streamed)?;
    match ext.as_deref() {
        Some("vol") => vol::read(path),
        Some("npy") => npy::read(path).map(|grid| GridFile { grid, bounds: None }),
        Some("vdb") => vdb::read_named(path, grid.unwrap_or(vdb::GRID_NAME)),
        Some("nvdb") => nvdb::read_named(path, grid.unwrap_or(nvdb::GRID_NAME)),
        _ => Err(Error::parse(
            path,
            "unknown volume format: expected a .vol, .npy, .vdb or .nvdb file",
        )),
    }
}

/// Parses a grid held in memory — a file dropped onto a web page, a download — choosing the
/// format from `name`'s extension as [`read_grid_named`] does; `name` labels every error. The
/// readers are the same: every check of a file applies to the bytes (the caller bounds their
/// size, e.g. by the page's memory).
pub fn parse_grid_named(bytes: &[u8], name: &Path, grid: Option<&str>) -> Result<GridFile> {
    let ext = name
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    if grid.is_some() && !matches!(ext.as_deref(), Some("vdb" | "nvdb")) {
        return Err(Error::invalid(
            name,
            "grid",
            "only .vdb and .nvdb files hold named grids",
        ));
    }
    match ext.as_deref() {
        Some("vol") => vol::parse(bytes, name),
        Some("npy") => npy::parse(bytes, name).map(|grid| GridFile { grid, bounds: None }),
        Some("vdb") => vdb::parse_named(bytes, name, grid.unwrap_or(vdb::GRID_NAME)),
        Some("nvdb") => nvdb::parse_named(bytes, name, grid.unwrap_or(nvdb::GRID_NAME)),
        _ => Err(Error::parse(
            name,
            "unknown volume format: expected a .vol, .npy, .vdb or .nvdb file",
        )),
    }
}

/// Writes `path` whole or not at all: [`crate::fsio::write_atomically`].
pub fn write_atomically(
    path: impl AsRef<Path>,
    write: impl FnOnce(&Path) -> Result<()>,
) -> Result<()> {
    crate::fsio::write_atomically(path.as_ref(), write)
}

/// Checks, before long work, that `path` can be written: its folder exists (it is created
/// when missing) and accepts a new file (probed with a hidden temporary that is removed).
pub fn check_writable(path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    if path.file_name().is_none() {
        return Err(Error::parse(path, "not a file path"));
    }
    let dir = path
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).map_err(|e| Error::io(path, e))?;
    let probe = dir.join(format!(".nimbus-write-probe-{}", std::process::id()));
    crate::fsio::create(&probe).map_err(|e| match e {
        Error::Io { err, .. } => Error::io(path, err),
        e => e,
    })?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Checks a grid output path before the grid is made: a `.vol` or `.npy` extension and a
/// writable folder ([`check_writable`]).
pub fn check_grid_output(path: impl AsRef<Path>) -> Result<()> {
    let path = path.as_ref();
    match path.extension().and_then(|e| e.to_str()) {
        Some("vol") | Some("npy") => check_writable(path),
        _ => Err(Error::parse(
            path,
            "can only write .vol or .npy volumes (choose one of these extensions)",
        )),
    }
}

/// Writes a grid, choosing the format from the extension (`.vol` or `.npy`), atomically.
pub fn write_grid(
    path: impl AsRef<Path>,
    grid: &DensityGrid,
    bounds: (DVec3, DVec3),
) -> Result<()> {
    let path = path.as_ref();
    match path.extension().and_then(|e| e.to_str()) {
        Some("vol") => write_atomically(path, |t| vol::write(t, grid, bounds)),
        Some("npy") => write_atomically(path, |t| npy::write(t, grid)),
        _ => Err(Error::parse(
            path,
            "can only write .vol or .npy volumes (choose one of these extensions)",
        )),
    }
}
