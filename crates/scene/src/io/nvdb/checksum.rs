//! NanoVDB grid checksums (`GridData::mChecksum`), verified before a grid is walked, so that a
//! damaged file is refused rather than read as other values.
//!
//! The checksum is two CRC-32s (zlib's: polynomial 0xEDB88320, reflected, initial and final
//! value all ones) at bytes 8 and 12 of the grid buffer, "head" then "tail". All ones in both
//! means no checksum; a tail of all ones alone means a partial checksum (the head only: what
//! `vdb_tool` and `nanovdb_convert` write by default). The ranges they cover changed twice
//! (NanoVDB `util/GridChecksum.h` and, from 32.7, `tools/GridChecksum.h`); the grid's version
//! (byte 16) says which rules wrote it:
//!
//! - **32.3 – 32.5** (OpenVDB 9 – 10, Debian's tools): the head covers bytes
//!   16 up to the end of the root's tile table (`GridData`, `TreeData`, the root); the tail is
//!   the CRC of the array of every node's own CRC (upper, then lower internal nodes, then
//!   leaves, each over its whole size), stored as `std::uint_fast32_t`, which is 8 bytes with
//!   glibc on 64-bit Linux and 4 bytes elsewhere: either is accepted.
//! - **32.6** (OpenVDB 11): the head covers bytes 16 up to the first upper node (without one:
//!   up to the blind metadata, else the whole grid); the tail is a blocked CRC of everything
//!   from there to the end of the grid (`mGridSize`).
//! - **32.7 and later** (OpenVDB 12 –): the head covers bytes 16 – 736 (`GridData` and
//!   `TreeData`), the tail a blocked CRC of the rest.
//!
//! A blocked CRC cuts its range into 4 KiB blocks (the remainder joins the last block), takes
//! each block's CRC and then the CRC of those CRCs as little-endian u32 values. A tail shorter
//! than one block has no blocks, so NanoVDB's own rule leaves it unchecked (its CRC is 0).
//!
//! The 32.3 – 32.5 rules are checked against files written by OpenVDB 10's `vdb_tool` with
//! partial and full checksums (`crates/scene/tests/data`); no file written by OpenVDB 11 or 12
//! is among the fixtures, so the later rules are checked against files whose checksums an
//! independent script computed from the NanoVDB source (`make_checksums.py`). Not covered by a
//! fixture: the 4-byte form of the 32.3 – 32.5 node table and 32.6's grids without upper
//! nodes.

use super::super::vdb::bytes::{Fail, PResult};
use super::{i64_at, u32_at};

/// Bytes of `GridData` and `TreeData`.
const GRID_AND_TREE: usize = 672 + 64;
const BLOCK: usize = 4096;

fn crc(bytes: &[u8]) -> u32 {
    crc32fast::hash(bytes)
}

/// CRC of the block CRCs of `bytes` (NanoVDB's `blockedCrc32`); an empty range has none.
fn blocked(bytes: &[u8]) -> u32 {
    let n = bytes.len() / BLOCK;
    let mut table = Vec::with_capacity(4 * n);
    for i in 0..n {
        let end = if i + 1 == n {
            bytes.len()
        } else {
            (i + 1) * BLOCK
        };
        table.extend_from_slice(&crc(&bytes[i * BLOCK..end]).to_le_bytes());
    }
    if bytes.is_empty() {
        u32::MAX
    } else {
        crc(&table)
    }
}

/// Node sizes of the upper and lower internal nodes (header and 8-byte table).
const UPPER: usize = 8256 + 8 * 32768;
const LOWER: usize = 1088 + 8 * 4096;

/// Verifies the checksum of grid buffer `b` (at least 672 + 64 bytes, magic checked) whose
/// leaves are `leaf_size` bytes; `name` labels errors.
pub(crate) fn verify(b: &[u8], name: &str, leaf_size: usize) -> PResult<()> {
    let (head, tail) = (u32_at(b, 8), u32_at(b, 12));
    if head == u32::MAX && tail == u32::MAX {
        return Ok(());
    }
    let fail =
        |what: &str, m: String| Fail::new("grid.checksum", format!("grid `{name}`: {what}: {m}"));
    let version = u32_at(b, 16);
    let (minor, patch) = ((version >> 10) & 0x7ff, version & 0x3ff);
    let rules = format!("NanoVDB 32.{minor}.{patch}'s rules");
    let grid_size = u64::from_le_bytes(b[32..40].try_into().unwrap());
    if grid_size != b.len() as u64 {
        return Err(fail(
            "GridData.mGridSize",
            format!("{grid_size} bytes, but the grid buffer holds {}", b.len()),
        ));
    }
    let offset = |k: usize| i64_at(b, 672 + 8 * k);
    let range = |from: i128, to: i128, what: &str| -> PResult<std::ops::Range<usize>> {
        if 16 <= from && from <= to && to <= b.len() as i128 {
            Ok(from as usize..to as usize)
        } else {
            Err(fail(
                "the checksummed range",
                format!(
                    "{what} ({from}..{to}) lies outside the grid's {} bytes",
                    b.len()
                ),
            ))
        }
    };
    let head_range = if minor < 6 {
        // The root sits right after TreeData; its table size is at byte 24 of the root.
        range(16, GRID_AND_TREE as i128 + 64, "the root's header")?;
        let table = u32_at(b, GRID_AND_TREE + 24) as i128;
        range(
            16,
            GRID_AND_TREE as i128 + 64 + 32 * table,
            "the root and its tiles",
        )?
    } else {
        let mid = if minor == 6 {
            let blind = (i64_at(b, 640), u32_at(b, 648));
            if offset(2) != 0 {
                672 + offset(2) as i128
            } else if blind.1 > 0 {
                blind.0 as i128
            } else {
                b.len() as i128
            }
        } else {
            GRID_AND_TREE as i128
        };
        range(16, mid, "the grid header")?
    };
    // The tail's CRC as each rule computes it (32.3 – 32.5: both widths of the node table).
    let tail_crc = || -> PResult<Vec<u32>> {
        if minor >= 6 {
            return Ok(vec![blocked(&b[head_range.end..])]);
        }
        let counts = [0, 1, 2].map(|k| u32_at(b, 672 + 32 + 4 * k) as i128);
        let mut node_crcs = Vec::new();
        for (k, size) in [(2, UPPER), (1, LOWER), (0, leaf_size)] {
            let first = 672 + offset(k) as i128;
            let nodes = range(first, first + counts[k] * size as i128, "the nodes")?;
            node_crcs.extend(b[nodes].chunks_exact(size).map(crc));
        }
        let as_u64: Vec<u8> = node_crcs
            .iter()
            .flat_map(|c| (*c as u64).to_le_bytes())
            .collect();
        let as_u32: Vec<u8> = node_crcs.iter().flat_map(|c| c.to_le_bytes()).collect();
        Ok(vec![crc(&as_u64), crc(&as_u32)])
    };
    let found = crc(&b[head_range.clone()]);
    if found != head {
        return Err(fail(
            "GridData.mChecksum",
            format!(
                "the header's CRC-32 is {found:#010x}, the file says {head:#010x} ({rules}): \
                 the file is damaged"
            ),
        ));
    }
    if tail != u32::MAX {
        let found = tail_crc()?;
        if !found.contains(&tail) {
            return Err(fail(
                "GridData.mChecksum",
                format!(
                    "the nodes' CRC-32 is {:#010x}, the file says {tail:#010x} ({rules}): the \
                     file is damaged",
                    found[0]
                ),
            ));
        }
    }
    Ok(())
}
