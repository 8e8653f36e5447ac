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

/// Blurs `src` into `dst` along one line with kernel `k` and zero padding (the accumulation
/// order of every blur in this module: taps in kernel order).
#[inline]
fn blur_line(src: &[f32], k: &[f32], dst: &mut [f32]) {
    let r = (k.len() / 2) as i64;
    let n = src.len() as i64;
    for (c, out) in dst.iter_mut().enumerate() {
        let mut acc = 0.0f32;
        for (j, w) in k.iter().enumerate() {
            let o = c as i64 + j as i64 - r;
            if o >= 0 && o < n {
                acc += w * src[o as usize];
            }
        }
        *out = acc;
    }
}

/// Blurs one z-plane (`nx` × `ny`, x fastest) along x, then along y, in place.
fn blur_plane_xy(plane: &mut [f32], nx: usize, ny: usize, k: &[f32]) {
    plane.par_chunks_mut(nx).for_each(|row| {
        let src = row.to_vec();
        blur_line(&src, k, row);
    });
    let plane_ro: &[f32] = plane;
    let cols: Vec<Vec<f32>> = (0..nx)
        .into_par_iter()
        .map(|x| {
            let col: Vec<f32> = (0..ny).map(|y| plane_ro[y * nx + x]).collect();
            let mut out = vec![0.0f32; ny];
            blur_line(&col, k, &mut out);
            out
        })
        .collect();
    for (x, c) in cols.iter().enumerate() {
        for (y, v) in c.iter().enumerate() {
            plane[y * nx + x] = *v;
        }
    }
}

/// Gaussian blur (σ in voxels, zero padding) of a whole grid in place: x and y plane by plane,
/// then z with a sliding window of the r original planes already overwritten, so the extra
/// memory is a few planes instead of whole-grid copies.
fn blur_in_place(data: &mut [f32], res: [usize; 3], sigma: f64) {
    let k = gauss_kernel(sigma);
    let [nx, ny, nz] = res;
    let plane = nx * ny;
    for p in data.chunks_mut(plane) {
        blur_plane_xy(p, nx, ny, &k);
    }
    let r = k.len() / 2;
    let mut hist: std::collections::VecDeque<Vec<f32>> = std::collections::VecDeque::new();
    let mut new_plane = vec![0.0f32; plane];
    for z in 0..nz {
        {
            let (data_ro, hist) = (&*data, &hist);
            new_plane.par_iter_mut().enumerate().for_each(|(i, v)| {
                let mut acc = 0.0f32;
                for (j, w) in k.iter().enumerate() {
                    let zz = z as i64 + j as i64 - r as i64;
                    if zz < 0 || zz >= nz as i64 {
                        continue;
                    }
                    let zz = zz as usize;
                    let val = if zz < z {
                        hist[hist.len() - (z - zz)][i]
                    } else {
                        data_ro[zz * plane + i]
                    };
                    acc += w * val;
                }
                *v = acc;
            });
        }
        if r > 0 {
            if hist.len() == r {
                hist.pop_front();
            }
            hist.push_back(data[z * plane..(z + 1) * plane].to_vec());
        }
        data[z * plane..(z + 1) * plane].copy_from_slice(&new_plane);
    }
}

/// Overlap weights resampling `n` cells onto `m` cells over the same extent: for each new cell,
/// the old cells it overlaps and their shares.
fn down_weights(n: usize, m: usize) -> Vec<Vec<(usize, f32)>> {
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
}

/// The next pyramid level: `prev` blurred with σ voxels, then halved in resolution (ceil) by
/// averaging the old cells overlapping each new cell (an odd last cell pairs with zero
/// padding weighted by its share of the box). Computed plane by plane of the output from a
/// sliding window of x-y-blurred input planes: the extra memory is ≈ 2r + 3 input planes, not
/// copies of `prev`, and the arithmetic (operands and order) is the whole-grid blur followed
/// by the downsampling, so the values are the same to the bit.
fn next_level(prev: &[f32], res: [usize; 3], sigma: f64) -> (Vec<f32>, [usize; 3]) {
    let k = gauss_kernel(sigma);
    let r = k.len() / 2;
    let [nx, ny, nz] = res;
    let plane = nx * ny;
    let nr = res.map(|v| v.div_ceil(2));
    let (wx, wy, wz) = (
        down_weights(nx, nr[0]),
        down_weights(ny, nr[1]),
        down_weights(nz, nr[2]),
    );
    let mut out = vec![0.0f32; nr[0] * nr[1] * nr[2]];
    let mut xy: std::collections::BTreeMap<usize, Vec<f32>> = Default::default();
    let mut bz: std::collections::BTreeMap<usize, Vec<f32>> = Default::default();
    for (z2, out_plane) in out.chunks_mut(nr[0] * nr[1]).enumerate() {
        for &(iz, _) in &wz[z2] {
            if bz.contains_key(&iz) {
                continue;
            }
            let (lo, hi) = (iz.saturating_sub(r), (iz + r).min(nz - 1));
            xy.retain(|&z, _| z >= lo);
            for zz in lo..=hi {
                xy.entry(zz).or_insert_with(|| {
                    let mut p = prev[zz * plane..(zz + 1) * plane].to_vec();
                    blur_plane_xy(&mut p, nx, ny, &k);
                    p
                });
            }
            let taps: Vec<Option<&Vec<f32>>> = (0..k.len())
                .map(|j| {
                    let zz = iz as i64 + j as i64 - r as i64;
                    (zz >= 0 && zz < nz as i64).then(|| &xy[&(zz as usize)])
                })
                .collect();
            let mut b = vec![0.0f32; plane];
            b.par_iter_mut().enumerate().for_each(|(i, v)| {
                let mut acc = 0.0f32;
                for (w, t) in k.iter().zip(&taps) {
                    if let Some(t) = t {
                        acc += w * t[i];
                    }
                }
                *v = acc;
            });
            bz.retain(|&z, _| z + 2 >= iz);
            bz.insert(iz, b);
        }
        out_plane.par_iter_mut().enumerate().for_each(|(i, v)| {
            let (x2, y2) = (i % nr[0], i / nr[0]);
            let mut acc = 0.0f32;
            for &(iz, az) in &wz[z2] {
                let b = &bz[&iz];
                for &(iy, ay) in &wy[y2] {
                    for &(ix, ax) in &wx[x2] {
                        acc += az * ay * ax * b[iy * nx + ix];
                    }
                }
            }
            *v = acc;
        });
    }
    (out, nr)
}

