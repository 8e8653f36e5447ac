//! A whole RPNN sample per pixel on the GPU (Kallweit 2017 §4.4 as [`crate::render`] does it,
//! without the CPU): `shaders/lib/rpnn_sample_core.wgsl` traces the camera rays, delta-tracks
//! them to their first real collision with the path tracer's WGSL tracking code, adds the
//! direct light there (ratio-tracked shadow rays to the sun, one phase-sampled sky direction)
//! and writes its network queries (one per collision, and one more per sky direction with the
//! paper's directions) straight into the descriptor stage's input; the descriptor and the
//! layers ([`crate::gpu_mlp`]) follow, and a resolve pass adds known + the predictions (the sky
//! head's contracted with the sky's coefficients, [`crate::sky`]) to the pixel's running sums.
//! Nothing comes back until [`GpuSampler::image`].
//!
//! Pixels go through in chunks of the network's batch ([`GpuMlp::max_batch`], divided by
//! 1 + the sky directions per collision with the paper's directions); a chunk's
//! queries are compacted by an atomic counter, so pixels that see only sky cost no network
//! work, and the later passes are dispatched indirectly for the count. The chunks' uniform
//! blocks and bind groups are made once; per sample only each chunk's sample index is
//! written, and the chunks of one sample share a command buffer.
//!
//! Supported: HG or isotropic phase, a delta or disc sun, no sky, a constant sky or an
//! environment map (nearest texel, as `nimbus_scene::EnvMap::radiance`) through the model's
//! sky head, a constant sky in the paper's directions (`rpnn-dirs`: uniform on the sphere, one
//! more query each). The paper's directions under an environment map (importance-sampled from
//! the map) and tabulated (Mie) phase functions stay with [`crate::render`] (CPU shading,
//! either network backend).
//!
//! The CPU twin is [`crate::render::accumulate`] with the same network: the tests compare the
//! two images statistically (independent random numbers), and the contraction with
//! [`crate::sky::product_in_frame`].

use std::time::Instant;

use bytemuck::{Pod, Zeroable};
use nimbus_gpu::params::VolumeParams;
use nimbus_gpu::timing::StageTimer;
use nimbus_gpu::{Gpu, shaders};
use nimbus_scene::{Image, Scene, Sky};
use nimbus_trace::gpu::{Density, DensityStorage, scene_params, upload_env};

use crate::descriptor::DESCRIPTOR_LEN;
use crate::gpu::{BoundDescriptor, GpuConfig, GpuDescriptor};
use crate::gpu_mlp::{BoundMlp, GpuMlp, Precision};
use crate::model::Rpnn;
use crate::pyramid::Pyramid;
use crate::render::{RenderError, SkySh};

/// `struct Sample` of the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default, PartialEq)]
pub struct SampleParams {
    pub first: u32,
    pub count: u32,
    pub sample: u32,
    pub flags: u32,
    pub env_w: u32,
    pub env_h: u32,
    pub outputs: u32,
    pub sun_outputs: u32,
    pub degree: u32,
    pub rows: u32,
    pub sky_dirs: u32,
    /// One sample in every `query_every` of a pixel asks the network
    /// ([`crate::render::RpnnOptions::query_every`]).
    pub query_every: u32,
}

/// Passes timed per submission (a query set holds at most 4 096 timestamps, two per pass).
const TIMER_PASSES: u32 = 2048;

const SKY: u32 = 1;
const ENV: u32 = 2;
const SKY_HEAD: u32 = 4;

/// GPU milliseconds per stage (timestamp queries; zero without them) and the wall time, summed
/// over the samples since the last [`GpuSampler::reset`].
#[derive(Debug, Clone, Default)]
pub struct SampleTimes {
    /// Camera rays, tracking, direct light, query compaction.
    pub shade_ms: f64,
    pub descriptor_ms: f64,
    pub inference_ms: f64,
    /// Network rows into the pixels (the sky head's contraction included).
    pub resolve_ms: f64,
    /// Wall-clock milliseconds of [`GpuSampler::add`], GPU work finished.
    pub total_ms: f64,
}

