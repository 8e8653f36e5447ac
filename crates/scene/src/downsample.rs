//! Block means of a grid at a coarser resolution over the same box: how an estimator that
//! cannot hold per-voxel data for the whole grid (the photon map's light volumes, 16 bytes per
//! voxel) gets a density at the resolution it works at, without densifying a sparse grid.
//!
//! Along each axis fine voxel i belongs to the coarse cell whose extent holds its centre,
//! c = ⌊(i + ½) · n / N⌋ for N fine and n coarse cells; a coarse value is the mean of the fine
//! voxels it holds (⌊N/n⌋ or ⌈N/n⌉ per axis). The mean density — and so the optical depth
//! through any slab of whole cells — is kept.

use rayon::prelude::*;

use crate::DensityGrid;

/// Coarse cell of each fine index along one axis, and how many fine indices each cell holds.
fn axis_map(fine: usize, coarse: usize) -> (Vec<u32>, Vec<u32>) {
    let map: Vec<u32> = (0..fine)
        .map(|i| ((2 * i + 1) * coarse / (2 * fine)) as u32)
        .collect();
    let mut count = vec![0u32; coarse];
    for &c in &map {
        count[c as usize] += 1;
    }
    (map, count)
}

/// The block means of `grid` at `res` (each axis in 1..= the grid's), x fastest. A dense grid
/// is read as it is, a sparse one plane by plane, only its non-zero bricks (never densified).
///
/// # Panics
/// If an axis of `res` is 0 or finer than the grid's (callers choose `res` from the grid).
pub fn block_means(grid: &DensityGrid, res: [usize; 3]) -> Vec<f32> {
    let fine = grid.res();
    assert!(
        (0..3).all(|a| res[a] >= 1 && res[a] <= fine[a]),
        "block means at {res:?} of a {fine:?} grid"
    );
    let [(mx, cx), (my, cy), (mz, cz)] = [0, 1, 2].map(|a| axis_map(fine[a], res[a]));
    let [nx, ny, _] = fine;
    let plane_cells = res[0] * res[1];
    let mut out = vec![0.0f32; plane_cells * res[2]];
    // The fine planes of each coarse z slab are consecutive: slabs in parallel, one plane
    // buffer each.
    let first: Vec<usize> = (0..res[2])
        .map(|c| mz.iter().position(|&m| m as usize == c).unwrap())
        .collect();
    out.par_chunks_mut(plane_cells)
        .enumerate()
        .for_each(|(c, slab)| {
            let mut sums = vec![0.0f64; plane_cells];
            let mut plane = vec![0.0f32; nx * ny];
            for z in first[c]..first[c] + cz[c] as usize {
                let Some((bx, by)) = grid.plane_into_zeroed(z, &mut plane) else {
                    continue;
                };
                for y in by[0]..=by[1] {
                    let row = &mut plane[y * nx + bx[0]..=y * nx + bx[1]];
                    let srow = &mut sums[my[y] as usize * res[0]..][..res[0]];
                    for (x, v) in (bx[0]..).zip(row.iter_mut()) {
                        srow[mx[x] as usize] += *v as f64;
                        *v = 0.0;
                    }
                }
            }
            for (i, (o, s)) in slab.iter_mut().zip(&sums).enumerate() {
                let n = cx[i % res[0]] as f64 * cy[i / res[0]] as f64 * cz[c] as f64;
                *o = (s / n) as f32;
            }
        });
    out
}

/// The fine-index range `first..first + count` of each coarse cell along one axis (the inverse
/// of the centre rule above).
pub fn axis_ranges(fine: usize, coarse: usize) -> Vec<std::ops::Range<usize>> {
    let (map, count) = axis_map(fine, coarse);
    let mut first = vec![0usize; coarse];
    for (i, &c) in map.iter().enumerate().rev() {
        first[c as usize] = i;
    }
    (0..coarse)
        .map(|c| first[c]..first[c] + count[c] as usize)
        .collect()
}

/// The coarse cell holding fine index `i` along an axis of `fine` cells (`coarse` of them).
pub fn coarse_of(i: usize, fine: usize, coarse: usize) -> usize {
    (2 * i + 1) * coarse / (2 * fine)
}

