//! The light grid: the resolution the photon stages work at and the density each stage reads.
//!
//! J (16 bytes per voxel), its flux directions (16) and T_sun (4) live at the light resolution
//! (`light_map`), densely or in pools of the 8³ bricks near density (`crate::light_map`); the
//! trace, the sun pass and the upsampling read a density at that resolution in the same layout
//! ("work density": the grid itself, or its block means, `nimbus_scene::downsample`). The ray
//! marcher reads J and T_sun there and the grid at its own resolution: from the work density when they coincide, else from a dense buffer or — for a
//! sparse grid or one beyond a storage binding — the brick map the GPU path tracer uses
//! (`shaders/lib/density_bricks.wgsl`), so a sparse cloud is never densified.

use nimbus_gpu::density::GpuDensity;
use nimbus_scene::DensityGrid;

use crate::light_map::LightMap;

use super::*;

/// Optical width (mean free paths) of a light voxel above which [`PhotonMapper::light_note`]
/// warns: beyond ≈ 2 the sun's transmittance falls by more than e² across one voxel and the
/// trilinear light volumes no longer resolve it.
pub const THICK_LIGHT_VOXEL: f64 = 2.0;

/// The density the ray marcher reads.
pub(super) enum MarchDensity {
    /// The work density (light and density resolution are equal).
    Work,
    /// The grid as one storage buffer.
    Dense(wgpu::Buffer),
    /// The grid as a brick map.
    Bricks(Box<GpuDensity>),
}

impl MarchDensity {
    /// The ray-marching stage for this density.
    pub fn stage(&self) -> &'static str {
        match self {
            MarchDensity::Work => "photon_raymarch_light.wgsl",
            MarchDensity::Dense(_) => "photon_raymarch.wgsl",
            MarchDensity::Bricks(_) => "photon_raymarch_bricks.wgsl",
        }
    }

    /// The final-gathering stage for this density (the same bindings as the ray marcher's).
    pub fn gather_stage(&self) -> &'static str {
        match self {
            MarchDensity::Work => "photon_gather_light.wgsl",
            MarchDensity::Dense(_) => "photon_gather.wgsl",
            MarchDensity::Bricks(_) => "photon_gather_bricks.wgsl",
        }
    }
}

/// Bytes per light voxel of the largest light volume (J), which must fit one storage binding.
const J_BYTES: u64 = 16;

/// Whether pools of `entries` (`crate::light_map`) and `words` of brick index fit the
/// adapter: J in one binding, the words in another, every entry a u32 index.
fn fits(entries: u64, words: u64, max_binding: u64) -> bool {
    entries * J_BYTES <= max_binding && words * 4 <= max_binding && entries <= u32::MAX as u64
}

/// Pool entries of the full layout at `r`.
fn full_entries(r: [u32; 3]) -> u64 {
    crate::light_map::BRICK_VOXELS as u64 + r.iter().map(|&v| v as u64).product::<u64>()
}

