//! Mitsuba `.vol` grids: `"VOL"`, version byte 3, int32 encoding (1 = float32), int32 xres, yres,
//! zres, int32 channels (1), 6 × float32 bounding box, then float32 data with x fastest, then y,
//! then z. All little-endian.

use std::path::Path;

use glam::DVec3;

use super::GridFile;
use crate::error::{Error, Result};
use crate::grid::{DensityGrid, check_resolution};

const HEADER_LEN: usize = 48;

/// What a header says: resolution and bounds (`None`: no box stored).
type Header = ([usize; 3], Option<(DVec3, DVec3)>);

/// Parses `.vol` bytes; `path` only labels errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<GridFile> {
    let (res, bounds) = parse_header(bytes, path)?;
    check_length(res, bytes.len() as u64, path)?;
    let data: Vec<f32> = bytes[HEADER_LEN..]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect();
    let grid = DensityGrid::new(res, data).map_err(|e| e.at(path))?;
    Ok(GridFile { grid, bounds })
}

/// Checks that a file of `len` bytes holds exactly the header and `res` float32 voxels.
fn check_length(res: [usize; 3], len: u64, path: &Path) -> Result<()> {
    let expected = HEADER_LEN as u64 + 4 * (res[0] * res[1] * res[2]) as u64;
    if len != expected {
        return Err(Error::invalid(
            path,
            "data",
            format!(
                "{}×{}×{} float32 voxels need {expected} bytes, the file has {len}",
                res[0], res[1], res[2],
            ),
        ));
    }
    Ok(())
}

/// Parses the header at the start of `bytes` (the whole file or at least its first 48 bytes).
fn parse_header(bytes: &[u8], path: &Path) -> Result<Header> {
    if bytes.len() < HEADER_LEN {
        return Err(Error::invalid(
            path,
            "header",
            format!(
                "file is {} bytes, a .vol header needs {HEADER_LEN}",
                bytes.len()
            ),
        ));
    }
    if &bytes[0..3] != b"VOL" {
        return Err(Error::invalid(
            path,
            "header.magic",
            "does not start with \"VOL\"",
        ));
    }
    if bytes[3] != 3 {
        return Err(Error::invalid(
            path,
            "header.version",
            format!("version {} is not supported (only 3)", bytes[3]),
        ));
    }
    let i32_at = |o: usize| i32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let f32_at = |o: usize| f32::from_le_bytes(bytes[o..o + 4].try_into().unwrap());
    let encoding = i32_at(4);
    if encoding != 1 {
        return Err(Error::invalid(
            path,
            "header.encoding",
            format!("encoding {encoding} is not supported (only 1 = float32)"),
        ));
    }
    let res = check_resolution(
        [i32_at(8) as i64, i32_at(12) as i64, i32_at(16) as i64],
        "header.resolution",
    )
    .map_err(|e| e.at(path))?;
    let channels = i32_at(20);
    if channels != 1 {
        return Err(Error::invalid(
            path,
            "header.channels",
            format!("{channels} channels; only single-channel density grids are supported"),
        ));
    }
    let bmin = DVec3::new(f32_at(24) as f64, f32_at(28) as f64, f32_at(32) as f64);
    let bmax = DVec3::new(f32_at(36) as f64, f32_at(40) as f64, f32_at(44) as f64);
    // A non-finite corner is a damaged header, not a missing box (writers without a box store
    // zeros: those, and other empty boxes, mean "no box" and the scene must give one).
    if !(bmin.is_finite() && bmax.is_finite()) {
        return Err(Error::invalid(
            path,
            "header.bbox",
            format!("corners {bmin} and {bmax} are not finite"),
        ));
    }
    let bounds = bmax.cmpgt(bmin).all().then_some((bmin, bmax));
    Ok((res, bounds))
}

/// Reads a `.vol` file, streaming its voxels straight into the grid (the file's bytes are
/// never held beside it: a 6.9 GB file needs at most 6.9 GB). A grid of more than
/// [`crate::brick::SPARSE_ABOVE_VOXELS`] voxels is read as 8³ bricks, 8 planes at a time,
/// keeping only the bricks that hold a non-zero value: its memory grows with the cloud, not
/// with its box (the same values, see the tests).
pub fn read(path: &Path) -> Result<GridFile> {
    read_with(path, crate::brick::SPARSE_ABOVE_VOXELS)
}

