//! NumPy `.npy` grids: float32 (or float64, converted) arrays of shape `[z][y][x]` in C order —
//! the same voxel order as `.vol`. The header is parsed by the `npyz` crate; sizes are checked
//! against the file length before any allocation, and [`read`] streams the data into the grid.

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

/// An array's layout from its header: shape, bytes per element (4: `<f4`, 8: `<f8`) and where
/// the data starts.
struct Layout {
    shape: Vec<u64>,
    elem: u64,
    data_start: usize,
}

/// Parses and checks the header at the start of `head` (the file's first bytes: at least the
/// whole header) against a file of `file_len` bytes: little-endian float32/float64, C order,
/// and a data size equal to what the file holds after the header, so nothing is allocated
/// beyond the file's size.
fn parse_layout(head: &[u8], file_len: u64, path: &Path) -> Result<Layout> {
    check_header_nesting(head, path)?;
    let mut cursor = Cursor::new(head);
    let header = npyz::NpyHeader::from_reader(&mut cursor)
        .map_err(|e| Error::invalid(path, "header", format!("not a valid .npy header: {e}")))?;
    let data_start = cursor.position() as usize;
    if header.order() != Order::C {
        return Err(Error::invalid(
            path,
            "header.fortran_order",
            "Fortran-ordered arrays are not supported; save with C order ([z][y][x])",
        ));
    }
    let shape = header.shape().to_vec();
    let descr = header.dtype().descr();
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
    let available = file_len.saturating_sub(data_start as u64);
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
    Ok(Layout {
        shape,
        elem,
        data_start,
    })
}

/// Converts little-endian float32 or float64 bytes (`elem` 4 or 8) into `out`.
fn convert(bytes: &[u8], elem: u64, out: &mut [f32]) {
    if elem == 4 {
        for (o, b) in out.iter_mut().zip(bytes.chunks_exact(4)) {
            *o = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
    } else {
        for (o, b) in out.iter_mut().zip(bytes.chunks_exact(8)) {
            *o = f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32;
        }
    }
}

/// Parses any little-endian float32/float64 C-order array as (shape, f32 values).
fn parse_array(bytes: &[u8], path: &Path) -> Result<(Vec<u64>, Vec<f32>)> {
    let l = parse_layout(bytes, bytes.len() as u64, path)?;
    let n = ((bytes.len() - l.data_start) as u64 / l.elem) as usize;
    let mut data = crate::memory::filled(n, 0.0f32, "data", "the array").map_err(|e| e.at(path))?;
    convert(&bytes[l.data_start..], l.elem, &mut data);
    Ok((l.shape, data))
}

/// Grid resolution (x, y, z) of a `[z][y][x]` shape.
fn resolution(shape: &[u64], path: &Path) -> Result<[usize; 3]> {
    if shape.len() != 3 {
        return Err(Error::invalid(
            path,
            "header.shape",
            format!("expected 3 dimensions [z][y][x], found {shape:?}"),
        ));
    }
    let as_i64 = |v: u64| i64::try_from(v).unwrap_or(i64::MAX);
    check_resolution(
        [as_i64(shape[2]), as_i64(shape[1]), as_i64(shape[0])],
        "header.shape",
    )
    .map_err(|e| e.at(path))
}

/// Parses `.npy` bytes; `path` only labels errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<DensityGrid> {
    let (shape, data) = parse_array(bytes, path)?;
    let res = resolution(&shape, path)?;
    DensityGrid::new(res, data).map_err(|e| e.at(path))
}

/// Reads any little-endian float32/float64 C-order array as (shape, f32 values) — used for
/// auxiliary arrays such as the references' optical-depth masks.
pub fn read_array(path: &Path) -> Result<(Vec<usize>, Vec<f32>)> {
    let bytes = crate::fsio::read_held(path, 2)?;
    let (shape, data) = parse_array(&bytes, path)?;
    Ok((shape.into_iter().map(|v| v as usize).collect(), data))
}

