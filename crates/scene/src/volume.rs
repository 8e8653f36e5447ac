//! A density grid placed in the world: the Mitsuba 3 `gridvolume` convention.
//!
//! - Values sit at cell centres. A world point `p` maps to the continuous index
//!   `u = (p − aabb_min) / (aabb_max − aabb_min) × res − 0.5`.
//! - Trilinear interpolation with indices clamped to the edge (clamp-to-edge: the half-cell border
//!   inside the box repeats the edge values).
//! - The medium exists only inside the AABB: σ_t = 0 outside.
//! - σ_t(p) = `density_scale` × lookup(p).

use glam::DVec3;

use crate::error::FieldError;
use crate::grid::DensityGrid;

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Aabb {
    pub min: DVec3,
    pub max: DVec3,
}

impl Aabb {
    /// Builds a box, requiring finite corners and a positive extent on every axis.
    pub fn new(min: DVec3, max: DVec3) -> Result<Self, FieldError> {
        if !min.is_finite() || !max.is_finite() {
            return Err(FieldError::new("aabb", "corners must be finite"));
        }
        if !(max.cmpgt(min).all()) {
            return Err(FieldError::new(
                "aabb_max",
                format!("must exceed aabb_min on every axis ({max} vs {min})"),
            ));
        }
        Ok(Self { min, max })
    }

    pub fn extent(&self) -> DVec3 {
        self.max - self.min
    }

    pub fn center(&self) -> DVec3 {
        0.5 * (self.min + self.max)
    }

    pub fn contains(&self, p: DVec3) -> bool {
        p.cmpge(self.min).all() && p.cmple(self.max).all()
    }

    /// Parametric interval `[t0, t1]` (clipped to `t ≥ 0`) where the ray `o + t d` is inside the
    /// box, or `None`. Robust for axis-parallel rays (division by ±0 gives ±∞, and NaN from
    /// 0 × ∞ is discarded by `max`/`min`).
    pub fn intersect(&self, o: DVec3, d: DVec3) -> Option<(f64, f64)> {
        let mut t0 = 0.0f64;
        let mut t1 = f64::INFINITY;
        for i in 0..3 {
            if d[i] == 0.0 {
                // Parallel to this slab: inside it (faces included) or a miss.
                if o[i] < self.min[i] || o[i] > self.max[i] {
                    return None;
                }
                continue;
            }
            let inv = 1.0 / d[i];
            let a = (self.min[i] - o[i]) * inv;
            let b = (self.max[i] - o[i]) * inv;
            t0 = t0.max(a.min(b));
            t1 = t1.min(a.max(b));
        }
        (t1 >= t0 && t1 > 0.0 && t0.is_finite()).then_some((t0, t1))
    }
}

/// A density grid in world space with a density scale: σ_t(p) = scale × lookup(p).
#[derive(Debug, Clone)]
pub struct Volume {
    grid: DensityGrid,
    aabb: Aabb,
    density_scale: f64,
    /// res / extent, precomputed.
    to_index: DVec3,
}

impl Volume {
    pub fn new(grid: DensityGrid, aabb: Aabb, density_scale: f64) -> Result<Self, FieldError> {
        if !density_scale.is_finite() || density_scale < 0.0 {
            return Err(FieldError::new(
                "density_scale",
                format!("must be finite and ≥ 0, got {density_scale}"),
            ));
        }
        // σ_t = scale × density must stay within the 32-bit floats of the GPU estimators and the
        // images (an infinite majorant stalls or poisons every estimator).
        let vmax = grid.stats().max as f64;
        if density_scale * vmax > f32::MAX as f64 {
            return Err(FieldError::new(
                "density_scale",
                format!(
                    "{density_scale:e} × the largest voxel {vmax:e} = {:e} exceeds the 32-bit float range (3.4e38) of the estimators",
                    density_scale * vmax
                ),
            ));
        }
        let r = grid.res();
        let to_index = DVec3::new(r[0] as f64, r[1] as f64, r[2] as f64) / aabb.extent();
        Ok(Self {
            grid,
            aabb,
            density_scale,
            to_index,
        })
    }

    pub fn grid(&self) -> &DensityGrid {
        &self.grid
    }

    pub fn aabb(&self) -> &Aabb {
        &self.aabb
    }

    pub fn density_scale(&self) -> f64 {
        self.density_scale
    }

    /// World size of one voxel on each axis.
    pub fn cell_size(&self) -> DVec3 {
        self.to_index.recip()
    }