fn read_with(path: &Path, sparse_above: usize) -> Result<GridFile> {
    use std::io::Read;
    let io = |e| Error::io(path, e);
    // Streamed: the grid's allocation is checked against the budget from the header.
    let (mut f, len) = crate::fsio::open(path, crate::fsio::Hold::Streamed)?;
    let mut head = vec![0u8; HEADER_LEN.min(len as usize)];
    f.read_exact(&mut head).map_err(io)?;
    let (res, bounds) = parse_header(&head, path)?;
    check_length(res, len, path)?;
    let what = format!("a {}×{}×{} grid", res[0], res[1], res[2]);
    if res[0] * res[1] * res[2] > sparse_above {
        let grid = read_bricks(&mut f, res, &what, path)?;
        return Ok(GridFile { grid, bounds });
    }
    let mut data = crate::memory::filled(res[0] * res[1] * res[2], 0.0f32, "data", &what)
        .map_err(|e| e.at(path))?;
    f.read_exact(bytemuck::cast_slice_mut(&mut data))
        .map_err(io)?;
    // The file is little-endian (a no-op on little-endian machines).
    for v in data.iter_mut() {
        *v = f32::from_bits(u32::from_le(v.to_bits()));
    }
    let grid = DensityGrid::new(res, data).map_err(|e| e.at(path))?;
    Ok(GridFile { grid, bounds })
}

/// The voxels after the header as bricks: a slab of 8 planes at a time is read and cut into
/// bricks; all-zero bricks stay absent. Values are checked (finite, non-negative) when the
/// bricks are finished, the error naming the voxel.
fn read_bricks(
    f: &mut std::fs::File,
    res: [usize; 3],
    what: &str,
    path: &Path,
) -> Result<DensityGrid> {
    use crate::brick::{BrickBuilder, DIM};
    use std::io::Read;
    let [nx, ny, nz] = res;
    let mut b = BrickBuilder::new(res, [0; 3], 0, "data", what).map_err(|e| e.at(path))?;
    let bres = b.brick_res();
    let mut slab =
        crate::memory::filled(nx * ny * DIM, 0.0f32, "data", what).map_err(|e| e.at(path))?;
    for k in 0..bres[2] {
        let planes = DIM.min(nz - k * DIM);
        let buf = &mut slab[..nx * ny * planes];
        f.read_exact(bytemuck::cast_slice_mut(buf))
            .map_err(|e| Error::io(path, e))?;
        for v in buf.iter_mut() {
            *v = f32::from_bits(u32::from_le(v.to_bits()));
        }
        for j in 0..bres[1] {
            for i in 0..bres[0] {
                let (x0, x1) = (i * DIM, ((i + 1) * DIM).min(nx));
                let (y0, y1) = (j * DIM, ((j + 1) * DIM).min(ny));
                let row = |l: usize, y: usize| &buf[(l * ny + y) * nx + x0..(l * ny + y) * nx + x1];
                let any =
                    (0..planes).any(|l| (y0..y1).any(|y| row(l, y).iter().any(|&v| v != 0.0)));
                if !any {
                    continue;
                }
                let dst = b.stored_mut([i, j, k]).map_err(|e| e.at(path))?;
                for l in 0..planes {
                    for y in y0..y1 {
                        let at = (l * DIM + y - y0) * DIM;
                        dst[at..at + x1 - x0].copy_from_slice(row(l, y));
                    }
                }
            }
        }
    }
    Ok(DensityGrid::from_bricks(
        b.finish().map_err(|e| e.at(path))?,
    ))
}

/// Serialises a grid as `.vol` bytes.
pub fn to_bytes(grid: &DensityGrid, bounds: (DVec3, DVec3)) -> Vec<u8> {
    let r = grid.res();
    let mut out = std::io::Cursor::new(Vec::with_capacity(HEADER_LEN + 4 * r[0] * r[1] * r[2]));
    write_to(&mut out, grid, bounds).expect("writing to memory cannot fail");
    out.into_inner()
}

