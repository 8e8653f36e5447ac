//! The light volumes' sparse layout: the work density, J, its flux directions and T_sun stored
//! per active 8³ brick of the light grid (CPU twin of `shaders/lib/light_bricks.wgsl`).
//!
//! Elek 2012 §4.3 upsamples the cache to J at every density voxel; the ray marcher reads J and
//! T_sun only where σ(x) > 0, and a trilinear lookup there touches only light voxels within
//! `near_radius` (1 or 2) of one that holds density (`mapper/light.rs`). So only bricks holding
//! such a voxel need storage: a cloud in a mostly empty box costs memory in proportion to the
//! cloud, not the box, and the light volumes can stay at the grid's resolution where a dense
//! J would not fit one storage binding.
//!
//! Layout: `index` holds each brick's slot (x fastest over ⌈res / 8⌉ bricks), 0 for an absent
//! brick; every volume is a pool of `slots × 512` values, slot `s` at `s × 512`, voxels x
//! fastest within it. Slot 0 is all zeros and never written, so a lookup in an absent brick
//! reads 0 with no branch. `slots[s]` is the brick of slot `s` (the kernels that write the
//! pools run over slots ≥ 1). The GPU gets `index` and `slots` as one u32 array, `slots`
//! starting at word `index.len()`.
//!
//! Two layouts: *full* — every brick has a slot (slot = brick + 1), for grids whose whole box
//! fits (the layout then never changes, so a density sequence can replace the values) — and
//! *sparse*, only the active bricks.

use nimbus_scene::DensityGrid;
use nimbus_scene::downsample::{axis_ranges, block_means_box, coarse_of};
use rayon::prelude::*;

/// Edge of a light brick, in light voxels.
pub const BRICK: usize = 8;
/// Light voxels per brick.
pub const BRICK_VOXELS: usize = BRICK * BRICK * BRICK;

/// The light grid's layout and the work density in it.
#[derive(Debug, Clone)]
pub struct LightMap {
    res: [usize; 3],
    bres: [usize; 3],
    index: Vec<u32>,
    slots: Vec<u32>,
    /// The work density (block means of the grid at the light resolution), one value per pool
    /// entry.
    pub density: Vec<f32>,
    full: bool,
    /// Slots the GPU pools were made for (≥ `slots.len()`).
    capacity: usize,
}

/// Bricks per axis for a light grid of `res` voxels.
pub fn brick_res(res: [usize; 3]) -> [usize; 3] {
    res.map(|r| r.div_ceil(BRICK))
}

/// Per brick of a light grid of `res` over a grid of `fine` voxels whose non-zero voxels lie in
/// `boxes` (inclusive fine indices, `nimbus_scene::downsample::nonzero_boxes`): whether it
/// holds a light voxel within `radius` of one with density (`true`: active), and whether it
/// holds one with density itself (`occupied`).
pub fn active_bricks(
    boxes: &[([usize; 3], [usize; 3])],
    fine: [usize; 3],
    res: [usize; 3],
    radius: usize,
) -> (Vec<bool>, Vec<bool>) {
    let b = brick_res(res);
    let n = b[0] * b[1] * b[2];
    let (mut active, mut occupied) = (vec![false; n], vec![false; n]);
    let mark = |lo: [usize; 3], hi: [usize; 3], m: &mut Vec<bool>| {
        for z in lo[2] / BRICK..=hi[2] / BRICK {
            for y in lo[1] / BRICK..=hi[1] / BRICK {
                for x in lo[0] / BRICK..=hi[0] / BRICK {
                    m[(z * b[1] + y) * b[0] + x] = true;
                }
            }
        }
    };
    for (l, h) in boxes {
        let lo: [usize; 3] = std::array::from_fn(|a| coarse_of(l[a], fine[a], res[a]));
        let hi: [usize; 3] = std::array::from_fn(|a| coarse_of(h[a], fine[a], res[a]));
        mark(lo, hi, &mut occupied);
        let dlo = lo.map(|v| v.saturating_sub(radius));
        let dhi: [usize; 3] = std::array::from_fn(|a| (hi[a] + radius).min(res[a] - 1));
        mark(dlo, dhi, &mut active);
    }
    (active, occupied)
}

