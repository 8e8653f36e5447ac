//! The light grid: the resolution the photon stages work at and the density each stage reads.
//!
//! J (16 bytes per voxel), its flux directions (16) and T_sun (4) live at the light resolution
//! ([`crate::settings::default_light_res`]); the trace, the sun pass and the upsampling read a
//! density at that resolution ("work density": the grid itself, or its block means,
//! `nimbus_scene::downsample`). The ray marcher reads J and T_sun there and the grid at its own
//! resolution: from the work density when they coincide, else from a dense buffer or — for a
//! sparse grid or one beyond a storage binding — the brick map the GPU path tracer uses
//! (`shaders/lib/density_bricks.wgsl`), so a sparse cloud is never densified.

use nimbus_gpu::density::GpuDensity;
use nimbus_scene::DensityGrid;

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
            MarchDensity::Bricks(_) => "photon_raymarch_bricks.wgsl",
            _ => "photon_raymarch.wgsl",
        }
    }
}

/// The light resolution for `grid`: the setting (each axis in 1..= the grid's), else the
/// default for this adapter.
pub(super) fn light_res(
    gpu: &Gpu,
    grid: &DensityGrid,
    settings: &PmSettings,
) -> Result<[u32; 3], PmError> {
    let d_res = grid.res();
    let r = match settings.light_res {
        Some(r) => check_axes("light_res", r, d_res, "density resolution")?,
        None => crate::settings::default_light_res(
            d_res,
            gpu.limits
                .max_storage_buffer_binding_size
                .min(gpu.limits.max_buffer_size),
        ),
    };
    let voxels = r.iter().map(|&v| v as u64).product::<u64>();
    if voxels > u32::MAX as u64 {
        return Err(PmError::Setting {
            field: "light_res",
            msg: format!("{r:?} = {voxels} voxels exceed the 2^32 the kernels can index"),
        });
    }
    Ok(r)
}

