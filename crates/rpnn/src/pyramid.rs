//! Gaussian-filtered density pyramid for the RPNN descriptor (Kallweit 2017 §4.2).
//!
//! Level i has a Gaussian prefilter of standard deviation σᵢ ≈ 2ⁱ voxels of the original grid:
//! level 0 is the grid blurred with σ = 1 voxel at full resolution; level i + 1 is level i
//! blurred with σ = √3 of its own voxels (variances add: 4ⁱ + 3·4ⁱ = 4ⁱ⁺¹) and then halved in
//! resolution by averaging pairs of cells (the pair average adds a little, ¼ cell², which the
//! "≈" absorbs). Every level covers the same world box with the cell-centred lookup convention;
//! outside the box the density is zero (the cloud is surrounded by empty space), so blurring
//! uses zero padding. The number of levels stops when a level is one cell on every axis.
//!
//! Values are the scaled density ρ = σ_t / σ̄, σ̄ the mean extinction of the non-zero voxels:
//! one unit of length is one mean free path (Kallweit §4.2).

use glam::DVec3;
use nimbus_scene::Volume;
use rayon::prelude::*;

/// One level: a dense grid over the volume's box.
#[derive(Debug, Clone, PartialEq)]
pub struct Level {
    pub res: [usize; 3],
    pub data: Vec<f32>,
    /// Gaussian standard deviation of this level's prefilter, in original voxels.
    pub sigma_voxels: f64,
}

/// The pyramid of one cloud.
#[derive(Debug, Clone)]
pub struct Pyramid {
    pub levels: Vec<Level>,
    pub aabb_min: DVec3,
    pub aabb_max: DVec3,
    /// σ̄: mean σ_t over non-zero voxels (world units⁻¹).
    pub mean_sigma: f64,
    /// Size of one original voxel (world units), smallest axis.
    pub voxel: f64,
}

/// Errors building a pyramid.
#[derive(Debug, thiserror::Error)]
pub enum PyramidError {
    #[error(
        "the cloud has no non-zero voxel (or a zero density scale): one mean free path is undefined"
    )]
    Empty,
    /// The pyramid does not fit the memory budget.
    #[error("{0}")]
    Memory(#[from] nimbus_scene::FieldError),
}

