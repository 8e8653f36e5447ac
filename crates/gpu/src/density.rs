//! The density on the GPU as a brick map over a 3D-texture atlas (`shaders/lib/
//! density_bricks.wgsl`), for grids that one storage binding cannot hold (lavapipe allows
//! 128 MiB per binding) and for sparse grids, which are never densified.
//!
//! The lattice is the sparse grid's (`nimbus_scene::brick`, 8³ bricks shifted by its offset; a
//! dense grid uses offset 0). `brick_index` gives each brick a slot in the atlas: slot 0 holds
//! zeros (absent bricks and all-zero dense bricks), every distinct constant value one shared
//! slot, every stored brick its own. The atlas is a `texture_3d<u32>` of 8³ blocks holding the
//! f32 bits (a u32 texture needs no filtering support), as few blocks wide as the adapter's
//! `max_texture_dimension_3d` allows. Voxels outside the box inside an edge brick read 0 but
//! are never read (lookups clamp to the box).
//!
//! [`AtlasPlan`] is the CPU half: the slot of every brick and what each slot holds, with
//! [`AtlasPlan::voxel`] the CPU twin of the WGSL `voxel()`; [`GpuDensity`] uploads a plan.

use std::collections::HashMap;

use bytemuck::{Pod, Zeroable};
use nimbus_scene::DensityGrid;
use nimbus_scene::brick::Content;

use crate::{Gpu, GpuError};

/// Brick edge in voxels (the sparse grid's; `8u` in `density_bricks.wgsl`).
pub use nimbus_scene::brick::DIM;
const VOXELS: usize = DIM * DIM * DIM;

/// `DensityInfo` of `shaders/lib/density_bricks.wgsl`.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Pod, Zeroable)]
pub struct DensityInfo {
    pub offset: [u32; 3],
    pub _a: u32,
    pub bricks: [u32; 3],
    pub _b: u32,
    pub atlas: [u32; 3],
    pub _c: u32,
}

/// What one atlas slot holds.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Slot {
    Constant(f32),
    /// Brick (bx, by, bz) of the grid, copied voxel by voxel.
    Brick([usize; 3]),
}

/// Where every brick of a grid lives in the atlas.
#[derive(Debug, Clone)]
pub struct AtlasPlan {
    pub info: DensityInfo,
    /// Slot of every brick, x fastest.
    pub index: Vec<u32>,
    slots: Vec<Slot>,
}

impl AtlasPlan {
    /// The plan for `grid` with an atlas at most `max_blocks` 8³ blocks along each axis.
    pub fn new(grid: &DensityGrid, max_blocks: u32) -> Result<Self, String> {
        let res = grid.res();
        let offset = grid.as_bricks().map_or([0; 3], |b| b.offset());
        let bricks: [usize; 3] = std::array::from_fn(|a| (res[a] + offset[a]).div_ceil(DIM));
        let n = bricks.iter().product::<usize>();
        let mut index = vec![0u32; n];
        let mut slots = vec![Slot::Constant(0.0)];
        let mut constants: HashMap<u32, u32> = HashMap::from([(0f32.to_bits(), 0)]);
        let mut put = |b: [usize; 3], c: Option<f32>, index: &mut [u32]| {
            let i = (b[2] * bricks[1] + b[1]) * bricks[0] + b[0];
            index[i] = match c {
                // -0.0 and 0.0 share slot 0.
                Some(v) => *constants
                    .entry(if v == 0.0 { 0 } else { v.to_bits() })
                    .or_insert_with(|| {
                        slots.push(Slot::Constant(v));
                        (slots.len() - 1) as u32
                    }),
                None => {
                    slots.push(Slot::Brick(b));
                    (slots.len() - 1) as u32
                }
            };
        };
        match grid.as_bricks() {
            Some(bk) => bk.visit(|v| {
                let b: [usize; 3] =
                    std::array::from_fn(|a| ((v.origin[a] + offset[a] as i64) as usize) / DIM);
                let c = match v.content {
                    Content::Constant(c) => Some(c),
                    Content::Stored(_) => None,
                };
                put(b, c, &mut index);
            }),
            None => {
                for bz in 0..bricks[2] {
                    for by in 0..bricks[1] {
                        for bx in 0..bricks[0] {
                            let lo = [bx * DIM, by * DIM, bz * DIM];
                            let hi: [usize; 3] =
                                std::array::from_fn(|a| (lo[a] + DIM).min(res[a]) - 1);
                            let zero = grid.max_in(lo, hi) == 0.0;
                            put([bx, by, bz], zero.then_some(0.0), &mut index);
                        }
                    }
                }
            }
        }
        let count = slots.len();
        let m = max_blocks.max(1) as usize;
        let ax = count.min(m);
        let ay = count.div_ceil(ax).min(m);
        let az = count.div_ceil(ax * ay);
        if az > m {
            return Err(format!(
                "{count} bricks of 8³ voxels need an atlas beyond {m} blocks per axis"
            ));
        }
        Ok(Self {
            info: DensityInfo {
                offset: offset.map(|v| v as u32),
                bricks: bricks.map(|v| v as u32),
                atlas: [ax as u32, ay as u32, az as u32],
                ..Default::default()
            },
            index,
            slots,
        })
    }

