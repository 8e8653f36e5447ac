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
        Some(r) => {
            if r.contains(&0) || r.iter().zip(d_res).any(|(&a, b)| a as usize > b) {
                return Err(PmError::Setting {
                    field: "light_res",
                    msg: format!(
                        "each axis must lie in 1..=density resolution {d_res:?}, got {r:?}"
                    ),
                });
            }
            r
        }
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
                "; at the densest a light voxel is {tau:.1} mean free paths wide: shadows and multiply scattered light inside it are smoothed and small dense features come out too dark (a finer --light-res or the path tracer)"
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
        match &self.march_density {
            MarchDensity::Work => {
                self.gpu
                    .queue
                    .write_buffer(&self.density, 0, bytemuck::cast_slice(data));
            }
            MarchDensity::Dense(b) => {
                self.gpu
                    .queue
                    .write_buffer(b, 0, bytemuck::cast_slice(data));
                let grid = DensityGrid::new(self.fine_res.map(|v| v as usize), data.to_vec())
                    .map_err(PmError::Memory)?;
                let (work, _) = work_density(&grid, self.params.light_res)?;
                self.gpu
                    .queue
                    .write_buffer(&self.density, 0, bytemuck::cast_slice(&work));
            }
            MarchDensity::Bricks(_) => {
                return Err(PmError::Unsupported(
                    "a density sequence needs a grid whose density fits one GPU storage binding"
                        .into(),
                ));
            }
        }
        self.sun.dirty = true;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::near_radius;

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
