//! A generated cloud streamed straight into a `.vol` file: no grid in memory, and the file
//! written while the next slabs are being generated.
//!
//! Each worker fills a slab of 8 z planes (the same [`fill_slice`] as [`super::generate`]) and
//! hands it to one writer thread, which writes its data pages at their offsets (a `.vol` is
//! z-major, so a slab is one contiguous range of the file; pages of zeros stay holes) and asks
//! the kernel to flush what it wrote every [`SYNC_BYTES`], so that the disk works while the
//! cores generate. Grids are normalised by their maximum (see the module docs of
//! [`super`]); a cloud's maximum is 1 wherever its deep interior is reached, and dividing by 1
//! changes nothing, so the values are written as they come. A cloud whose maximum comes out
//! below 1 has its file divided in place afterwards ([`crate::io::vol::SlabFile::divide`]):
//! the bytes are those of `generate` followed by `write_grid` either way (tested).

use std::path::Path;
use std::sync::Mutex;
use std::sync::mpsc::sync_channel;

use rayon::prelude::*;

use super::{CloudKind, Field, Plan, fill_slice, make_field};
use crate::error::{Error, FieldError, Result};
use crate::grid::GridStats;
use crate::io::vol::SlabFile;

/// z planes per slab (a brick's depth, as the sparse path of [`super::generate`]).
const SLAB: usize = crate::brick::DIM;

/// Data bytes between two requests to flush the file to disk.
const SYNC_BYTES: usize = 256 << 20;

/// Slabs waiting for the writer at most (each nx × ny × 8 values).
const QUEUED: usize = 2;

/// Generates a cloud (as [`super::generate`]) into the `.vol` file `path` over `bounds`,
/// streaming; returns the statistics of the normalised grid. Errors name `path` or the field.
pub fn generate_vol(
    kind: CloudKind,
    seed: u64,
    res: [usize; 3],
    path: &Path,
    bounds: (glam::DVec3, glam::DVec3),
) -> Result<GridStats> {
    let res = crate::brick::check_sparse_resolution(res.map(|r| r as i64), "resolution")
        .map_err(|e| e.at(path))?;
    if res.iter().any(|&r| r < 4) {
        return Err(FieldError::new(
            "resolution",
            format!("procedural clouds need at least 4 voxels per axis, got {res:?}"),
        )
        .at(path));
    }
    let [nx, ny, nz] = res;
    let slab_len = nx * ny * SLAB;
    // The slab buffers alive at once: one per worker, the queue's and the writer's.
    crate::memory::check(
        ((rayon::current_num_threads() + QUEUED + 1) * slab_len * 4) as u128,
        "resolution",
        &format!("the slab buffers of a {nx}×{ny}×{nz} cloud being written"),
    )
    .map_err(|e| e.at(path))?;
    let file = SlabFile::create(path, res, bounds)?;
    let (max, sum, nonzero) = write_raw(kind, seed, res, &file).map_err(|e| Error::io(path, e))?;
    if max <= 0.0 {
        return Err(FieldError::new(
            "seed",
            format!(
                "{} with seed {seed} at {res:?} came out empty; try another seed",
                kind.name()
            ),
        )
        .at(path));
    }
    if max != 1.0 {
        file.divide(max).map_err(|e| Error::io(path, e))?;
    }
    let total = (nx * ny * nz) as f64;
    Ok(GridStats {
        min: 0.0,
        max: 1.0,
        mean: sum / max as f64 / total,
        nonzero_fraction: nonzero as f64 / total,
    })
}

