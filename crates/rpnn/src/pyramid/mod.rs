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
//!
//! **Only the levels a stencil reads are stored.** The finest level any stencil level reads is
//! [`Pyramid::level_for`]`(1)`; it depends on the voxel size in mean free paths. On a large or
//! thin cloud it is coarse (a 1200³ cumulus: level 2, 1/64 of the voxels), and the finer levels
//! are streamed through plane by plane (`stream.rs`) without being stored ([`Cells::Absent`]).
//! Levels of more than [`SPARSE_LEVEL_ABOVE`] cells are stored as 8³ bricks, absent where
//! the level is zero ([`Cells::Sparse`]): a sparse cloud in a huge box (a production VDB)
//! costs what its cloud costs at any level a stencil reads.
//! [`Pyramid::with_every_level`] keeps them all (for analysis and tests).

mod lattice;
mod stream;

use glam::DVec3;
use nimbus_scene::{DensityGrid, Volume};
use stream::{Blur, Down, GridPlanes, Planes, SlicePlanes};

/// How a level's cells are held.
#[derive(Debug, Clone, PartialEq)]
pub enum Cells {
    /// Not stored: no stencil reads the level (see the module docs).
    Absent,
    /// Every cell, x fastest.
    Dense(Vec<f32>),
    /// 8³ bricks, absent where the level is zero: levels of more than
    /// [`SPARSE_LEVEL_ABOVE`] cells, so a cloud filling a few percent of a huge box costs what
    /// its cloud costs (the values are those of the dense level, bit for bit).
    Sparse(DensityGrid),
}

/// Levels with more cells than this (256 MiB as dense f32; the threshold at which clouds are
/// generated and read as bricks) are stored as bricks.
pub const SPARSE_LEVEL_ABOVE: usize = nimbus_scene::generate::SPARSE_ABOVE_VOXELS;

/// One level over the volume's box.
#[derive(Debug, Clone, PartialEq)]
pub struct Level {
    pub res: [usize; 3],
    pub cells: Cells,
    /// Gaussian standard deviation of this level's prefilter, in original voxels.
    pub sigma_voxels: f64,
}

impl Level {
    /// Whether a stencil can read it (dense or sparse).
    pub fn is_stored(&self) -> bool {
        !matches!(self.cells, Cells::Absent)
    }

    /// The dense cells (None when absent or sparse).
    pub fn dense(&self) -> Option<&[f32]> {
        match &self.cells {
            Cells::Dense(d) => Some(d),
            _ => None,
        }
    }

    /// Cell (x, y, z) of a stored level.
    #[inline]
    pub fn get(&self, x: usize, y: usize, z: usize) -> f32 {
        match &self.cells {
            Cells::Dense(d) => d[(z * self.res[1] + y) * self.res[0] + x],
            Cells::Sparse(g) => g.get(x, y, z),
            Cells::Absent => panic!("pyramid level {:?} is not stored", self.res),
        }
    }

    /// The eight cells (x[i], y[j], z[k]) of a trilinear lookup in the order i + 2j + 4k (each
    /// pair a cell and itself or its successor), as `DensityGrid::corners` gives them: one
    /// dispatch on the storage for all eight (the descriptor reads them 2 250 times a query).
    #[inline]
    fn corners(&self, x: [usize; 2], y: [usize; 2], z: [usize; 2]) -> [f32; 8] {
        match &self.cells {
            Cells::Dense(d) => {
                let (nx, ny) = (self.res[0], self.res[1]);
                let base = (z[0] * ny + y[0]) * nx + x[0];
                let (dx, dy, dz) = (x[1] - x[0], (y[1] - y[0]) * nx, (z[1] - z[0]) * nx * ny);
                std::array::from_fn(|n| {
                    d[base + [0, dx][n & 1] + [0, dy][(n >> 1) & 1] + [0, dz][n >> 2]]
                })
            }
            Cells::Sparse(g) => g.corners(x, y, z),
            Cells::Absent => panic!("pyramid level {:?} is not stored", self.res),
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        match &self.cells {
            Cells::Absent => 0,
            Cells::Dense(d) => 4 * d.len(),
            Cells::Sparse(g) => g.bytes(),
        }
    }

    /// Σ of the cells (f64).
    fn sum(&self) -> f64 {
        match &self.cells {
            Cells::Absent => 0.0,
            Cells::Dense(d) => d.iter().map(|v| *v as f64).sum(),
            // The grid's own sum (over its stored bricks), as its mean times the cells.
            Cells::Sparse(g) => {
                g.stats().mean * self.res.iter().map(|&r| r as f64).product::<f64>()
            }
        }
    }

    /// The level's cells as a plane source (for the next level).
    fn planes(&self) -> Box<dyn Planes + '_> {
        match &self.cells {
            Cells::Dense(d) => Box::new(SlicePlanes::new(d, self.res)),
            // × 1.0 is exact: the planes are the stored values.
            Cells::Sparse(g) => Box::new(GridPlanes::new(g, 1.0)),
            Cells::Absent => panic!("pyramid level {:?} is not stored", self.res),
        }
    }
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

/// One pyramid level's trilinear lookups ([`Pyramid::sampler`]).
pub struct LevelSampler<'a> {
    level: &'a Level,
    lo: glam::Vec3A,
    hi: glam::Vec3A,
    extent: glam::Vec3A,
    resf: glam::Vec3A,
    /// The last cell index per axis.
    last: glam::Vec3A,
}