/// The work density at `l_res` (the grid's values when equal, its block means otherwise) and
/// its largest value.
pub(super) fn work_density(
    grid: &DensityGrid,
    l_res: [u32; 3],
) -> Result<(std::borrow::Cow<'_, [f32]>, f32), PmError> {
    let l = l_res.map(|v| v as usize);
    let data = if l == grid.res() {
        grid.dense().map_err(PmError::Memory)?
    } else {
        nimbus_scene::downsample::block_means(grid, l).into()
    };
    let max = data.iter().fold(0.0f32, |m, &v| m.max(v));
    Ok((data, max))
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

/// 1 for each cache cell (of `i_res` over the box) that no stage after the trace reads, given
/// the work density at `l_res`: no non-zero light voxel within the cell's extent grown by one
/// cell and three light voxels. The upsampling of a voxel reads the 3³ cells around its own,
/// and only voxels within `near_radius` ≤ 2 light voxels of density are upsampled; the trilinear
/// density a beam scatters on is non-zero only within one light voxel of a non-zero one.
pub fn skippable_cells(work: &[f32], l_res: [u32; 3], i_res: [u32; 3]) -> Vec<u32> {
    let l = l_res.map(|v| v as usize);
    let i = i_res.map(|v| v as usize);
    // Light voxels with density within 3 voxels (separable dilation, axis by axis).
    let mut mask: Vec<bool> = work.iter().map(|&v| v > 0.0).collect();
    for a in 0..3 {
        let stride = [1, l[0], l[0] * l[1]][a];
        let mut out = vec![false; mask.len()];
        for (idx, o) in out.iter_mut().enumerate() {
            let c = (idx / stride) % l[a];
            let lo = c.saturating_sub(3);
            let hi = (c + 3).min(l[a] - 1);
            *o = (lo..=hi).any(|k| mask[idx - c * stride + k * stride]);
        }
        mask = out;
    }
    // Cells overlapped by such a voxel, then grown by one cell.
    let mut used = vec![false; i.iter().product()];
    let span = |v: usize, a: usize| (v * i[a] / l[a])..=(((v + 1) * i[a]).div_ceil(l[a]) - 1);
    for (idx, _) in mask.iter().enumerate().filter(|(_, m)| **m) {
        let v = [idx % l[0], (idx / l[0]) % l[1], idx / (l[0] * l[1])];
        for z in span(v[2], 2) {
            for y in span(v[1], 1) {
                for x in span(v[0], 0) {
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
        VolumeParams {
            d_res: self.fine_res,
            ..self.params
        }
    }

    /// Whether the light volumes are coarser than the density grid.
    pub fn light_is_coarse(&self) -> bool {
        self.fine_res != self.params.light_res
    }

    /// Resolution of the light volumes (J, T_sun) and of the density the photons trace.
    pub fn light_res(&self) -> [u32; 3] {
        self.params.light_res
    }

    /// What a user should know about coarse light volumes (`None` at full resolution): their
    /// resolution and, when a light voxel at the grid's densest is more than
    /// [`THICK_LIGHT_VOXEL`] mean free paths wide, that light varying inside it is smoothed —
    /// small dense features then come out too dark (a 6-voxel sphere at 9 voxels per light
    /// voxel, τ ≈ 4.5: 0.3 × the path tracer; BENCHMARKS.md "Volumes at scale").
    pub fn light_note(&self) -> Option<String> {
        if !self.light_is_coarse() {
            return None;
        }
        let [x, y, z] = self.params.light_res;
        let k = (0..3)
            .map(|a| self.fine_res[a] as f64 / self.params.light_res[a] as f64)
            .fold(0.0, f64::max);
        let mut note =
            format!("light volumes {x}×{y}×{z} (each ≤ {k:.1} grid voxels along an axis)");
        let tau = self.light_voxel_depth();
        if tau > THICK_LIGHT_VOXEL {
            note += &format!(
                "; at the densest a light voxel is {tau:.1} mean free paths wide: shadows and multiply scattered light inside it are smoothed and small dense features come out too dark (the path tracer, or a finer --light-res where the adapter allows a larger J)"
            );
        }
        Some(note)
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
        let work: Vec<f32> = match &self.march_density {
            MarchDensity::Work => data.to_vec(),
            MarchDensity::Dense(b) => {
                self.gpu
                    .queue
                    .write_buffer(b, 0, bytemuck::cast_slice(data));
                let grid = DensityGrid::new(self.fine_res.map(|v| v as usize), data.to_vec())
                    .map_err(PmError::Memory)?;
                work_density(&grid, self.params.light_res)?.0.into_owned()
            }
            MarchDensity::Bricks(_) => {
                return Err(PmError::Unsupported(
                    "a density sequence needs the grid in one dense GPU buffer; this scene's grid (sparse, or beyond one storage binding) is read through a brick map"
                        .into(),
                ));
            }
        };
        self.gpu
            .queue
            .write_buffer(&self.density, 0, bytemuck::cast_slice(&work));
        if self.params.skip_empty != 0 {
            let skip = skippable_cells(&work, self.params.light_res, self.params.i_res);
            self.gpu
                .queue
                .write_buffer(&self.cell_skip, 0, bytemuck::cast_slice(&skip));
        }
        self.grid_max = data.iter().fold(0.0f32, |m, &v| m.max(v)) as f64;
        self.sun.dirty = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{near_radius, skippable_cells};

    /// One non-zero light voxel in a 40³ grid under a 10³ cache (4 voxels per cell): the cells
    /// within the reach of the voxel (3 voxels, then one cell) are kept, every other is skipped;
    /// an empty grid skips everything, a full one nothing.
    #[test]
    fn skippable_cells_keep_the_reach_of_density() {
        let (l, i) = ([40u32; 3], [10u32; 3]);
        let mut work = vec![0.0f32; 40 * 40 * 40];
        work[(20 * 40 + 20) * 40 + 20] = 0.5;
        let skip = skippable_cells(&work, l, i);
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
            skippable_cells(&vec![0.0; work.len()], l, i)
                .iter()
                .all(|&s| s == 1)
        );
        assert!(
            skippable_cells(&vec![1.0; work.len()], l, i)
                .iter()
                .all(|&s| s == 0)
        );
        // Cells coarser than voxels and not dividing them: a voxel's cells are those it overlaps.
        let mut w = vec![0.0f32; 7 * 7 * 7];
        w[0] = 1.0;
        let s = skippable_cells(&w, [7; 3], [3; 3]);
        assert_eq!(s.iter().filter(|&&v| v == 0).count(), 27);
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