/// How a [`GpuSampler`] is built.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SamplerSettings {
    /// Network queries per chunk, lowered to what the adapter's bindings hold.
    pub max_batch: usize,
    pub storage: DensityStorage,
    pub precision: Precision,
    /// The network's kernel.
    pub tiles: crate::gpu_mlp::Tiles,
    /// Under a constant sky without the sky head: the paper's sky directions per collision
    /// (Kallweit §4.4, `rpnn-dirs`).
    pub sky_dirs: u32,
    /// One sample in every this many of a pixel asks the network (1: every sample, the paper;
    /// [`crate::render::RpnnOptions::query_every`]).
    pub query_every: u32,
}

impl Default for SamplerSettings {
    fn default() -> Self {
        Self {
            max_batch: crate::gpu_mlp::DEFAULT_BATCH,
            storage: DensityStorage::Auto,
            precision: Precision::F32,
            tiles: Default::default(),
            sky_dirs: 4,
            query_every: 1,
        }
    }
}

/// Why a scene or model needs the CPU shading path ([`crate::render`]); `None` when the whole
/// sample runs on the GPU. Under a sky without `sky_sh` the paper's `sky_dirs` directions are
/// taken, which the GPU sample does for a constant sky.
pub fn unsupported(
    scene: &Scene,
    model: &Rpnn,
    sky_sh: Option<&SkySh>,
    sky_dirs: u32,
) -> Option<String> {
    if let Err(e) = scene_params(scene) {
        return Some(e.to_string());
    }
    let head = sky_sh.is_some() && model.sky_coeffs() > 0;
    match &scene.sky {
        Some(Sky::Env(_)) if !head => {
            return Some(
                "the paper's sky directions under an environment map run with CPU shading (its \
                 importance sampling is not on the GPU; a model with a sky head runs there)"
                    .into(),
            );
        }
        Some(Sky::Constant(_)) if !head && sky_dirs == 0 => {
            return Some("a sky without the sky head needs at least one sky direction".into());
        }
        _ => {}
    }
    if let Some(s) = sky_sh
        && head
        && scene.sky.is_some()
        && model.sky_coeffs() < crate::sky::coeffs(s.degree)
    {
        return Some(format!(
            "the model's sky head gives {} coefficients, the sky's degree {} needs {}",
            model.sky_coeffs(),
            s.degree,
            crate::sky::coeffs(s.degree)
        ));
    }
    None
}

/// A scene, its density pyramid and a network on the GPU, with the running sums of an image.
pub struct GpuSampler<'g> {
    gpu: &'g Gpu,
    desc: GpuDescriptor<'g>,
    mlp: GpuMlp<'g>,
    params: VolumeParams,
    params_buf: wgpu::Buffer,
    density: Density,
    shade: wgpu::ComputePipeline,
    args_pipeline: wgpu::ComputePipeline,
    resolve: wgpu::ComputePipeline,
    /// Indirect dispatch arguments written on the GPU per chunk (descriptor, resolve, layers).
    args: wgpu::Buffer,
    layer_tiles: wgpu::Buffer,
    base: SampleParams,
    /// Queries per chunk (the network's batch).
    rows: usize,
    /// [0]: this chunk's queries; [1]: all queries since the last reset.
    counter: wgpu::Buffer,
    configs: wgpu::Buffer,
    extra: wgpu::Buffer,
    heads: wgpu::Buffer,
    env: wgpu::Buffer,
    sky_tab: wgpu::Buffer,
    acc: wgpu::Buffer,
    /// Per chunk of pixels: its uniform block and bind groups, made once (and again for a new
    /// image size); the descriptor pass's and the layers' bind groups serve every chunk.
    chunks: Vec<Chunk>,
    desc_bound: BoundDescriptor,
    mlp_bound: BoundMlp,
    samples: u32,
    timer: StageTimer,
    pub times: SampleTimes,
}

