//! Scalar density grids: dense (one float per voxel, x fastest, then y, then z) or sparse
//! ([`crate::brick`]: 8³ bricks, absent where the cloud is not). Every estimator reads either
//! through [`DensityGrid::get`]; one that needs the whole box in one array (the GPU uploads
//! today) asks for [`DensityGrid::dense`], which a sparse grid answers with a copy checked
//! against the memory budget.

use std::borrow::Cow;
use std::sync::Arc;

use crate::brick::{Bricks, Content};
use crate::error::FieldError;

/// Largest number of voxels of a dense grid (2^31): beyond this a grid is almost surely a
/// corrupt header, and it would not fit a GPU storage binding either. Sparse grids
/// ([`crate::brick`]) may span larger boxes.
pub const MAX_VOXELS: usize = 1 << 31;

/// A dense grid of non-negative, finite densities. Values sit at cell centres
/// (see the crate docs for the lookup convention).
#[derive(Debug, Clone, PartialEq)]
pub struct DensityGrid {
    res: [usize; 3],
    storage: Storage,
}

/// Shared by clones: a grid given to several volumes (another density scale or box, the
/// Python module's scenes over one numpy array) is held once.
#[derive(Debug, Clone, PartialEq)]
enum Storage {
    // Arc<Vec>, not Arc<[f32]>: a Vec moves in without a copy.
    Dense(Arc<Vec<f32>>),
    Sparse(Arc<Bricks>),
}

/// Summary statistics of a grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridStats {
    pub min: f32,
    pub max: f32,
    pub mean: f64,
    /// Fraction of voxels with a value > 0.
    pub nonzero_fraction: f64,
}

/// Checks a resolution read from a header or a scene: every axis ≥ 1 and the total voxel count
/// below [`MAX_VOXELS`].
pub fn check_resolution(res: [i64; 3], field: &str) -> Result<[usize; 3], FieldError> {
    for (axis, &r) in ["x", "y", "z"].iter().zip(res.iter()) {
        if r < 1 {
            return Err(FieldError::new(
                format!("{field}.{axis}"),
                format!("resolution must be at least 1, got {r}"),
            ));
        }
    }
    let total = res.iter().try_fold(1i64, |acc, &r| acc.checked_mul(r));
    match total {
        Some(n) if (n as u128) <= MAX_VOXELS as u128 => {
            Ok([res[0] as usize, res[1] as usize, res[2] as usize])
        }
        _ => Err(FieldError::new(
            field,
            format!(
                "{}×{}×{} voxels is more than the supported {MAX_VOXELS}",
                res[0], res[1], res[2]
            ),
        )),
    }
}

impl DensityGrid {
    /// Builds a grid, rejecting a wrong data length and NaN, infinite or negative voxels.
    pub fn new(res: [usize; 3], data: Vec<f32>) -> Result<Self, FieldError> {
        check_resolution(res.map(|r| r as i64), "resolution")?;
        let n = res[0] * res[1] * res[2];
        if data.len() != n {
            return Err(FieldError::new(
                "data",
                format!(
                    "expected {n} values for {}×{}×{}, found {}",
                    res[0],
                    res[1],
                    res[2],
                    data.len()
                ),
            ));
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite() || *v < 0.0) {
            let x = i % res[0];
            let y = (i / res[0]) % res[1];
            let z = i / (res[0] * res[1]);
            return Err(FieldError::new(
                format!("voxel[{x},{y},{z}]"),
                format!("density must be finite and non-negative, found {}", data[i]),
            ));
        }
        Ok(Self {
            res,
            storage: Storage::Dense(Arc::new(data)),
        })
    }

    /// A sparse grid (validated when its builder finished).
    pub fn from_bricks(bricks: Bricks) -> Self {
        Self {
            res: bricks.res(),
            storage: Storage::Sparse(Arc::new(bricks)),
        }
    }