/// The light grid for `vol`: its resolution and layout with the work density
/// (`crate::light_map`). The resolution is the setting (each axis in 1..= the grid's), else
/// the grid's divided by an integer k ≥ 1 (⌈N/k⌉ per axis): the smallest k at which every 8³
/// brick fits the adapter (the *full* layout), unless a light voxel would then be more than
/// [`THICK_LIGHT_VOXEL`] mean free paths wide at the grid's largest density — light varying
/// inside it would be smoothed away — in which case the coarsest k that is thin enough and
/// fits with only the bricks near density stored (*sparse*), else the finest k that fits at
/// all. So a cloud whose light volumes fit as they are keeps today's layout and cost, and a
/// small dense cloud in a large box gets light voxels fine enough for it, at a memory cost in
/// proportion to the cloud. Where nothing fits, the smallest J is checked (and refused with its
/// bytes) before any allocation.
pub(super) fn light_map(
    gpu: &Gpu,
    vol: &nimbus_scene::Volume,
    grid_max: f64,
    settings: &PmSettings,
) -> Result<LightMap, PmError> {
    let grid = vol.grid();
    let d_res = grid.res();
    let fine = d_res.map(|v| v as u32);
    let max_binding = gpu
        .limits
        .max_storage_buffer_binding_size
        .min(gpu.limits.max_buffer_size);
    let boxes = nimbus_scene::downsample::nonzero_boxes(grid);
    // (full layout fits, some layout fits, pool entries).
    let plan = |r: [u32; 3]| -> (bool, bool, u64) {
        if fits(full_entries(r), 1, max_binding) {
            return (true, true, full_entries(r));
        }
        let l = r.map(|v| v as usize);
        let bricks = crate::light_map::brick_res(l).iter().product::<usize>() as u64;
        // The index alone must fit a binding (and its flags host memory): else coarser, before
        // anything of the brick count's size is allocated.
        if bricks * 4 > max_binding || bricks > 1 << 30 {
            return (false, false, u64::MAX);
        }
        let radius = near_radius(fine, r) as usize;
        let (active, _) = crate::light_map::active_bricks(&boxes, d_res, l, radius);
        let slots = active.iter().filter(|&&a| a).count() as u64 + 1;
        let entries = slots * crate::light_map::BRICK_VOXELS as u64;
        (false, fits(entries, bricks + slots, max_binding), entries)
    };
    let d = fine.map(|v| v.max(1));
    let res_k = |k: u32| d.map(|v| v.div_ceil(k));
    let ext = vol.aabb().extent();
    let depth = |r: [u32; 3]| {
        let edge = (0..3).map(|a| ext[a] / r[a] as f64).fold(0.0, f64::max);
        vol.density_scale() * grid_max * edge
    };
    let (r, full, entries) = match settings.light_res {
        Some(r) => {
            let r = check_axes("light_res", r, d_res, "density resolution")?;
            let (full, _, entries) = plan(r);
            (r, full, entries)
        }
        None => {
            // The smallest k at which every brick fits.
            let mut k_full = 1u32;
            let fits_full = |r: [u32; 3]| fits(full_entries(r), 1, max_binding);
            while !fits_full(res_k(k_full)) && res_k(k_full) != [1, 1, 1] {
                k_full += 1;
            }
            let mut k = k_full;
            if depth(res_k(k_full)) > THICK_LIGHT_VOXEL {
                // The coarsest thin-enough k, then coarser until a layout fits.
                while k > 1 && depth(res_k(k)) > THICK_LIGHT_VOXEL {
                    k -= 1;
                }
                while k < k_full && !plan(res_k(k)).1 {
                    k += 1;
                }
            }
            let r = res_k(k);
            let (full, _, entries) = plan(r);
            (r, full, entries)
        }
    };
    let voxels = entries;
    if voxels == u64::MAX {
        let b = crate::light_map::brick_res(r.map(|v| v as usize));
        return Err(PmError::Setting {
            field: "light_res",
            msg: format!(
                "{r:?}: the index of its {}×{}×{} light bricks would not fit one storage binding of {max_binding} bytes; choose a coarser resolution",
                b[0], b[1], b[2]
            ),
        });
    }
    if voxels > u32::MAX as u64 {
        return Err(PmError::Setting {
            field: "light_res",
            msg: format!(
                "{r:?}: {voxels} entries in the light volumes exceed the 2^32 the kernels can index"
            ),
        });
    }
    gpu.check_storage("the upsampled cache J", voxels * J_BYTES)?;
    let radius = near_radius(fine, r) as usize;
    Ok(LightMap::build(
        grid,
        &boxes,
        r.map(|v| v as usize),
        radius,
        full,
    ))
}

/// Which density the ray marcher will read, decided before anything is allocated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum MarchPlan {
    Work,
    Dense,
    Bricks,
}

/// The ray marcher's density for `grid` at light resolution `l_res`, and the bytes it adds
/// (for a brick map, the grid's own bytes: an upper bound of its atlas, which shares constant
/// bricks).
pub(super) fn march_plan(gpu: &Gpu, grid: &DensityGrid, l_res: [u32; 3]) -> (MarchPlan, u64) {
    let res = grid.res();
    if l_res.map(|v| v as usize) == res {
        return (MarchPlan::Work, 0);
    }
    let bytes = res.iter().map(|&v| v as u64).product::<u64>() * 4;
    if grid.as_dense().is_some() && gpu.check_storage("the density grid", bytes).is_ok() {
        (MarchPlan::Dense, bytes)
    } else {
        (MarchPlan::Bricks, grid.bytes() as u64)
    }
}

/// Uploads the ray marcher's density as planned.
pub(super) fn march_density(
    gpu: &Gpu,
    grid: &DensityGrid,
    plan: MarchPlan,
) -> Result<MarchDensity, PmError> {
    Ok(match (plan, grid.as_dense()) {
        (MarchPlan::Work, _) => MarchDensity::Work,
        (MarchPlan::Dense, Some(d)) => MarchDensity::Dense(gpu.storage("density (ray marcher)", d)),
        _ => MarchDensity::Bricks(Box::new(GpuDensity::new(gpu, grid, "the density grid")?)),
    })
}

