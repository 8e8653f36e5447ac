//! The 5-4-3 float tree of an OpenVDB grid: topology (root tiles and children, internal nodes'
//! masks and tile values, leaf masks) and the leaf buffers (OpenVDB `RootNode`, `InternalNode`
//! and `LeafNode` `readTopology` / `readBuffers`, `io::readCompressedValues`).
//!
//! Only what a density volume needs is kept: active voxels (leaf values under the value mask)
//! and active tiles (constant blocks of 8³, 128³ or 4096³ voxels). Every count and length comes
//! from the file and is checked against the bytes left before it is used; the leaves' storage
//! is checked against the memory budget once their number is known.

use super::archive::{COMPRESS_ACTIVE_MASK, COMPRESS_BLOSC, COMPRESS_ZIP, GridHeader};
use super::bytes::{Cursor, Fail, PResult, bit, count_on};

/// Node sizes: log2 of the children per axis of the leaf, lower and upper internal nodes.
const LOG2: [u32; 3] = [3, 4, 5];

/// An 8³ leaf: its origin (index space), value mask and values (x slowest, z fastest).
#[derive(Debug, Clone)]
pub struct Leaf {
    pub origin: [i64; 3],
    pub mask: [u64; 8],
    pub values: Vec<f32>,
}

/// An active tile: a cube of `dim`³ voxels of one value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tile {
    pub origin: [i64; 3],
    pub dim: i64,
    pub value: f32,
}

/// The active content of a float tree.
#[derive(Debug, Clone, Default)]
pub struct Tree {
    pub background: f32,
    pub leaves: Vec<Leaf>,
    pub tiles: Vec<Tile>,
}

/// Coordinates of child `i` of a node with `log2` children per axis, each `child_dim` wide.
fn child_origin(origin: [i64; 3], i: usize, log2: u32, child_dim: i64) -> [i64; 3] {
    let n = 1usize << log2;
    let (x, y, z) = (i >> (2 * log2), (i >> log2) & (n - 1), i & (n - 1));
    [
        origin[0] + x as i64 * child_dim,
        origin[1] + y as i64 * child_dim,
        origin[2] + z as i64 * child_dim,
    ]
}

/// Value decoding settings of one grid.
struct Codec {
    compression: u32,
    half: bool,
    background: f32,
}