/// The block means of `grid` at `res` over the coarse cells `lo..hi` (exclusive, clamped to
/// `res`), x fastest — the values [`block_means`] gives there, bit for bit (each cell's f64
/// sum runs over its fine voxels in the same z, y, x order), without the rest of the box.
/// `ranges` are [`axis_ranges`] of the three axes.
pub fn block_means_box(
    grid: &DensityGrid,
    ranges: &[Vec<std::ops::Range<usize>>; 3],
    lo: [usize; 3],
    hi: [usize; 3],
) -> Vec<f32> {
    let hi: [usize; 3] = std::array::from_fn(|a| hi[a].min(ranges[a].len()));
    let n: [usize; 3] = std::array::from_fn(|a| hi[a].saturating_sub(lo[a]));
    let mut out = vec![0.0f32; n[0] * n[1] * n[2]];
    let mut i = 0;
    for cz in lo[2]..hi[2] {
        for cy in lo[1]..hi[1] {
            for cx in lo[0]..hi[0] {
                let (rx, ry, rz) = (&ranges[0][cx], &ranges[1][cy], &ranges[2][cz]);
                let mut s = 0.0f64;
                for z in rz.clone() {
                    for y in ry.clone() {
                        for x in rx.clone() {
                            s += grid.get(x, y, z) as f64;
                        }
                    }
                }
                out[i] = (s / (rx.len() * ry.len() * rz.len()) as f64) as f32;
                i += 1;
            }
        }
    }
    out
}

/// Grows the inclusive box `b` (none yet: `None`) to hold index `v`.
pub fn grow_box(b: &mut Option<([usize; 3], [usize; 3])>, v: [usize; 3]) {
    *b = Some(match *b {
        None => (v, v),
        Some((l, h)) => (
            std::array::from_fn(|a| l[a].min(v[a])),
            std::array::from_fn(|a| h[a].max(v[a])),
        ),
    })
}

