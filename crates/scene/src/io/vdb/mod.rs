//! OpenVDB `.vdb` float grids, read by our own bounds-checked reader.
//!
//! Supported: file versions 222–224 (OpenVDB 3.0 – 12), `Tree_float_5_4_3` grids stored as full
//! or half floats (`saveFloatAsHalf`), uncompressed, zlib or Blosc compressed, with or without
//! active-mask compression; instanced grids; axis-aligned transforms (uniform or non-uniform
//! scale, translation, and affine maps without rotation). The grid named `density` is read
//! unless another is named; a file without it is an error listing the grids it has.
//!
//! Active voxels and active tiles become a sparse grid ([`crate::brick`]) over their index
//! bounding box, leaf for brick and tile for constant bricks (inactive voxels read as 0, the
//! usual background of density grids): a file is never densified, so memory grows with the
//! cloud, not with its box. The world bounds are
//! `(index_min − ½, index_max + ½) × voxel_size + translation`, so voxel centres land where
//! OpenVDB puts them.
//!
//! Robustness: every length, count and offset read from the file is checked against the bytes
//! left before it is used, and every allocation whose size follows from the file (leaves,
//! tiles, the dense grid) against the memory budget ([`crate::memory`]); errors name the field
//! and the byte offset (`grid.buffers: truncated at byte 8817 while reading a leaf's value
//! mask (leaf buffer 3)`). No panic or abort is reachable from the file's bytes (fuzzed:
//! `fuzz/README.md`).
//!
//! Not supported (clear error): other value types (vec3, double, int, bool, points), frustum or
//! rotated transforms, multi-buffer trees, file versions before 222 (OpenVDB 2).

mod archive;
pub(crate) mod bytes;
pub(crate) mod codec;
mod tree;

use std::path::Path;

use glam::DVec3;

use super::GridFile;
use crate::brick::{BrickBuilder, DIM, check_sparse_resolution};
use crate::error::{Error, Result};
use crate::grid::DensityGrid;
use bytes::{Cursor, Fail, PResult, bit};
pub use tree::{Leaf, Tile, Tree};

/// The grid name looked up in `.vdb` files.
pub const GRID_NAME: &str = "density";

/// A float grid's active content and its index-to-world map.
#[derive(Debug, Clone)]
pub struct SparseGrid {
    pub tree: Tree,
    /// World = index × `voxel_size` + `translation`.
    pub voxel_size: DVec3,
    pub translation: DVec3,
}

/// Parses `.vdb` bytes, grid [`GRID_NAME`]; `path` only labels errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<GridFile> {
    parse_named(bytes, path, GRID_NAME)
}

/// Parses `.vdb` bytes, the float grid called `name`; `path` only labels errors.
pub fn parse_named(bytes: &[u8], path: &Path, name: &str) -> Result<GridFile> {
    grid_file(read_sparse(bytes, name), name, path)
}

/// A sparse grid read from `path` (or the error reading it), turned into bricks in a
/// [`GridFile`]; shared by the OpenVDB and NanoVDB readers.
pub(crate) fn grid_file(sparse: PResult<SparseGrid>, name: &str, path: &Path) -> Result<GridFile> {
    let fail = |e: Fail| Error::invalid(path, e.field, e.msg);
    let (bricks, bounds) = to_bricks(sparse.map_err(fail)?, name).map_err(fail)?;
    let bricks = bricks.finish().map_err(|e| e.at(path))?;
    Ok(GridFile {
        grid: DensityGrid::from_bricks(bricks),
        bounds: Some(bounds),
    })
}

/// The names and types of the grids in a `.vdb` file (half-float grids end in `(half)`).
pub fn grid_names(bytes: &[u8]) -> PResult<Vec<String>> {
    let h = archive::read_header(&mut Cursor::new(bytes))?;
    Ok(h.descriptors.iter().map(|d| d.name.clone()).collect())
}

/// Reads the active voxels and tiles of the float grid `name`, without densifying.
pub fn read_sparse(bytes: &[u8], name: &str) -> PResult<SparseGrid> {
    let mut c = Cursor::new(bytes);
    let h = archive::read_header(&mut c)?;
    let Some(d) = h.descriptors.iter().find(|d| d.name == name) else {
        let names: Vec<&str> = h.descriptors.iter().map(|d| d.name.as_str()).collect();
        return Err(Fail::new(
            "grid",
            format!(
                "no grid named `{name}` (grids in file: {names:?}); choose one with `grid = \"…\"` in [volume] or `--grid`"
            ),
        ));
    };
    if d.grid_type != "Tree_float_5_4_3" {
        return Err(Fail::new(
            "grid.type",
            format!(
                "grid `{name}` has type {}; only float grids (Tree_float_5_4_3) are supported",
                d.grid_type
            ),
        ));
    }
    let gh = archive::read_grid_header(&mut c, d)?;
    // An instance shares its parent's tree (stored once, after the parent's transform, and
    // read with the parent's storage settings).
    let tree = if d.instance_parent.is_empty() {
        tree::read_tree(&mut c, &gh)?
    } else {
        let Some(p) = h
            .descriptors
            .iter()
            .find(|p| p.name == d.instance_parent && p.instance_parent.is_empty())
        else {
            return Err(Fail::new(
                "grid.instance_parent",
                format!(
                    "grid `{name}` is an instance of `{}`, which is not in the file",
                    d.instance_parent
                ),
            ));
        };
        let ph = archive::read_grid_header(&mut c, p)?;
        tree::read_tree(&mut c, &ph)?
    };
    Ok(SparseGrid {
        tree,
        voxel_size: DVec3::from_array(gh.transform.scale),
        translation: DVec3::from_array(gh.transform.translation),
    })
}

