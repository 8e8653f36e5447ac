//! The descriptor on the GPU (`shaders/rpnn_descriptor.wgsl`): the pyramid lives in one storage
//! buffer, a batch of N configurations gives N × 2 251 floats.

use bytemuck::{Pod, Zeroable};
use nimbus_gpu::{Gpu, GpuError, shaders};

use crate::descriptor::{Config, DESCRIPTOR_LEN, LEVELS};
use crate::pyramid::{Cells, Pyramid};

/// `struct DescParams` of the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default, PartialEq)]
pub struct DescParams {
    pub aabb_min: [f32; 3],
    /// One mean free path in world units.
    pub mfp: f32,
    pub aabb_max: [f32; 3],
    pub n_configs: u32,
    /// Pyramid level of stencil levels 1..=10, 4 per row.
    pub level_of: [[u32; 4]; 3],
}

/// `struct LevelInfo` of the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default, PartialEq)]
pub struct LevelInfo {
    pub res: [u32; 3],
    pub offset: u32,
}

/// `struct Config` of the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default, PartialEq)]
pub struct GpuConfig {
    pub x: [f32; 4],
    pub view: [f32; 4],
    pub to_light: [f32; 4],
}

/// A pyramid uploaded to the GPU with its descriptor pipeline.
pub struct GpuDescriptor<'g> {
    gpu: &'g Gpu,
    params: DescParams,
    pipeline: wgpu::ComputePipeline,
    levels: wgpu::Buffer,
    info: wgpu::Buffer,
    /// `count` of a batch whose size the CPU knows: no limit.
    no_limit: wgpu::Buffer,
}

impl<'g> GpuDescriptor<'g> {
    pub fn new(gpu: &'g Gpu, pyr: &Pyramid) -> Result<Self, GpuError> {
        // The shader reads dense levels: a sparse level (bricks) is expanded here, once the
        // whole buffer is known to fit the adapter's binding limit.
        let cells = |l: &crate::pyramid::Level| {
            if l.is_stored() {
                l.res.iter().product::<usize>() as u64
            } else {
                0
            }
        };
        let total: u64 = pyr.levels.iter().map(cells).sum();
        gpu.check_storage("the density pyramid", total * 4)?;
        // The upload's host copy (dense levels copied, sparse ones expanded).
        nimbus_scene::memory::check(
            total as u128 * 4,
            "volume",
            "the density pyramid's GPU upload",
        )
        .map_err(|e| GpuError::Memory(e.to_string()))?;
        let mut data = Vec::with_capacity(total as usize);
        let mut info = Vec::new();
        for l in &pyr.levels {
            info.push(LevelInfo {
                res: l.res.map(|v| v as u32),
                offset: data.len() as u32,
            });
            match &l.cells {
                Cells::Absent => {}
                Cells::Dense(d) => data.extend_from_slice(d),
                Cells::Sparse(g) => g.try_for_each_row(|row| {
                    data.extend_from_slice(row);
                    Ok::<(), GpuError>(())
                })?,
            }
        }
        let mut level_of = [[0u32; 4]; 3];
        for k in 1..=LEVELS {
            level_of[(k - 1) / 4][(k - 1) % 4] = pyr.level_for(k as u32) as u32;
        }
        let params = DescParams {
            aabb_min: pyr.aabb_min.as_vec3().to_array(),
            mfp: (1.0 / pyr.mean_sigma) as f32,
            aabb_max: pyr.aabb_max.as_vec3().to_array(),
            n_configs: 0,
            level_of,
        };
        Ok(Self {
            gpu,
            params,
            pipeline: gpu.pipeline(
                "rpnn descriptor",
                &shaders::source("rpnn_descriptor.wgsl"),
                "descriptor",
            ),
            levels: gpu.storage("pyramid", &data),
            info: gpu.storage("pyramid levels", &info),
            no_limit: gpu.storage("descriptor no row limit", &[u32::MAX]),
        })
    }

    /// Descriptors of `configs` (rows of [`DESCRIPTOR_LEN`]).
    pub fn compute(&self, configs: &[Config]) -> Result<Vec<f32>, GpuError> {
        if configs.is_empty() {
            return Ok(Vec::new());
        }
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        let out = self.encode(&mut enc, configs, None)?;
        self.gpu.queue.submit([enc.finish()]);
        self.gpu.read(&out)
    }

