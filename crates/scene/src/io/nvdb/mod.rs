//! NanoVDB `.nvdb` float grids (the format of pbrt-v4's cloud scenes), read by our own
//! bounds-checked reader into the same sparse form as OpenVDB files ([`super::vdb::SparseGrid`]).
//!
//! Supported: NanoVDB 32.x files (OpenVDB 10 – 11's `nanovdb` library, vdb_tool, pbrt-v4) with
//! uncompressed, zlib or Blosc grid buffers; grid types `Float` and the quantised `Fp4`, `Fp8`,
//! `Fp16` (a value is `minimum + code × quantum` per leaf); axis-aligned maps. The grid named
//! `density` is read unless another is named.
//!
//! File layout (NanoVDB `io/IO.h`): segments of a 16-byte header (magic `NanoVDB0`, version,
//! grid count u16, codec u16: 0 none, 1 zlib, 2 Blosc), then per grid a 176-byte `FileMetaData`
//! (grid and file size, voxel count, grid type, bounding boxes, name size, node and tile
//! counts, codec, version) and its name, then the grid buffers. A grid buffer is the in-memory
//! grid (`NanoVDB.h`): `GridData` (672 bytes: magic, version, sizes, name, map, bounds, voxel
//! size, class, type), `TreeData` (byte offsets of the leaf, lower, upper and root arrays and
//! their counts), the root (a 64-byte header and a table of 32-byte tiles keyed by 21-bit
//! coordinates, each a value or the offset of an upper node), upper and lower internal nodes
//! (bounding box, flags, value and child masks, statistics, then a table of 8-byte values or
//! child offsets relative to the node) and leaves (bounding box, flags, value mask,
//! statistics, values from byte 96).
//!
//! Robustness: the grid's checksum is verified first where the file has one (`checksum.rs`:
//! NanoVDB 32.3 – 32.5, 32.6 and 32.7+ rules); every offset is checked to lie inside the grid
//! buffer with room for the whole node; the tree is walked from the root and may reach no more
//! nodes than `TreeData` declares (so shared or cyclic child offsets cannot multiply the work);
//! buffer sizes are checked against the bytes in the file, the compression ratio a codec can
//! reach and the memory budget before anything is allocated.

use std::borrow::Cow;
use std::path::Path;

use glam::DVec3;

mod checksum;

use super::GridFile;
use super::vdb::bytes::{Cursor, Fail, PResult, bit, count_on};
use super::vdb::{Leaf, SparseGrid, Tile, Tree};
use crate::error::Result;

/// The grid name looked up unless another is named.
pub const GRID_NAME: &str = "density";

const MAGIC: &[u8; 8] = b"NanoVDB0";
const GRID_DATA: usize = 672;
const ROOT_HEADER: usize = 64;
const ROOT_TILE: usize = 32;
/// Header bytes (before the table) and table entries of the upper and lower nodes.
const UPPER: (usize, usize) = (8256, 32768);
const LOWER: (usize, usize) = (1088, 4096);
/// zlib cannot expand by more than ≈ 1032×, LZ4 inside Blosc by ≈ 255×; a grid buffer claiming
/// more than this many bytes per compressed byte is refused before it is allocated.
const MAX_RATIO: u64 = 1100;

/// Value encodings of the leaves.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Codes {
    Float,
    /// Quantised: bits per code (4, 8 or 16).
    Fp(u32),
}

impl Codes {
    fn from_grid_type(t: u32) -> Option<(Self, &'static str)> {
        match t {
            1 => Some((Codes::Float, "Float")),
            13 => Some((Codes::Fp(4), "Fp4")),
            14 => Some((Codes::Fp(8), "Fp8")),
            15 => Some((Codes::Fp(16), "Fp16")),
            _ => None,
        }
    }

    fn leaf_size(self) -> usize {
        match self {
            Codes::Float => 96 + 512 * 4,
            Codes::Fp(bits) => 96 + 512 * bits as usize / 8,
        }
    }
}

/// Parses `.nvdb` bytes, grid [`GRID_NAME`]; `path` only labels errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<GridFile> {
    parse_named(bytes, path, GRID_NAME)
}

/// Parses `.nvdb` bytes, the grid called `name`.
pub fn parse_named(bytes: &[u8], path: &Path, name: &str) -> Result<GridFile> {
    super::vdb::grid_file(read_sparse(bytes, name), name, path)
}

pub fn read(path: &Path) -> Result<GridFile> {
    read_named(path, GRID_NAME)
}

/// Reads the grid called `name`.
pub fn read_named(path: &Path, name: &str) -> Result<GridFile> {
    let bytes = crate::fsio::read_held(path, 2)?;
    parse_named(&bytes, path, name)
}

/// One grid as listed in a segment.
struct Entry {
    name: String,
    grid_size: u64,
    file_size: u64,
    codec: u16,
}