/// Reads the tree: topology at the cursor (just after the transform), then the leaf buffers.
pub fn read_tree(c: &mut Cursor, h: &GridHeader) -> PResult<Tree> {
    c.field = "grid.tree";
    let buffers = c.i32("the buffer count")?;
    if buffers != 1 {
        return Err(c.fail(format!(
            "buffer count {buffers}: only single-buffer trees are supported"
        )));
    }
    let background = c.f32("the background value")?;
    let codec = Codec {
        compression: h.compression,
        half: h.half,
        background,
    };
    let tiles_n = c.u32("the root tile count")? as u64;
    let children_n = c.u32("the root child count")? as u64;
    // A root tile is 17 bytes, a root child at least 12 + 2 × 4096 bytes.
    if tiles_n * 17 + children_n * (12 + 8192) > c.left() as u64 {
        return Err(c.fail(format!(
            "the root claims {tiles_n} tiles and {children_n} children, which do not fit in the {} bytes left",
            c.left()
        )));
    }
    let mut tree = Tree {
        background,
        ..Default::default()
    };
    let root_dim = 1i64 << (LOG2[0] + LOG2[1] + LOG2[2]);
    for _ in 0..tiles_n {
        let o = c.ivec3("a root tile")?;
        let value = c.f32("a root tile")?;
        let active = c.u8("a root tile")?;
        if active != 0 {
            tree.tiles.push(Tile {
                origin: o.map(i64::from),
                dim: root_dim,
                value,
            });
        }
    }
    // Each root child: its origin, then its subtree (children in the root's (x, y, z) order;
    // the leaf buffers follow the same order).
    let mut leaves: Vec<([i64; 3], [u64; 8])> = Vec::new();
    for _ in 0..children_n {
        let o = c.ivec3("a root child's origin")?;
        if o.iter().any(|v| v.rem_euclid(root_dim as i32) != 0) {
            return Err(c.fail(format!(
                "root child origin {o:?} at byte {} is not a multiple of {root_dim}",
                c.pos() - 12
            )));
        }
        read_internal(c, &codec, o.map(i64::from), 2, &mut tree.tiles, &mut leaves)?;
    }
    // Leaf storage: 512 floats and a mask each; checked before the buffers are read.
    let bytes = leaves.len() as u128 * (512 * 4 + 64 + 24);
    crate::memory::check(
        bytes,
        "grid.tree",
        &format!("the {} leaves of the grid", leaves.len()),
    )
    .map_err(|e| Fail::new(&e.field, e.msg))?;
    // The buffers follow the topology directly; OpenVDB reads them in sequence and so do we
    // (some writers store a block offset that points elsewhere; it is not needed).
    c.field = "grid.buffers";
    let mut values = vec![0.0f32; 512];
    tree.leaves.reserve_exact(leaves.len());
    for (i, (origin, _)) in leaves.into_iter().enumerate() {
        let m = c
            .mask(8, "a leaf's value mask")
            .map_err(|e| e.context(format!("leaf buffer {i}")))?;
        let mask: [u64; 8] = m.try_into().unwrap();
        read_values(c, &codec, &mut values, &mask)
            .map_err(|e| e.context(format!("leaf buffer {i}")))?;
        if count_on(&mask) > 0 {
            tree.leaves.push(Leaf {
                origin,
                mask,
                values: values.clone(),
            });
        }
    }
    Ok(tree)
}

/// An internal node's topology (`InternalNode::readTopology`): child mask, value mask, the
/// node's values (tiles), then each child in mask order. `level` 2 = upper (32³ children of
/// 128³ voxels), 1 = lower (16³ leaves of 8³ voxels).
fn read_internal(
    c: &mut Cursor,
    codec: &Codec,
    origin: [i64; 3],
    level: usize,
    tiles: &mut Vec<Tile>,
    leaves: &mut Vec<([i64; 3], [u64; 8])>,
) -> PResult<()> {
    let log2 = LOG2[level];
    let child_dim = 1i64 << LOG2[..level].iter().sum::<u32>();
    let n = 1usize << (3 * log2);
    let what = if level == 2 {
        "an upper node"
    } else {
        "a lower node"
    };
    let child_mask = c.mask(n / 64, what)?;
    let value_mask = c.mask(n / 64, what)?;
    // Tiles are kept as entries of 32 bytes; a few compressed bytes can activate 32 768 of
    // them, so their storage is checked against the budget as it grows.
    crate::memory::check(
        (tiles.len() + n) as u128 * std::mem::size_of::<Tile>() as u128 * 2,
        "grid.tree",
        "the grid's active tiles",
    )
    .map_err(|e| Fail::new(&e.field, e.msg))?;
    let mut values = vec![0.0f32; n];
    read_values(c, codec, &mut values, &value_mask)
        .map_err(|e| e.context(format!("{what} at {origin:?}")))?;
    for (i, &value) in values.iter().enumerate() {
        if bit(&value_mask, i) && !bit(&child_mask, i) {
            tiles.push(Tile {
                origin: child_origin(origin, i, log2, child_dim),
                dim: child_dim,
                value,
            });
        }
    }
    for i in 0..n {
        if !bit(&child_mask, i) {
            continue;
        }
        let o = child_origin(origin, i, log2, child_dim);
        if level == 2 {
            read_internal(c, codec, o, 1, tiles, leaves)?;
        } else {
            let m = c.mask(8, "a leaf's value mask")?;
            leaves.push((o, m.try_into().unwrap()));
        }
    }
    Ok(())
}