/// Bounding boxes (inclusive fine indices) of the non-zero voxels of each 8³ block of the
/// grid that holds any (for a sparse grid, its bricks; for a dense one, aligned 8³ blocks):
/// where a coarser or sparse structure derived from the grid can be non-zero, found in one
/// pass that never densifies.
pub fn nonzero_boxes(grid: &DensityGrid) -> Vec<([usize; 3], [usize; 3])> {
    const B: usize = 8;
    let [nx, ny, nz] = grid.res();
    if let Some(b) = grid.as_bricks() {
        let mut out = Vec::new();
        b.visit(|v| {
            let mut bx = None;
            match v.content {
                crate::brick::Content::Constant(c) => {
                    if c > 0.0 {
                        bx = Some((v.lo, v.hi.map(|h| h - 1)));
                    }
                }
                crate::brick::Content::Stored(s) => {
                    for z in v.lo[2]..v.hi[2] {
                        for y in v.lo[1]..v.hi[1] {
                            for x in v.lo[0]..v.hi[0] {
                                if s[v.local(x, y, z)] > 0.0 {
                                    grow_box(&mut bx, [x, y, z]);
                                }
                            }
                        }
                    }
                }
            }
            out.extend(bx);
        });
        return out;
    }
    let data = grid.as_dense().expect("a grid is dense or bricks");
    let (bx, by) = (nx.div_ceil(B), ny.div_ceil(B));
    (0..nz.div_ceil(B))
        .into_par_iter()
        .flat_map_iter(|bz| {
            let mut boxes = vec![None; bx * by];
            for z in bz * B..((bz + 1) * B).min(nz) {
                for y in 0..ny {
                    let row = &data[(z * ny + y) * nx..][..nx];
                    for (x, &v) in row.iter().enumerate() {
                        if v > 0.0 {
                            grow_box(&mut boxes[(y / B) * bx + x / B], [x, y, z]);
                        }
                    }
                }
            }
            boxes.into_iter().flatten()
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(res: [usize; 3]) -> Vec<f32> {
        (0..res.iter().product::<usize>())
            .map(|i| ((i * 7919) % 101) as f32 * 0.01 * (i % 3 != 0) as u32 as f32)
            .collect()
    }

    /// Against a direct sum over the fine voxels whose centres lie in each coarse cell, for
    /// factors that divide the axis and ones that do not, from dense and sparse storage.
    #[test]
    fn means_of_the_voxels_inside_each_cell() {
        let fine = [13, 9, 17];
        let data = grid(fine);
        let dense = DensityGrid::new(fine, data.clone()).unwrap();
        let sparse =
            DensityGrid::from_bricks(crate::brick::from_dense(fine, &data, [3, 0, 5]).unwrap());
        for res in [[13, 9, 17], [7, 3, 5], [1, 1, 1], [4, 9, 6]] {
            let mut sum = vec![0.0f64; res.iter().product()];
            let mut n = vec![0u32; sum.len()];
            for z in 0..fine[2] {
                for y in 0..fine[1] {
                    for x in 0..fine[0] {
                        // Coarse cell holding the voxel centre, in floating point.
                        let c = [x, y, z].map(|v| v as f64 + 0.5);
                        let k: [usize; 3] = std::array::from_fn(|a| {
                            (c[a] / fine[a] as f64 * res[a] as f64) as usize
                        });
                        let i = (k[2] * res[1] + k[1]) * res[0] + k[0];
                        sum[i] += data[(z * fine[1] + y) * fine[0] + x] as f64;
                        n[i] += 1;
                    }
                }
            }
            for g in [&dense, &sparse] {
                let m = block_means(g, res);
                for i in 0..m.len() {
                    let want = (sum[i] / n[i] as f64) as f32;
                    assert!(
                        (m[i] - want).abs() <= 1e-6,
                        "{res:?} cell {i}: {} vs {want}",
                        m[i]
                    );
                }
            }
            // Any box of cells, from either storage, is the same part of the whole.
            let ranges = [0, 1, 2].map(|a| axis_ranges(fine[a], res[a]));
            let (lo, hi) = ([1.min(res[0] - 1), 0, res[2] / 2], [res[0], 2, res[2] + 5]);
            let whole = block_means(&dense, res);
            for g in [&dense, &sparse] {
                let part = block_means_box(g, &ranges, lo, hi);
                let mut i = 0;
                for z in lo[2]..res[2] {
                    for y in lo[1]..hi[1].min(res[1]) {
                        for x in lo[0]..res[0] {
                            assert_eq!(part[i], whole[(z * res[1] + y) * res[0] + x]);
                            i += 1;
                        }
                    }
                }
                assert_eq!(i, part.len());
            }
            // Equal resolution is the grid itself.
            if res == fine {
                assert_eq!(block_means(&dense, res), data);
            }
        }
    }

    /// The boxes hold every non-zero voxel, are tight (each face touches one) and come from
    /// dense and sparse storage alike.
    #[test]
    fn nonzero_boxes_bound_the_density() {
        let fine = [21, 9, 17];
        let mut data = vec![0.0f32; fine.iter().product()];
        for (i, v) in data.iter_mut().enumerate() {
            if i % 97 == 3 || i % 89 == 5 {
                *v = 0.5;
            }
        }
        let dense = DensityGrid::new(fine, data.clone()).unwrap();
        let sparse =
            DensityGrid::from_bricks(crate::brick::from_dense(fine, &data, [3, 0, 5]).unwrap());
        for g in [&dense, &sparse] {
            let boxes = nonzero_boxes(g);
            let inside = |v: [usize; 3]| {
                boxes
                    .iter()
                    .any(|(l, h)| (0..3).all(|a| l[a] <= v[a] && v[a] <= h[a]))
            };
            for (i, &v) in data.iter().enumerate() {
                let p = [
                    i % fine[0],
                    (i / fine[0]) % fine[1],
                    i / (fine[0] * fine[1]),
                ];
                if v > 0.0 {
                    assert!(inside(p), "{p:?}");
                }
            }
            for (l, h) in &boxes {
                assert!((0..3).all(|a| h[a] - l[a] < 8));
                let at = |v: [usize; 3]| data[(v[2] * fine[1] + v[1]) * fine[0] + v[0]];
                let mut hit = [[false; 2]; 3];
                for z in l[2]..=h[2] {
                    for y in l[1]..=h[1] {
                        for x in l[0]..=h[0] {
                            if at([x, y, z]) > 0.0 {
                                for (a, c) in [x, y, z].into_iter().enumerate() {
                                    hit[a][0] |= c == l[a];
                                    hit[a][1] |= c == h[a];
                                }
                            }
                        }
                    }
                }
                assert!(
                    hit.iter().flatten().all(|&b| b),
                    "box {l:?}..{h:?} not tight"
                );
            }
        }
        assert!(nonzero_boxes(&DensityGrid::new(fine, vec![0.0; data.len()]).unwrap()).is_empty());
    }
}