/// Finds grid `name` in the file and returns its active voxels and tiles.
pub fn read_sparse(bytes: &[u8], name: &str) -> PResult<SparseGrid> {
    let mut c = Cursor::new(bytes);
    if bytes.is_empty() {
        return Err(Fail::new(
            "header",
            "the file is empty (a NanoVDB file starts with the magic number `NanoVDB0`)",
        ));
    }
    let mut names = Vec::new();
    while c.left() > 0 {
        c.field = "header";
        let start = c.pos();
        if c.take(8, "the magic number")? != MAGIC {
            return Err(c.fail(format!(
                "no NanoVDB segment at byte {start} (bad magic number; expected `NanoVDB0`)"
            )));
        }
        let version = c.u32("the file version")?;
        if version >> 21 != 32 {
            return Err(Fail::new(
                "header.version",
                format!(
                    "NanoVDB version {}.{}.{} is not supported (32.x is)",
                    version >> 21,
                    (version >> 10) & 0x7ff,
                    version & 0x3ff
                ),
            ));
        }
        let count = c.take(2, "the grid count")?;
        let count = u16::from_le_bytes([count[0], count[1]]) as usize;
        let codec = c.take(2, "the codec")?;
        let seg_codec = u16::from_le_bytes([codec[0], codec[1]]);
        if seg_codec > 2 {
            return Err(c.fail(format!(
                "unknown codec {seg_codec} (0 none, 1 zlib, 2 Blosc)"
            )));
        }
        if count == 0 || count * 176 > c.left() {
            return Err(c.fail(format!(
                "grid count {count} at byte {} does not fit in the {} bytes left",
                start + 12,
                c.left()
            )));
        }
        c.field = "grid.metadata";
        let mut entries = Vec::with_capacity(count);
        for _ in 0..count {
            let grid_size = c.i64("the grid size")? as u64;
            let file_size = c.i64("the grid's file size")? as u64;
            c.take(16, "the name key and voxel count")?;
            c.take(4 + 4 + 48 + 24 + 24, "the grid type, class and bounds")?;
            let name_size = c.u32("the name size")?;
            c.take(16 + 12, "the node and tile counts")?;
            let codec = c.take(2, "the grid codec")?;
            let codec = u16::from_le_bytes([codec[0], codec[1]]);
            c.take(6, "the grid version")?;
            let n = c.take_i64(name_size as i64, "the grid name")?;
            let name = String::from_utf8_lossy(n.split(|b| *b == 0).next().unwrap_or(&[]));
            entries.push(Entry {
                name: name.into_owned(),
                grid_size,
                file_size,
                codec,
            });
        }
        for e in entries {
            c.field = "grid.buffer";
            if e.file_size > c.left() as u64 {
                return Err(c.fail(format!(
                    "grid `{}` claims {} bytes at byte {}, {} are left",
                    e.name,
                    e.file_size,
                    c.pos(),
                    c.left()
                )));
            }
            let stored = c.take(e.file_size as usize, "a grid buffer")?;
            if e.name != name {
                names.push(e.name);
                continue;
            }
            let codec = if e.codec <= 2 { e.codec } else { seg_codec };
            let buf = decode(stored, e.grid_size, codec)
                .map_err(|m| Fail::new("grid.buffer", format!("grid `{name}`: {m}")))?;
            return read_grid(&buf, name);
        }
    }
    Err(Fail::new(
        "grid",
        format!(
            "no grid named `{name}` (grids in file: {names:?}); choose one with `grid = \"…\"` in [volume] or `--grid`"
        ),
    ))
}