    /// Records the descriptor pass for `configs` into `enc` and returns the buffer it fills
    /// (`configs.len()` × [`DESCRIPTOR_LEN`] floats), for later passes to read on the GPU.
    pub fn encode(
        &self,
        enc: &mut wgpu::CommandEncoder,
        configs: &[Config],
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) -> Result<wgpu::Buffer, GpuError> {
        let n = configs.len() as u64;
        self.gpu
            .check_storage("the descriptor batch", n * DESCRIPTOR_LEN as u64 * 4)?;
        let cfg: Vec<GpuConfig> = configs
            .iter()
            .map(|c| GpuConfig {
                x: c.x.extend(0.0).to_array(),
                view: c.view.extend(0.0).to_array(),
                to_light: c.to_light.extend(0.0).to_array(),
            })
            .collect();
        let cbuf = self.gpu.storage("configs", &cfg);
        let out = self
            .gpu
            .zeroed("descriptors", (n * DESCRIPTOR_LEN as u64 * 4).max(4));
        self.encode_rows(enc, &cbuf, None, configs.len(), &out, None, timestamps);
        Ok(out)
    }

    /// Records the descriptor pass for the configurations in `configs` (a buffer of
    /// [`GpuConfig`]) into `out`: `rows` of them, or fewer when `count` (a GPU-written u32)
    /// says so; with `indirect` (buffer, byte offset) the workgroup counts are read there
    /// (written on the GPU for the count).
    #[allow(clippy::too_many_arguments)]
    pub fn encode_rows(
        &self,
        enc: &mut wgpu::CommandEncoder,
        configs: &wgpu::Buffer,
        count: Option<&wgpu::Buffer>,
        rows: usize,
        out: &wgpu::Buffer,
        indirect: Option<(&wgpu::Buffer, u64)>,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let bound = self.bind_rows(configs, count, rows, out);
        self.encode_bound(enc, &bound, indirect, timestamps);
    }

    /// The uniform block and bind group of a descriptor pass over `configs` into `out` (see
    /// [`GpuDescriptor::encode_rows`]), made once for passes recorded again and again.
    pub fn bind_rows(
        &self,
        configs: &wgpu::Buffer,
        count: Option<&wgpu::Buffer>,
        rows: usize,
        out: &wgpu::Buffer,
    ) -> BoundDescriptor {
        let params = DescParams {
            n_configs: rows as u32,
            ..self.params
        };
        let ubuf = self.gpu.uniform("desc params", &params);
        let bind = self.gpu.bind(
            &self.pipeline,
            &[
                (0, &ubuf),
                (1, &self.levels),
                (2, &self.info),
                (3, configs),
                (4, out),
                (5, count.unwrap_or(&self.no_limit)),
            ],
        );
        BoundDescriptor {
            bind,
            _params: ubuf,
            rows,
        }
    }

    /// Records a descriptor pass made by [`GpuDescriptor::bind_rows`].
    pub fn encode_bound(
        &self,
        enc: &mut wgpu::CommandEncoder,
        bound: &BoundDescriptor,
        indirect: Option<(&wgpu::Buffer, u64)>,
        timestamps: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let (x, y) = Gpu::workgroups_1d((bound.rows * DESCRIPTOR_LEN) as u32);
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("rpnn descriptor"),
            timestamp_writes: timestamps,
        });
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &bound.bind, &[]);
        match indirect {
            Some((buf, offset)) => pass.dispatch_workgroups_indirect(buf, offset),
            None => pass.dispatch_workgroups(x, y, 1),
        }
    }
}

/// A descriptor pass's bind group and uniform block ([`GpuDescriptor::bind_rows`]).
pub struct BoundDescriptor {
    bind: wgpu::BindGroup,
    _params: wgpu::Buffer,
    rows: usize,
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::offset_of;

    fn members(name: &str) -> (Vec<(String, u32)>, u32) {
        shaders::struct_layout("rpnn_descriptor.wgsl", name)
    }

    #[test]
    fn layouts_match_wgsl() {
        let (m, span) = members("DescParams");
        assert_eq!(span as usize, std::mem::size_of::<DescParams>());
        let rust = [
            offset_of!(DescParams, aabb_min),
            offset_of!(DescParams, mfp),
            offset_of!(DescParams, aabb_max),
            offset_of!(DescParams, n_configs),
            offset_of!(DescParams, level_of),
        ];
        assert_eq!(m.iter().map(|x| x.1 as usize).collect::<Vec<_>>(), rust);
        let (m, span) = members("LevelInfo");
        assert_eq!(span as usize, std::mem::size_of::<LevelInfo>());
        assert_eq!(m[1].1 as usize, offset_of!(LevelInfo, offset));
        let (m, span) = members("Config");
        assert_eq!(span as usize, std::mem::size_of::<GpuConfig>());
        assert_eq!(m[2].1 as usize, offset_of!(GpuConfig, to_light));
    }
}