    /// Interpolated grid value (unscaled) at `p`; 0 outside the box.
    #[inline]
    pub fn lookup(&self, p: DVec3) -> f64 {
        if !self.aabb.contains(p) {
            return 0.0;
        }
        let u = (p - self.aabb.min) * self.to_index - DVec3::splat(0.5);
        let r = self.grid.res();
        let base = u.floor();
        let f = u - base;
        let clamp = |v: f64, n: usize| -> usize { v.clamp(0.0, (n - 1) as f64) as usize };
        let x0 = clamp(base.x, r[0]);
        let x1 = clamp(base.x + 1.0, r[0]);
        let y0 = clamp(base.y, r[1]);
        let y1 = clamp(base.y + 1.0, r[1]);
        let z0 = clamp(base.z, r[2]);
        let z1 = clamp(base.z + 1.0, r[2]);
        let c = self
            .grid
            .corners([x0, x1], [y0, y1], [z0, z1])
            .map(|v| v as f64);
        let c00 = c[0] * (1.0 - f.x) + c[1] * f.x;
        let c10 = c[2] * (1.0 - f.x) + c[3] * f.x;
        let c01 = c[4] * (1.0 - f.x) + c[5] * f.x;
        let c11 = c[6] * (1.0 - f.x) + c[7] * f.x;
        let c0 = c00 * (1.0 - f.y) + c10 * f.y;
        let c1 = c01 * (1.0 - f.y) + c11 * f.y;
        c0 * (1.0 - f.z) + c1 * f.z
    }

    /// Extinction coefficient σ_t at `p` (per world unit).
    #[inline]
    pub fn sigma_t(&self, p: DVec3) -> f64 {
        self.density_scale * self.lookup(p)
    }

    /// Largest σ_t anywhere in the volume.
    pub fn max_sigma_t(&self) -> f64 {
        self.density_scale * self.grid.stats().max as f64
    }

    /// Largest optical depth along a voxel column parallel to each axis.
    pub fn max_axis_optical_depth(&self) -> [f64; 3] {
        let cols = self.grid.max_column_sums();
        let cell = self.cell_size();
        [
            cols[0] * cell.x * self.density_scale,
            cols[1] * cell.y * self.density_scale,
            cols[2] * cell.z * self.density_scale,
        ]
    }
}

/// A coarse grid of upper bounds of σ_t (pbrt-v4's majorant grid): each cell stores the largest
/// σ_t that trilinear interpolation can produce inside it. Delta and ratio tracking step through it
/// with a 3D DDA so empty and thin regions are crossed with a small majorant.
#[derive(Debug, Clone)]
pub struct MajorantGrid {
    res: [usize; 3],
    values: Vec<f64>,
    aabb: Aabb,
    /// Cells per world unit along each axis (res / extent).
    cells_per_unit: [f64; 3],
}

impl MajorantGrid {
    /// Builds the majorant grid of `volume` with `res` cells per axis (each at least 1). A
    /// resolution of `[1, 1, 1]` is the single global majorant.
    pub fn new(volume: &Volume, res: [usize; 3]) -> Self {
        let res = res.map(|r| r.max(1));
        let g = volume.grid();
        let gr = g.res();
        let mut values = vec![0.0f64; res[0] * res[1] * res[2]];
        // For a coarse cell spanning continuous grid index range [a, b] (cell-centre convention),
        // trilinear lookups inside it read voxels floor(a − 0.5) ..= floor(b − 0.5) + 1, clamped.
        let range = |c: usize, n_coarse: usize, n_fine: usize| -> (usize, usize) {
            let a = c as f64 / n_coarse as f64 * n_fine as f64 - 0.5;
            let b = (c + 1) as f64 / n_coarse as f64 * n_fine as f64 - 0.5;
            let lo = (a.floor().max(0.0) as usize).min(n_fine - 1);
            let hi = ((b.floor() + 1.0).max(0.0) as usize).min(n_fine - 1);
            (lo, hi)
        };
        for cz in 0..res[2] {
            let (z0, z1) = range(cz, res[2], gr[2]);
            for cy in 0..res[1] {
                let (y0, y1) = range(cy, res[1], gr[1]);
                for cx in 0..res[0] {
                    let (x0, x1) = range(cx, res[0], gr[0]);
                    let m = g.max_in([x0, y0, z0], [x1, y1, z1]);
                    values[(cz * res[1] + cy) * res[0] + cx] = m as f64 * volume.density_scale();
                }
            }
        }
        let ext = volume.aabb().extent();
        Self {
            res,
            values,
            aabb: *volume.aabb(),
            cells_per_unit: std::array::from_fn(|a| res[a] as f64 / ext[a]),
        }
    }

    /// A majorant grid with about `block`-voxel blocks: `ceil(res / block)` cells per axis, at
    /// least `min(res, 16)` (small grids would otherwise get one or two cells whose majorant is
    /// the dense core's, and tracking through their thin fringes would take σ̄ · length tentative
    /// steps: minutes for very dense media), capped at 64 per axis.
    pub fn with_block(volume: &Volume, block: usize) -> Self {
        let r = volume.grid().res();
        let b = block.max(1);
        Self::new(volume, r.map(|n| n.div_ceil(b).max(n.min(16)).clamp(1, 64)))
    }