/// The in-memory grid from its stored bytes.
fn decode(stored: &[u8], grid_size: u64, codec: u16) -> std::result::Result<Cow<'_, [u8]>, String> {
    if codec == 0 {
        if grid_size != stored.len() as u64 {
            return Err(format!(
                "an uncompressed grid of {grid_size} bytes stored in {} bytes",
                stored.len()
            ));
        }
        return Ok(Cow::Borrowed(stored));
    }
    if grid_size > MAX_RATIO * stored.len() as u64 + (1 << 20) {
        return Err(format!(
            "{grid_size} bytes claimed from {} compressed bytes: beyond what the codec can expand",
            stored.len()
        ));
    }
    crate::memory::check(
        grid_size as u128,
        "grid.buffer",
        "the decompressed NanoVDB grid",
    )
    .map_err(|e| e.msg)?;
    let mut c = Cursor::new(stored);
    let mut out = Vec::new();
    out.try_reserve_exact(grid_size as usize)
        .map_err(|_| format!("cannot allocate {grid_size} bytes"))?;
    // zlib: one block; Blosc: chunks until the grid is complete. Each is an i64 length and data.
    while (out.len() as u64) < grid_size {
        let at = c.pos();
        let n = c.i64("a compressed block's length").map_err(|e| e.msg)?;
        let src = c.take_i64(n, "a compressed block").map_err(|e| e.msg)?;
        let want = (grid_size - out.len() as u64) as usize;
        let chunk = if codec == 1 {
            super::vdb::codec::inflate(src, want)
        } else {
            super::vdb::codec::unblosc_chunk(src, want)
        }
        .map_err(|m| format!("the compressed block at byte {at} of the grid buffer: {m}"))?;
        out.extend_from_slice(&chunk);
        if codec == 1 && (out.len() as u64) < grid_size {
            return Err(format!(
                "zlib data ends after {} of {grid_size} bytes",
                out.len()
            ));
        }
    }
    Ok(Cow::Owned(out))
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn i64_at(b: &[u8], at: usize) -> i64 {
    i64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn f64_at(b: &[u8], at: usize) -> f64 {
    f64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

fn mask(b: &[u8], at: usize, words: usize) -> Vec<u64> {
    (0..words)
        .map(|w| u64::from_le_bytes(b[at + 8 * w..at + 8 * w + 8].try_into().unwrap()))
        .collect()
}

/// The walk's state: the buffer, node budgets from `TreeData`, and the result.
struct Walk<'a> {
    b: &'a [u8],
    codes: Codes,
    left: [u64; 3],
    tree: Tree,
}

impl Walk<'_> {
    /// Checks that a node of `size` bytes at `base + offset` lies inside the buffer.
    fn node(&mut self, base: usize, offset: i64, size: usize, level: usize) -> PResult<usize> {
        let (what, plural) = [
            ("a leaf", "leaves"),
            ("a lower node", "lower nodes"),
            ("an upper node", "upper nodes"),
        ][level];
        let at = base as i128 + offset as i128;
        if offset <= 0 || at + size as i128 > self.b.len() as i128 {
            return Err(Fail::new(
                "grid.tree",
                format!(
                    "{what} at offset {offset} from byte {base} does not fit in the {}-byte grid",
                    self.b.len()
                ),
            ));
        }
        if self.left[level] == 0 {
            return Err(Fail::new(
                "grid.tree",
                format!(
                    "more {plural} are reachable than the tree declares (shared or cyclic child offsets)"
                ),
            ));
        }
        self.left[level] -= 1;
        Ok(at as usize)
    }

    fn internal(&mut self, at: usize, origin: [i64; 3], level: usize) -> PResult<()> {
        let (header, n) = if level == 2 { UPPER } else { LOWER };
        let log2 = if level == 2 { 5 } else { 4 };
        let child_dim = if level == 2 { 128 } else { 8 };
        let words = n / 64;
        let values = mask(self.b, at + 32, words);
        let children = mask(self.b, at + 32 + 8 * words, words);
        crate::memory::check(
            (self.tree.tiles.len() + count_on(&values)) as u128 * 64,
            "grid.tree",
            "the grid's active tiles",
        )
        .map_err(|e| Fail::new(&e.field, e.msg))?;
        for i in 0..n {
            let (is_child, is_on) = (bit(&children, i), bit(&values, i));
            if !is_child && !is_on {
                continue;
            }
            let (x, y, z) = (
                i >> (2 * log2),
                (i >> log2) & ((1 << log2) - 1),
                i & ((1 << log2) - 1),
            );
            let o = [
                origin[0] + x as i64 * child_dim,
                origin[1] + y as i64 * child_dim,
                origin[2] + z as i64 * child_dim,
            ];
            let entry = at + header + 8 * i;
            if is_child {
                let offset = i64_at(self.b, entry);
                if level == 2 {
                    let p = self.node(at, offset, LOWER.0 + 8 * LOWER.1, 1)?;
                    self.internal(p, o, 1)?;
                } else {
                    let p = self.node(at, offset, self.codes.leaf_size(), 0)?;
                    self.leaf(p, o)?;
                }
            } else {
                self.tree.tiles.push(Tile {
                    origin: o,
                    dim: child_dim,
                    value: f32_at(self.b, entry),
                });
            }
        }
        Ok(())
    }

    fn leaf(&mut self, at: usize, origin: [i64; 3]) -> PResult<()> {
        let m: [u64; 8] = mask(self.b, at + 16, 8).try_into().unwrap();
        if count_on(&m) == 0 {
            return Ok(());
        }
        let own = [0, 4, 8].map(|k| (u32_at(self.b, at + k) as i32 as i64) & !7);
        if own != origin {
            return Err(Fail::new(
                "grid.tree",
                format!(
                    "the leaf at byte {at} says its origin is {own:?}, its parent places it at {origin:?}"
                ),
            ));
        }
        let values: Vec<f32> = match self.codes {
            Codes::Float => (0..512).map(|i| f32_at(self.b, at + 96 + 4 * i)).collect(),
            Codes::Fp(bits) => {
                let (min, quantum) = (f32_at(self.b, at + 80), f32_at(self.b, at + 84));
                let c = &self.b[at + 96..];
                (0..512)
                    .map(|i| {
                        let code = match bits {
                            4 => ((c[i / 2] >> ((i & 1) * 4)) & 15) as u32,
                            8 => c[i] as u32,
                            _ => u16::from_le_bytes([c[2 * i], c[2 * i + 1]]) as u32,
                        };
                        min + quantum * code as f32
                    })
                    .collect()
            }
        };
        self.tree.leaves.push(Leaf {
            origin,
            mask: m,
            values,
        });
        Ok(())
    }
}