    /// Number of atlas slots in use.
    pub fn slots(&self) -> usize {
        self.slots.len()
    }

    /// Atlas size in texels.
    pub fn extent(&self) -> [u32; 3] {
        self.info.atlas.map(|v| v * DIM as u32)
    }

    /// Bytes of the atlas texture and the index.
    pub fn bytes(&self) -> u64 {
        let [x, y, z] = self.extent();
        x as u64 * y as u64 * z as u64 * 4 + self.index.len() as u64 * 4
    }

    /// The values of slot `s` (512, x fastest).
    fn slot_values(&self, grid: &DensityGrid, s: usize, out: &mut [f32; VOXELS]) {
        match self.slots[s] {
            Slot::Constant(c) => out.fill(c),
            Slot::Brick(b) => {
                let res = grid.res();
                let o = self.info.offset;
                for (i, v) in out.iter_mut().enumerate() {
                    let l = [i % DIM, (i / DIM) % DIM, i / (DIM * DIM)];
                    let g: [i64; 3] =
                        std::array::from_fn(|a| (b[a] * DIM + l[a]) as i64 - o[a] as i64);
                    *v = if (0..3).all(|a| g[a] >= 0 && (g[a] as usize) < res[a]) {
                        grid.get(g[0] as usize, g[1] as usize, g[2] as usize)
                    } else {
                        0.0
                    };
                }
            }
        }
    }

    /// CPU twin of `voxel()` in `shaders/lib/density_bricks.wgsl`: the value of voxel
    /// (x, y, z) read through the index and the slot contents.
    pub fn voxel(&self, grid: &DensityGrid, x: usize, y: usize, z: usize) -> f32 {
        let o = self.info.offset.map(|v| v as usize);
        let g = [x + o[0], y + o[1], z + o[2]];
        let [bx, by, _] = self.info.bricks.map(|v| v as usize);
        let s = self.index[((g[2] / DIM) * by + g[1] / DIM) * bx + g[0] / DIM] as usize;
        let mut vals = [0.0f32; VOXELS];
        self.slot_values(grid, s, &mut vals);
        vals[((g[2] % DIM) * DIM + g[1] % DIM) * DIM + g[0] % DIM]
    }
}

/// A grid uploaded as a brick map: bind `info` (uniform), `index` (storage) and `view` (the
/// atlas) to the bindings the stage declares for `DI`, `brick_index` and `atlas`.
pub struct GpuDensity {
    pub info: wgpu::Buffer,
    pub index: wgpu::Buffer,
    pub atlas: wgpu::Texture,
    pub view: wgpu::TextureView,
    pub plan_info: DensityInfo,
    pub slots: usize,
    pub bytes: u64,
}

impl GpuDensity {
    /// Uploads `grid` with the largest atlas the adapter allows.
    pub fn new(gpu: &Gpu, grid: &DensityGrid, what: &str) -> Result<Self, GpuError> {
        Self::with_max_blocks(
            gpu,
            grid,
            what,
            gpu.limits.max_texture_dimension_3d / DIM as u32,
        )
    }

