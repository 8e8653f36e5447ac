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
//! Every volume is a pool whose first 512 entries are zeros, never written. Two layouts:
//! - *full*, for light grids whose whole box fits: the voxels follow, x fastest (entry
//!   512 + the dense index) — the plain dense layout, with no lookup;
//! - *sparse*: `index` holds each brick's slot (x fastest over ⌈res / 8⌉ bricks), 0 for an
//!   absent brick, slot `s` at entries `s × 512 ..`, voxels x fastest within it, so a lookup in
//!   an absent brick reads the zeros of slot 0 with no branch; `slots[s]` is the brick of slot
//!   `s`. The GPU gets `index` and `slots` as one u32 array, `slots` from word `index.len()`.
//!
//! The kernels that write the pools run over the entries from 512 on. A full layout never
//! changes, so a density sequence can replace its values; a sparse one is rebuilt within the
//! pools' capacity.

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
    /// Entries the GPU pools were made for (≥ `density.len()` while it is held).
    capacity: usize,
    /// Entries in use (512 + the voxels of the stored bricks or the whole grid).
    len: usize,
}

/// Bricks per axis for a light grid of `res` voxels.
pub fn brick_res(res: [usize; 3]) -> [usize; 3] {
    res.map(|r| r.div_ceil(BRICK))
}