/// Reads a grid, streaming: the header first (checked against the file's length), then the
/// data straight into the grid (float64 files through a 1 MiB buffer), so the file's bytes and
/// the grid are never held at once.
pub fn read(path: &Path) -> Result<DensityGrid> {
    use std::io::Read;
    let io = |e| Error::io(path, e);
    // Streamed: the grid's allocation is checked against the budget from the header.
    let (mut f, len) = crate::fsio::open(path, crate::fsio::Hold::Streamed)?;
    // Magic (6), version (2), header length (2 in version 1, 4 later), then the header.
    let mut pre = vec![0u8; 12.min(len as usize)];
    f.read_exact(&mut pre).map_err(io)?;
    let header_len = match pre.get(6) {
        Some(1) if pre.len() >= 10 => 10 + u16::from_le_bytes([pre[8], pre[9]]) as u64,
        Some(_) if pre.len() >= 12 => {
            12 + u32::from_le_bytes([pre[8], pre[9], pre[10], pre[11]]) as u64
        }
        _ => len,
    };
    if header_len > len {
        return Err(Error::invalid(
            path,
            "header.length",
            format!("header of {header_len} bytes does not fit in the file ({len} bytes)"),
        ));
    }
    let mut head = pre;
    head.resize(header_len as usize, 0);
    if header_len as usize > 12.min(len as usize) {
        let at = 12.min(len as usize);
        f.read_exact(&mut head[at..]).map_err(io)?;
    } else {
        head.truncate(header_len as usize);
    }
    let l = parse_layout(&head, len, path)?;
    let res = resolution(&l.shape, path)?;
    let what = format!("a {}×{}×{} grid", res[0], res[1], res[2]);
    let mut data = crate::memory::filled(res[0] * res[1] * res[2], 0.0f32, "data", &what)
        .map_err(|e| e.at(path))?;
    if l.elem == 4 {
        f.read_exact(bytemuck::cast_slice_mut(&mut data))
            .map_err(io)?;
        for v in data.iter_mut() {
            *v = f32::from_bits(u32::from_le(v.to_bits()));
        }
    } else {
        let mut buf = vec![0u8; 1 << 20];
        for chunk in data.chunks_mut((1 << 20) / 8) {
            let bytes = &mut buf[..chunk.len() * 8];
            f.read_exact(bytes).map_err(io)?;
            convert(bytes, 8, chunk);
        }
    }
    DensityGrid::new(res, data).map_err(|e| e.at(path))
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
    crate::fsio::write_bytes(path, &out)
}

pub fn write(path: &Path, grid: &DensityGrid) -> Result<()> {
    // Streamed: no second copy of the grid in memory.
    let r = grid.res();
    let f = crate::fsio::create(path)?;
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

    /// The streamed reader gives what the in-memory parser gives, for float32 and float64
    /// files, and the same errors for a short file, a header longer than the file and garbage.
    #[test]
    fn streamed_read_matches_parse() {
        let dir = std::env::temp_dir().join(format!("nimbus-npy-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let data: Vec<f32> = (0..4 * 3 * 5).map(|i| i as f32 * 0.25).collect();
        let g = DensityGrid::new([4, 3, 5], data.clone()).unwrap();
        let f32_path = dir.join("g32.npy");
        std::fs::write(&f32_path, to_bytes(&g)).unwrap();
        assert_eq!(read(&f32_path).unwrap(), g);
        // float64, written by npyz, converted on the fly in 1 MiB pieces.
        let f64_path = dir.join("g64.npy");
        let mut buf = Vec::new();
        {
            let mut w = npyz::WriteOptions::new()
                .default_dtype()
                .shape(&[5, 3, 4])
                .writer(&mut buf)
                .begin_nd()
                .unwrap();
            for v in &data {
                w.push(&(*v as f64)).unwrap();
            }
            w.finish().unwrap();
        }
        std::fs::write(&f64_path, &buf).unwrap();
        assert_eq!(read(&f64_path).unwrap(), g);
        assert_eq!(parse(&buf, &f64_path).unwrap(), g);
        // One value short.
        let short = dir.join("short.npy");
        let b = to_bytes(&g);
        std::fs::write(&short, &b[..b.len() - 4]).unwrap();
        let m = read(&short).unwrap_err().to_string();
        assert!(
            m.contains("short.npy") && m.contains("`data`") && m.contains("needs 240 bytes"),
            "{m}"
        );
        // A header length beyond the file.
        let mut long = b.clone();
        long[8] = 0xff;
        long[9] = 0xff;
        let lp = dir.join("long.npy");
        std::fs::write(&lp, &long[..300]).unwrap();
        let m = read(&lp).unwrap_err().to_string();
        assert!(m.contains("header.length") || m.contains("header"), "{m}");
        let gp = dir.join("garbage.npy");
        std::fs::write(&gp, b"garbage").unwrap();
        assert!(read(&gp).unwrap_err().to_string().contains("header"));
        std::fs::write(&gp, b"").unwrap();
        assert!(read(&gp).is_err());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
