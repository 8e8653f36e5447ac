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
            // Equal resolution is the grid itself.
            if res == fine {
                assert_eq!(block_means(&dense, res), data);
            }
        }
    }
}