/// Radius of the neighbourhood the sun pass and the upsampling look for density in
/// (`near_density` in shaders/lib/grid.wgsl): 1, or 2 where an axis of the light volumes is
/// coarser than the grid's by a factor between 1 and 2 — there the fine voxel that makes
/// σ(x) > 0 can lie in the light voxel two away from a trilinear neighbour of x.
pub fn near_radius(d_res: [u32; 3], l_res: [u32; 3]) -> u32 {
    if (0..3).any(|a| l_res[a] != d_res[a] && 2 * l_res[a] > d_res[a]) {
        2
    } else {
        1
    }
}

/// Fill of the densest cache cell below which [`PhotonMapper::cache_note`] warns.
pub const THIN_CACHE_FILL: f64 = 0.1;

/// Mean work density of the densest cache cell (of `i_res` over the box; each light voxel
/// counts in the cell holding its centre) over the largest work density; 0 for an empty grid.
pub fn cache_fill(map: &LightMap, i_res: [u32; 3]) -> f64 {
    let l = map.res();
    let i = i_res.map(|v| v as usize);
    let counts = [0, 1, 2].map(|a| {
        let mut c = vec![0usize; i[a]];
        for v in 0..l[a] {
            c[nimbus_scene::downsample::coarse_of(v, l[a], i[a])] += 1;
        }
        c
    });
    let mut sums = vec![0.0f64; i.iter().product()];
    for (p, &d) in map.density.iter().enumerate() {
        if d > 0.0
            && let Some(v) = map.voxel_of(p)
        {
            let c: [usize; 3] =
                std::array::from_fn(|a| nimbus_scene::downsample::coarse_of(v[a], l[a], i[a]));
            sums[(c[2] * i[1] + c[1]) * i[0] + c[0]] += d as f64;
        }
    }
    let max = map.max() as f64;
    if max <= 0.0 {
        return 0.0;
    }
    sums.iter()
        .enumerate()
        .map(|(k, s)| {
            let n =
                counts[0][k % i[0]] * counts[1][(k / i[0]) % i[1]] * counts[2][k / (i[0] * i[1])];
            s / n.max(1) as f64
        })
        .fold(0.0, f64::max)
        / max
}

/// For each cache cell (of `i_res` over the box; each light voxel counts in the cell holding its
/// centre): its mean work density over its largest, in [0, 1] (0 for an empty cell). 1 where the
/// cell holds homogeneous cloud; small where the cloud's features are far smaller than the
/// cell (its scattered light is averaged over mostly empty space): the final gathering reads the
/// cache only in cells filled at least [`crate::mapper::GATHER_MIN_FILL`].
pub fn cell_fills(map: &LightMap, i_res: [u32; 3]) -> Vec<f32> {
    let l = map.res();
    let i = i_res.map(|v| v as usize);
    let counts = [0, 1, 2].map(|a| {
        let mut c = vec![0usize; i[a]];
        for v in 0..l[a] {
            c[nimbus_scene::downsample::coarse_of(v, l[a], i[a])] += 1;
        }
        c
    });
    let n = i.iter().product();
    let (mut sums, mut maxes) = (vec![0.0f64; n], vec![0.0f32; n]);
    for (p, &d) in map.density.iter().enumerate() {
        if d > 0.0
            && let Some(v) = map.voxel_of(p)
        {
            let c: [usize; 3] =
                std::array::from_fn(|a| nimbus_scene::downsample::coarse_of(v[a], l[a], i[a]));
            let k = (c[2] * i[1] + c[1]) * i[0] + c[0];
            sums[k] += d as f64;
            maxes[k] = maxes[k].max(d);
        }
    }
    (0..n)
        .map(|k| {
            let cnt =
                counts[0][k % i[0]] * counts[1][(k / i[0]) % i[1]] * counts[2][k / (i[0] * i[1])];
            if maxes[k] > 0.0 {
                ((sums[k] / cnt.max(1) as f64) / maxes[k] as f64).min(1.0) as f32
            } else {
                0.0
            }
        })
        .collect()
}

