//! Sparse brick storage for density grids: memory that grows with the cloud, not its box.
//!
//! The index box of a grid is cut into 8³-voxel bricks on a lattice shifted by `offset`
//! (0..8 per axis), chosen so that OpenVDB and NanoVDB leaves — 8³ voxels whose origins are
//! multiples of 8 — map one to one onto bricks, and their tiles onto whole bricks. Each brick is
//! - **absent**: every voxel 0 (nothing stored: 4 bytes of index);
//! - **constant**: one value (an OpenVDB tile);
//! - **stored**: 512 floats in the pool, x fastest, then y, then z (as the dense layout).
//!
//! A lookup costs one index read more than a dense grid. The box may be far larger than a
//! dense grid could be (a 1999×1349×2449 file of three spheres is 6.6 G voxels, 13 M bricks:
//! 52 MB of index, the pool holding only the spheres' surfaces); every allocation is checked
//! against the memory budget ([`crate::memory`]) before it is made.

use crate::error::FieldError;
use crate::memory;

/// Grids of more voxels than this (256 MiB as dense f32) are generated as sparse 8³ bricks, and
/// read as bricks from `.vol` files: memory then grows with the cloud, not with its box. Smaller
/// ones stay dense (a dense lookup is the cheaper one for the path tracer; the values are the
/// same either way).
pub const SPARSE_ABOVE_VOXELS: usize = 1 << 26;

/// Voxels along a brick's edge.
pub const DIM: usize = 8;
/// Voxels in a brick.
pub const VOXELS: usize = DIM * DIM * DIM;
/// Index flag: the low bits index the constants.
const CONST: u32 = 1 << 31;
/// An absent brick: the constant 0 (`consts[0]`).
const ABSENT: u32 = CONST;
/// Most voxels along one axis of a sparse grid (2^24: 16.7 M).
pub const MAX_AXIS: usize = 1 << 24;
/// Most bricks in a grid: the index of a stored brick and of a constant fit 31 bits.
pub const MAX_BRICKS: usize = 1 << 31;

/// A brick's content as [`Bricks::visit`] passes it.
#[derive(Debug, Clone, Copy)]
pub enum Content<'a> {
    /// Every voxel of the brick has this value (0 for an absent brick).
    Constant(f32),
    /// The brick's 512 values, x fastest.
    Stored(&'a [f32]),
}

/// One brick seen by [`Bricks::visit`]: its content and the part of the grid's index box it
/// covers, `lo..hi` (exclusive) per axis; `origin` is the grid index of the brick's voxel
/// (0, 0, 0), which may lie before the box (negative) when the lattice is shifted.
#[derive(Debug, Clone, Copy)]
pub struct BrickView<'a> {
    pub content: Content<'a>,
    pub lo: [usize; 3],
    pub hi: [usize; 3],
    pub origin: [i64; 3],
}

impl BrickView<'_> {
    /// Voxels of the box inside this brick.
    pub fn count(&self) -> usize {
        (0..3).map(|a| self.hi[a] - self.lo[a]).product()
    }

    /// Offset of grid voxel (x, y, z) (inside `lo..hi`) within the brick's 512 values.
    #[inline]
    pub fn local(&self, x: usize, y: usize, z: usize) -> usize {
        let l = |v: usize, a: usize| (v as i64 - self.origin[a]) as usize;
        (l(z, 2) * DIM + l(y, 1)) * DIM + l(x, 0)
    }
}

/// A sparse grid of 8³ bricks (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Bricks {
    res: [usize; 3],
    offset: [usize; 3],
    bres: [usize; 3],
    index: Vec<u32>,
    consts: Vec<f32>,
    pool: Vec<f32>,
}