fn gauss_kernel(sigma: f64) -> Vec<f32> {
    let r = (3.0 * sigma).ceil() as i64;
    let w: Vec<f64> = (-r..=r)
        .map(|i| (-(i * i) as f64 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f64 = w.iter().sum();
    w.into_iter().map(|v| (v / s) as f32).collect()
}

/// Separable blur with zero padding along one axis.
fn blur_axis(data: &[f32], res: [usize; 3], axis: usize, k: &[f32]) -> Vec<f32> {
    let r = (k.len() / 2) as i64;
    let stride = [1, res[0], res[0] * res[1]][axis];
    let n = res[axis] as i64;
    (0..data.len())
        .into_par_iter()
        .map(|i| {
            let c = [i % res[0], (i / res[0]) % res[1], i / (res[0] * res[1])][axis] as i64;
            let mut acc = 0.0f32;
            for (j, w) in k.iter().enumerate() {
                let o = c + j as i64 - r;
                if o >= 0 && o < n {
                    acc += w * data[(i as i64 + (o - c) * stride as i64) as usize];
                }
            }
            acc
        })
        .collect()
}

fn blur(data: &[f32], res: [usize; 3], sigma: f64) -> Vec<f32> {
    let k = gauss_kernel(sigma);
    let a = blur_axis(data, res, 0, &k);
    let b = blur_axis(&a, res, 1, &k);
    drop(a);
    blur_axis(&b, res, 2, &k)
}

/// Halves the resolution (ceil) by averaging pairs of cells; an odd last cell pairs with zero
/// padding weighted by its share of the box.
fn downsample(data: &[f32], res: [usize; 3]) -> (Vec<f32>, [usize; 3]) {
    let nr = res.map(|r| r.div_ceil(2));
    let mut out = vec![0.0f32; nr[0] * nr[1] * nr[2]];
    // Each new cell spans two old cells on each axis (the box extent stays the same, so when
    // an axis has an odd count the new cells are 2·old·(n/(2⌈n/2⌉)) wide; we resample by
    // averaging the old cells overlapping each new cell with their overlap weights).
    let weights = |n: usize, m: usize| -> Vec<Vec<(usize, f32)>> {
        (0..m)
            .map(|j| {
                let a = j as f64 * n as f64 / m as f64;
                let b = (j + 1) as f64 * n as f64 / m as f64;
                let mut v = Vec::new();
                let mut i = a.floor() as usize;
                while (i as f64) < b && i < n {
                    let lo = (i as f64).max(a);
                    let hi = ((i + 1) as f64).min(b);
                    if hi > lo {
                        v.push((i, ((hi - lo) / (b - a)) as f32));
                    }
                    i += 1;
                }
                v
            })
            .collect()
    };
    let (wx, wy, wz) = (
        weights(res[0], nr[0]),
        weights(res[1], nr[1]),
        weights(res[2], nr[2]),
    );
    for z in 0..nr[2] {
        for y in 0..nr[1] {
            for x in 0..nr[0] {
                let mut acc = 0.0f32;
                for &(iz, az) in &wz[z] {
                    for &(iy, ay) in &wy[y] {
                        for &(ix, ax) in &wx[x] {
                            acc += az * ay * ax * data[(iz * res[1] + iy) * res[0] + ix];
                        }
                    }
                }
                out[(z * nr[1] + y) * nr[0] + x] = acc;
            }
        }
    }
    (out, nr)
}

impl Pyramid {
    /// The pyramid of a cloud; an empty cloud is an error (training records need a mean free
    /// path to normalise by).
    pub fn new(volume: &Volume) -> Result<Self, PyramidError> {
        let (sum, count) = Self::nonzero(volume);
        if count == 0 || volume.density_scale() <= 0.0 {
            return Err(PyramidError::Empty);
        }
        Self::build(volume, volume.density_scale() * sum / count as f64)
    }

    /// For rendering: like [`Pyramid::new`], but an empty cloud gets a unit normalisation
    /// instead of an error — a renderer never finds a collision in it, so no descriptor is
    /// ever taken, and the image is the sky (found by `nimbus stress`).
    pub fn for_rendering(volume: &Volume) -> Result<Self, PyramidError> {
        match Self::new(volume) {
            Err(PyramidError::Empty) => Self::build(volume, 1.0),
            other => other,
        }
    }

    fn nonzero(volume: &Volume) -> (f64, usize) {
        let s = volume.grid().stats();
        let n = volume.grid().res().iter().product::<usize>() as f64;
        (s.mean * n, (s.nonzero_fraction * n).round() as usize)
    }

    fn build(volume: &Volume, mean_sigma: f64) -> Result<Self, PyramidError> {
        let g = volume.grid();
        let [x, y, z] = g.res();
        // Peak: the scaled copy and two blur passes (3 grids of f32), then the levels
        // (≈ 1.15 grids in all, held with one pass of the next level's blur).
        nimbus_scene::memory::check(
            3 * (x * y * z) as u128 * 4,
            "volume",
            &format!("the RPNN density pyramid of a {x}×{y}×{z} grid"),
        )?;
        let scale = (volume.density_scale() / mean_sigma) as f32;
        let raw: Vec<f32> = g.dense()?.iter().map(|v| v * scale).collect();
        let first = blur(&raw, g.res(), 1.0);
        drop(raw);
        let mut levels = vec![Level {
            res: g.res(),
            data: first,
            sigma_voxels: 1.0,
        }];
        let mut sigma = 1.0;
        loop {
            let prev = levels.last().expect("level 0");
            if !(prev.res.iter().any(|&r| r > 1) && levels.len() < 16) {
                break;
            }
            let b = blur(&prev.data, prev.res, 3f64.sqrt());
            let (d, nr) = downsample(&b, prev.res);
            sigma *= 2.0;
            levels.push(Level {
                res: nr,
                data: d,
                sigma_voxels: sigma,
            });
        }
        let cell = volume.cell_size();
        Ok(Self {
            levels,
            aabb_min: volume.aabb().min,
            aabb_max: volume.aabb().max,
            mean_sigma,
            voxel: cell.min_element(),
        })
    }

    /// Pyramid level used by stencil level `k` (1-based): the stencil's point spacing is
    /// h = 0.5 · 2^(k−1) mean free paths = h / (σ̄ · voxel) voxels; prefiltering with a Gaussian
    /// of σ ≈ h/2 removes what the stencil cannot resolve, so we take the level with the largest
    /// σᵢ = 2ⁱ ≤ h/2 (level 0 when h/2 < 2), capped at the coarsest level.
    pub fn level_for(&self, k: u32) -> usize {
        let h_vox = 0.5 * 2f64.powi(k as i32 - 1) / (self.mean_sigma * self.voxel);
        let i = (h_vox / 2.0).log2().floor();
        if i.is_nan() || i < 0.0 {
            0
        } else {
            (i as usize).min(self.levels.len() - 1)
        }
    }

    /// ρ at world point p from level `i` (trilinear, clamp-to-edge inside the box, 0 outside).
    /// f32 arithmetic in the same order as `shaders/rpnn_descriptor.wgsl`.
    pub fn lookup(&self, i: usize, p: glam::Vec3) -> f32 {
        let (lo, hi) = (self.aabb_min.as_vec3(), self.aabb_max.as_vec3());
        if !(p.cmpge(lo).all() && p.cmple(hi).all()) {
            return 0.0;
        }
        let l = &self.levels[i];
        let resf = glam::DVec3::new(l.res[0] as f64, l.res[1] as f64, l.res[2] as f64);
        let u = (p - lo) / (hi - lo) * resf.as_vec3() - glam::Vec3::splat(0.5);
        let b = u.floor();
        let f = u - b;
        let hi = resf.as_vec3() - glam::Vec3::ONE;
        let i0 = b.clamp(glam::Vec3::ZERO, hi);
        let i1 = (b + glam::Vec3::ONE).clamp(glam::Vec3::ZERO, hi);
        let at = |x: f32, y: f32, z: f32| {
            l.data[((z as usize) * l.res[1] + y as usize) * l.res[0] + x as usize]
        };
        let mix = |a: f32, b: f32, t: f32| a * (1.0 - t) + b * t;
        let c00 = mix(at(i0.x, i0.y, i0.z), at(i1.x, i0.y, i0.z), f.x);
        let c10 = mix(at(i0.x, i1.y, i0.z), at(i1.x, i1.y, i0.z), f.x);
        let c01 = mix(at(i0.x, i0.y, i1.z), at(i1.x, i0.y, i1.z), f.x);
        let c11 = mix(at(i0.x, i1.y, i1.z), at(i1.x, i1.y, i1.z), f.x);
        mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z)
    }

    /// Total "mass" Σ ρ × cell volume of a level (world units³).
    pub fn mass(&self, i: usize) -> f64 {
        let l = &self.levels[i];
        let ext = self.aabb_max - self.aabb_min;
        let cell = ext.x * ext.y * ext.z / (l.res[0] * l.res[1] * l.res[2]) as f64;
        l.data.iter().map(|v| *v as f64).sum::<f64>() * cell
    }
}