impl LevelSampler<'_> {
    /// ρ at world point p (trilinear, clamp-to-edge inside the box, 0 outside), in the f32
    /// arithmetic and order of `shaders/rpnn_descriptor.wgsl` (lane-wise SIMD: the same IEEE
    /// operations per axis).
    #[inline]
    pub fn at(&self, p: glam::Vec3) -> f32 {
        let p = glam::Vec3A::from(p);
        if !(p.cmpge(self.lo).all() && p.cmple(self.hi).all()) {
            return 0.0;
        }
        let u = (p - self.lo) / self.extent * self.resf - glam::Vec3A::splat(0.5);
        let b = u.floor();
        let f = u - b;
        let i0 = b.clamp(glam::Vec3A::ZERO, self.last);
        let i1 = (b + glam::Vec3A::ONE).clamp(glam::Vec3A::ZERO, self.last);
        let pair = |a: f32, b: f32| [a as usize, b as usize];
        let (x, y, z) = (pair(i0.x, i1.x), pair(i0.y, i1.y), pair(i0.z, i1.z));
        let c = self.level.corners(x, y, z);
        let mix = |a: f32, b: f32, t: f32| a * (1.0 - t) + b * t;
        let c00 = mix(c[0], c[1], f.x);
        let c10 = mix(c[2], c[3], f.x);
        let c01 = mix(c[4], c[5], f.x);
        let c11 = mix(c[6], c[7], f.x);
        mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z)
    }
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

/// [`Pyramid::level_for`] before the pyramid exists (non-decreasing in `k`).
fn level_index(k: u32, mean_sigma: f64, voxel: f64, levels: usize) -> usize {
    level_index_scaled(k, 1.0, mean_sigma, voxel, levels)
}