    /// Uploads `grid` with an atlas of at most `max_blocks` blocks per axis (tests lower it to
    /// exercise the wrapping of slots over the atlas's rows and layers).
    pub fn with_max_blocks(
        gpu: &Gpu,
        grid: &DensityGrid,
        what: &str,
        max_blocks: u32,
    ) -> Result<Self, GpuError> {
        let plan = AtlasPlan::new(grid, max_blocks).map_err(|msg| GpuError::Atlas {
            what: what.to_string(),
            msg,
            adapter: gpu.info.name.clone(),
        })?;
        gpu.check_storage(
            &format!("the brick index of {what}"),
            plan.index.len() as u64 * 4,
        )?;
        // The atlas is checked against the memory budget before it is created (on a software
        // adapter it is host memory; a failed allocation inside wgpu would abort).
        nimbus_scene::memory::check(
            plan.bytes() as u128,
            "volume",
            &format!(
                "the GPU atlas of {what} ({} bricks of 8³ voxels)",
                plan.slots()
            ),
        )
        .map_err(|e| GpuError::Atlas {
            what: what.to_string(),
            msg: e.msg,
            adapter: gpu.info.name.clone(),
        })?;
        let [ex, ey, ez] = plan.extent();
        let atlas = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("density atlas"),
            size: wgpu::Extent3d {
                width: ex,
                height: ey,
                depth_or_array_layers: ez,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D3,
            format: wgpu::TextureFormat::R32Uint,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        // One row of blocks at a time (ex × 8 × 8 texels): a few MiB of staging at most.
        let [ax, ay, _] = plan.info.atlas.map(|v| v as usize);
        let mut row = vec![0.0f32; ax * VOXELS];
        let mut vals = [0.0f32; VOXELS];
        let mut pending = 0usize;
        for r0 in (0..plan.slots()).step_by(ax) {
            if pending > 64 << 20 {
                // Queued texture writes hold staging copies until a submission completes:
                // flush every 64 MiB so a large atlas is not held twice.
                gpu.queue.submit([]);
                let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
                pending = 0;
            }
            pending += row.len() * 4;
            let n = ax.min(plan.slots() - r0);
            row.fill(0.0);
            for k in 0..n {
                plan.slot_values(grid, r0 + k, &mut vals);
                for (i, v) in vals.iter().enumerate() {
                    let (x, y, z) = (i % DIM, (i / DIM) % DIM, i / (DIM * DIM));
                    row[(z * DIM + y) * ax * DIM + k * DIM + x] = *v;
                }
            }
            let (by, bz) = ((r0 / ax) % ay, r0 / (ax * ay));
            gpu.queue.write_texture(
                wgpu::TexelCopyTextureInfo {
                    texture: &atlas,
                    mip_level: 0,
                    origin: wgpu::Origin3d {
                        x: 0,
                        y: (by * DIM) as u32,
                        z: (bz * DIM) as u32,
                    },
                    aspect: wgpu::TextureAspect::All,
                },
                bytemuck::cast_slice(&row),
                wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(ex * 4),
                    rows_per_image: Some(DIM as u32),
                },
                wgpu::Extent3d {
                    width: ex,
                    height: DIM as u32,
                    depth_or_array_layers: DIM as u32,
                },
            );
        }
        let view = atlas.create_view(&Default::default());
        Ok(Self {
            info: gpu.uniform("density info", &plan.info),
            index: gpu.storage("brick index", &plan.index),
            atlas,
            view,
            plan_info: plan.info,
            slots: plan.slots(),
            bytes: plan.bytes(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::offset_of;

    #[test]
    fn layout_matches_wgsl() {
        let (members, span) = crate::shaders::struct_layout("pt_bricks.wgsl", "DensityInfo");
        assert_eq!(span as usize, std::mem::size_of::<DensityInfo>());
        let rust = [
            ("offset", offset_of!(DensityInfo, offset)),
            ("_a", offset_of!(DensityInfo, _a)),
            ("bricks", offset_of!(DensityInfo, bricks)),
            ("_b", offset_of!(DensityInfo, _b)),
            ("atlas", offset_of!(DensityInfo, atlas)),
            ("_c", offset_of!(DensityInfo, _c)),
        ];
        let wgsl: Vec<(&str, usize)> = members
            .iter()
            .map(|(n, o)| (n.as_str(), *o as usize))
            .collect();
        assert_eq!(wgsl, rust);
    }

    fn noise_grid(res: [usize; 3]) -> Vec<f32> {
        let mut s = 7u32;
        (0..res.iter().product::<usize>())
            .map(|i| {
                s = s.wrapping_mul(1664525).wrapping_add(1013904223);
                let (x, z) = (i % res[0], i / (res[0] * res[1]));
                // Noise, a constant slab, zeros: every kind of slot.
                if z < 5 {
                    (s >> 8) as f32 / (1 << 24) as f32
                } else if z < 14 && x < 9 {
                    0.5
                } else {
                    0.0
                }
            })
            .collect()
    }

    /// The plan reads every voxel back through index and slots, dense and sparse (a shifted
    /// lattice), with an atlas narrow enough to wrap over rows and layers.
    #[test]
    fn plan_reads_every_voxel_back() {
        let res = [19, 10, 23];
        let data = noise_grid(res);
        let dense = DensityGrid::new(res, data.clone()).unwrap();
        let sparse = DensityGrid::from_bricks(
            nimbus_scene::brick::from_dense(res, &data, [5, 2, 7]).unwrap(),
        );
        for g in [&dense, &sparse] {
            let plan = AtlasPlan::new(g, 3).unwrap();
            assert!(plan.info.atlas[2] > 1, "{:?}", plan.info.atlas);
            // Slot 0 (zeros) and one shared slot for the constant 0.5 at most.
            let constants = plan
                .slots
                .iter()
                .filter(|s| matches!(s, Slot::Constant(_)))
                .count();
            assert!(constants <= 2, "{constants} constant slots");
            assert!(
                plan.slots() < plan.index.len(),
                "absent bricks share slot 0"
            );
            for z in 0..res[2] {
                for y in 0..res[1] {
                    for x in 0..res[0] {
                        assert_eq!(plan.voxel(g, x, y, z), g.get(x, y, z), "({x}, {y}, {z})");
                    }
                }
            }
        }
        assert!(AtlasPlan::new(&dense, 2).is_err()); // 8 slots for 11
    }
}