    /// A grid filled with one value.
    pub fn constant(res: [usize; 3], value: f32) -> Result<Self, FieldError> {
        let n = check_resolution(res.map(|r| r as i64), "resolution")?
            .iter()
            .product();
        let what = format!("a {}×{}×{} grid", res[0], res[1], res[2]);
        Self::new(res, crate::memory::filled(n, value, "resolution", &what)?)
    }

    pub fn res(&self) -> [usize; 3] {
        self.res
    }

    /// The values, x fastest, when the grid is stored densely.
    pub fn as_dense(&self) -> Option<&[f32]> {
        match &self.storage {
            Storage::Dense(d) => Some(&d[..]),
            Storage::Sparse(_) => None,
        }
    }

    /// The sparse storage, when the grid has one.
    pub fn as_bricks(&self) -> Option<&Bricks> {
        match &self.storage {
            Storage::Dense(_) => None,
            Storage::Sparse(b) => Some(b),
        }
    }

    /// The values of the whole box, x fastest: borrowed from a dense grid, copied from a sparse
    /// one (checked against the memory budget; the error names field `volume`).
    pub fn dense(&self) -> Result<Cow<'_, [f32]>, FieldError> {
        match &self.storage {
            Storage::Dense(d) => Ok(Cow::Borrowed(&d[..])),
            Storage::Sparse(b) => b.to_dense("volume").map(Cow::Owned),
        }
    }

    /// Calls `f` with every row of x values in order (y, then z), stopping at its first error:
    /// how writers stream a grid without a dense copy.
    pub fn try_for_each_row<E>(&self, mut f: impl FnMut(&[f32]) -> Result<(), E>) -> Result<(), E> {
        let [nx, ny, nz] = self.res;
        match &self.storage {
            Storage::Dense(d) => d.chunks(nx).try_for_each(f),
            Storage::Sparse(b) => {
                let mut row = vec![0.0f32; nx];
                for z in 0..nz {
                    for y in 0..ny {
                        for (x, v) in row.iter_mut().enumerate() {
                            *v = b.get(x, y, z);
                        }
                        f(&row)?;
                    }
                }
                Ok(())
            }
        }
    }

    /// Copies the z-plane `z` (x fastest, `nx × ny` values) into `out`: a slice copy from a
    /// dense grid, the bricks crossing the plane from a sparse one (absent bricks give 0).
    /// How consumers that work plane by plane read a grid without densifying it.
    pub fn plane(&self, z: usize, out: &mut [f32]) {
        let [nx, ny, _] = self.res;
        assert_eq!(out.len(), nx * ny, "plane buffer of nx × ny values");
        match &self.storage {
            Storage::Dense(d) => out.copy_from_slice(&d[z * nx * ny..(z + 1) * nx * ny]),
            Storage::Sparse(_) => {
                out.fill(0.0);
                self.plane_into_zeroed(z, out);
            }
        }
    }

    /// [`DensityGrid::plane`] into a buffer that is already all zero: only non-zero bricks are
    /// written (absent ones are skipped, so the untouched part of a large, mostly empty plane
    /// costs nothing). Returns a bound of the cells written, inclusive x and y ranges (None:
    /// the plane is zero); the values outside it are zero.
    pub fn plane_into_zeroed(&self, z: usize, out: &mut [f32]) -> Option<([usize; 2], [usize; 2])> {
        let [nx, ny, _] = self.res;
        assert_eq!(out.len(), nx * ny, "plane buffer of nx × ny values");
        match &self.storage {
            Storage::Dense(_) => {
                self.plane(z, out);
                Some(([0, nx - 1], [0, ny - 1]))
            }
            Storage::Sparse(b) => {
                let mut bound: Option<([usize; 2], [usize; 2])> = None;
                b.visit_range([0, 0, z], [nx - 1, ny - 1, z], |v| {
                    let content = v.content;
                    if matches!(content, crate::brick::Content::Constant(c) if c == 0.0) {
                        return;
                    }
                    for y in v.lo[1]..v.hi[1] {
                        let row = &mut out[y * nx + v.lo[0]..y * nx + v.hi[0]];
                        match content {
                            crate::brick::Content::Constant(c) => row.fill(c),
                            crate::brick::Content::Stored(s) => {
                                let at = v.local(v.lo[0], y, z);
                                row.copy_from_slice(&s[at..at + row.len()]);
                            }
                        }
                    }
                    let (x, y) = ([v.lo[0], v.hi[0] - 1], [v.lo[1], v.hi[1] - 1]);
                    bound = Some(match bound {
                        None => (x, y),
                        Some((bx, by)) => (
                            [bx[0].min(x[0]), bx[1].max(x[1])],
                            [by[0].min(y[0]), by[1].max(y[1])],
                        ),
                    });
                });
                bound
            }
        }
    }

    /// Bytes the grid's values occupy.
    pub fn bytes(&self) -> usize {
        match &self.storage {
            Storage::Dense(d) => 4 * d.len(),
            Storage::Sparse(b) => b.bytes(),
        }
    }

    /// Feeds the grid's layout and values to `h` (a cache key of the content).
    pub fn hash_into(&self, mut h: impl FnMut(&[u8])) {
        match &self.storage {
            Storage::Dense(d) => {
                for v in d.iter() {
                    h(&v.to_le_bytes());
                }
            }
            Storage::Sparse(b) => {
                h(b"sparse");
                b.hash_into(h);
            }
        }
    }

    /// Index of voxel (x, y, z) in the dense layout.
    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.res[1] + y) * self.res[0] + x
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize, z: usize) -> f32 {
        match &self.storage {
            Storage::Dense(d) => d[self.index(x, y, z)],
            Storage::Sparse(b) => b.get(x, y, z),
        }
    }

    /// The eight voxels `(x[i], y[j], z[k])` in the order i + 2j + 4k (trilinear interpolation's
    /// corners); each pair is a voxel and itself or its successor (`x[1] - x[0]` ∈ {0, 1}).
    #[inline]
    pub fn corners(&self, x: [usize; 2], y: [usize; 2], z: [usize; 2]) -> [f32; 8] {
        debug_assert!(
            [x, y, z].iter().all(|p| p[1] == p[0] || p[1] == p[0] + 1),
            "corners {x:?} {y:?} {z:?}"
        );
        match &self.storage {
            Storage::Dense(d) => {
                // One base index and three strides (the corners are 0 or 1 voxel apart per
                // axis): the index arithmetic of a trilinear lookup, the path tracer's most
                // frequent operation, done once instead of eight times.
                let base = self.index(x[0], y[0], z[0]);
                let dx = x[1] - x[0];
                let dy = (y[1] - y[0]) * self.res[0];
                let dz = (z[1] - z[0]) * self.res[0] * self.res[1];
                let row = |o: usize| [d[base + o], d[base + o + dx]];
                let [c0, c1] = row(0);
                let [c2, c3] = row(dy);
                let [c4, c5] = row(dz);
                let [c6, c7] = row(dy + dz);
                [c0, c1, c2, c3, c4, c5, c6, c7]
            }
            Storage::Sparse(b) => b.corners(x, y, z),
        }
    }

    /// Largest value over voxels `lo..=hi` (inclusive, per axis, inside the box).
    pub fn max_in(&self, lo: [usize; 3], hi: [usize; 3]) -> f32 {
        match &self.storage {
            Storage::Dense(d) => {
                let mut m = 0.0f32;
                for z in lo[2]..=hi[2] {
                    for y in lo[1]..=hi[1] {
                        let row = self.index(0, y, z);
                        for &v in &d[row + lo[0]..=row + hi[0]] {
                            m = m.max(v);
                        }
                    }
                }
                m
            }
            Storage::Sparse(b) => b.max_in(lo, hi),
        }
    }

    pub fn stats(&self) -> GridStats {
        let mut min = f32::INFINITY;
        let mut max = 0.0f32;
        let mut sum = 0.0f64;
        let mut nonzero = 0usize;
        match &self.storage {
            Storage::Dense(d) => {
                for &v in d.iter() {
                    min = min.min(v);
                    max = max.max(v);
                    sum += v as f64;
                    nonzero += (v > 0.0) as usize;
                }
            }
            Storage::Sparse(b) => b.visit(|v| {
                let mut add = |x: f32, n: usize| {
                    min = min.min(x);
                    max = max.max(x);
                    sum += x as f64 * n as f64;
                    nonzero += if x > 0.0 { n } else { 0 };
                };
                match v.content {
                    Content::Constant(c) => add(c, v.count()),
                    Content::Stored(s) => {
                        for z in v.lo[2]..v.hi[2] {
                            for y in v.lo[1]..v.hi[1] {
                                let l = v.local(v.lo[0], y, z);
                                for &x in &s[l..l + v.hi[0] - v.lo[0]] {
                                    add(x, 1);
                                }
                            }
                        }
                    }
                }
            }),
        }
        let n = self.res.iter().map(|&r| r as f64).product::<f64>();
        GridStats {
            min,
            max,
            mean: sum / n,
            nonzero_fraction: nonzero as f64 / n,
        }
    }

    /// Largest sum of voxel values along a line of voxels parallel to each axis, in voxel units
    /// (multiply by the cell size and the density scale to get an optical depth).
    pub fn max_column_sums(&self) -> [f64; 3] {
        if let Storage::Sparse(b) = &self.storage {
            return sparse_column_sums(b);
        }
        let [nx, ny, nz] = self.res;
        let mut best = [0.0f64; 3];
        // x columns
        for z in 0..nz {
            for y in 0..ny {
                let s: f64 = (0..nx).map(|x| self.get(x, y, z) as f64).sum();
                best[0] = best[0].max(s);
            }
        }
        for z in 0..nz {
            for x in 0..nx {
                let s: f64 = (0..ny).map(|y| self.get(x, y, z) as f64).sum();
                best[1] = best[1].max(s);
            }
        }
        for y in 0..ny {
            for x in 0..nx {
                let s: f64 = (0..nz).map(|z| self.get(x, y, z) as f64).sum();
                best[2] = best[2].max(s);
            }
        }
        best
    }
}