/// Checks the resolution of a sparse grid: every axis in 1..=[`MAX_AXIS`] and at most
/// [`MAX_BRICKS`] bricks (the index itself is checked against the memory budget when built).
pub fn check_sparse_resolution(res: [i64; 3], field: &str) -> Result<[usize; 3], FieldError> {
    for (axis, &r) in ["x", "y", "z"].iter().zip(res.iter()) {
        if r < 1 || r as u128 > MAX_AXIS as u128 {
            return Err(FieldError::new(
                format!("{field}.{axis}"),
                format!("resolution must be between 1 and {MAX_AXIS}, got {r}"),
            ));
        }
    }
    let bricks: u128 = res
        .iter()
        .map(|&r| (r as u128).div_ceil(DIM as u128) + 1)
        .product();
    if bricks > MAX_BRICKS as u128 {
        return Err(FieldError::new(
            field,
            format!(
                "{}×{}×{} voxels need more than the supported {MAX_BRICKS} bricks of {DIM}³",
                res[0], res[1], res[2]
            ),
        ));
    }
    Ok(res.map(|r| r as usize))
}

impl Bricks {
    pub fn res(&self) -> [usize; 3] {
        self.res
    }

    /// Bricks per axis.
    pub fn brick_res(&self) -> [usize; 3] {
        self.bres
    }

    /// Shift of the brick lattice: voxel (x, y, z) lies in brick ((x, y, z) + offset) / 8.
    pub fn offset(&self) -> [usize; 3] {
        self.offset
    }

    /// (stored, constant, absent) brick counts.
    pub fn counts(&self) -> (usize, usize, usize) {
        let absent = self.index.iter().filter(|&&e| e == ABSENT).count();
        let stored = self.pool.len() / VOXELS;
        (stored, self.index.len() - stored - absent, absent)
    }

    /// Bytes held: index, constants and pool.
    pub fn bytes(&self) -> usize {
        4 * (self.index.len() + self.consts.len() + self.pool.len())
    }

    /// The value of voxel (x, y, z), which must lie inside the box.
    #[inline]
    pub fn get(&self, x: usize, y: usize, z: usize) -> f32 {
        let (gx, gy, gz) = (x + self.offset[0], y + self.offset[1], z + self.offset[2]);
        let b = ((gz / DIM) * self.bres[1] + gy / DIM) * self.bres[0] + gx / DIM;
        let e = self.index[b];
        if e & CONST != 0 {
            self.consts[(e & !CONST) as usize]
        } else {
            self.pool[e as usize * VOXELS + ((gz % DIM) * DIM + gy % DIM) * DIM + gx % DIM]
        }
    }

    /// The eight voxels `(x[i], y[j], z[k])` in the order i + 2j + 4k, as trilinear interpolation
    /// reads them: one index read when they share a brick (7 of 8 cells of a brick).
    #[inline]
    pub fn corners(&self, x: [usize; 2], y: [usize; 2], z: [usize; 2]) -> [f32; 8] {
        let o = self.offset;
        let (gx, gy, gz) = (
            [x[0] + o[0], x[1] + o[0]],
            [y[0] + o[1], y[1] + o[1]],
            [z[0] + o[2], z[1] + o[2]],
        );
        if gx[0] / DIM == gx[1] / DIM && gy[0] / DIM == gy[1] / DIM && gz[0] / DIM == gz[1] / DIM {
            let b = ((gz[0] / DIM) * self.bres[1] + gy[0] / DIM) * self.bres[0] + gx[0] / DIM;
            let e = self.index[b];
            if e & CONST != 0 {
                return [self.consts[(e & !CONST) as usize]; 8];
            }
            let p = &self.pool[e as usize * VOXELS..(e as usize + 1) * VOXELS];
            let at = |i: usize, j: usize, k: usize| {
                p[((gz[k] % DIM) * DIM + gy[j] % DIM) * DIM + gx[i] % DIM]
            };
            return std::array::from_fn(|n| at(n & 1, (n >> 1) & 1, n >> 2));
        }
        std::array::from_fn(|n| self.get(x[n & 1], y[(n >> 1) & 1], z[n >> 2]))
    }

