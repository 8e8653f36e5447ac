//! The OpenVDB archive around the trees: file header, metadata, grid descriptors, the grid's
//! compression flags and transform (OpenVDB `io::Archive`, `io::GridDescriptor`, `MetaMap`,
//! `math::Transform`; file versions 222–224, written by OpenVDB 3.0 and later).
//!
//! Layout (little-endian): magic `0x56444220` as i64 · file version u32 · library major,
//! minor u32 · has-grid-offsets u8 · UUID (36 ASCII bytes) · file metadata · grid count i32 ·
//! per grid: descriptor (unique name, type name, instance parent, grid / block / end offsets as
//! i64) followed by the grid itself at the grid offset: compression flags u32, grid metadata,
//! transform, tree topology, and from the block offset on the leaf buffers (see `tree`).

use super::bytes::{Cursor, Fail, PResult};

/// `OPENVDB_FILE_VERSION_NODE_MASK_COMPRESSION`: the oldest version read here.
pub const MIN_VERSION: u32 = 222;
/// `OPENVDB_FILE_VERSION_MULTIPASS_IO`: the newest format (OpenVDB 4 – 12).
pub const MAX_VERSION: u32 = 224;

/// Per-grid compression flags (`io::COMPRESS_*`).
pub const COMPRESS_ZIP: u32 = 0x1;
pub const COMPRESS_ACTIVE_MASK: u32 = 0x2;
pub const COMPRESS_BLOSC: u32 = 0x4;

/// Suffix of a grid type whose floats are stored as halves (`HALF_FLOAT_TYPENAME_SUFFIX`).
const HALF_SUFFIX: &str = "_HalfFloat";

/// One grid as listed in the file.
#[derive(Debug, Clone)]
pub struct Descriptor {
    /// The grid's name (the unique name's `\x1e` suffix for repeated names removed).
    pub name: String,
    /// Tree type without the half-float suffix, e.g. `Tree_float_5_4_3`.
    pub grid_type: String,
    pub half: bool,
    pub instance_parent: String,
    pub grid_pos: i64,
}

/// Header fields the tree reader needs.
#[derive(Debug, Clone)]
pub struct Header {
    pub descriptors: Vec<Descriptor>,
}

/// Reads the header and every grid descriptor (descriptors sit before each grid; the end
/// offset of one leads to the next).
pub fn read_header(c: &mut Cursor) -> PResult<Header> {
    c.field = "header.magic";
    let magic = c.take(8, "the magic number").map_err(|_| {
        Fail::new(
            "header.magic",
            "not an OpenVDB file (shorter than its magic number)",
        )
    })?;
    if magic != [0x20, 0x42, 0x44, 0x56, 0, 0, 0, 0] {
        return Err(c.fail("not an OpenVDB file (bad magic number)"));
    }
    c.field = "header.version";
    let version = c.u32("the file version")?;
    if !(MIN_VERSION..=MAX_VERSION).contains(&version) {
        return Err(c.fail(format!(
            "file version {version} is not supported (OpenVDB 3.0 and later write {MIN_VERSION}–{MAX_VERSION})"
        )));
    }
    c.field = "header";
    let _major = c.u32("the library version")?;
    let _minor = c.u32("the library version")?;
    if c.u8("has-grid-offsets")? != 1 {
        return Err(Fail::new(
            "header.has_grid_offsets",
            "grids without offsets (a streamed archive) are not supported",
        ));
    }
    c.take(36, "the UUID")?;
    c.field = "header.metadata";
    skip_metadata(c)?;
    c.field = "header.grid_count";
    let count = c.i32("the grid count")?;
    // A descriptor takes at least 3 strings (12 bytes) and 3 offsets (24 bytes).
    if count < 0 || count as u64 * 36 > c.left() as u64 {
        return Err(c.fail(format!(
            "grid count {count} does not fit in the {} bytes left",
            c.left()
        )));
    }
    let mut descriptors = Vec::with_capacity(count as usize);
    for i in 0..count {
        c.field = "grid.descriptor";
        let start = c.pos();
        let unique = c.string("a grid name")?;
        let type_name = c.string("a grid type")?;
        let instance_parent = c.string("a grid's instance parent")?;
        let grid_pos = c.i64("a grid offset")?;
        let block_pos = c.i64("a block offset")?;
        let end_pos = c.i64("an end offset")?;
        let here = c.pos() as i64;
        if !(here <= grid_pos && grid_pos <= block_pos && block_pos <= end_pos)
            || end_pos > c.len() as i64
        {
            return Err(Fail::new(
                "grid.descriptor",
                format!(
                    "grid {i} (descriptor at byte {start}) has offsets grid {grid_pos}, blocks {block_pos}, end {end_pos}: not increasing after byte {here} within the {} bytes of the file",
                    c.len()
                ),
            ));
        }
        let name = unique.split('\u{1e}').next().unwrap_or("").to_string();
        let (grid_type, half) = match type_name.strip_suffix(HALF_SUFFIX) {
            Some(t) => (t.to_string(), true),
            None => (type_name, false),
        };
        descriptors.push(Descriptor {
            name,
            grid_type,
            half,
            instance_parent,
            grid_pos,
        });
        c.seek(end_pos, "the grid's end offset")?;
    }
    Ok(Header { descriptors })
}