/// [`DensityGrid::max_column_sums`] brick by brick: a constant brick adds its value × its
/// length to each column through it, an absent one nothing.
fn sparse_column_sums(b: &Bricks) -> [f64; 3] {
    let [nx, ny, nz] = b.res();
    // Column sums per axis, indexed by the other two coordinates. Their size grows with the
    // box's faces (87 MB for a 1999×1349×2449 box), not its volume.
    let mut sx = vec![0.0f64; ny * nz];
    let mut sy = vec![0.0f64; nx * nz];
    let mut sz = vec![0.0f64; nx * ny];
    b.visit(|v| {
        let [x0, y0, z0] = v.lo;
        let [x1, y1, z1] = v.hi;
        match v.content {
            Content::Constant(c) => {
                if c == 0.0 {
                    return;
                }
                let c = c as f64;
                for z in z0..z1 {
                    for y in y0..y1 {
                        sx[z * ny + y] += c * (x1 - x0) as f64;
                    }
                    for x in x0..x1 {
                        sy[z * nx + x] += c * (y1 - y0) as f64;
                    }
                }
                for y in y0..y1 {
                    for x in x0..x1 {
                        sz[y * nx + x] += c * (z1 - z0) as f64;
                    }
                }
            }
            Content::Stored(s) => {
                for z in z0..z1 {
                    for y in y0..y1 {
                        for x in x0..x1 {
                            let c = s[v.local(x, y, z)] as f64;
                            sx[z * ny + y] += c;
                            sy[z * nx + x] += c;
                            sz[y * nx + x] += c;
                        }
                    }
                }
            }
        }
    });
    let max = |v: &[f64]| v.iter().cloned().fold(0.0, f64::max);
    [max(&sx), max(&sy), max(&sz)]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_data() {
        assert!(DensityGrid::new([2, 2, 2], vec![0.0; 7]).is_err());
        let mut d = vec![1.0; 8];
        d[5] = f32::NAN;
        let e = DensityGrid::new([2, 2, 2], d).unwrap_err();
        assert_eq!(e.field, "voxel[1,0,1]");
        let e = DensityGrid::new([2, 2, 2], vec![-1.0; 8]).unwrap_err();
        assert!(e.msg.contains("non-negative"));
        assert!(DensityGrid::new([0, 2, 2], vec![]).is_err());
        assert!(check_resolution([1 << 20, 1 << 20, 1], "r").is_err());
        assert!(check_resolution([-3, 2, 2], "r").is_err());
    }

    #[test]
    fn stats_and_columns() {
        let g = DensityGrid::new([2, 1, 2], vec![0.0, 1.0, 2.0, 3.0]).unwrap();
        let s = g.stats();
        assert_eq!((s.min, s.max), (0.0, 3.0));
        assert!((s.mean - 1.5).abs() < 1e-12);
        assert!((s.nonzero_fraction - 0.75).abs() < 1e-12);
        assert_eq!(g.max_column_sums(), [5.0, 3.0, 4.0]);
    }

    #[test]
    fn sparse_and_dense_agree() {
        let res = [19, 10, 23];
        let mut s = 5u32;
        let data: Vec<f32> = (0..res.iter().product::<usize>())
            .map(|i| {
                s = s.wrapping_mul(1664525).wrapping_add(1013904223);
                // Noise in part of the box, a constant slab, zeros elsewhere.
                match i % (19 * 10) {
                    0..=60 => (s >> 8) as f32 / (1 << 24) as f32,
                    61..=130 => 0.75,
                    _ => 0.0,
                }
            })
            .collect();
        let d = DensityGrid::new(res, data.clone()).unwrap();
        let b = DensityGrid::from_bricks(crate::brick::from_dense(res, &data, [5, 2, 7]).unwrap());
        assert!(b.as_bricks().is_some() && b.as_dense().is_none());
        let (sd, sb) = (d.stats(), b.stats());
        assert_eq!((sd.min, sd.max), (sb.min, sb.max));
        assert!((sd.mean - sb.mean).abs() < 1e-9 && sd.nonzero_fraction == sb.nonzero_fraction);
        let (cd, cb) = (d.max_column_sums(), b.max_column_sums());
        for a in 0..3 {
            // Sums of the same values in another order: equal to f64 round-off.
            assert!((cd[a] - cb[a]).abs() < 1e-9 * cd[a], "{cd:?} {cb:?}");
        }
        assert_eq!(
            d.max_in([1, 2, 3], [17, 9, 20]),
            b.max_in([1, 2, 3], [17, 9, 20])
        );
        assert_eq!(b.dense().unwrap().as_ref(), data.as_slice());
        // Planes from the shifted bricks (constant slabs, stored noise, absent bricks) are the
        // dense grid's planes, value for value.
        let (mut pd, mut pb) = (vec![0.0; 19 * 10], vec![-1.0; 19 * 10]);
        for z in 0..res[2] {
            d.plane(z, &mut pd);
            b.plane(z, &mut pb);
            assert_eq!(pd, pb, "plane {z}");
            assert_eq!(pd.as_slice(), &data[z * 190..(z + 1) * 190]);
            // Into a zeroed buffer: the same values, every non-zero one inside the bound.
            let mut pz = vec![0.0; 19 * 10];
            let bound = b.plane_into_zeroed(z, &mut pz);
            assert_eq!(pz, pd, "plane {z} into zeros");
            for (i, &v) in pd.iter().enumerate() {
                let (x, y) = (i % 19, i / 19);
                if v != 0.0 {
                    let (bx, by) = bound.expect("a bound around the non-zero values");
                    assert!((bx[0]..=bx[1]).contains(&x) && (by[0]..=by[1]).contains(&y));
                }
            }
        }
    }
}