/// 1 for each cache cell (of `i_res` over the box) that no stage after the trace reads, given
/// the work density in `map`: no non-zero light voxel within the cell's extent grown by one
/// cell and three light voxels. The upsampling of a voxel reads the 3³ cells around its own,
/// and only voxels within `near_radius` ≤ 2 light voxels of density are upsampled; the trilinear
/// density a beam scatters on is non-zero only within one light voxel of a non-zero one. Each
/// light brick's non-zero voxels count by their bounding box (conservative: a cell kept for
/// nothing costs only Woodcock steps).
pub fn skippable_cells(map: &LightMap, i_res: [u32; 3]) -> Vec<u32> {
    let l = map.res();
    let i = i_res.map(|v| v as usize);
    let mut used = vec![false; i.iter().product()];
    let span_lo = |v: usize, a: usize| v * i[a] / l[a];
    let span_hi = |v: usize, a: usize| ((v + 1) * i[a]).div_ceil(l[a]) - 1;
    for (lo, hi) in map.nonzero_boxes() {
        let c0: [usize; 3] = std::array::from_fn(|a| span_lo(lo[a].saturating_sub(3), a));
        let c1: [usize; 3] = std::array::from_fn(|a| span_hi((hi[a] + 3).min(l[a] - 1), a));
        for z in c0[2]..=c1[2] {
            for y in c0[1]..=c1[1] {
                for x in c0[0]..=c1[0] {
                    used[(z * i[1] + y) * i[0] + x] = true;
                }
            }
        }
    }
    let near = |c: usize, a: usize| c.saturating_sub(1)..=(c + 1).min(i[a] - 1);
    (0..used.len())
        .map(|idx| {
            let c = [idx % i[0], (idx / i[0]) % i[1], idx / (i[0] * i[1])];
            let any = near(c[2], 2).any(|z| {
                near(c[1], 1).any(|y| near(c[0], 0).any(|x| used[(z * i[1] + y) * i[0] + x]))
            });
            u32::from(!any)
        })
        .collect()
}