impl LightMap {
    /// The light map of `grid` at `res` (each axis in 1..= the grid's): the active bricks of
    /// [`active_bricks`] (`boxes` from `nonzero_boxes(grid)`), or every brick when `full`, with
    /// the grid's block means in the bricks that hold density.
    pub fn build(
        grid: &DensityGrid,
        boxes: &[([usize; 3], [usize; 3])],
        res: [usize; 3],
        radius: usize,
        full: bool,
    ) -> Self {
        let fine = grid.res();
        let (active, occupied) = active_bricks(boxes, fine, res, radius);
        let mut map = Self::layout(res, &active, full);
        let ranges = [0, 1, 2].map(|a| axis_ranges(fine[a], res[a]));
        let bres = map.bres;
        let slots = &map.slots;
        map.density
            .par_chunks_mut(BRICK_VOXELS)
            .enumerate()
            .skip(1)
            .for_each(|(s, out)| {
                let b = slots[s] as usize;
                if !occupied[b] {
                    return;
                }
                let bc = [
                    b % bres[0],
                    (b / bres[0]) % bres[1],
                    b / (bres[0] * bres[1]),
                ];
                let lo = bc.map(|c| c * BRICK);
                let hi = lo.map(|c| c + BRICK);
                let vals = block_means_box(grid, &ranges, lo, hi);
                let n: [usize; 3] = std::array::from_fn(|a| hi[a].min(res[a]) - lo[a]);
                let mut i = 0;
                for z in 0..n[2] {
                    for y in 0..n[1] {
                        let row = (z * BRICK + y) * BRICK;
                        out[row..row + n[0]].copy_from_slice(&vals[i..i + n[0]]);
                        i += n[0];
                    }
                }
            });
        map
    }

    /// The light map of a work density given densely at `res` (its own resolution: tests,
    /// density sequences).
    pub fn from_dense(res: [usize; 3], data: &[f32], radius: usize, full: bool) -> Self {
        let grid = DensityGrid::new(res, data.to_vec()).expect("work density of its resolution");
        let boxes = nimbus_scene::downsample::nonzero_boxes(&grid);
        Self::build(&grid, &boxes, res, radius, full)
    }

    /// Slots for the active bricks (or all), with a zero work density.
    fn layout(res: [usize; 3], active: &[bool], full: bool) -> Self {
        let bres = brick_res(res);
        let mut index = vec![0u32; active.len()];
        let mut slots = vec![u32::MAX];
        for (b, &a) in active.iter().enumerate() {
            if a || full {
                index[b] = slots.len() as u32;
                slots.push(b as u32);
            }
        }
        let density = vec![0.0; slots.len() * BRICK_VOXELS];
        let capacity = slots.len();
        Self {
            res,
            bres,
            index,
            slots,
            capacity,
            density,
            full,
        }
    }

    /// The same map, its pools sized for `capacity` slots (at least its own).
    pub fn with_capacity(mut self, capacity: usize) -> Self {
        self.capacity = capacity.max(self.slots.len());
        self
    }

    /// Slots the pools hold (a density sequence's later frames may use fewer).
    pub fn slots_capacity(&self) -> usize {
        self.capacity
    }

    /// Voxels of the stored bricks, slot 0 excluded: what the writing kernels run over.
    pub fn light_voxels(&self) -> u32 {
        ((self.slots.len() - 1) * BRICK_VOXELS) as u32
    }

    /// Drops the work density (uploaded), keeping the layout.
    pub fn drop_values(&mut self) {
        self.density = Vec::new();
    }

    /// Light voxels per axis.
    pub fn res(&self) -> [usize; 3] {
        self.res
    }

    /// Whether every brick has a slot.
    pub fn is_full(&self) -> bool {
        self.full
    }

    /// Slots, the zero slot 0 included.
    pub fn slots(&self) -> usize {
        self.slots.len()
    }

    /// Values in each pool (`capacity × 512`).
    pub fn pool_len(&self) -> usize {
        self.capacity * BRICK_VOXELS
    }

    /// The brick index and the slots' bricks, as the GPU reads them.
    pub fn gpu_words(&self) -> Vec<u32> {
        let mut w = self.index.clone();
        w.extend(&self.slots);
        w
    }

    /// Words of [`Self::gpu_words`].
    pub fn words(&self) -> usize {
        self.index.len() + self.slots.len()
    }

    /// Pool entry of light voxel `v` (in slot 0 when its brick is absent).
    pub fn pool_index(&self, v: [usize; 3]) -> usize {
        let b = v.map(|c| c / BRICK);
        let s = self.index[(b[2] * self.bres[1] + b[1]) * self.bres[0] + b[0]] as usize;
        s * BRICK_VOXELS + ((v[2] % BRICK) * BRICK + v[1] % BRICK) * BRICK + v[0] % BRICK
    }

    /// The light voxel of pool entry `i` (slot ≥ 1; `None` past the grid's edge or in slot 0).
    pub fn voxel_of(&self, i: usize) -> Option<[usize; 3]> {
        let s = i / BRICK_VOXELS;
        if s == 0 || s >= self.slots.len() {
            return None;
        }
        let b = self.slots[s] as usize;
        let l = i % BRICK_VOXELS;
        let bc = [
            b % self.bres[0],
            (b / self.bres[0]) % self.bres[1],
            b / (self.bres[0] * self.bres[1]),
        ];
        let v = [
            bc[0] * BRICK + l % BRICK,
            bc[1] * BRICK + (l / BRICK) % BRICK,
            bc[2] * BRICK + l / (BRICK * BRICK),
        ];
        (0..3).all(|a| v[a] < self.res[a]).then_some(v)
    }