/// Zero values filling one 4 KiB page of the file are not written but skipped with a seek: in
/// a file they become a hole (no disk blocks or page-cache copies on file systems that support
/// them; zeros when read), so a cloud that fills a few percent of its box costs little more
/// than its cloud. Pages are counted from the file's start (after the 48-byte header).
const HOLE_VALUES: usize = 1024;

/// The 48-byte header of a grid of resolution `r` over `bounds`.
fn header(r: [usize; 3], bounds: (DVec3, DVec3)) -> Vec<u8> {
    let mut header = Vec::with_capacity(HEADER_LEN);
    header.extend_from_slice(b"VOL");
    header.push(3);
    for v in [1i32, r[0] as i32, r[1] as i32, r[2] as i32, 1] {
        header.extend_from_slice(&v.to_le_bytes());
    }
    for v in [
        bounds.0.x, bounds.0.y, bounds.0.z, bounds.1.x, bounds.1.y, bounds.1.z,
    ] {
        header.extend_from_slice(&(v as f32).to_le_bytes());
    }
    header
}

/// Calls `f` with the runs of plane `z` that hold data, as value ranges of the plane, in
/// order: the plane cut at the file's page boundaries, pages of zeros left out (they become
/// holes), consecutive data pages merged into one run.
fn data_runs(
    plane: &[f32],
    z: usize,
    mut f: impl FnMut(std::ops::Range<usize>) -> std::io::Result<()>,
) -> std::io::Result<()> {
    let g0 = z * plane.len();
    let first = (HOLE_VALUES - (g0 + HEADER_LEN / 4) % HOLE_VALUES) % HOLE_VALUES;
    let mut run: Option<usize> = None;
    let mut at = 0;
    while at < plane.len() {
        let end = if at == 0 && first > 0 {
            first
        } else {
            at + HOLE_VALUES
        }
        .min(plane.len());
        let chunk = &plane[at..end];
        if chunk.len() == HOLE_VALUES && chunk.iter().all(|&v| v.to_bits() == 0) {
            if let Some(a) = run.take() {
                f(a..at)?;
            }
        } else {
            run.get_or_insert(at);
        }
        at = end;
    }
    match run {
        Some(a) => f(a..plane.len()),
        None => Ok(()),
    }
}

/// `values` as little-endian f32 bytes (on a little-endian machine the values' own memory;
/// elsewhere converted into `bytes`).
fn le_bytes<'a>(values: &'a [f32], bytes: &'a mut Vec<u8>) -> &'a [u8] {
    if cfg!(target_endian = "little") {
        bytemuck::cast_slice(values)
    } else {
        bytes.clear();
        bytes.extend(values.iter().flat_map(|v| v.to_le_bytes()));
        bytes
    }
}

/// Streams a grid as `.vol` bytes, z-plane by z-plane (no second copy of the grid in memory;
/// bricks are read a plane at a time), seeking over the pages of zeros.
pub fn write_to(
    out: &mut (impl std::io::Write + std::io::Seek),
    grid: &DensityGrid,
    bounds: (DVec3, DVec3),
) -> std::io::Result<()> {
    use std::io::SeekFrom;
    let r = grid.res();
    out.write_all(&header(r, bounds))?;
    let n = r[0] * r[1];
    let mut plane = vec![0.0f32; n];
    let mut bytes = Vec::new();
    // The value the cursor is at.
    let mut pos = 0usize;
    for z in 0..r[2] {
        grid.plane(z, &mut plane);
        data_runs(&plane, z, |run| {
            let g = z * n + run.start;
            if g > pos {
                out.seek(SeekFrom::Current(4 * (g - pos) as i64))?;
            }
            out.write_all(le_bytes(&plane[run.clone()], &mut bytes))?;
            pos = z * n + run.end;
            Ok(())
        })?;
    }
    let total = n * r[2];
    if pos < total {
        // The last value is written, so the file has its full length.
        out.seek(SeekFrom::Current(4 * (total - pos) as i64 - 4))?;
        out.write_all(&[0; 4])?;
    }
    Ok(())
}