/// [`level_index`] for a stencil scaled by `s` (points `s` times closer or farther apart).
fn level_index_scaled(k: u32, s: f64, mean_sigma: f64, voxel: f64, levels: usize) -> usize {
    let h_vox = s * 0.5 * 2f64.powi(k as i32 - 1) / (mean_sigma * voxel);
    let i = (h_vox / 2.0).log2().floor();
    if i.is_nan() || i < 0.0 {
        0
    } else {
        (i as usize).min(levels - 1)
    }
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

    /// Like [`Pyramid::new`], with every level stored, including those no stencil reads.
    pub fn with_every_level(volume: &Volume) -> Result<Self, PyramidError> {
        let (sum, count) = Self::nonzero(volume);
        if count == 0 || volume.density_scale() <= 0.0 {
            return Err(PyramidError::Empty);
        }
        Self::build_levels(
            volume,
            volume.density_scale() * sum / count as f64,
            true,
            SPARSE_LEVEL_ABOVE,
        )
    }

    fn build(volume: &Volume, mean_sigma: f64) -> Result<Self, PyramidError> {
        Self::build_levels(volume, mean_sigma, false, SPARSE_LEVEL_ABOVE)
    }

    /// The build: every level stored or only those a stencil reads; levels of more than
    /// `sparse_above` cells as bricks.
    fn build_levels(
        volume: &Volume,
        mean_sigma: f64,
        every: bool,
        sparse_above: usize,
    ) -> Result<Self, PyramidError> {
        // The stream's recycled plane buffers are freed however the build ends.
        struct ReleasePlanes;
        impl Drop for ReleasePlanes {
            fn drop(&mut self) {
                stream::release_planes();
            }
        }
        let _release = ReleasePlanes;
        let g = volume.grid();
        let [x, y, z] = g.res();
        let voxel = volume.cell_size().min_element();
        let resolutions = level_resolutions(g.res());
        let first = if every {
            0
        } else {
            level_index(1, mean_sigma, voxel, resolutions.len())
        };
        // Peak: the stored levels and the streaming windows (per stage ≈ 2r + 4 planes of its
        // input, r = 3σ: 8 planes of level 0 for its blur, then 17 for each halving, each a
        // quarter the size of the one before): no whole-grid temporaries, no dense copy of a
        // sparse grid. A sparse level counts its brick index here; its bricks are checked
        // against the budget as they are stored. The windows come to ≈ 14 level-0 planes; the
        // 40 counted also cover the recycled planes the stream keeps (`stream::POOL_MAX`, 16).
        let level_bytes: u128 = resolutions[first..]
            .iter()
            .map(|r| {
                let n = (r[0] * r[1] * r[2]) as u128;
                if n > sparse_above as u128 {
                    n / 512 * 4
                } else {
                    n * 4
                }
            })
            .sum();
        const WINDOW_PLANES: usize = 40;
        const _: () = assert!(14 + stream::POOL_MAX <= WINDOW_PLANES);
        let window_bytes = (WINDOW_PLANES * x * y) as u128 * 4;
        let what = format!("the RPNN density pyramid of a {x}×{y}×{z} grid");
        nimbus_scene::memory::check(level_bytes + window_bytes, "volume", &what)?;
        let store = |p: &mut dyn Planes| -> Result<Cells, PyramidError> {
            let [a, b, c] = p.res();
            Ok(if a * b * c > sparse_above {
                Cells::Sparse(stream::collect_bricks(p, &what)?)
            } else {
                Cells::Dense(stream::collect(p))
            })
        };
        let scale = (volume.density_scale() / mean_sigma) as f32;
        let mut stage: Box<dyn Planes> =
            Box::new(Blur::new(Box::new(GridPlanes::new(g, scale)), 1.0));
        for _ in 0..first {
            stage = Box::new(Down::new(stage, 3f64.sqrt()));
        }
        let mut levels: Vec<Level> = (0..first)
            .map(|i| Level {
                res: resolutions[i],
                cells: Cells::Absent,
                sigma_voxels: 2f64.powi(i as i32),
            })
            .collect();
        levels.push(Level {
            res: resolutions[first],
            cells: store(stage.as_mut())?,
            sigma_voxels: 2f64.powi(first as i32),
        });
        drop(stage);
        for _ in first + 1..resolutions.len() {
            let prev = levels.last().expect("a stored level");
            let mut down = Down::new(prev.planes(), 3f64.sqrt());
            let level = Level {
                res: down.res(),
                cells: store(&mut down)?,
                sigma_voxels: 2.0 * prev.sigma_voxels,
            };
            drop(down);
            levels.push(level);
        }
        Ok(Self {
            levels,
            aabb_min: volume.aabb().min,
            aabb_max: volume.aabb().max,
            mean_sigma,
            voxel,
        })
    }

    /// The finest level stored (the one stencil level 1 reads).
    pub fn finest_stored(&self) -> usize {
        self.level_for(1)
    }

    /// Bytes of the stored levels.
    pub fn bytes(&self) -> usize {
        self.levels.iter().map(Level::bytes).sum()
    }

    /// Pyramid level used by stencil level `k` (1-based): the stencil's point spacing is
    /// h = 0.5 · 2^(k−1) mean free paths = h / (σ̄ · voxel) voxels; prefiltering with a Gaussian
    /// of σ ≈ h/2 removes what the stencil cannot resolve, so we take the level with the largest
    /// σᵢ = 2ⁱ ≤ h/2 (level 0 when h/2 < 2), capped at the coarsest level.
    pub fn level_for(&self, k: u32) -> usize {
        level_index(k, self.mean_sigma, self.voxel, self.levels.len())
    }

    /// [`Pyramid::level_for`] for the stencil scaled by `s` (spacing s · 0.5 · 2^(k−1) mean
    /// free paths); `s` = 1 is `level_for`. For experiments with the descriptor's scale.
    pub fn level_for_scaled(&self, k: u32, s: f64) -> usize {
        level_index_scaled(k, s, self.mean_sigma, self.voxel, self.levels.len())
    }

    /// ρ at world point p from level `i` (trilinear, clamp-to-edge inside the box, 0 outside).
    /// f32 arithmetic in the same order as `shaders/rpnn_descriptor.wgsl`.
    pub fn lookup(&self, i: usize, p: glam::Vec3) -> f32 {
        // Outside the box: 0 before the level is looked at, as `at` answers.
        let (lo, hi) = (self.aabb_min.as_vec3(), self.aabb_max.as_vec3());
        if !(p.cmpge(lo).all() && p.cmple(hi).all()) {
            return 0.0;
        }
        self.sampler(i).at(p)
    }

    /// Level `i`'s lookups with what they share computed once: the descriptor reads 225
    /// points of each level per query ([`LevelSampler::at`] is [`Pyramid::lookup`], bit for bit).
    pub fn sampler(&self, i: usize) -> LevelSampler<'_> {
        let l = &self.levels[i];
        debug_assert!(l.is_stored(), "level {i} is not stored");
        let (lo, hi) = (self.aabb_min.as_vec3a(), self.aabb_max.as_vec3a());
        let resf = glam::DVec3::new(l.res[0] as f64, l.res[1] as f64, l.res[2] as f64).as_vec3a();
        LevelSampler {
            level: l,
            lo,
            hi,
            extent: hi - lo,
            resf,
            last: resf - glam::Vec3A::ONE,
        }
    }

    /// Total "mass" Σ ρ × cell volume of a level (world units³).
    pub fn mass(&self, i: usize) -> f64 {
        let l = &self.levels[i];
        assert!(
            l.is_stored(),
            "pyramid level {i} is not stored (no stencil reads it; see Pyramid::with_every_level)"
        );
        let ext = self.aabb_max - self.aabb_min;
        let cell = ext.x * ext.y * ext.z / (l.res[0] * l.res[1] * l.res[2]) as f64;
        l.sum() * cell
    }
}