/// Generates the cloud's values before normalisation into `file`; returns their maximum, sum
/// and non-zero count.
fn write_raw(
    kind: CloudKind,
    seed: u64,
    res: [usize; 3],
    file: &SlabFile,
) -> std::io::Result<(f32, f64, u64)> {
    let [nx, ny, nz] = res;
    let slab_len = nx * ny * SLAB;
    let pool: Mutex<Vec<Vec<f32>>> = Mutex::new(Vec::new());
    let (send, recv) = sync_channel::<(usize, Vec<f32>)>(QUEUED);
    // Per slab: maximum, sum and non-zero count of the raw values.
    std::thread::scope(|s| {
        let writer = s.spawn(|| -> std::io::Result<()> {
            let mut unsynced = 0usize;
            for (k, slab) in recv {
                let planes = (nz - k * SLAB).min(SLAB);
                unsynced += file.write_planes(k * SLAB, &slab[..planes * nx * ny])?;
                if unsynced >= SYNC_BYTES {
                    file.sync()?;
                    unsynced = 0;
                }
                pool.lock().expect("no panics hold the pool").push(slab);
            }
            Ok(())
        });
        let init = || -> (Field, Option<Plan>) { make_field(kind, seed, res, true) };
        let stats = (0..nz.div_ceil(SLAB))
            .into_par_iter()
            .map_init(
                || (init(), send.clone()),
                |((field, plan), send), k| {
                    let reused = pool.lock().expect("no panics hold the pool").pop();
                    let mut slab = reused.unwrap_or_default();
                    slab.clear();
                    slab.resize(slab_len, 0.0);
                    let (mut max, mut sum, mut nonzero) = (0.0f32, 0.0f64, 0u64);
                    for (l, slice) in slab.chunks_mut(nx * ny).enumerate() {
                        let z = k * SLAB + l;
                        if z < nz {
                            fill_slice(field, plan, res, z, slice);
                            for &v in slice.iter() {
                                max = max.max(v);
                                sum += v as f64;
                                nonzero += (v > 0.0) as u64;
                            }
                        }
                    }
                    // A writer that stopped (an I/O error) has dropped the receiver: its error
                    // is reported below.
                    let _ = send.send((k, slab));
                    (max, sum, nonzero)
                },
            )
            .reduce(
                || (0.0f32, 0.0f64, 0u64),
                |a, b| (a.0.max(b.0), a.1 + b.1, a.2 + b.2),
            );
        drop(send);
        writer
            .join()
            .expect("the writer does not panic")
            .map(|()| stats)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmp(name: &str) -> std::path::PathBuf {
        let d = std::env::temp_dir().join(format!("nimbus-stream-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d.join(name)
    }

    /// Streamed and in-memory generation give the same file byte for byte, for every kind (odd
    /// sizes: a last slab of fewer than 8 planes), whether or not the maximum came out as 1;
    /// and the same statistics.
    #[test]
    fn streamed_file_equals_generate_then_write() {
        let mut divided = 0;
        for (i, kind) in CloudKind::ALL.into_iter().enumerate() {
            let res = [44, 29 + i, 37];
            let bounds = super::super::default_aabb(res);
            let (a, b) = (tmp(&format!("a{i}.vol")), tmp(&format!("b{i}.vol")));
            let st = generate_vol(kind, 5, res, &a, bounds).unwrap();
            let grid = super::super::generate(kind, 5, res).unwrap();
            let c = tmp(&format!("c{i}.vol"));
            let raw = write_raw(kind, 5, res, &SlabFile::create(&c, res, bounds).unwrap());
            divided += usize::from(raw.unwrap().0 != 1.0);
            crate::io::vol::write(&b, &grid, bounds).unwrap();
            assert!(
                std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap(),
                "{kind:?}"
            );
            let want = grid.stats();
            assert!((st.mean / want.mean - 1.0).abs() < 1e-9, "{kind:?}");
            assert_eq!(st.nonzero_fraction, want.nonzero_fraction);
        }
        // Both ways were taken: a maximum of 1 (written as generated) and below (divided).
        assert!((1..4).contains(&divided), "{divided} of 4 kinds divided");
    }

    /// The in-place division: every stored value divided in f32, zero pages left as holes.
    #[test]
    fn divide_in_place() {
        let res = [40, 30, 3];
        let p = tmp("div.vol");
        let f = SlabFile::create(&p, res, (glam::DVec3::ZERO, glam::DVec3::ONE)).unwrap();
        let n = 40 * 30;
        let values: Vec<f32> = (0..3 * n)
            .map(|i| if i % 7 == 0 { i as f32 * 0.37 } else { 0.0 })
            .collect();
        f.write_planes(0, &values).unwrap();
        f.divide(0.3).unwrap();
        let back = crate::io::vol::read(&p).unwrap().grid;
        let mut plane = vec![0.0f32; n];
        for z in 0..3 {
            back.plane(z, &mut plane);
            for (x, v) in plane.iter().zip(&values[z * n..(z + 1) * n]) {
                assert_eq!(x.to_bits(), (v / 0.3).to_bits());
            }
        }
    }
}