/// [`write_to`] for a file, planes in parallel: the file is sized first (all holes) and each
/// plane's data runs are written at their offsets — copying gigabytes into the page cache is
/// itself slow enough to be worth both cores (a 1200³ cumulus: 2.6 GB of data pages).
#[cfg(unix)]
fn write_file(
    f: &std::fs::File,
    grid: &DensityGrid,
    bounds: (DVec3, DVec3),
) -> std::io::Result<()> {
    use rayon::prelude::*;
    use std::os::unix::fs::FileExt;
    let r = grid.res();
    let n = r[0] * r[1];
    // One plane buffer per worker, within the memory budget.
    crate::memory::check(
        (rayon::current_num_threads() * n * 4) as u128,
        "volume",
        "the plane buffers of a .vol being written",
    )
    .map_err(|e| std::io::Error::other(e.msg))?;
    f.set_len((HEADER_LEN + 4 * n * r[2]) as u64)?;
    f.write_all_at(&header(r, bounds), 0)?;
    (0..r[2]).into_par_iter().try_for_each_init(
        || (vec![0.0f32; n], Vec::new()),
        |(plane, bytes), z| {
            grid.plane(z, plane);
            data_runs(plane, z, |run| {
                let at = HEADER_LEN + 4 * (z * n + run.start);
                f.write_all_at(le_bytes(&plane[run], bytes), at as u64)
            })
        },
    )
}

/// A `.vol` file written in parts, from several threads: created at its full length (all
/// holes) with its header; [`SlabFile::write_planes`] writes consecutive z planes at their
/// offsets, pages of zeros left out (see `HOLE_VALUES`).
#[cfg(unix)]
pub struct SlabFile {
    file: std::fs::File,
    res: [usize; 3],
}

#[cfg(unix)]
impl SlabFile {
    pub fn create(path: &Path, res: [usize; 3], bounds: (DVec3, DVec3)) -> Result<Self> {
        use std::os::unix::fs::FileExt;
        let file = crate::fsio::create(path)?;
        file.set_len((HEADER_LEN + 4 * res[0] * res[1] * res[2]) as u64)
            .and_then(|()| file.write_all_at(&header(res, bounds), 0))
            .map_err(|e| Error::io(path, e))?;
        Ok(Self { file, res })
    }

    /// Writes planes `z0`, `z0 + 1`, … (`values`: whole planes, x fastest); returns the bytes
    /// written (data pages only).
    pub fn write_planes(&self, z0: usize, values: &[f32]) -> std::io::Result<usize> {
        use std::os::unix::fs::FileExt;
        let n = self.res[0] * self.res[1];
        assert!(values.len().is_multiple_of(n) && z0 + values.len() / n <= self.res[2]);
        let mut bytes = Vec::new();
        let mut written = 0;
        for (l, plane) in values.chunks_exact(n).enumerate() {
            let z = z0 + l;
            data_runs(plane, z, |run| {
                let at = HEADER_LEN + 4 * (z * n + run.start);
                written += 4 * run.len();
                self.file
                    .write_all_at(le_bytes(&plane[run], &mut bytes), at as u64)
            })?;
        }
        Ok(written)
    }

    /// Asks the kernel to write what is cached to disk (and waits for it).
    pub fn sync(&self) -> std::io::Result<()> {
        self.file.sync_data()
    }

    /// Divides every value by `by` (the f32 division of a grid's normalisation), plane by
    /// plane, in parallel; holes read as zeros and stay holes.
    pub fn divide(&self, by: f32) -> std::io::Result<()> {
        use rayon::prelude::*;
        use std::os::unix::fs::FileExt;
        let n = self.res[0] * self.res[1];
        (0..self.res[2]).into_par_iter().try_for_each_init(
            || (vec![0.0f32; n], vec![0u8; 4 * n]),
            |(plane, bytes), z| {
                self.file
                    .read_exact_at(bytes, (HEADER_LEN + 4 * z * n) as u64)?;
                for (v, b) in plane.iter_mut().zip(bytes.chunks_exact(4)) {
                    *v = f32::from_le_bytes(b.try_into().expect("4 bytes")) / by;
                }
                self.write_planes(z, plane).map(|_| ())
            },
        )
    }
}