    /// A pool as a dense grid at the light resolution (x fastest; absent bricks give the
    /// default value).
    pub fn to_dense<T: Copy + Default>(&self, pool: &[T]) -> Vec<T> {
        let [nx, ny, nz] = self.res;
        let mut out = vec![T::default(); nx * ny * nz];
        for (i, o) in out.iter_mut().enumerate() {
            *o = pool[self.pool_index([i % nx, (i / nx) % ny, i / (nx * ny)])];
        }
        out
    }

    /// The largest work density.
    pub fn max(&self) -> f32 {
        self.density.iter().fold(0.0f32, |m, &v| m.max(v))
    }

    /// Per slot with density, the bounding box (inclusive light voxels) of its non-zero values.
    pub fn nonzero_boxes(&self) -> Vec<([usize; 3], [usize; 3])> {
        (1..self.slots.len())
            .filter_map(|s| {
                let mut b: Option<([usize; 3], [usize; 3])> = None;
                for l in 0..BRICK_VOXELS {
                    let i = s * BRICK_VOXELS + l;
                    if self.density[i] > 0.0 {
                        let v = self.voxel_of(i)?;
                        b = Some(match b {
                            None => (v, v),
                            Some((lo, hi)) => (
                                std::array::from_fn(|a| lo[a].min(v[a])),
                                std::array::from_fn(|a| hi[a].max(v[a])),
                            ),
                        });
                    }
                }
                b
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(res: [usize; 3]) -> Vec<f32> {
        (0..res.iter().product::<usize>())
            .map(|i| {
                let p = [i % res[0], (i / res[0]) % res[1], i / (res[0] * res[1])];
                // Two small blobs far apart in a mostly empty box.
                let near = |c: [usize; 3]| (0..3).all(|a| p[a].abs_diff(c[a]) <= 1);
                if near([2, 2, 2]) || near([res[0] - 3, res[1] - 2, res[2] - 4]) {
                    0.25 + (i % 7) as f32 * 0.1
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// Sparse and full layouts hold the block means `nimbus_scene::downsample::block_means`
    /// gives, bit for bit, at the grid's resolution and coarser, from dense and sparse grids;
    /// the sparse one stores only bricks near density, and every light voxel within the
    /// radius of a non-zero one has a slot.
    #[test]
    fn layouts_hold_the_block_means_where_they_are_read() {
        let fine = [45, 20, 39];
        let data = sample(fine);
        let dense = DensityGrid::new(fine, data.clone()).unwrap();
        let bricks = DensityGrid::from_bricks(
            nimbus_scene::brick::from_dense(fine, &data, [3, 0, 5]).unwrap(),
        );
        for res in [fine, [23, 10, 20], [17, 20, 13]] {
            let want = nimbus_scene::downsample::block_means(&dense, res);
            for g in [&dense, &bricks] {
                let boxes = nimbus_scene::downsample::nonzero_boxes(g);
                for full in [false, true] {
                    let m = LightMap::build(g, &boxes, res, 2, full);
                    assert_eq!(m.to_dense(&m.density), want, "{res:?} full {full}");
                    let total = brick_res(res).iter().product::<usize>();
                    if full {
                        assert_eq!(m.slots(), total + 1);
                    } else {
                        assert!(m.slots() - 1 < total / 2, "{} of {total}", m.slots() - 1);
                    }
                    // Every voxel within 2 of density is stored; pool entries map back.
                    for (i, _) in want.iter().enumerate().filter(|(_, v)| **v > 0.0) {
                        let v = [i % res[0], (i / res[0]) % res[1], i / (res[0] * res[1])];
                        for d in 0..125usize {
                            let o = [d % 5, (d / 5) % 5, d / 25];
                            let q: [i64; 3] =
                                std::array::from_fn(|a| v[a] as i64 + o[a] as i64 - 2);
                            if (0..3).any(|a| q[a] < 0 || q[a] >= res[a] as i64) {
                                continue;
                            }
                            let q = q.map(|c| c as usize);
                            let p = m.pool_index(q);
                            assert!(p >= BRICK_VOXELS, "{q:?} not stored");
                            assert_eq!(m.voxel_of(p), Some(q));
                        }
                    }
                    assert!(m.density[..BRICK_VOXELS].iter().all(|&v| v == 0.0));
                }
            }
        }
    }
}