/// The whole-grid blur and downsampling this module used before the plane-by-plane build:
/// the reference the build must match to the bit.
#[cfg(test)]
mod whole_grid {
    use super::stream::{down_weights, gauss_kernel};
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
        let (wx, wy, wz) = (
            down_weights(res[0], nr[0]),
            down_weights(res[1], nr[1]),
            down_weights(res[2], nr[2]),
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

    /// The streamed blur, the streamed next level and the two chained (a level streamed
    /// through without being stored) equal the whole-grid operations bit for bit, on odd and
    /// even sizes (odd sizes use the zero-padded last cell).
    #[test]
    fn plane_by_plane_build_matches_the_whole_grid_bit_for_bit() {
        let s3 = 3f64.sqrt();
        for res in [
            [9usize, 7, 11],
            [16, 8, 10],
            [1, 5, 3],
            [13, 1, 1],
            [12, 10, 30],
            [40, 30, 24],
        ] {
            let n = res[0] * res[1] * res[2];
            let mut state = 12345u64;
            let data: Vec<f32> = (0..n)
                .map(|i| {
                    state = state
                        .wrapping_mul(6364136223846793005)
                        .wrapping_add(1442695040888963407);
                    // Zero planes and rows among the noise: the skipped ones must agree too.
                    let (x, y, z) = (i % res[0], (i / res[0]) % res[1], i / (res[0] * res[1]));
                    // [40, 30, 24]: a blob far from the edges, so blurs and halvings work on
                    // bounds of the non-zero values smaller than the planes.
                    let outside = res[0] == 40 && !((17..23).contains(&x) && (9..14).contains(&y));
                    if z % 7 == 3 || y % 4 == 1 || outside {
                        0.0
                    } else {
                        ((state >> 40) as f32 / (1u64 << 24) as f32) * 3.0
                    }
                })
                .collect();
            let slice = || Box::new(SlicePlanes::new(&data, res));
            let want = whole_grid::blur(&data, res, 1.0);
            let got = stream::collect(&mut Blur::new(slice(), 1.0));
            assert_eq!(got, want, "{res:?}: level 0");
            let b = whole_grid::blur(&want, res, s3);
            let (want1, nr) = whole_grid::downsample(&b, res);
            let mut down = Down::new(Box::new(SlicePlanes::new(&want, res)), s3);
            assert_eq!(down.res(), nr);
            assert_eq!(stream::collect(&mut down), want1, "{res:?}: level 1");
            let b2 = whole_grid::blur(&want1, nr, s3);
            let (want2, _) = whole_grid::downsample(&b2, nr);
            let mut chain = Down::new(
                Box::new(Down::new(Box::new(Blur::new(slice(), 1.0)), s3)),
                s3,
            );
            assert_eq!(
                stream::collect(&mut chain),
                want2,
                "{res:?}: level 2 streamed through 0, 1"
            );
        }
        assert_eq!(level_resolutions([9, 7, 11]).len(), 5);
        assert_eq!(level_resolutions([1, 1, 1]).len(), 1);
    }

    /// `Pyramid::lookup` as eight separate `Level::get` reads (the arithmetic of the shader).
    fn per_cell_lookup(pyr: &Pyramid, i: usize, p: glam::Vec3) -> f32 {
        let (lo, hi) = (pyr.aabb_min.as_vec3(), pyr.aabb_max.as_vec3());
        if !(p.cmpge(lo).all() && p.cmple(hi).all()) {
            return 0.0;
        }
        let l = &pyr.levels[i];
        let res = glam::Vec3::new(l.res[0] as f32, l.res[1] as f32, l.res[2] as f32);
        let u = (p - lo) / (hi - lo) * res - glam::Vec3::splat(0.5);
        let b = u.floor();
        let f = u - b;
        let top = res - glam::Vec3::ONE;
        let i0 = b.clamp(glam::Vec3::ZERO, top);
        let i1 = (b + glam::Vec3::ONE).clamp(glam::Vec3::ZERO, top);
        let at = |x: f32, y: f32, z: f32| l.get(x as usize, y as usize, z as usize);
        let mix = |a: f32, b: f32, t: f32| a * (1.0 - t) + b * t;
        let c00 = mix(at(i0.x, i0.y, i0.z), at(i1.x, i0.y, i0.z), f.x);
        let c10 = mix(at(i0.x, i1.y, i0.z), at(i1.x, i1.y, i0.z), f.x);
        let c01 = mix(at(i0.x, i0.y, i1.z), at(i1.x, i0.y, i1.z), f.x);
        let c11 = mix(at(i0.x, i1.y, i1.z), at(i1.x, i1.y, i1.z), f.x);
        mix(mix(c00, c10, f.y), mix(c01, c11, f.y), f.z)
    }

    /// Levels stored as bricks hold the dense levels' values bit for bit (every cell, the
    /// lookups, the masses to rounding), from a dense grid and from bricks, and a small cloud in
    /// a large box stores a fraction of the dense bytes.
    #[test]
    fn sparse_levels_hold_the_dense_values() {
        use nimbus_scene::{Aabb, brick};
        // Two small blobs in a 70×45×83 box (sizes not multiples of 8: partial edge bricks).
        let res = [70usize, 45, 83];
        let mut data = vec![0.0f32; res.iter().product()];
        for (c, r) in [([12.0, 10.0, 15.0], 4.0), ([55.0, 30.0, 70.0], 6.0f64)] {
            for z in 0..res[2] {
                for y in 0..res[1] {
                    for x in 0..res[0] {
                        let d = ((x as f64 - c[0]).powi(2)
                            + (y as f64 - c[1]).powi(2)
                            + (z as f64 - c[2]).powi(2))
                        .sqrt();
                        if d < r {
                            data[(z * res[1] + y) * res[0] + x] = (1.0 - d / r) as f32 + 0.1;
                        }
                    }
                }
            }
        }
        // A −0 beside the first blob, in a stored brick: the levels' bits still equal the
        // whole-grid blur's, which turns it into +0 (the recycled buffers' part of this is
        // `stream::tests::recycled_planes_come_back_all_zero_bits`).
        data[(15 * res[1] + 13) * res[0] + 8] = -0.0;
        let aabb = Aabb::new(DVec3::ZERO, DVec3::new(0.7, 0.45, 0.83)).unwrap();
        let dense = DensityGrid::new(res, data.clone()).unwrap();
        let bricks = DensityGrid::from_bricks(brick::from_dense(res, &data, [0, 0, 0]).unwrap());
        for grid in [dense, bricks] {
            let vol = Volume::new(grid, aabb, 30.0).unwrap();
            let (sum, count) = Pyramid::nonzero(&vol);
            let ms = vol.density_scale() * sum / count as f64;
            // The whole-grid blur of level 0 (the build's scaling): the reference for the bits.
            let scale = (vol.density_scale() / ms) as f32;
            let scaled: Vec<f32> = data.iter().map(|v| v * scale).collect();
            let level0 = whole_grid::blur(&scaled, res, 1.0);
            let want = Pyramid::build_levels(&vol, ms, true, usize::MAX).unwrap();
            let w0 = want.levels[0].dense().expect("level 0 stored dense");
            assert!(
                w0.iter()
                    .zip(&level0)
                    .all(|(a, b)| a.to_bits() == b.to_bits()),
                "level 0 differs in its bits from the whole-grid blur"
            );
            // Every level with more than 1 000 cells as bricks: levels 0–2.
            let got = Pyramid::build_levels(&vol, ms, true, 1000).unwrap();
            let mut sparse = 0;
            for (i, (a, b)) in got.levels.iter().zip(&want.levels).enumerate() {
                assert_eq!(a.res, b.res);
                sparse += usize::from(matches!(a.cells, Cells::Sparse(_)));
                let [nx, ny, nz] = a.res;
                for z in 0..nz {
                    for y in 0..ny {
                        for x in 0..nx {
                            assert_eq!(a.get(x, y, z).to_bits(), b.get(x, y, z).to_bits());
                        }
                    }
                }
                let (ma, mb) = (got.mass(i), want.mass(i));
                assert!((ma - mb).abs() <= 1e-9 * mb, "level {i}: {ma} vs {mb}");
            }
            assert_eq!(sparse, 3);
            // Level 0 is 261 450 cells (1 MB dense); the blobs and their blur reach few bricks.
            assert!(
                got.levels[0].bytes() * 4 < want.levels[0].bytes(),
                "{} vs {}",
                got.levels[0].bytes(),
                want.levels[0].bytes()
            );
            for k in 0..200 {
                let t = k as f32 / 200.0;
                let p = glam::Vec3::new(0.7 * t, 0.45 * (1.0 - t), 0.83 * (t * 7.0).fract());
                for i in 0..3 {
                    assert_eq!(got.lookup(i, p).to_bits(), want.lookup(i, p).to_bits());
                }
            }
            // The eight-corner fetch against eight single reads, dense and sparse levels, at
            // points in and around both blobs and at the box's corners (every edge clamp).
            let centres = [
                glam::Vec3::new(0.125, 0.105, 0.155),
                glam::Vec3::new(0.555, 0.305, 0.705),
            ];
            let mut points: Vec<glam::Vec3> = Vec::new();
            for c in centres {
                for k in 0..343 {
                    let o = glam::Vec3::new((k % 7) as f32, ((k / 7) % 7) as f32, (k / 49) as f32);
                    points.push(c + (o - glam::Vec3::splat(3.0)) * 0.0213);
                }
            }
            for k in 0..8 {
                let b = |bit: usize, v: f32| if k & bit == 0 { 0.0 } else { v };
                points.push(glam::Vec3::new(b(1, 0.7), b(2, 0.45), b(4, 0.83)));
            }
            let mut reached = 0;
            for p in points {
                for pyr in [&got, &want] {
                    for i in 0..3 {
                        let r = per_cell_lookup(pyr, i, p);
                        assert_eq!(pyr.lookup(i, p).to_bits(), r.to_bits(), "level {i} at {p}");
                        reached += usize::from(r > 0.0);
                    }
                }
            }
            assert!(reached > 1000, "only {reached} lookups reach the blobs");
        }
    }
}
