//! NumPy `.npy` grids: float32 (or float64, converted) arrays of shape `[z][y][x]` in C order —
//! the same voxel order as `.vol`. Parsing goes through the `npyz` crate; sizes are checked
//! against the file length before any allocation.

use std::io::Cursor;
use std::path::Path;

use npyz::{Order, WriterBuilder};

use crate::error::{Error, Result};
use crate::grid::{DensityGrid, check_resolution};

/// Refuses headers longer than the file, and headers whose brackets nest deeper than a plain array header needs (`{… (z, y, x)}`:
/// depth 2; structured dtypes reach 3–4) before `npyz` parses them: its header parser
/// backtracks exponentially on deep nesting (found by `cargo fuzz run npy`: 100 `[` took
/// longer than 10 s).
fn check_header_nesting(bytes: &[u8], path: &Path) -> Result<()> {
    const MAX_DEPTH: usize = 8;
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Ok(()); // npyz reports the bad magic number
    }
    let (len, start): (usize, usize) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        _ if bytes.len() >= 12 => (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        ),
        _ => return Ok(()),
    };
    if start.saturating_add(len) > bytes.len() {
        // npyz would allocate the stated length first (up to 4 GiB; found by `cargo fuzz`).
        return Err(Error::invalid(
            path,
            "header.length",
            format!(
                "header of {len} bytes does not fit in the file ({} bytes)",
                bytes.len()
            ),
        ));
    }
    let header = &bytes[start..start + len];
    let mut depth = 0usize;
    for &c in header {
        match c {
            b'(' | b'[' | b'{' => {
                depth += 1;
                if depth > MAX_DEPTH {
                    return Err(Error::invalid(
                        path,
                        "header",
                        format!("brackets nested deeper than {MAX_DEPTH}: not an array header"),
                    ));
                }
            }
            b')' | b']' | b'}' => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    Ok(())
}

/// Parses any little-endian float32/float64 C-order array as (shape, f32 values). The data
/// size must match the header's shape exactly, so nothing is allocated beyond the file's size.
fn parse_array(bytes: &[u8], path: &Path) -> Result<(Vec<u64>, Vec<f32>)> {
    check_header_nesting(bytes, path)?;
    let mut cursor = Cursor::new(bytes);
    let header = npyz::NpyHeader::from_reader(&mut cursor)
        .map_err(|e| Error::invalid(path, "header", format!("not a valid .npy header: {e}")))?;
    let data_start = cursor.position() as usize;
    let npy = npyz::NpyFile::with_header(header, &bytes[data_start..]);
    if npy.order() != Order::C {
        return Err(Error::invalid(
            path,
            "header.fortran_order",
            "Fortran-ordered arrays are not supported; save with C order ([z][y][x])",
        ));
    }
    let shape = npy.shape().to_vec();
    let descr = npy.dtype().descr();
    let descr = descr.trim_matches('\'');
    let elem: u64 = match descr {
        "<f4" => 4,
        "<f8" => 8,
        other => {
            return Err(Error::invalid(
                path,
                "header.descr",
                format!("dtype {other} is not supported (use little-endian float32 '<f4')"),
            ));
        }
    };
    let available = (bytes.len() - data_start) as u64;
    let needed = shape.iter().try_fold(elem, |a, &b| a.checked_mul(b));
    if needed != Some(available) {
        return Err(Error::invalid(
            path,
            "data",
            format!(
                "shape {shape:?} of {descr} needs {} bytes, the file has {available}",
                needed.map_or("too many".to_string(), |n| n.to_string())
            ),
        ));
    }
    let data: Vec<f32> = if elem == 4 {
        npy.into_vec::<f32>()
            .map_err(|e| Error::invalid(path, "data", e.to_string()))?
    } else {
        npy.into_vec::<f64>()
            .map_err(|e| Error::invalid(path, "data", e.to_string()))?
            .into_iter()
            .map(|v| v as f32)
            .collect()
    };
    Ok((shape, data))
}

/// Parses `.npy` bytes; `path` only labels errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<DensityGrid> {
    let (shape, data) = parse_array(bytes, path)?;
    if shape.len() != 3 {
        return Err(Error::invalid(
            path,
            "header.shape",
            format!("expected 3 dimensions [z][y][x], found {shape:?}"),
        ));
    }
    let as_i64 = |v: u64| i64::try_from(v).unwrap_or(i64::MAX);
    let res = check_resolution(
        [as_i64(shape[2]), as_i64(shape[1]), as_i64(shape[0])],
        "header.shape",
    )
    .map_err(|e| e.at(path))?;
    DensityGrid::new(res, data).map_err(|e| e.at(path))
}