pub fn write(path: &Path, grid: &DensityGrid, bounds: (DVec3, DVec3)) -> Result<()> {
    let f = crate::fsio::create(path)?;
    #[cfg(unix)]
    {
        write_file(&f, grid, bounds).map_err(|e| Error::io(path, e))
    }
    #[cfg(not(unix))]
    {
        let mut w = std::io::BufWriter::new(f);
        write_to(&mut w, grid, bounds)
            .and_then(|()| std::io::Write::flush(&mut w))
            .map_err(|e| Error::io(path, e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> DensityGrid {
        DensityGrid::new([3, 2, 1], vec![0.0, 0.5, 1.0, 1.5, 2.0, 2.5]).unwrap()
    }

    #[test]
    fn non_finite_box_is_a_damaged_header() {
        let mut bytes = to_bytes(&sample(), (DVec3::ZERO, DVec3::ONE));
        bytes[28..32].copy_from_slice(&f32::NAN.to_le_bytes());
        let e = parse(&bytes, Path::new("nan_box.vol"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("nan_box.vol") && e.contains("header.bbox"),
            "{e}"
        );
        // A zero box means "no box".
        let zero = to_bytes(&sample(), (DVec3::ZERO, DVec3::ZERO));
        assert!(parse(&zero, Path::new("z.vol")).unwrap().bounds.is_none());
    }

    #[test]
    fn streamed_read_checks_the_file_before_filling_the_grid() {
        let dir = std::env::temp_dir().join(format!("nimbus-vol-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let b = (DVec3::ZERO, DVec3::ONE);
        let bytes = to_bytes(&sample(), b);
        // Whole: the same grid and box as the in-memory parser.
        let ok = dir.join("ok.vol");
        std::fs::write(&ok, &bytes).unwrap();
        let f = read(&ok).unwrap();
        assert_eq!(f.grid, sample());
        assert_eq!(f.bounds, Some(b));
        // Shorter than a header, and one voxel short: errors naming the field and the sizes.
        for (name, len, field, words) in [
            ("head.vol", 10, "header", "10 bytes"),
            (
                "short.vol",
                bytes.len() - 4,
                "data",
                "need 72 bytes, the file has 68",
            ),
        ] {
            let p = dir.join(name);
            std::fs::write(&p, &bytes[..len]).unwrap();
            match read(&p).unwrap_err() {
                Error::Invalid { field: f, msg, .. } => {
                    assert_eq!(f, field, "{name}");
                    assert!(msg.contains(words), "{name}: {msg}");
                }
                e => panic!("{name}: {e}"),
            }
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Above the threshold the file is read as bricks: the same values, zero bricks absent,
    /// and a bad value still named by its voxel and the file.
    #[test]
    fn large_grids_are_read_as_bricks() {
        let dir = std::env::temp_dir().join(format!("nimbus-volb-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let res = [19, 10, 21];
        let mut s = 3u32;
        let data: Vec<f32> = (0..res.iter().product::<usize>())
            .map(|i| {
                s = s.wrapping_mul(1664525).wrapping_add(1013904223);
                let (x, z) = (i % 19, i / 190);
                if (4..9).contains(&x) && (3..13).contains(&z) {
                    (s >> 8) as f32 / (1 << 24) as f32
                } else {
                    0.0
                }
            })
            .collect();
        let dense = DensityGrid::new(res, data.clone()).unwrap();
        let p = dir.join("big.vol");
        write(&p, &dense, (DVec3::ZERO, DVec3::ONE)).unwrap();
        let f = read_with(&p, 100).unwrap();
        let b = f.grid.as_bricks().expect("read as bricks");
        let (stored, _, absent) = b.counts();
        assert!(stored > 0 && absent > 0, "{:?}", b.counts());
        assert_eq!(f.grid.dense().unwrap().as_ref(), data.as_slice());
        assert_eq!(read_with(&p, usize::MAX).unwrap().grid, dense);
        let mut bad = data;
        bad[(14 * 10 + 2) * 19 + 6] = f32::NAN;
        let q = dir.join("nan.vol");
        std::fs::write(&q, to_bytes_unchecked(res, &bad)).unwrap();
        let e = read_with(&q, 100).unwrap_err().to_string();
        assert!(e.contains("nan.vol") && e.contains("voxel[6,2,14]"), "{e}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// `.vol` bytes of raw values (no validation: for writing damaged files).
    fn to_bytes_unchecked(res: [usize; 3], data: &[f32]) -> Vec<u8> {
        let mut b = b"VOL\x03".to_vec();
        for v in [1i32, res[0] as i32, res[1] as i32, res[2] as i32, 1] {
            b.extend(v.to_le_bytes());
        }
        for v in [0f32, 0.0, 0.0, 1.0, 1.0, 1.0] {
            b.extend(v.to_le_bytes());
        }
        for v in data {
            b.extend(v.to_le_bytes());
        }
        b
    }

    #[test]
    fn long_zero_runs_are_skipped_yet_read_back_as_zeros() {
        // Planes of 97 × 64 values (the file's pages fall at a different place in each):
        // zero runs longer than a page at the start, in the middle and at the end (the file
        // must still have its full length), a −0.0 inside one (its bits are kept), data in
        // between; from a file (planes in parallel) and from memory, the same bytes.
        let res = [97, 64, 5];
        let n = 97 * 64;
        let data: Vec<f32> = (0..res.iter().product::<usize>())
            .map(|i| match i / n {
                1 if i % 97 == 0 => -0.0,
                2 => (i % 13) as f32 * 0.25,
                3 if (i % n) < 300 || (i % n) % 1500 == 7 => 1.5,
                _ => 0.0,
            })
            .collect();
        let grid = DensityGrid::new(res, data.clone()).unwrap();
        let bounds = (DVec3::ZERO, DVec3::ONE);
        let mem = to_bytes(&grid, bounds);
        assert_eq!(
            mem[HEADER_LEN..],
            to_bytes_unchecked(res, &data)[HEADER_LEN..]
        );
        let dir = std::env::temp_dir().join(format!("nimbus-volh-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("holes.vol");
        write(&p, &grid, bounds).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), mem);
        let back = read_with(&p, usize::MAX).unwrap().grid;
        assert!(
            back.dense()
                .unwrap()
                .iter()
                .zip(&data)
                .all(|(a, b)| a.to_bits() == b.to_bits())
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn round_trip() {
        let b = (DVec3::splat(-1.0), DVec3::new(1.0, 2.0, 3.0));
        let bytes = to_bytes(&sample(), b);
        let f = parse(&bytes, Path::new("t.vol")).unwrap();
        assert_eq!(f.grid, sample());
        assert_eq!(f.bounds, Some(b));
    }

    #[test]
    fn malformed_files_name_the_field() {
        let p = Path::new("bad.vol");
        let good = to_bytes(&sample(), (DVec3::ZERO, DVec3::ONE));
        let msg = |b: &[u8]| parse(b, p).unwrap_err().to_string();
        assert!(msg(&good[..20]).contains("header"));
        assert!(msg(&good[..good.len() - 1]).contains("field `data`"));
        let mut b = good.clone();
        b[0] = b'X';
        assert!(msg(&b).contains("header.magic"));
        let mut b = good.clone();
        b[8..12].copy_from_slice(&(-5i32).to_le_bytes());
        assert!(msg(&b).contains("header.resolution.x"));
        let mut b = good.clone();
        b[8..12].copy_from_slice(&i32::MAX.to_le_bytes());
        b[12..16].copy_from_slice(&i32::MAX.to_le_bytes());
        assert!(msg(&b).contains("header.resolution"));
        let mut b = good.clone();
        b[4..8].copy_from_slice(&2i32.to_le_bytes());
        assert!(msg(&b).contains("header.encoding"));
        let mut b = good.clone();
        b[HEADER_LEN + 8..HEADER_LEN + 12].copy_from_slice(&f32::NAN.to_le_bytes());
        let m = msg(&b);
        assert!(m.contains("voxel[2,0,0]") && m.contains("bad.vol"), "{m}");
        // Random garbage never panics.
        let mut s = 7u64;
        for len in [0usize, 3, 47, 48, 49, 100, 1000] {
            let g: Vec<u8> = (0..len)
                .map(|_| {
                    s = s.wrapping_mul(6364136223846793005).wrapping_add(1);
                    (s >> 56) as u8
                })
                .collect();
            assert!(parse(&g, p).is_err());
        }
    }
}