/// A metadata map (`MetaMap::readMeta`): count, then name, type name and a sized value. Returns
/// the boolean `is_saved_as_half_float` if present.
fn read_metadata(c: &mut Cursor) -> PResult<Option<bool>> {
    let count = c.u32("the metadata count")?;
    // Each entry holds at least two strings and a size: 12 bytes.
    if count as u64 * 12 > c.left() as u64 {
        return Err(c.fail(format!(
            "metadata count {count} at byte {} does not fit in the {} bytes left",
            c.pos() - 4,
            c.left()
        )));
    }
    let mut half = None;
    for _ in 0..count {
        let name = c.string("a metadata name")?;
        let ty = c.string("a metadata type")?;
        let size = c.u32("a metadata size")?;
        let value = c.take_i64(size as i64, "a metadata value")?;
        if name == "is_saved_as_half_float" && ty == "bool" && size == 1 {
            half = Some(value[0] != 0);
        }
    }
    Ok(half)
}

fn skip_metadata(c: &mut Cursor) -> PResult<()> {
    read_metadata(c).map(|_| ())
}

/// The index-to-world map of a grid: world = index × scale + translation (axis-aligned).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Transform {
    pub scale: [f64; 3],
    pub translation: [f64; 3],
}

/// What precedes a grid's tree: compression flags, metadata and transform.
#[derive(Debug, Clone)]
pub struct GridHeader {
    pub compression: u32,
    pub half: bool,
    pub transform: Transform,
}

/// Reads the grid header at the descriptor's grid offset.
pub fn read_grid_header(c: &mut Cursor, d: &Descriptor) -> PResult<GridHeader> {
    c.field = "grid.compression";
    c.seek(d.grid_pos, "the grid offset")?;
    let compression = c.u32("the compression flags")?;
    if compression & !(COMPRESS_ZIP | COMPRESS_ACTIVE_MASK | COMPRESS_BLOSC) != 0 {
        return Err(c.fail(format!("unknown compression flags {compression:#x}")));
    }
    if compression & COMPRESS_ZIP != 0 && compression & COMPRESS_BLOSC != 0 {
        return Err(c.fail("both zlib and Blosc compression set"));
    }
    c.field = "grid.metadata";
    let half_meta = read_metadata(c)?;
    c.field = "grid.transform";
    let transform = read_transform(c)?;
    Ok(GridHeader {
        compression,
        half: d.half || half_meta == Some(true),
        transform,
    })
}

/// `math::Transform::read` for the axis-aligned maps: uniform and non-uniform scale, with or
/// without translation, translation alone, and affine maps without rotation or shear.
fn read_transform(c: &mut Cursor) -> PResult<Transform> {
    let ty = c.string("the transform type")?;
    let t = match ty.as_str() {
        "UniformScaleMap" | "ScaleMap" => {
            let _scale = c.dvec3("the map's scale")?;
            let voxel = c.dvec3("the map's voxel size")?;
            c.take(3 * 24, "the map's derived terms")?;
            Transform {
                scale: voxel,
                translation: [0.0; 3],
            }
        }
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => {
            let translation = c.dvec3("the map's translation")?;
            let _scale = c.dvec3("the map's scale")?;
            let voxel = c.dvec3("the map's voxel size")?;
            c.take(3 * 24, "the map's derived terms")?;
            Transform {
                scale: voxel,
                translation,
            }
        }
        "TranslationMap" => Transform {
            scale: [1.0; 3],
            translation: c.dvec3("the map's translation")?,
        },
        "AffineMap" => {
            // Mat4d, row-major, row vectors: rows 0–2 hold the linear part, row 3 the
            // translation.
            let mut m = [0.0f64; 16];
            for v in &mut m {
                *v = c.f64("the affine matrix")?;
            }
            let off_diagonal = [1, 2, 4, 6, 8, 9, 3, 7, 11];
            if off_diagonal.iter().any(|&i| m[i] != 0.0) || m[15] != 1.0 {
                return Err(c.fail(
                    "an affine transform with rotation, shear or projection is not supported (only scale and translation)",
                ));
            }
            Transform {
                scale: [m[0], m[5], m[10]],
                translation: [m[12], m[13], m[14]],
            }
        }
        other => {
            return Err(c.fail(format!(
                "transform type `{other}` is not supported (scale and translate maps only)"
            )));
        }
    };
    if !t.scale.iter().all(|s| s.is_finite() && *s > 0.0)
        || !t.translation.iter().all(|s| s.is_finite())
    {
        return Err(c.fail(format!(
            "invalid voxel size {:?} or translation {:?}",
            t.scale, t.translation
        )));
    }
    Ok(t)
}