/// Walks one in-memory grid buffer.
fn read_grid(b: &[u8], name: &str) -> PResult<SparseGrid> {
    let fail = |m: String| Fail::new("grid", format!("grid `{name}`: {m}"));
    if b.len() < GRID_DATA + 64 || &b[..8] != MAGIC {
        return Err(fail(
            "the grid buffer does not start with a NanoVDB grid".into(),
        ));
    }
    let grid_type = u32_at(b, 636);
    let Some((codes, _)) = Codes::from_grid_type(grid_type) else {
        return Err(Fail::new(
            "grid.type",
            format!(
                "grid `{name}` has NanoVDB grid type {grid_type}; only Float, Fp4, Fp8 and Fp16 are supported"
            ),
        ));
    };
    checksum::verify(b, name, codes.leaf_size())?;
    // Map (at 296): float matrix, inverse, vector, taper; then the same in double (at 384).
    let m: Vec<f64> = (0..9).map(|k| f64_at(b, 384 + 8 * k)).collect();
    let t = [f64_at(b, 528), f64_at(b, 536), f64_at(b, 544)];
    if [1, 2, 3, 5, 6, 7].iter().any(|&k| m[k] != 0.0) {
        return Err(Fail::new(
            "grid.map",
            format!(
                "grid `{name}` has a rotated or sheared map; only scale and translation are supported"
            ),
        ));
    }
    let scale = DVec3::new(m[0], m[4], m[8]);
    let translation = DVec3::from_array(t);
    if !(scale.is_finite() && scale.min_element() > 0.0 && translation.is_finite()) {
        return Err(Fail::new(
            "grid.map",
            format!("grid `{name}`: invalid voxel size {scale} or translation {translation}"),
        ));
    }
    // TreeData at 672: node offsets (leaf, lower, upper, root) relative to it, node counts.
    let tree_at = GRID_DATA;
    let offsets: Vec<i64> = (0..4).map(|k| i64_at(b, tree_at + 8 * k)).collect();
    let counts = [0, 1, 2].map(|k| u32_at(b, tree_at + 32 + 4 * k) as u64);
    let root_at = tree_at as i128 + offsets[3] as i128;
    if offsets[3] <= 0 || root_at + ROOT_HEADER as i128 > b.len() as i128 {
        return Err(fail(format!(
            "the root offset {} lies outside the grid",
            offsets[3]
        )));
    }
    let root_at = root_at as usize;
    let table = u32_at(b, root_at + 24) as usize;
    let background = f32_at(b, root_at + 28);
    if table > (b.len() - root_at - ROOT_HEADER) / ROOT_TILE {
        return Err(fail(format!(
            "the root's {table} tiles do not fit in the grid"
        )));
    }
    let mut walk = Walk {
        b,
        codes,
        left: counts,
        tree: Tree {
            background,
            ..Default::default()
        },
    };
    let bytes = counts[0] as u128 * (512 * 4 + 64 + 24);
    crate::memory::check(
        bytes,
        "grid.tree",
        &format!("the {} leaves of the grid", counts[0]),
    )
    .map_err(|e| Fail::new(&e.field, e.msg))?;
    for k in 0..table {
        let e = root_at + ROOT_HEADER + ROOT_TILE * k;
        let key = u64::from_le_bytes(b[e..e + 8].try_into().unwrap());
        let child = i64_at(b, e + 8);
        let state = u32_at(b, e + 16);
        let field = |shift: u32| (((key >> shift) & ((1 << 21) - 1)) << 12) as u32 as i32 as i64;
        let origin = [field(42), field(21), field(0)];
        if child == 0 {
            if state != 0 {
                walk.tree.tiles.push(Tile {
                    origin,
                    dim: 4096,
                    value: f32_at(b, e + 20),
                });
            }
        } else {
            let p = walk.node(root_at, child, UPPER.0 + 8 * UPPER.1, 2)?;
            walk.internal(p, origin, 2)?;
        }
    }
    Ok(SparseGrid {
        tree: walk.tree,
        voxel_size: scale,
        translation,
    })
}