    /// Calls `f` for every brick that overlaps the box cells `lo..=hi` (inclusive, clamped to
    /// the box), with the overlap as the view's range.
    pub fn visit_range(&self, lo: [usize; 3], hi: [usize; 3], mut f: impl FnMut(BrickView<'_>)) {
        let hi: [usize; 3] = std::array::from_fn(|a| hi[a].min(self.res[a] - 1));
        if (0..3).any(|a| lo[a] > hi[a]) {
            return;
        }
        let b0: [usize; 3] = std::array::from_fn(|a| (lo[a] + self.offset[a]) / DIM);
        let b1: [usize; 3] = std::array::from_fn(|a| (hi[a] + self.offset[a]) / DIM);
        for bz in b0[2]..=b1[2] {
            for by in b0[1]..=b1[1] {
                for bx in b0[0]..=b1[0] {
                    let bc = [bx, by, bz];
                    let origin: [i64; 3] =
                        std::array::from_fn(|a| (bc[a] * DIM) as i64 - self.offset[a] as i64);
                    let vlo: [usize; 3] =
                        std::array::from_fn(|a| (origin[a].max(0) as usize).max(lo[a]));
                    let vhi: [usize; 3] =
                        std::array::from_fn(|a| ((origin[a] + DIM as i64) as usize).min(hi[a] + 1));
                    let e = self.index[(bz * self.bres[1] + by) * self.bres[0] + bx];
                    let content = if e & CONST != 0 {
                        Content::Constant(self.consts[(e & !CONST) as usize])
                    } else {
                        let s = e as usize * VOXELS;
                        Content::Stored(&self.pool[s..s + VOXELS])
                    };
                    f(BrickView {
                        content,
                        lo: vlo,
                        hi: vhi,
                        origin,
                    });
                }
            }
        }
    }

    /// Calls `f` for every brick, with the part of the box it covers.
    pub fn visit(&self, f: impl FnMut(BrickView<'_>)) {
        self.visit_range([0; 3], self.res.map(|r| r - 1), f)
    }

    /// Largest value in the box cells `lo..=hi` (inclusive).
    pub fn max_in(&self, lo: [usize; 3], hi: [usize; 3]) -> f32 {
        let mut m = 0.0f32;
        self.visit_range(lo, hi, |v| match v.content {
            Content::Constant(c) => m = m.max(c),
            Content::Stored(s) => {
                for z in v.lo[2]..v.hi[2] {
                    for y in v.lo[1]..v.hi[1] {
                        let row = v.local(v.lo[0], y, z);
                        for &x in &s[row..row + (v.hi[0] - v.lo[0])] {
                            m = m.max(x);
                        }
                    }
                }
            }
        });
        m
    }

    /// The dense copy (x fastest), checked against the memory budget; `field` labels the error.
    pub fn to_dense(&self, field: &str) -> Result<Vec<f32>, FieldError> {
        let [nx, ny, nz] = self.res;
        let what = format!(
            "the dense copy of a sparse {nx}×{ny}×{nz} grid (an estimator that needs the whole box)"
        );
        let mut data = memory::filled(nx * ny * nz, 0.0f32, field, &what)?;
        self.visit(|v| {
            for z in v.lo[2]..v.hi[2] {
                for y in v.lo[1]..v.hi[1] {
                    let row = (z * ny + y) * nx;
                    let dst = &mut data[row + v.lo[0]..row + v.hi[0]];
                    match v.content {
                        Content::Constant(c) => dst.fill(c),
                        Content::Stored(s) => {
                            let l = v.local(v.lo[0], y, z);
                            dst.copy_from_slice(&s[l..l + dst.len()]);
                        }
                    }
                }
            }
        });
        Ok(data)
    }

    /// Feeds the layout and every value to `h` (a cache key of the content).
    pub fn hash_into(&self, mut h: impl FnMut(&[u8])) {
        for v in self.res.iter().chain(&self.offset) {
            h(&(*v as u64).to_le_bytes());
        }
        h(bytemuck::cast_slice(&self.index));
        h(bytemuck::cast_slice(&self.consts));
        h(bytemuck::cast_slice(&self.pool));
    }
}

/// Fills a [`Bricks`] brick by brick.
#[derive(Debug)]
pub struct BrickBuilder {
    b: Bricks,
}

impl BrickBuilder {
    /// An empty grid of `res` voxels on a lattice shifted by `offset` (each < 8), with room for
    /// `stored` stored bricks; the index and the pool are checked against the memory budget
    /// (`field` and `what` label the error).
    pub fn new(
        res: [usize; 3],
        offset: [usize; 3],
        stored: usize,
        field: &str,
        what: &str,
    ) -> Result<Self, FieldError> {
        check_sparse_resolution(res.map(|r| r as i64), field)?;
        let offset = offset.map(|o| o % DIM);
        let bres: [usize; 3] = std::array::from_fn(|a| (res[a] + offset[a]).div_ceil(DIM));
        let n = bres.iter().product::<usize>();
        let index_bytes = n as u128 * 4;
        let pool_bytes = stored as u128 * (VOXELS as u128) * 4;
        memory::check(index_bytes + pool_bytes, field, what)?;
        let index = memory::filled(n, ABSENT, field, what)?;
        let mut pool = Vec::new();
        pool.try_reserve_exact(stored * VOXELS).map_err(|_| {
            FieldError::new(
                field,
                format!(
                    "{what} needs {}, which this machine could not allocate now",
                    memory::human(pool_bytes)
                ),
            )
        })?;
        Ok(Self {
            b: Bricks {
                res,
                offset,
                bres,
                index,
                consts: vec![0.0],
                pool,
            },
        })
    }

    /// Bricks per axis.
    pub fn brick_res(&self) -> [usize; 3] {
        self.b.bres
    }

    /// The lattice shift.
    pub fn offset(&self) -> [usize; 3] {
        self.b.offset
    }

    fn slot(&self, bc: [usize; 3]) -> Result<usize, FieldError> {
        let r = self.b.bres;
        if (0..3).any(|a| bc[a] >= r[a]) {
            return Err(FieldError::new(
                "volume",
                format!("brick {bc:?} lies outside the {r:?} bricks of the grid"),
            ));
        }
        Ok((bc[2] * r[1] + bc[1]) * r[0] + bc[0])
    }

    /// Makes brick `bc` the constant `value` (absent for 0), replacing what it held (a stored
    /// brick's pool slot is left unused).
    pub fn set_constant(&mut self, bc: [usize; 3], value: f32) -> Result<(), FieldError> {
        let s = self.slot(bc)?;
        self.b.index[s] = if value == 0.0 {
            ABSENT
        } else {
            match self.b.consts.last() {
                Some(&c) if c == value && self.b.consts.len() > 1 => {
                    CONST | (self.b.consts.len() - 1) as u32
                }
                _ => {
                    self.b.consts.push(value);
                    CONST | (self.b.consts.len() - 1) as u32
                }
            }
        };
        Ok(())
    }

    /// The 512 values of brick `bc` (x fastest), storing it first if it was absent or constant
    /// (filled with its constant). Grows the pool beyond the room reserved if needed, checked
    /// against the memory budget.
    pub fn stored_mut(&mut self, bc: [usize; 3]) -> Result<&mut [f32], FieldError> {
        let s = self.slot(bc)?;
        let e = self.b.index[s];
        let start = if e & CONST != 0 {
            let fill = self.b.consts[(e & !CONST) as usize];
            let start = self.b.pool.len();
            if self.b.pool.capacity() < start + VOXELS {
                let bytes = (start + VOXELS) as u128 * 4;
                memory::check(bytes, "volume", "the bricks of a sparse grid")?;
                self.b.pool.try_reserve(VOXELS).map_err(|_| {
                    FieldError::new(
                        "volume",
                        format!(
                            "the bricks of a sparse grid need {}, which this machine could not allocate now",
                            memory::human(bytes)
                        ),
                    )
                })?;
            }
            self.b.pool.resize(start + VOXELS, fill);
            self.b.index[s] = (start / VOXELS) as u32;
            start
        } else {
            e as usize * VOXELS
        };
        Ok(&mut self.b.pool[start..start + VOXELS])
    }

    /// The finished grid: every value finite and non-negative (else an error naming the
    /// voxel), stored bricks whose values are all equal turned into constants, and the pool
    /// compacted.
    pub fn finish(mut self) -> Result<Bricks, FieldError> {
        let b = &mut self.b;
        for (i, &v) in b.consts.iter().enumerate() {
            if !v.is_finite() || v < 0.0 {
                let s = b.index.iter().position(|&e| e == CONST | i as u32);
                let at = s.map(|s| self_voxel(b, s, 0)).unwrap_or([0; 3]);
                return Err(bad_voxel(at, v));
            }
        }
        // Constant stored bricks become constants; the others move down to fill the gaps, in
        // pool order (bricks were stored in whatever order they were first written), so a
        // move never overwrites a brick not yet moved.
        let mut owner = vec![u32::MAX; b.pool.len() / VOXELS];
        for (s, &e) in b.index.iter().enumerate() {
            if e & CONST == 0 {
                owner[e as usize] = s as u32;
            }
        }
        let mut next = 0usize;
        for (p, &s) in owner.iter().enumerate() {
            if s == u32::MAX {
                continue; // replaced by a constant after it was stored
            }
            let s = s as usize;
            let src = p * VOXELS;
            let vals = &b.pool[src..src + VOXELS];
            if let Some(i) = vals.iter().position(|v| !v.is_finite() || *v < 0.0) {
                let v = vals[i];
                return Err(bad_voxel(self_voxel(b, s, i), v));
            }
            let first = vals[0];
            if vals.iter().all(|&v| v == first) {
                b.index[s] = if first == 0.0 {
                    ABSENT
                } else {
                    b.consts.push(first);
                    CONST | (b.consts.len() - 1) as u32
                };
                continue;
            }
            if src != next * VOXELS {
                b.pool.copy_within(src..src + VOXELS, next * VOXELS);
            }
            b.index[s] = next as u32;
            next += 1;
        }
        b.pool.truncate(next * VOXELS);
        b.pool.shrink_to_fit();
        Ok(self.b)
    }
}

/// Grid index of value `i` of the brick in index slot `s` (for error messages; may lie in the
/// part of an edge brick outside the box).
fn self_voxel(b: &Bricks, s: usize, i: usize) -> [i64; 3] {
    let bc = [
        s % b.bres[0],
        (s / b.bres[0]) % b.bres[1],
        s / (b.bres[0] * b.bres[1]),
    ];
    let l = [i % DIM, (i / DIM) % DIM, i / (DIM * DIM)];
    std::array::from_fn(|a| (bc[a] * DIM + l[a]) as i64 - b.offset[a] as i64)
}

fn bad_voxel(at: [i64; 3], v: f32) -> FieldError {
    FieldError::new(
        format!("voxel[{},{},{}]", at[0], at[1], at[2]),
        format!("density must be finite and non-negative, found {v}"),
    )
}

/// Bricks from a dense grid (x fastest): absent where a brick is all zero, constant where all
/// equal; for tests and for converting small dense grids.
pub fn from_dense(res: [usize; 3], data: &[f32], offset: [usize; 3]) -> Result<Bricks, FieldError> {
    let mut bb = BrickBuilder::new(res, offset, 0, "volume", "a sparse copy of a dense grid")?;
    let off = bb.offset();
    for z in 0..res[2] {
        for y in 0..res[1] {
            for x in 0..res[0] {
                let v = data[(z * res[1] + y) * res[0] + x];
                if v == 0.0 {
                    continue;
                }
                let g = [x + off[0], y + off[1], z + off[2]];
                let brick = bb.stored_mut(g.map(|c| c / DIM))?;
                brick[((g[2] % DIM) * DIM + g[1] % DIM) * DIM + g[0] % DIM] = v;
            }
        }
    }
    bb.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(n: usize, seed: u32) -> Vec<f32> {
        let mut s = seed;
        (0..n)
            .map(|_| {
                s = s.wrapping_mul(1664525).wrapping_add(1013904223);
                if s >> 30 == 0 {
                    (s >> 8) as f32 / (1 << 24) as f32
                } else {
                    0.0
                }
            })
            .collect()
    }

    #[test]
    fn bricks_read_back_the_dense_grid_at_every_offset() {
        let res = [13, 9, 17];
        let n = res.iter().product();
        let mut data = noise(n, 7);
        // A region of one value: whole bricks of it become constants.
        for z in 0..res[2] {
            for y in 0..res[1] {
                for x in 0..res[0] {
                    if z >= 8 {
                        data[(z * res[1] + y) * res[0] + x] = if x < 8 { 0.5 } else { 0.0 };
                    }
                }
            }
        }
        for off in [[0, 0, 0], [3, 7, 1], [7, 7, 7]] {
            let b = from_dense(res, &data, off).unwrap();
            for z in 0..res[2] {
                for y in 0..res[1] {
                    for x in 0..res[0] {
                        assert_eq!(b.get(x, y, z), data[(z * res[1] + y) * res[0] + x]);
                    }
                }
            }
            assert_eq!(b.to_dense("t").unwrap(), data, "offset {off:?}");
            let (stored, constant, absent) = b.counts();
            let [bx, by, bz] = b.brick_res();
            assert_eq!(stored + constant + absent, bx * by * bz);
            if off == [0, 0, 0] {
                // z in 8..16: the brick x, y < 8 is all 0.5 (constant); those with x ≥ 8 are
                // absent. Edge bricks that stick out of the box hold 0 outside it: stored.
                assert!(constant == 1 && absent >= 2, "{:?}", b.counts());
            }
            // max over a range equals the dense maximum there.
            let (lo, hi) = ([2, 1, 3], [10, 7, 12]);
            let mut m = 0.0f32;
            for z in lo[2]..=hi[2] {
                for y in lo[1]..=hi[1] {
                    for x in lo[0]..=hi[0] {
                        m = m.max(data[(z * res[1] + y) * res[0] + x]);
                    }
                }
            }
            assert_eq!(b.max_in(lo, hi), m);
        }
    }

    #[test]
    fn bad_values_and_sizes_are_refused() {
        let mut data = vec![0.0f32; 27];
        data[13] = f32::NAN;
        let e = from_dense([3, 3, 3], &data, [2, 0, 0]).unwrap_err();
        assert_eq!(e.field, "voxel[1,1,1]");
        data[13] = -1.0;
        assert!(from_dense([3, 3, 3], &data, [0; 3]).is_err());
        assert!(check_sparse_resolution([1 << 25, 1, 1], "r").is_err());
        assert!(check_sparse_resolution([0, 1, 1], "r").is_err());
        // 2^21 bricks per axis on two axes is beyond MAX_BRICKS.
        assert!(check_sparse_resolution([1 << 24, 1 << 24, 8], "r").is_err());
        assert!(check_sparse_resolution([1999, 1349, 2449], "r").is_ok());
    }

    #[test]
    fn the_pool_is_checked_against_the_budget_before_allocation() {
        // 2^40 stored bricks would be 2 PiB.
        let e =
            BrickBuilder::new([8, 8, 8], [0; 3], 1 << 40, "grid.bounds", "the bricks").unwrap_err();
        assert_eq!(e.field, "grid.bounds");
        assert!(e.msg.contains("memory budget"), "{e}");
    }
}