/// One chunk of pixels: `first .. first + count`.
struct Chunk {
    first: usize,
    count: usize,
    params: wgpu::Buffer,
    shade: wgpu::BindGroup,
    args: wgpu::BindGroup,
    resolve: wgpu::BindGroup,
}

impl<'g> GpuSampler<'g> {
    /// Uploads `scene`'s density and lights, the pyramid and the network. `sky_sh`: the sky
    /// through the sky head (else, under a constant sky, 4 of the paper's sky directions; see
    /// [`unsupported`]); `max_batch`: network queries per chunk, lowered to what the adapter's
    /// bindings hold.
    pub fn new(
        gpu: &'g Gpu,
        scene: &Scene,
        pyr: &Pyramid,
        model: &Rpnn,
        sky_sh: Option<&SkySh>,
        max_batch: usize,
    ) -> Result<Self, RenderError> {
        let s = SamplerSettings {
            max_batch,
            ..Default::default()
        };
        Self::with_settings(gpu, scene, pyr, model, sky_sh, &s)
    }

    /// Like [`GpuSampler::new`], with every setting: how the density is stored (tests compare
    /// both), how the network's weights and activations are ([`Precision`]), the paper's sky
    /// directions.
    pub fn with_settings(
        gpu: &'g Gpu,
        scene: &Scene,
        pyr: &Pyramid,
        model: &Rpnn,
        sky_sh: Option<&SkySh>,
        settings: &SamplerSettings,
    ) -> Result<Self, RenderError> {
        let SamplerSettings {
            max_batch,
            storage,
            precision,
            tiles,
            sky_dirs,
            query_every,
        } = *settings;
        crate::render::check_query_every(query_every)?;
        if let Some(why) = unsupported(scene, model, sky_sh, sky_dirs) {
            return Err(RenderError::Setting(format!(
                "{}: {why}",
                scene.source.display()
            )));
        }
        // The GPU's own refusals (a binding or atlas too large) stay GPU errors, so a caller
        // can fall back to CPU shading; the rest are settings.
        let gpu_err = |e: nimbus_trace::gpu::GpuPtError| match e {
            nimbus_trace::gpu::GpuPtError::Gpu(g) => RenderError::Gpu(g),
            e => RenderError::Setting(e.to_string()),
        };
        let params = scene_params(scene).map_err(gpu_err)?;
        let mut flags = match &scene.sky {
            None => 0,
            Some(Sky::Constant(_)) => SKY,
            Some(Sky::Env(_)) => SKY | ENV,
        };
        let (env, [env_w, env_h]) = upload_env(gpu, scene)?;
        let (degree, table) = match sky_sh {
            Some(s) if model.sky_coeffs() > 0 && scene.sky.is_some() => {
                flags |= SKY_HEAD;
                (s.degree as u32, crate::sky::gpu_table(&s.world))
            }
            _ => (0, vec![0.0; 1]),
        };
        // The paper's directions: a constant sky without the sky head.
        let dirs = match &scene.sky {
            Some(Sky::Constant(_)) if flags & SKY_HEAD == 0 => sky_dirs,
            _ => 0,
        };
        // Without a sky to contract with, the sky head's layers are left out.
        let sun_only;
        let model = if flags & SKY_HEAD == 0 && model.sky_coeffs() > 0 {
            sun_only = model.without_sky_head();
            &sun_only
        } else {
            model
        };
        let density = Density::upload(gpu, scene, storage).map_err(gpu_err)?;
        let desc = GpuDescriptor::new(gpu, pyr)?;
        let mlp = GpuMlp::with_options(
            gpu,
            model,
            max_batch,
            crate::gpu_mlp::NetOptions { precision, tiles },
        )?;
        let rows = mlp.max_batch;
        if rows < 1 + dirs as usize {
            return Err(RenderError::Setting(format!(
                "{} sky directions need a network batch of at least {} queries, this one holds {rows}",
                dirs,
                dirs + 1
            )));
        }
        gpu.check_storage("the descriptor batch", (rows * DESCRIPTOR_LEN * 4) as u64)?;
        let (w, h) = (scene.camera.width, scene.camera.height);
        gpu.check_storage("the image", (w * h) as u64 * 16)?;
        let stage = if density.is_bricks() {
            "rpnn_sample_bricks.wgsl"
        } else {
            "rpnn_sample.wgsl"
        };
        let source = shaders::source(stage);
        let tiles = mlp.layer_tiles();
        let counter = gpu.zeroed("rpnn query counter", 12);
        let configs = gpu.zeroed(
            "rpnn query configs",
            (rows * std::mem::size_of::<GpuConfig>()) as u64,
        );
        let descriptors = gpu.zeroed("rpnn descriptors", (rows * DESCRIPTOR_LEN * 4) as u64);
        let desc_bound = desc.bind_rows(&configs, Some(&counter), rows, &descriptors);
        // Every chunk binds the whole batch; the count the shading pass writes lowers it.
        let mlp_bound = mlp.bind(&descriptors, rows, Some(&counter));
        let mut sampler = Self {
            gpu,
            shade: gpu.pipeline("rpnn shade", &source, "shade"),
            args_pipeline: gpu.pipeline("rpnn dispatch args", &source, "dispatch_args"),
            resolve: gpu.pipeline("rpnn resolve", &source, "resolve"),
            args: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("rpnn dispatch args"),
                size: 12 * (2 + tiles.len() as u64),
                usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDIRECT,
                mapped_at_creation: false,
            }),
            layer_tiles: gpu.storage("rpnn layer tiles", &tiles),
            base: SampleParams {
                flags,
                env_w,
                env_h,
                outputs: mlp.outputs as u32,
                sun_outputs: mlp.sun_outputs as u32,
                degree,
                rows: rows as u32,
                sky_dirs: dirs,
                query_every,
                ..Default::default()
            },
            desc,
            mlp,
            params_buf: gpu.uniform("rpnn sample params", &params),
            params,
            density,
            rows,
            counter,
            configs,
            extra: gpu.zeroed("rpnn query weights", rows as u64 * 16),
            heads: gpu.zeroed("rpnn query heads", rows as u64 * 32),
            env,
            sky_tab: gpu.storage("sky coefficients", &table),
            acc: gpu.zeroed("rpnn image sums", (w * h) as u64 * 16),
            chunks: Vec::new(),
            desc_bound,
            mlp_bound,
            samples: 0,
            timer: StageTimer::new(gpu, TIMER_PASSES),
            times: SampleTimes::default(),
        };
        sampler.build_chunks();
        Ok(sampler)
    }

    /// The chunks of the current image size with their bind groups.
    fn build_chunks(&mut self) {
        let gpu = self.gpu;
        let pixels = (self.params.width * self.params.height) as usize;
        // A collision takes up to 1 + sky_dirs slots of the batch.
        let step = (self.rows / (1 + self.base.sky_dirs as usize)).max(1);
        self.chunks = (0..pixels)
            .step_by(step)
            .map(|first| {
                let count = (pixels - first).min(step);
                let params = gpu.uniform(
                    "rpnn sample",
                    &SampleParams {
                        first: first as u32,
                        count: count as u32,
                        ..self.base
                    },
                );
                let shade = self.density.bind(
                    gpu,
                    &self.shade,
                    &[
                        (0, &self.params_buf),
                        (2, &params),
                        (3, &self.counter),
                        (4, &self.configs),
                        (7, &self.extra),
                        (8, &self.acc),
                        (9, &self.env),
                        (14, &self.heads),
                    ],
                );
                let args = gpu.bind(
                    &self.args_pipeline,
                    &[
                        (2, &params),
                        (3, &self.counter),
                        (12, &self.args),
                        (13, &self.layer_tiles),
                    ],
                );
                let resolve = gpu.bind(
                    &self.resolve,
                    &[
                        (2, &params),
                        (3, &self.counter),
                        (4, &self.configs),
                        (7, &self.extra),
                        (8, &self.acc),
                        (10, self.mlp.output()),
                        (14, &self.heads),
                        (11, &self.sky_tab),
                    ],
                );
                Chunk {
                    first,
                    count,
                    params,
                    shade,
                    args,
                    resolve,
                }
            })
            .collect();
    }

    /// Takes the scene's camera, sun and constant sky as they are now (the viewer moves them);
    /// a new image size empties the sums. The density, the environment map and the sky's
    /// coefficients are fixed at [`GpuSampler::new`] (the coefficients: [`GpuSampler::set_sky`]).
    pub fn sync(&mut self, scene: &Scene) -> Result<(), RenderError> {
        let seed = self.params.seed;
        let p = scene_params(scene).map_err(|e| RenderError::Setting(e.to_string()))?;
        let resized = (p.width, p.height) != (self.params.width, self.params.height);
        self.params = VolumeParams { seed, ..p };
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        if resized {
            let (w, h) = (p.width as u64, p.height as u64);
            self.gpu.check_storage("the image", w * h * 16)?;
            self.acc = self.gpu.zeroed("rpnn image sums", w * h * 16);
            self.samples = 0;
            self.build_chunks();
        }
        Ok(())
    }

    /// New sky coefficients for the sky head (a sky whose colours follow the sun).
    pub fn set_sky(&mut self, sky_sh: &SkySh) {
        if self.base.flags & SKY_HEAD != 0 {
            let table = crate::sky::gpu_table(&sky_sh.world);
            self.gpu
                .queue
                .write_buffer(&self.sky_tab, 0, bytemuck::cast_slice(&table));
        }
    }

    /// Empties the sums; the next samples are drawn with `seed`.
    pub fn reset(&mut self, seed: u64) {
        self.params.seed = (seed ^ (seed >> 32)) as u32;
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.acc, 0, None);
        enc.clear_buffer(&self.counter, 0, None);
        self.gpu.queue.submit([enc.finish()]);
        self.samples = 0;
        self.times = SampleTimes::default();
    }

    /// Adds `spp` samples per pixel to the sums (sample indices continue from those already
    /// in them, so steps give the image one call gives). A submission holds the chunks of one
    /// sample that the timer has room for (all of them below 2 048 timed passes).
    pub fn add(&mut self, spp: u32) -> Result<(), RenderError> {
        let t_all = Instant::now();
        // Timed passes per chunk: shade, descriptor, the layers, resolve.
        let per_chunk = 3 + self.mlp.layer_tiles().len();
        let chunks_per_submit = (TIMER_PASSES as usize / per_chunk).max(1);
        for s in 0..spp {
            let sample = self.samples + s;
            for lo in (0..self.chunks.len()).step_by(chunks_per_submit) {
                let hi = (lo + chunks_per_submit).min(self.chunks.len());
                let mut enc = self.gpu.device.create_command_encoder(&Default::default());
                for k in lo..hi {
                    // Each chunk has its own uniform block: the writes land before this
                    // submission, in queue order after the previous one.
                    let c = &self.chunks[k];
                    let p = SampleParams {
                        first: c.first as u32,
                        count: c.count as u32,
                        sample,
                        ..self.base
                    };
                    self.gpu
                        .queue
                        .write_buffer(&c.params, 0, bytemuck::bytes_of(&p));
                    self.encode_chunk(&mut enc, k);
                }
                self.timer.resolve(&mut enc);
                self.gpu.queue.submit([enc.finish()]);
                for (name, ms) in self.timer.read(self.gpu) {
                    let t = &mut self.times;
                    match name {
                        "shade" => t.shade_ms += ms,
                        "descriptor" => t.descriptor_ms += ms,
                        "resolve" => t.resolve_ms += ms,
                        _ => t.inference_ms += ms,
                    }
                }
            }
        }
        // Reading the timestamps waits for each submission; without them this is the wait.
        self.gpu
            .device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| nimbus_gpu::GpuError::Readback(e.to_string()))?;
        self.samples += spp;
        self.times.total_ms += t_all.elapsed().as_secs_f64() * 1e3;
        Ok(())
    }

    fn encode_chunk(&mut self, enc: &mut wgpu::CommandEncoder, k: usize) {
        let c = &self.chunks[k];
        enc.clear_buffer(&self.counter, 0, Some(4));
        enc.clear_buffer(&self.counter, 8, Some(4));
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("rpnn shade"),
                timestamp_writes: self.timer.pass("shade"),
            });
            pass.set_pipeline(&self.shade);
            pass.set_bind_group(0, &c.shade, &[]);
            let (x, y) = Gpu::workgroups_1d(c.count as u32);
            pass.dispatch_workgroups(x, y, 1);
        }
        {
            let mut pass = enc.begin_compute_pass(&Default::default());
            pass.set_pipeline(&self.args_pipeline);
            pass.set_bind_group(0, &c.args, &[]);
            pass.dispatch_workgroups(1, 1, 1);
        }
        self.desc.encode_bound(
            enc,
            &self.desc_bound,
            Some((&self.args, 0)),
            self.timer.pass("descriptor"),
        );
        self.mlp.encode_bound(
            enc,
            &self.mlp_bound,
            Some((&self.args, 24)),
            Some(&mut self.timer),
        );
        let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("rpnn resolve"),
            timestamp_writes: self.timer.pass("resolve"),
        });
        pass.set_pipeline(&self.resolve);
        pass.set_bind_group(0, &c.resolve, &[]);
        pass.dispatch_workgroups_indirect(&self.args, 12);
    }

    /// Samples per pixel in the sums.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// Network queries since the last reset (read from the GPU).
    pub fn queries(&self) -> Result<u64, RenderError> {
        let c: Vec<u32> = self.gpu.read(&self.counter)?;
        Ok(c[1] as u64)
    }

    /// The mean image and the variance of each pixel's mean luminance (0 below two samples).
    pub fn image(&self) -> Result<(Image, Vec<f32>), RenderError> {
        let (w, h) = (self.params.width as usize, self.params.height as usize);
        let sums: Vec<[f32; 4]> = self.gpu.read(&self.acc)?;
        let n = self.samples.max(1) as f64;
        let mut img = Image::new(w, h);
        let mut var = vec![0.0f32; w * h];
        for (i, s) in sums.iter().take(w * h).enumerate() {
            let rgb = [s[0] as f64 / n, s[1] as f64 / n, s[2] as f64 / n];
            img.pixels[i] = rgb.map(|v| v as f32);
            if self.samples > 1 {
                let mean = (rgb[0] + rgb[1] + rgb[2]) / 3.0;
                var[i] = ((s[3] as f64 / n - mean * mean).max(0.0) / (n - 1.0)) as f32;
            }
        }
        Ok((img, var))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sample_struct_matches_wgsl() {
        let (members, size) = shaders::struct_layout("rpnn_sample.wgsl", "Sample");
        assert_eq!(size as usize, std::mem::size_of::<SampleParams>());
        let names = [
            "first",
            "count",
            "sample",
            "flags",
            "env_w",
            "env_h",
            "outputs",
            "sun_outputs",
            "degree",
            "rows",
            "sky_dirs",
            "query_every",
        ];
        assert_eq!(members.len(), names.len());
        for (i, (name, off)) in members.iter().enumerate() {
            assert_eq!(name, names[i]);
            assert_eq!(*off as usize, 4 * i);
        }
    }
}