    pub fn res(&self) -> [usize; 3] {
        self.res
    }

    pub fn aabb(&self) -> &Aabb {
        &self.aabb
    }

    /// Cells per world unit along each axis.
    #[inline]
    pub fn cells_per_unit(&self) -> [f64; 3] {
        self.cells_per_unit
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize, z: usize) -> f64 {
        self.values[(z * self.res[1] + y) * self.res[0] + x]
    }

    pub fn max(&self) -> f64 {
        self.values.iter().cloned().fold(0.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vol(res: [usize; 3], data: Vec<f32>) -> Volume {
        Volume::new(
            DensityGrid::new(res, data).unwrap(),
            Aabb::new(DVec3::ZERO, DVec3::ONE).unwrap(),
            2.0,
        )
        .unwrap()
    }

    #[test]
    fn sigma_t_beyond_f32_is_refused() {
        let grid = DensityGrid::new([2, 1, 1], vec![1.0, 10.0]).unwrap();
        let b = Aabb::new(DVec3::ZERO, DVec3::ONE).unwrap();
        // 1e38 × 10 = 1e39 > f32::MAX ≈ 3.4e38; 1e37 × 10 fits.
        let e = Volume::new(grid.clone(), b, 1e38).unwrap_err();
        assert_eq!(e.field, "density_scale");
        assert!(e.msg.contains("1e39") && e.msg.contains("32-bit"), "{e}");
        assert!(Volume::new(grid, b, 1e37).is_ok());
    }

    #[test]
    fn lookup_follows_mitsuba_convention() {
        // Two voxels along x: centres at 0.25 and 0.75.
        let v = vol([2, 1, 1], vec![1.0, 3.0]);
        let at = |x: f64| v.lookup(DVec3::new(x, 0.5, 0.5));
        assert_eq!(at(0.1), 1.0); // clamp-to-edge border
        assert_eq!(at(0.25), 1.0);
        assert!((at(0.5) - 2.0).abs() < 1e-12);
        assert_eq!(at(0.75), 3.0);
        assert_eq!(at(0.99), 3.0);
        assert_eq!(at(1.01), 0.0); // outside the box
        assert!((v.sigma_t(DVec3::new(0.5, 0.5, 0.5)) - 4.0).abs() < 1e-12);
    }

    #[test]
    fn aabb_intersection() {
        let b = Aabb::new(DVec3::ZERO, DVec3::ONE).unwrap();
        let (t0, t1) = b.intersect(DVec3::new(-1.0, 0.5, 0.5), DVec3::X).unwrap();
        assert!((t0 - 1.0).abs() < 1e-12 && (t1 - 2.0).abs() < 1e-12);
        assert!(b.intersect(DVec3::new(-1.0, 2.0, 0.5), DVec3::X).is_none());
        assert!(b.intersect(DVec3::new(2.0, 0.5, 0.5), DVec3::X).is_none());
        let (t0, t1) = b.intersect(DVec3::splat(0.5), DVec3::Y).unwrap();
        assert!(t0 == 0.0 && (t1 - 0.5).abs() < 1e-12);
        // Origin on a face plane, travelling parallel to it.
        assert!(b.intersect(DVec3::new(-1.0, 0.0, 0.5), DVec3::X).is_some());
        assert!(Aabb::new(DVec3::ONE, DVec3::ZERO).is_err());
    }

    #[test]
    fn majorant_bounds_every_lookup() {
        let mut data = vec![0.0f32; 8 * 8 * 8];
        let mut s = 12345u32;
        for v in data.iter_mut() {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            *v = if s >> 30 == 0 {
                (s >> 8) as f32 / (1 << 24) as f32
            } else {
                0.0
            };
        }
        let v = vol([8, 8, 8], data);
        let m = MajorantGrid::new(&v, [3, 3, 3]);
        let mut s = 99u32;
        for _ in 0..20000 {
            let mut r = || {
                s = s.wrapping_mul(1664525).wrapping_add(1013904223);
                (s >> 8) as f64 / (1 << 24) as f64
            };
            let p = DVec3::new(r(), r(), r());
            let c = (p * 3.0).floor().clamp(DVec3::ZERO, DVec3::splat(2.0));
            let bound = m.get(c.x as usize, c.y as usize, c.z as usize);
            assert!(v.sigma_t(p) <= bound + 1e-12);
        }
        assert!((m.max() - v.max_sigma_t()).abs() < 1e-12);
    }
}