impl PhotonMapper<'_> {
    /// The uniform block of the ray marcher: the work parameters with the grid's resolution.
    pub fn march_params(&self) -> VolumeParams {
        super::params::march(&self.params, self.fine_res)
    }

    /// Whether the light volumes are coarser than the density grid.
    pub fn light_is_coarse(&self) -> bool {
        self.fine_res != self.params.light_res
    }

    /// Resolution of the light volumes (J, T_sun) and of the density the photons trace.
    pub fn light_res(&self) -> [u32; 3] {
        self.params.light_res
    }

    /// What a user should know about the light volumes (`None` at full resolution with every
    /// brick stored): their resolution, how many bricks are stored and, when a light voxel at the grid's densest is more than
    /// [`THICK_LIGHT_VOXEL`] mean free paths wide, that light varying inside it is smoothed —
    /// small dense features then come out too dark (a 6-voxel sphere at 9 voxels per light
    /// voxel, τ ≈ 4.5: 0.3 × the path tracer; BENCHMARKS.md "Volumes at scale").
    pub fn light_note(&self) -> Option<String> {
        let [x, y, z] = self.params.light_res;
        let (stored, total) = self.light_bricks();
        let bricks = if self.map.is_full() {
            String::new()
        } else {
            format!(", {stored} of {total} 8³ bricks stored (those near density)")
        };
        if !self.light_is_coarse() {
            return (!self.map.is_full())
                .then(|| format!("light volumes {x}×{y}×{z} (the grid's){bricks}"));
        }
        let k = (0..3)
            .map(|a| self.fine_res[a] as f64 / self.params.light_res[a] as f64)
            .fold(0.0, f64::max);
        let mut note =
            format!("light volumes {x}×{y}×{z} (each ≤ {k:.1} grid voxels along an axis){bricks}");
        let tau = self.light_voxel_depth();
        if tau > THICK_LIGHT_VOXEL {
            note += &format!(
                "; at the densest a light voxel is {tau:.1} mean free paths wide: shadows and multiply scattered light inside it are smoothed and small dense features come out too dark (the path tracer, or a finer --light-res where the adapter allows a larger J)"
            );
        }
        Some(note)
    }

    /// What a user should know about the cache (`None` when its densest cell is at least
    /// [`THIN_CACHE_FILL`] filled): a cloud whose features are far smaller than a cache cell
    /// gets its scattered light averaged over the whole cell, mostly empty space, and comes out
    /// too dark (the far-spheres file: 0.24 × the path tracer, BENCHMARKS.md).
    pub fn cache_note(&self) -> Option<String> {
        (self.cache_fill < THIN_CACHE_FILL).then(|| {
            let w = (0..3)
                .map(|a| self.fine_res[a] as f64 / self.params.i_res[a] as f64)
                .fold(0.0, f64::max);
            let consequence = if self.gather.is_some() {
                // Final gathering bounces on through such cells (`GATHER_MIN_FILL`).
                "so gather paths bounce on through them instead of ending there (slower)"
            } else {
                "so scattered light is averaged over mostly empty space and the image comes out too dark (a finer --cache-res, --method pm, or the path tracer)"
            };
            format!(
                "the densest cache cell is only {:.1} % filled: the cloud's features are far smaller than a cache cell (≈ {w:.0} grid voxels wide), {consequence}",
                100.0 * self.cache_fill
            )
        })
    }

    /// Mean work density of the densest cache cell over the largest work density (1 when a
    /// cell lies wholly inside the densest part of the cloud).
    pub fn cache_fill(&self) -> f64 {
        self.cache_fill
    }

    /// Optical width of a light voxel at the grid's largest density: σ_max × its longest edge.
    pub fn light_voxel_depth(&self) -> f64 {
        let p = &self.params;
        let edge = (0..3)
            .map(|a| (p.aabb_max[a] - p.aabb_min[a]) as f64 / p.light_res[a] as f64)
            .fold(0.0, f64::max);
        p.density_scale as f64 * self.grid_max * edge
    }

    /// Replaces the density field (the grid's resolution) for the following frames: the work
    /// density and, when the light volumes are coarser, the ray marcher's.
    pub fn set_density(&mut self, data: &[f32]) -> Result<(), PmError> {
        let n = self.fine_res.iter().map(|&v| v as usize).product::<usize>();
        if data.len() != n {
            return Err(PmError::Setting {
                field: "density",
                msg: format!("expected {n} voxels, got {}", data.len()),
            });
        }
        if let Some(i) = data.iter().position(|v| !v.is_finite() || *v < 0.0) {
            return Err(PmError::Setting {
                field: "density",
                msg: format!("voxel {i} is {}; densities must be finite and ≥ 0", data[i]),
            });
        }
        let fine = self.fine_res.map(|v| v as usize);
        let radius = self.params.near_radius.max(1) as usize;
        let l_res = self.map.res();
        let full = self.map.is_full();
        let map = match &self.march_density {
            MarchDensity::Work => LightMap::from_dense(fine, data, radius, full),
            MarchDensity::Dense(b) => {
                self.gpu
                    .queue
                    .write_buffer(b, 0, bytemuck::cast_slice(data));
                let grid = DensityGrid::new(fine, data.to_vec()).map_err(PmError::Memory)?;
                let boxes = nimbus_scene::downsample::nonzero_boxes(&grid);
                LightMap::build(&grid, &boxes, l_res, radius, full)
            }
            MarchDensity::Bricks(_) => {
                return Err(PmError::Unsupported(
                    "a density sequence needs the grid in one dense GPU buffer; this scene's grid (sparse, or beyond one storage binding) is read through a brick map"
                        .into(),
                ));
            }
        };
        // A sparse layout keeps its pools: the new density's bricks must fit them.
        if map.len() > self.map.pool_len() {
            return Err(PmError::Setting {
                field: "density",
                msg: format!(
                    "this frame's density needs {} light bricks; the light volumes were made for {} (the first frame's); give --light-res to size them",
                    map.stored_bricks(),
                    self.map.stored_bricks()
                ),
            });
        }
        self.gpu
            .queue
            .write_buffer(&self.light_map, 0, bytemuck::cast_slice(&map.gpu_words()));
        self.gpu
            .queue
            .write_buffer(&self.density, 0, bytemuck::cast_slice(&map.density));
        self.params.light_voxels = map.light_voxels();
        if self.params.skip_empty != 0 {
            let skip = skippable_cells(&map, self.params.i_res);
            self.gpu
                .queue
                .write_buffer(&self.cell_skip, 0, bytemuck::cast_slice(&skip));
        }
        self.cache_fill = cache_fill(&map, self.params.i_res);
        self.gpu.queue.write_buffer(
            &self.cell_fill,
            0,
            bytemuck::cast_slice(&cell_fills(&map, self.params.i_res)),
        );
        let mut map = map.with_capacity(self.map.pool_len());
        map.drop_values();
        self.map = map;
        self.grid_max = data.iter().fold(0.0f32, |m, &v| m.max(v)) as f64;
        self.sun.dirty = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{near_radius, skippable_cells};
    use crate::light_map::LightMap;

    fn map(res: [usize; 3], data: &[f32]) -> LightMap {
        LightMap::from_dense(res, data, 1, false)
    }

    /// One non-zero light voxel in a 40³ grid under a 10³ cache (4 voxels per cell): the cells
    /// within the reach of the voxel (3 voxels, then one cell) are kept, every other is skipped;
    /// an empty grid skips everything, a full one nothing.
    #[test]
    fn skippable_cells_keep_the_reach_of_density() {
        let i = [10u32; 3];
        let mut work = vec![0.0f32; 40 * 40 * 40];
        work[(20 * 40 + 20) * 40 + 20] = 0.5;
        let skip = skippable_cells(&map([40; 3], &work), i);
        // The voxel grown by 3 covers voxels 17..=23: cells 4..=5; grown by one cell: 3..=6.
        for z in 0..10usize {
            for y in 0..10usize {
                for x in 0..10usize {
                    let kept = [x, y, z].iter().all(|c| (3..=6).contains(c));
                    assert_eq!(
                        skip[(z * 10 + y) * 10 + x],
                        u32::from(!kept),
                        "cell {x},{y},{z}"
                    );
                }
            }
        }
        assert!(
            skippable_cells(&map([40; 3], &vec![0.0; work.len()]), i)
                .iter()
                .all(|&s| s == 1)
        );
        assert!(
            skippable_cells(&map([40; 3], &vec![1.0; work.len()]), i)
                .iter()
                .all(|&s| s == 0)
        );
        // Cells coarser than voxels and not dividing them: a voxel's cells are those it overlaps.
        let mut w = vec![0.0f32; 7 * 7 * 7];
        w[0] = 1.0;
        let s = skippable_cells(&map([7; 3], &w), [3; 3]);
        assert_eq!(s.iter().filter(|&&v| v == 0).count(), 27);
    }

    /// A cell wholly inside a uniform cloud is filled; a one-voxel speck in a cell of 4³ fills
    /// 1/64 of it; an empty grid fills nothing.
    #[test]
    fn cache_fill_is_the_densest_cells_mean_over_the_maximum() {
        use super::cache_fill;
        let res = [16usize; 3];
        let mut w = vec![0.0f32; 16 * 16 * 16];
        w[(5 * 16 + 5) * 16 + 5] = 2.0;
        assert!((cache_fill(&map(res, &w), [4; 3]) - 1.0 / 64.0).abs() < 1e-12);
        assert!((cache_fill(&map(res, &w), [16; 3]) - 1.0).abs() < 1e-12);
        for v in w.iter_mut().take(16 * 16 * 8) {
            *v = 2.0;
        }
        assert!((cache_fill(&map(res, &w), [4; 3]) - 1.0).abs() < 1e-12);
        assert_eq!(cache_fill(&map(res, &vec![0.0; w.len()]), [4; 3]), 0.0);
    }

    /// The claim behind the skip, checked along one axis for every pair of resolutions up to
    /// 40: wherever a lone non-zero fine voxel i makes the fine trilinear lookup at x non-zero
    /// (x sampled every 1/64 voxel, clamped lookups at the box's ends), the light volume's
    /// trilinear lookup at x reads only light voxels within `near_radius` of i's light voxel
    /// (the one holding its centre, as the block means assign it).
    #[test]
    fn skipped_voxels_are_never_read_where_there_is_density() {
        let corners = |u: f64, n: usize| {
            let b = (u - 0.5).floor();
            let c = |v: f64| v.clamp(0.0, n as f64 - 1.0) as usize;
            [c(b), c(b + 1.0)]
        };
        for fine in 1..=40usize {
            for coarse in 1..=fine {
                let r = near_radius([fine as u32, 1, 1], [coarse as u32, 1, 1]) as i64;
                for i in 0..fine {
                    let home = ((2 * i + 1) * coarse / (2 * fine)) as i64;
                    for s in 0..=(fine * 64) {
                        let x = s as f64 / 64.0;
                        if !corners(x, fine).contains(&i) {
                            continue;
                        }
                        for c in corners(x * coarse as f64 / fine as f64, coarse) {
                            assert!(
                                (c as i64 - home).abs() <= r,
                                "{fine} → {coarse}: voxel {i} at x = {x} reads light voxel {c}, {home} ± {r}"
                            );
                        }
                    }
                }
            }
        }
        // Radius 1 is not enough for a factor between 1 and 2 (so 2 is needed there).
        assert_eq!(near_radius([3, 8, 8], [2, 8, 8]), 2);
        assert_eq!(near_radius([4, 8, 8], [2, 8, 8]), 1);
    }
}