/// Resolutions of every level of a pyramid over a grid of `res` (halved, ceil, until one cell
/// on every axis; at most 16 levels).
fn level_resolutions(res: [usize; 3]) -> Vec<[usize; 3]> {
    let mut v = vec![res];
    while v.len() < 16 && v.last().expect("level 0").iter().any(|&r| r > 1) {
        let l = *v.last().expect("level 0");
        v.push(l.map(|r| r.div_ceil(2)));
    }
    v
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
        // Peak: the finished levels (level 0 is the scaled copy, blurred in place) and the
        // sliding windows of the blurs (a few planes of level 0): no whole-grid temporaries.
        let resolutions = level_resolutions(g.res());
        let level_bytes: u128 = resolutions
            .iter()
            .map(|r| (r[0] * r[1] * r[2]) as u128 * 4)
            .sum();
        let window_bytes = 20 * (x * y) as u128 * 4;
        nimbus_scene::memory::check(
            level_bytes + window_bytes,
            "volume",
            &format!("the RPNN density pyramid of a {x}×{y}×{z} grid"),
        )?;
        let scale = (volume.density_scale() / mean_sigma) as f32;
        let mut first = g.dense()?.into_owned();
        first.iter_mut().for_each(|v| *v *= scale);
        blur_in_place(&mut first, g.res(), 1.0);
        let mut levels = vec![Level {
            res: g.res(),
            data: first,
            sigma_voxels: 1.0,
        }];
        let mut sigma = 1.0;
        for _ in 1..resolutions.len() {
            let prev = levels.last().expect("level 0");
            let (d, nr) = next_level(&prev.data, prev.res, 3f64.sqrt());
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

/// The whole-grid blur and downsampling this module used before the plane-by-plane build:
/// the reference the build must match to the bit.
#[cfg(test)]
mod whole_grid {
    use super::gauss_kernel;
    use rayon::prelude::*;

    /// Separable blur with zero padding along one axis.
    pub(super) fn blur_axis(data: &[f32], res: [usize; 3], axis: usize, k: &[f32]) -> Vec<f32> {
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

    pub(super) fn blur(data: &[f32], res: [usize; 3], sigma: f64) -> Vec<f32> {
        let k = gauss_kernel(sigma);
        let a = blur_axis(data, res, 0, &k);
        let b = blur_axis(&a, res, 1, &k);
        drop(a);
        blur_axis(&b, res, 2, &k)
    }

    /// Halves the resolution (ceil) by averaging pairs of cells; an odd last cell pairs with zero
    /// padding weighted by its share of the box.
    pub(super) fn downsample(data: &[f32], res: [usize; 3]) -> (Vec<f32>, [usize; 3]) {
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
}

#[cfg(test)]
mod build_tests {
    use super::*;

    /// Blur in place and the windowed next level equal the whole-grid operations bit for bit,
    /// on odd and even sizes (odd sizes use the zero-padded last cell).
    #[test]
    fn plane_by_plane_build_matches_the_whole_grid_bit_for_bit() {
        for res in [[9usize, 7, 11], [16, 8, 10], [1, 5, 3], [13, 1, 1]] {
            let n = res[0] * res[1] * res[2];
            let mut state = 12345u64;
            let data: Vec<f32> = (0..n)
                .map(|_| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    ((state >> 40) as f32 / (1u64 << 24) as f32) * 3.0
                })
                .collect();
            let want = whole_grid::blur(&data, res, 1.0);
            let mut got = data.clone();
            blur_in_place(&mut got, res, 1.0);
            assert_eq!(got, want, "{res:?}: level 0");
            let b = whole_grid::blur(&want, res, 3f64.sqrt());
            let (want1, nr) = whole_grid::downsample(&b, res);
            let (got1, nr1) = next_level(&want, res, 3f64.sqrt());
            assert_eq!(nr, nr1);
            assert_eq!(got1, want1, "{res:?}: level 1");
        }
        assert_eq!(level_resolutions([9, 7, 11]).len(), 5);
        assert_eq!(level_resolutions([1, 1, 1]).len(), 1);
    }
}