/// `io::readCompressedValues`: per-node metadata byte, optional inactive values and selection
/// mask, then the stored values (all of them, or only the active ones under mask compression),
/// decoded into `out` (inactive slots get the reconstructed inactive values).
fn read_values(c: &mut Cursor, codec: &Codec, out: &mut [f32], value_mask: &[u64]) -> PResult<()> {
    let n = out.len();
    let meta = c.u8("the node's compression metadata")?;
    if meta > 6 {
        return Err(c.fail(format!(
            "node compression metadata {meta} at byte {} is not one of 0–6",
            c.pos() - 1
        )));
    }
    let bg = codec.background;
    let mut inactive0 = if meta == 1 { -bg } else { bg };
    let mut inactive1 = bg;
    if matches!(meta, 2 | 4 | 5) {
        inactive0 = c.f32("an inactive value")?;
        if meta == 5 {
            inactive1 = c.f32("an inactive value")?;
        }
    }
    let selection = if matches!(meta, 3..=5) {
        Some(c.mask(n / 64, "a selection mask")?)
    } else {
        None
    };
    let masked = codec.compression & COMPRESS_ACTIVE_MASK != 0 && meta != 6;
    let stored = if masked { count_on(value_mask) } else { n };
    let elem = if codec.half { 2 } else { 4 };
    // `HalfWriter` writes nothing at all for an empty array (no block length either).
    let bytes = if codec.half && stored == 0 {
        std::borrow::Cow::Borrowed(&[][..])
    } else {
        read_data(c, codec.compression, stored * elem)?
    };
    let decode = |k: usize| -> f32 {
        if codec.half {
            half::f16::from_le_bytes([bytes[2 * k], bytes[2 * k + 1]]).to_f32()
        } else {
            f32::from_le_bytes(bytes[4 * k..4 * k + 4].try_into().unwrap())
        }
    };
    if stored == n {
        for (k, v) in out.iter_mut().enumerate() {
            *v = decode(k);
        }
    } else {
        let mut k = 0;
        for (i, v) in out.iter_mut().enumerate() {
            *v = if bit(value_mask, i) {
                k += 1;
                decode(k - 1)
            } else if selection.as_ref().is_some_and(|s| bit(s, i)) {
                inactive1
            } else {
                inactive0
            };
        }
    }
    Ok(())
}

/// `io::readData`: `nbytes` of values, raw, zlib or Blosc compressed. Compressed blocks start
/// with an i64 byte count; a count ≤ 0 means −count raw bytes follow.
fn read_data<'a>(
    c: &mut Cursor<'a>,
    compression: u32,
    nbytes: usize,
) -> PResult<std::borrow::Cow<'a, [u8]>> {
    use std::borrow::Cow;
    if compression & (COMPRESS_ZIP | COMPRESS_BLOSC) == 0 {
        return Ok(Cow::Borrowed(c.take(nbytes, "uncompressed values")?));
    }
    let codec = if compression & COMPRESS_ZIP != 0 {
        "zlib"
    } else {
        "Blosc"
    };
    let start = c.pos();
    let k = c.i64("a compressed block's length")?;
    if k <= 0 {
        if k.unsigned_abs() != nbytes as u64 {
            return Err(c.fail(format!(
                "a {codec} block at byte {start} stores {} raw bytes where {nbytes} are expected",
                k.unsigned_abs()
            )));
        }
        return Ok(Cow::Borrowed(c.take(nbytes, "uncompressed values")?));
    }
    let src = c.take_i64(k, "a compressed block")?;
    let out = if codec == "zlib" {
        super::codec::inflate(src, nbytes)
    } else {
        super::codec::unblosc(src, nbytes)
    };
    out.map(Cow::Owned).map_err(|m| {
        c.fail(format!(
            "the {codec} block at byte {start} ({k} bytes) is invalid: {m}"
        ))
    })
}