/// Reads any little-endian float32/float64 C-order array as (shape, f32 values) — used for
/// auxiliary arrays such as the references' optical-depth masks.
pub fn read_array(path: &Path) -> Result<(Vec<usize>, Vec<f32>)> {
    crate::memory::check_file(path, 2)?;
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let (shape, data) = parse_array(&bytes, path)?;
    Ok((shape.into_iter().map(|v| v as usize).collect(), data))
}

pub fn read(path: &Path) -> Result<DensityGrid> {
    // The file's bytes and the grid are held at once (float64 files: 1.5×).
    crate::memory::check_file(path, 2)?;
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse(&bytes, path)
}

/// Serialises a grid as float32 `.npy` bytes of shape `[z][y][x]`.
pub fn to_bytes(grid: &DensityGrid) -> Vec<u8> {
    let r = grid.res();
    let mut out = Vec::new();
    {
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[r[2] as u64, r[1] as u64, r[0] as u64])
            .writer(&mut out)
            .begin_nd()
            .expect("writing to memory cannot fail");
        grid.try_for_each_row(|row| w.extend(row.iter().copied()))
            .expect("writing to memory cannot fail");
        w.finish().expect("writing to memory cannot fail");
    }
    out
}

/// Writes a float32 C-order array of any shape (e.g. per-pixel variances `[height, width]`).
pub fn write_array(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    assert_eq!(shape.iter().product::<usize>(), data.len());
    let mut out = Vec::new();
    {
        let shape: Vec<u64> = shape.iter().map(|&v| v as u64).collect();
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&shape)
            .writer(&mut out)
            .begin_nd()
            .expect("writing to memory cannot fail");
        w.extend(data.iter().copied())
            .expect("writing to memory cannot fail");
        w.finish().expect("writing to memory cannot fail");
    }
    std::fs::write(path, out).map_err(|e| Error::io(path, e))
}

pub fn write(path: &Path, grid: &DensityGrid) -> Result<()> {
    // Streamed: no second copy of the grid in memory.
    let r = grid.res();
    let f = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let mut buf = std::io::BufWriter::new(f);
    let io = |e: std::io::Error| Error::io(path, e);
    {
        let mut w = npyz::WriteOptions::new()
            .default_dtype()
            .shape(&[r[2] as u64, r[1] as u64, r[0] as u64])
            .writer(&mut buf)
            .begin_nd()
            .map_err(io)?;
        grid.try_for_each_row(|row| w.extend(row.iter().copied()))
            .map_err(io)?;
        w.finish().map_err(io)?;
    }
    std::io::Write::flush(&mut buf).map_err(io)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deeply_nested_header_is_refused_quickly() {
        // The fuzzer's input: 100 nested `[` in the shape field.
        let mut h = b"{'descr': '<f4', 'fortran_order': False, 'shape': ".to_vec();
        h.extend(std::iter::repeat_n(b'[', 100));
        h.extend(b"(6, 6), }\n");
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend((h.len() as u16).to_le_bytes());
        bytes.extend(&h);
        // Before the check this call did not return within 10 s.
        let e = parse(&bytes, Path::new("deep.npy"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("deep.npy") && e.contains("nested"), "{e}");
        // A version-2 header claiming 3.9 GB: refused before anything is allocated.
        let mut big = b"\x93NUMPY\x02\x00".to_vec();
        big.extend(3_890_734_966u32.to_le_bytes());
        big.extend(b"{'descr': '<f4'");
        let e = parse(&big, Path::new("big.npy")).unwrap_err().to_string();
        assert!(e.contains("big.npy") && e.contains("header.length"), "{e}");
    }

    #[test]
    fn round_trip_and_errors() {
        let g = DensityGrid::new([3, 2, 1], vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5]).unwrap();
        let bytes = to_bytes(&g);
        let p = Path::new("g.npy");
        assert_eq!(parse(&bytes, p).unwrap(), g);
        let m = parse(&bytes[..bytes.len() - 2], p).unwrap_err().to_string();
        assert!(m.contains("g.npy") && m.contains("`data`"), "{m}");
        assert!(
            parse(b"garbage", p)
                .unwrap_err()
                .to_string()
                .contains("header")
        );
        assert!(parse(&[], p).is_err());
        let mut s = 3u64;
        for len in [10usize, 64, 128, 200] {
            let mut b = bytes.clone();
            for _ in 0..len / 10 {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let i = (s >> 33) as usize % b.len();
                b[i] = (s >> 20) as u8;
            }
            let _ = parse(&b, p); // must not panic
        }
    }
}