/// The light voxel at the corner of brick `b` (x fastest over `bres` bricks).
fn brick_origin(b: usize, bres: [usize; 3]) -> [usize; 3] {
    [
        b % bres[0] * BRICK,
        (b / bres[0]) % bres[1] * BRICK,
        b / (bres[0] * bres[1]) * BRICK,
    ]
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
        let whole = res.iter().product::<usize>() <= 1 << 26;
        Self::build_in(grid, boxes, res, radius, full, whole)
    }

    /// [`Self::build`], the block means computed for the whole light grid at once (`whole`) or
    /// brick by brick.
    fn build_in(
        grid: &DensityGrid,
        boxes: &[([usize; 3], [usize; 3])],
        res: [usize; 3],
        radius: usize,
        full: bool,
        whole: bool,
    ) -> Self {
        let fine = grid.res();
        let (active, occupied) = active_bricks(boxes, fine, res, radius);
        let mut map = Self::layout(res, &active, full);
        let bres = map.bres;
        // The bricks to fill: (brick, first pool entry) — in the full layout the brick's
        // voxels are scattered over rows of the dense grid.
        let todo: Vec<usize> = (0..active.len()).filter(|&b| occupied[b]).collect();
        let brick_lo = |b: usize| brick_origin(b, bres);
        // A light grid of up to 2^26 voxels (256 MB) is computed whole, plane by plane
        // (`block_means`: fast, a sparse grid read by its non-zero bricks); a larger one brick
        // by brick, only where there is density.
        let dense = whole.then(|| nimbus_scene::downsample::block_means(grid, res));
        if full && let Some(d) = &dense {
            map.density[BRICK_VOXELS..].copy_from_slice(d);
            return map;
        }
        let ranges = [0, 1, 2].map(|a| axis_ranges(fine[a], res[a]));
        let values: Vec<(usize, Vec<f32>)> = todo
            .par_iter()
            .map(|&b| {
                let lo = brick_lo(b);
                let hi: [usize; 3] = std::array::from_fn(|a| (lo[a] + BRICK).min(res[a]));
                let vals = match &dense {
                    Some(d) => {
                        let mut v = Vec::with_capacity(BRICK_VOXELS);
                        for z in lo[2]..hi[2] {
                            for y in lo[1]..hi[1] {
                                let row = (z * res[1] + y) * res[0];
                                v.extend_from_slice(&d[row + lo[0]..row + hi[0]]);
                            }
                        }
                        v
                    }
                    None => block_means_box(grid, &ranges, lo, hi),
                };
                (b, vals)
            })
            .collect();
        for (b, vals) in values {
            let lo = brick_lo(b);
            let hi: [usize; 3] = std::array::from_fn(|a| (lo[a] + BRICK).min(res[a]));
            let mut i = 0;
            for z in lo[2]..hi[2] {
                for y in lo[1]..hi[1] {
                    let at = map.pool_index([lo[0], y, z]);
                    let n = hi[0] - lo[0];
                    map.density[at..at + n].copy_from_slice(&vals[i..i + n]);
                    i += n;
                }
            }
        }
        map
    }

    /// The light map of a work density given densely at `res` (its own resolution: tests,
    /// density sequences).
    pub fn from_dense(res: [usize; 3], data: &[f32], radius: usize, full: bool) -> Self {
        let grid = DensityGrid::new(res, data.to_vec()).expect("work density of its resolution");
        let boxes = nimbus_scene::downsample::nonzero_boxes(&grid);
        Self::build(&grid, &boxes, res, radius, full)
    }

    /// The layout: every voxel (`full`) or slots for the active bricks, with a zero work
    /// density.
    fn layout(res: [usize; 3], active: &[bool], full: bool) -> Self {
        let bres = brick_res(res);
        let (mut index, mut slots) = (Vec::new(), Vec::new());
        let len = if full {
            BRICK_VOXELS + res.iter().product::<usize>()
        } else {
            index = vec![0u32; active.len()];
            slots.push(u32::MAX);
            for (b, &a) in active.iter().enumerate() {
                if a {
                    index[b] = slots.len() as u32;
                    slots.push(b as u32);
                }
            }
            slots.len() * BRICK_VOXELS
        };
        Self {
            res,
            bres,
            index,
            slots,
            density: vec![0.0; len],
            full,
            capacity: len,
            len,
        }
    }

    /// The same map, its pools sized for `capacity` entries (at least its own).
    pub fn with_capacity(mut self, capacity: usize) -> Self {
        self.capacity = capacity.max(self.len);
        self
    }

    /// Entries each pool holds (a density sequence's later frames may use fewer).
    pub fn pool_len(&self) -> usize {
        self.capacity
    }

    /// Entries in use: 512 (the zeros) + the stored voxels.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no voxel is stored (an empty sparse grid).
    pub fn is_empty(&self) -> bool {
        self.len == BRICK_VOXELS
    }

    /// Stored voxels, the zeros excluded: what the writing kernels run over.
    pub fn light_voxels(&self) -> u32 {
        (self.len - BRICK_VOXELS) as u32
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

    /// Bricks stored (every brick in the full layout).
    pub fn stored_bricks(&self) -> usize {
        if self.full {
            self.bres.iter().product()
        } else {
            self.slots.len() - 1
        }
    }

    /// The brick index and the slots' bricks, as the GPU reads them (one unused word in the
    /// full layout).
    pub fn gpu_words(&self) -> Vec<u32> {
        if self.full {
            return vec![0];
        }
        let mut w = self.index.clone();
        w.extend(&self.slots);
        w
    }

    /// Words of [`Self::gpu_words`].
    pub fn words(&self) -> usize {
        if self.full {
            1
        } else {
            self.index.len() + self.slots.len()
        }
    }

    /// Pool entry of light voxel `v` (among the zeros when its brick is absent).
    pub fn pool_index(&self, v: [usize; 3]) -> usize {
        if self.full {
            return BRICK_VOXELS + (v[2] * self.res[1] + v[1]) * self.res[0] + v[0];
        }
        let b = v.map(|c| c / BRICK);
        let s = self.index[(b[2] * self.bres[1] + b[1]) * self.bres[0] + b[0]] as usize;
        s * BRICK_VOXELS + ((v[2] % BRICK) * BRICK + v[1] % BRICK) * BRICK + v[0] % BRICK
    }

    /// The light voxel of pool entry `i` (slot ≥ 1; `None` past the grid's edge or in slot 0).
    pub fn voxel_of(&self, i: usize) -> Option<[usize; 3]> {
        if self.full {
            let j = i.checked_sub(BRICK_VOXELS)?;
            let [nx, ny, nz] = self.res;
            return (j < nx * ny * nz).then_some([j % nx, (j / nx) % ny, j / (nx * ny)]);
        }
        let s = i / BRICK_VOXELS;
        if s == 0 || s >= self.slots.len() {
            return None;
        }
        let o = brick_origin(self.slots[s] as usize, self.bres);
        let l = i % BRICK_VOXELS;
        let v = [
            o[0] + l % BRICK,
            o[1] + (l / BRICK) % BRICK,
            o[2] + l / (BRICK * BRICK),
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

    /// Per stored brick with density, the bounding box (inclusive light voxels) of its
    /// non-zero values.
    pub fn nonzero_boxes(&self) -> Vec<([usize; 3], [usize; 3])> {
        let bricks: Vec<usize> = if self.full {
            (0..self.bres.iter().product()).collect()
        } else {
            self.slots[1..].iter().map(|&b| b as usize).collect()
        };
        bricks
            .into_iter()
            .filter_map(|b| {
                let lo = brick_origin(b, self.bres);
                let hi: [usize; 3] = std::array::from_fn(|a| (lo[a] + BRICK).min(self.res[a]));
                let mut bx = None;
                for z in lo[2]..hi[2] {
                    for y in lo[1]..hi[1] {
                        for x in lo[0]..hi[0] {
                            if self.density[self.pool_index([x, y, z])] > 0.0 {
                                nimbus_scene::downsample::grow_box(&mut bx, [x, y, z]);
                            }
                        }
                    }
                }
                bx
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
    /// gives, bit for bit (computed whole or brick by brick), at the grid's resolution and
    /// coarser, from dense and sparse grids; the sparse one stores only bricks near density,
    /// and every light voxel within the radius of a non-zero one has a slot.
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
                for (full, whole) in [(false, false), (false, true), (true, false), (true, true)] {
                    let m = LightMap::build_in(g, &boxes, res, 2, full, whole);
                    assert_eq!(m.to_dense(&m.density), want, "{res:?} full {full}");
                    let total = brick_res(res).iter().product::<usize>();
                    let voxels = res.iter().product::<usize>();
                    if full {
                        assert_eq!(
                            (m.stored_bricks(), m.light_voxels()),
                            (total, voxels as u32)
                        );
                    } else {
                        let n = m.stored_bricks();
                        assert!(n < total / 2, "{n} of {total}");
                        assert_eq!(m.light_voxels() as usize, n * BRICK_VOXELS);
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