/// Active voxels and tiles as bricks over their index bounding box (inactive = 0), with the
/// box's world bounds; the builder is finished (values checked) by the caller.
pub fn to_bricks(g: SparseGrid, name: &str) -> PResult<(BrickBuilder, (DVec3, DVec3))> {
    let t = &g.tree;
    let mut lo = [i64::MAX; 3];
    let mut hi = [i64::MIN; 3];
    let mut grow = |o: [i64; 3], s: i64| {
        for a in 0..3 {
            lo[a] = lo[a].min(o[a]);
            hi[a] = hi[a].max(o[a] + s - 1);
        }
    };
    for tile in &t.tiles {
        grow(tile.origin, tile.dim);
    }
    for leaf in &t.leaves {
        for i in 0..512 {
            if bit(&leaf.mask, i) {
                grow(voxel(leaf.origin, i), 1);
            }
        }
    }
    if lo[0] > hi[0] {
        return Err(Fail::new(
            "grid",
            format!("grid `{name}` has no active voxels"),
        ));
    }
    let fe = |e: crate::FieldError| Fail::new(&e.field, e.msg);
    let res = check_sparse_resolution(
        [hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1],
        "grid.bounds",
    )
    .map_err(fe)?;
    // The brick lattice is shifted so that leaves (origins at multiples of 8) are bricks.
    let offset = lo.map(|l| l.rem_euclid(DIM as i64) as usize);
    let base = lo.map(|l| l - l.rem_euclid(DIM as i64));
    let what = format!(
        "the sparse {}×{}×{} grid spanning its active voxels ({} leaves)",
        res[0],
        res[1],
        res[2],
        t.leaves.len()
    );
    let mut b = BrickBuilder::new(res, offset, t.leaves.len(), "grid.bounds", &what).map_err(fe)?;
    // Origins off the 8-lattice cannot come from a well-formed tree (nodes sit at multiples of
    // their size); a crafted file gets an error, not a misplaced brick.
    let brick = |p: [i64; 3], what: &str| -> PResult<[usize; 3]> {
        if p.iter().any(|c| c.rem_euclid(DIM as i64) != 0) {
            return Err(Fail::new(
                "grid.tree",
                format!("{what} origin {p:?} is not a multiple of {DIM}"),
            ));
        }
        Ok(std::array::from_fn(|a| {
            ((p[a] - base[a]) / DIM as i64) as usize
        }))
    };
    for tile in &t.tiles {
        if tile.dim < DIM as i64 || tile.dim % DIM as i64 != 0 {
            return Err(Fail::new(
                "grid.tree",
                format!("a tile of {} voxels is not a multiple of {DIM}", tile.dim),
            ));
        }
        let (b0, n) = (brick(tile.origin, "a tile's")?, tile.dim as usize / DIM);
        for bz in b0[2]..b0[2] + n {
            for by in b0[1]..b0[1] + n {
                for bx in b0[0]..b0[0] + n {
                    b.set_constant([bx, by, bz], tile.value).map_err(fe)?;
                }
            }
        }
    }
    let SparseGrid {
        tree,
        voxel_size,
        translation,
    } = g;
    for leaf in tree.leaves {
        if leaf.mask.iter().all(|&m| m == 0) {
            continue; // no active voxel: it may lie outside the box
        }
        let dst = b.stored_mut(brick(leaf.origin, "a leaf's")?).map_err(fe)?;
        for (i, &v) in leaf.values.iter().enumerate().take(512) {
            if bit(&leaf.mask, i) {
                // Leaf order is x slowest, z fastest; bricks are x fastest.
                let (x, y, z) = (i >> 6, (i >> 3) & 7, i & 7);
                dst[(z * DIM + y) * DIM + x] = v;
            }
        }
    }
    let lo_w = DVec3::new(lo[0] as f64, lo[1] as f64, lo[2] as f64) - DVec3::splat(0.5);
    let hi_w = DVec3::new(hi[0] as f64, hi[1] as f64, hi[2] as f64) + DVec3::splat(0.5);
    Ok((
        b,
        (
            lo_w * voxel_size + translation,
            hi_w * voxel_size + translation,
        ),
    ))
}

/// Index coordinates of voxel `i` of a leaf (x slowest, z fastest: `LeafNode::offsetToLocalCoord`).
fn voxel(origin: [i64; 3], i: usize) -> [i64; 3] {
    [
        origin[0] + (i >> 6) as i64,
        origin[1] + ((i >> 3) & 7) as i64,
        origin[2] + (i & 7) as i64,
    ]
}

pub fn read(path: &Path) -> Result<GridFile> {
    read_named(path, GRID_NAME)
}

/// Reads the float grid called `name`.
pub fn read_named(path: &Path, name: &str) -> Result<GridFile> {
    // The file's bytes and the grid are held at once (leaves, tiles and bricks are bounded by
    // a small multiple of the file size and checked separately).
    let bytes = crate::fsio::read_held(path, 2)?;
    parse_named(&bytes, path, name)
}
