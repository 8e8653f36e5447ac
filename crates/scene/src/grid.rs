//! Dense scalar density grids (one float per voxel, x fastest, then y, then z).

use crate::error::FieldError;

/// Largest number of voxels accepted (2^31): beyond this a grid is almost surely a corrupt header,
/// and it would not fit a GPU storage binding either.
pub const MAX_VOXELS: usize = 1 << 31;

/// A dense grid of non-negative, finite densities. Values sit at cell centres
/// (see the crate docs for the lookup convention).
#[derive(Debug, Clone, PartialEq)]
pub struct DensityGrid {
    res: [usize; 3],
    data: Vec<f32>,
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
        Ok(Self { res, data })
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

    pub fn data(&self) -> &[f32] {
        &self.data
    }

    #[inline]
    pub fn index(&self, x: usize, y: usize, z: usize) -> usize {
        (z * self.res[1] + y) * self.res[0] + x
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize, z: usize) -> f32 {
        self.data[self.index(x, y, z)]
    }

    pub fn stats(&self) -> GridStats {
        let mut min = f32::INFINITY;
        let mut max = 0.0f32;
        let mut sum = 0.0f64;
        let mut nonzero = 0usize;
        for &v in &self.data {
            min = min.min(v);
            max = max.max(v);
            sum += v as f64;
            nonzero += (v > 0.0) as usize;
        }
        let n = self.data.len() as f64;
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
}
