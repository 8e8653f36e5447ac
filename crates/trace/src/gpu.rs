//! The path tracer on the GPU (`shaders/pt.wgsl`, `shaders/pt_bricks.wgsl`): whole images (`--method pt --device gpu`,
//! progressive) and batches of indirect-radiance estimates for RPNN training records. Same
//! algorithm as [`crate::integrator`] in f32, with a global majorant instead of the majorant
//! grid and next-event estimation alone (no MIS) for a sun disc. Supported: HG or isotropic
//! phase, a delta or disc sun, a constant sky or an environment map (reached by phase sampling,
//! the nearest texel); other scenes get a clear error (use the CPU path tracer).
//!
//! The density is one storage buffer when the grid is dense and fits one binding, else a brick
//! map over a 3D-texture atlas ([`nimbus_gpu::density`]): a sparse grid is never densified, and
//! a dense box beyond the adapter's binding size still renders. Both read the same values.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use nimbus_gpu::density::GpuDensity;
use nimbus_gpu::params::VolumeParams;
use nimbus_gpu::{Gpu, GpuError, shaders};
use nimbus_scene::{Image, Phase, Scene, Sky};

/// `struct Task` of the shader.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default)]
pub struct Task {
    pub spp: u32,
    pub sample_offset: u32,
    pub mode: u32,
    pub max_depth: i32,
    pub n_tasks: u32,
    pub slots: u32,
    /// The environment map's size (0: the constant sky).
    pub env_w: u32,
    pub env_h: u32,
}

/// `struct LiTask` of the shader: a shading configuration.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default)]
pub struct LiTask {
    pub x: [f32; 4],
    pub view: [f32; 4],
    pub to_light: [f32; 4],
}

/// Errors of the GPU path tracer.
#[derive(Debug, thiserror::Error)]
pub enum GpuPtError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[error("{0} (the GPU path tracer supports HG/isotropic phase; use --device cpu)")]
    Unsupported(String),
    #[error("{0}")]
    Memory(String),
}

/// Samples per invocation per dispatch (keeps each dispatch short enough for any driver).
pub const SPP_PER_DISPATCH: u32 = 4;

fn f3(v: DVec3) -> [f32; 3] {
    v.as_vec3().to_array()
}

/// A scene uploaded for GPU path tracing.
pub struct GpuPathTracer<'g> {
    gpu: &'g Gpu,
    params: VolumeParams,
    pipeline: wgpu::ComputePipeline,
    params_buf: wgpu::Buffer,
    density: Density,
    max_depth: i32,
    /// Progressive sums (R, G, B, Σ lum²) per pixel and the samples they hold.
    acc: Option<wgpu::Buffer>,
    samples: u32,
    /// The environment map's texels (one black texel without one) and its size.
    env: wgpu::Buffer,
    env_size: [u32; 2],
}

/// The density as the shader reads it.
pub enum Density {
    Dense(wgpu::Buffer),
    Bricks(Box<GpuDensity>),
}

/// How [`GpuPathTracer::with_storage`] stores the density.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DensityStorage {
    /// A dense grid that fits one storage binding: one buffer; anything else: a brick map.
    Auto,
    /// A brick map whose atlas is at most this many 8³ blocks per axis.
    Bricks { max_blocks: u32 },
}

/// The uniform block of a scene for the volume shaders that trace it (this path tracer, the
/// RPNN's whole-sample renderer): box, density scale, majorant, albedo, HG g, sun, constant sky,
/// camera, image size, seed. Refuses what the GPU tracking code does not model (a tabulated
/// phase function; an environment map is the caller's to refuse or bind).
pub fn scene_params(scene: &Scene) -> Result<VolumeParams, GpuPtError> {
    let src = scene.source.display();
    let g = match &scene.medium.phase {
        Phase::HenyeyGreenstein(hg) => hg.g(),
        Phase::Isotropic => 0.0,
        Phase::Tabulated(_) => {
            return Err(GpuPtError::Unsupported(format!(
                "{src}: tabulated (Mie) phase function"
            )));
        }
    };
    let vol = &scene.volume;
    let r = vol.grid().res();
    let (forward, right, up, tan_half) = scene.camera.basis();
    let aabb = vol.aabb();
    Ok(VolumeParams {
        aabb_min: f3(aabb.min),
        density_scale: vol.density_scale() as f32,
        aabb_max: f3(aabb.max),
        albedo: scene.medium.albedo as f32,
        d_res: r.map(|v| v as u32),
        g: g as f32,
        sigma_max: vol.max_sigma_t().max(1e-30) as f32,
        sun_dir: f3(scene.sun.as_ref().map_or(DVec3::Y, |s| s.dir)),
        sun_irradiance: f3(scene.sun.as_ref().map_or(DVec3::ZERO, |s| s.irradiance)),
        sun_cos_max: scene
            .sun
            .as_ref()
            .map_or(1.0, |s| s.angular_radius.cos() as f32),
        sun_disc_radiance: scene
            .sun
            .as_ref()
            .filter(|s| !s.is_delta())
            .map_or(0.0, |s| {
                (1.0 / (std::f64::consts::PI * s.angular_radius.sin().powi(2))) as f32
            }),
        sky_radiance: match &scene.sky {
            Some(Sky::Constant(c)) => f3(*c),
            _ => [0.0; 3],
        },
        cam_origin: f3(scene.camera.origin),
        tan_half: tan_half as f32,
        cam_forward: f3(forward),
        aspect: (scene.camera.width as f64 / scene.camera.height as f64) as f32,
        cam_right: f3(right),
        cam_up: f3(up),
        width: scene.camera.width as u32,
        height: scene.camera.height as u32,
        seed: scene.render.seed as u32,
        ..Default::default()
    })
}

/// The scene's environment map for the shaders' `lib/env_map.wgsl`: its texels × scale as
/// RGBA f32 (one black texel without a map, so the binding exists) and its size ([0, 0]: the
/// constant sky).
pub fn upload_env(gpu: &Gpu, scene: &Scene) -> Result<(wgpu::Buffer, [u32; 2]), GpuError> {
    let Some(Sky::Env(env)) = &scene.sky else {
        return Ok((gpu.storage("environment map", &[[0.0f32; 4]]), [0, 0]));
    };
    let img = env.image();
    let s = env.scale() as f32;
    gpu.check_storage("the environment map", img.pixels.len() as u64 * 16)?;
    let texels: Vec<[f32; 4]> = img
        .pixels
        .iter()
        .map(|p| [p[0] * s, p[1] * s, p[2] * s, 0.0])
        .collect();
    Ok((
        gpu.storage("environment map", &texels),
        [img.width as u32, img.height as u32],
    ))
}

impl Density {
    /// The scene's density on the GPU: one storage buffer when the grid is dense and fits one
    /// binding (with [`DensityStorage::Auto`]), else a brick map.
    pub fn upload(gpu: &Gpu, scene: &Scene, storage: DensityStorage) -> Result<Self, GpuPtError> {
        let vol = &scene.volume;
        let r = vol.grid().res();
        let dense_fits = vol.grid().as_dense().is_some()
            && gpu
                .check_storage("the density grid", (r[0] * r[1] * r[2]) as u64 * 4)
                .is_ok();
        Ok(match (storage, vol.grid().as_dense()) {
            (DensityStorage::Auto, Some(d)) if dense_fits => {
                Density::Dense(gpu.storage("density", d))
            }
            (DensityStorage::Auto, _) => Density::Bricks(Box::new(GpuDensity::new(
                gpu,
                vol.grid(),
                "the density grid",
            )?)),
            (DensityStorage::Bricks { max_blocks }, _) => Density::Bricks(Box::new(
                GpuDensity::with_max_blocks(gpu, vol.grid(), "the density grid", max_blocks)?,
            )),
        })
    }

    /// Whether the shader reads a brick map (the `*_bricks.wgsl` stage) or one buffer.
    pub fn is_bricks(&self) -> bool {
        matches!(self, Density::Bricks(_))
    }

    /// A bind group of `pipeline` with `common` and the density's bindings (1 = the buffer or
    /// the brick index, 5 = the brick map's `DensityInfo`, 6 = its atlas).
    pub fn bind(
        &self,
        gpu: &Gpu,
        pipeline: &wgpu::ComputePipeline,
        common: &[(u32, &wgpu::Buffer)],
    ) -> wgpu::BindGroup {
        let mut b = common.to_vec();
        match self {
            Density::Dense(d) => {
                b.push((1, d));
                gpu.bind(pipeline, &b)
            }
            Density::Bricks(k) => {
                b.extend([(1, &k.index), (5, &k.info)]);
                gpu.bind_with(pipeline, &b, &[(6, &k.view)])
            }
        }
    }
}

impl<'g> GpuPathTracer<'g> {
    pub fn new(gpu: &'g Gpu, scene: &Scene) -> Result<Self, GpuPtError> {
        Self::with_storage(gpu, scene, DensityStorage::Auto)
    }

    /// Like [`GpuPathTracer::new`], choosing how the density is stored (tests compare both).
    pub fn with_storage(
        gpu: &'g Gpu,
        scene: &Scene,
        storage: DensityStorage,
    ) -> Result<Self, GpuPtError> {
        let params = scene_params(scene)?;
        let (env, env_size) = upload_env(gpu, scene)?;
        let density = Density::upload(gpu, scene, storage)?;
        let stage = if density.is_bricks() {
            "pt_bricks.wgsl"
        } else {
            "pt.wgsl"
        };
        Ok(Self {
            gpu,
            pipeline: gpu.pipeline("path tracer", &shaders::source(stage), "pt"),
            params_buf: gpu.uniform("pt params", &params),
            density,
            params,
            max_depth: scene
                .render
                .max_depth
                .unwrap_or(crate::integrator::MAX_SCATTERINGS)
                .min(i32::MAX as u32) as i32,
            acc: None,
            samples: 0,
            env,
            env_size,
        })
    }

    /// A new camera (position, orientation, field of view or image size): the progressive sums
    /// start again.
    pub fn set_camera(&mut self, camera: &nimbus_scene::Camera) {
        let (forward, right, up, tan_half) = camera.basis();
        self.params.cam_origin = f3(camera.origin);
        self.params.cam_forward = f3(forward);
        self.params.cam_right = f3(right);
        self.params.cam_up = f3(up);
        self.params.tan_half = tan_half as f32;
        self.params.aspect = (camera.width as f64 / camera.height as f64) as f32;
        if (self.params.width, self.params.height) != (camera.width as u32, camera.height as u32) {
            self.acc = None;
        }
        self.params.width = camera.width as u32;
        self.params.height = camera.height as u32;
        self.samples = 0;
    }

    /// The scene's sun and sky as they are now (a moved sun, an atmosphere's new colours): the
    /// progressive sums start again.
    pub fn set_lights(&mut self, scene: &Scene) {
        let sun = scene.sun.as_ref();
        self.params.sun_dir = f3(sun.map_or(DVec3::Y, |s| s.dir));
        self.params.sun_irradiance = f3(sun.map_or(DVec3::ZERO, |s| s.irradiance));
        if let Some(Sky::Constant(c)) = &scene.sky {
            self.params.sky_radiance = f3(*c);
        }
        self.samples = 0;
    }

    /// Empties the progressive sums; the next samples are drawn with `seed`.
    pub fn reset(&mut self, seed: u64) -> Result<(), GpuPtError> {
        self.params.seed = (seed ^ (seed >> 32)) as u32;
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let (w, h) = (self.params.width as usize, self.params.height as usize);
        match &self.acc {
            Some(b) => {
                let mut enc = self.gpu.device.create_command_encoder(&Default::default());
                enc.clear_buffer(b, 0, None);
                self.gpu.queue.submit([enc.finish()]);
            }
            None => {
                self.gpu.check_storage("the image", (w * h) as u64 * 16)?;
                self.acc = Some(self.gpu.zeroed("pt image", (w * h) as u64 * 16));
            }
        }
        self.samples = 0;
        Ok(())
    }

    /// Adds `spp` samples per pixel to the progressive sums (sample indices continue from the
    /// samples already in them, so steps give the image one call gives).
    pub fn add(&mut self, spp: u32) -> Result<(), GpuPtError> {
        if self.acc.is_none() {
            self.reset(self.params.seed as u64)?;
        }
        let (w, h) = (self.params.width as usize, self.params.height as usize);
        let none = self.gpu.zeroed("no tasks", 48);
        let out = self.acc.as_ref().expect("made by reset");
        let mut done = 0;
        while done < spp {
            let n = SPP_PER_DISPATCH.min(spp - done);
            let task = Task {
                spp: n,
                sample_offset: self.samples + done,
                mode: 0,
                max_depth: self.max_depth,
                ..Default::default()
            };
            self.dispatch(task, &none, out, (w * h) as u32);
            done += n;
        }
        self.samples += spp;
        Ok(())
    }

    /// Samples per pixel in the progressive sums.
    pub fn samples(&self) -> u32 {
        self.samples
    }

    /// The mean image of the progressive sums and the variance of each pixel's mean luminance.
    pub fn image(&self) -> Result<(Image, Vec<f32>), GpuPtError> {
        let (w, h) = (self.params.width as usize, self.params.height as usize);
        let Some(out) = &self.acc else {
            return Ok((Image::new(w, h), vec![0.0; w * h]));
        };
        let sums: Vec<[f32; 4]> = self.gpu.read(out)?;
        let spp = self.samples;
        let n = spp.max(1) as f64;
        let mut img = Image::new(w, h);
        let mut var = vec![0.0f32; w * h];
        for (i, s) in sums.iter().enumerate() {
            let rgb = [s[0] as f64 / n, s[1] as f64 / n, s[2] as f64 / n];
            img.pixels[i] = rgb.map(|v| v as f32);
            let mean = (rgb[0] + rgb[1] + rgb[2]) / 3.0;
            if spp > 1 {
                var[i] = ((s[3] as f64 / n - mean * mean).max(0.0) / (n - 1.0)) as f32;
            }
        }
        Ok((img, var))
    }

    fn dispatch(&self, task: Task, tasks: &wgpu::Buffer, out: &wgpu::Buffer, invocations: u32) {
        // Images see the environment map; the training records' indirect radiance (mode 1) is
        // for unit irradiance from one direction and no sky.
        let [env_w, env_h] = if task.mode == 0 {
            self.env_size
        } else {
            [0, 0]
        };
        let task = Task {
            env_w,
            env_h,
            ..task
        };
        let tbuf = self.gpu.uniform("pt task", &task);
        let bind = self.density.bind(
            self.gpu,
            &self.pipeline,
            &[
                (0, &self.params_buf),
                (2, &tbuf),
                (3, tasks),
                (4, out),
                (7, &self.env),
            ],
        );
        self.gpu.dispatch_1d(&self.pipeline, &bind, invocations);
    }

    /// Renders `spp` samples per pixel with seed `seed`: (mean image, variance of each pixel's
    /// mean luminance).
    pub fn render(&mut self, spp: u32, seed: u64) -> Result<(Image, Vec<f32>), GpuPtError> {
        self.reset(seed)?;
        self.add(spp)?;
        self.image()
    }

    /// For each configuration, (Σ L_i, Σ L_i², n) over `samples` (rounded up to whole dispatches)
    /// indirect-radiance samples for unit irradiance from its light direction; `round` selects
    /// independent random numbers for progressive estimation.
    pub fn indirect(
        &mut self,
        configs: &[LiTask],
        samples: u32,
        round: u32,
        seed: u64,
    ) -> Result<Vec<[f64; 3]>, GpuPtError> {
        if configs.is_empty() {
            return Ok(Vec::new());
        }
        self.params.seed = (seed ^ (seed >> 32)) as u32;
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let slots = samples.div_ceil(SPP_PER_DISPATCH).clamp(1, 4096);
        let per = samples.div_ceil(slots);
        let tasks = self.gpu.storage("li tasks", configs);
        let n = configs.len() as u64 * slots as u64;
        self.gpu.check_storage("the estimate slots", n * 16)?;
        let out = self.gpu.zeroed("li sums", n * 16);
        let task = Task {
            spp: per,
            sample_offset: round.wrapping_mul(1 << 20),
            mode: 1,
            max_depth: self.max_depth,
            n_tasks: configs.len() as u32,
            slots,
            ..Default::default()
        };
        self.dispatch(task, &tasks, &out, n as u32);
        let sums: Vec<[f32; 4]> = self.gpu.read(&out)?;
        Ok(sums
            .chunks(slots as usize)
            .map(|c| {
                c.iter().fold([0.0f64; 3], |a, s| {
                    [a[0] + s[0] as f64, a[1] + s[1] as f64, a[2] + s[2] as f64]
                })
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::offset_of;

    /// (member offsets, size) of a struct in `pt.wgsl`, computed by naga.
    fn wgsl_layout(name: &str) -> (Vec<u32>, u32) {
        let (m, span) = shaders::struct_layout("pt.wgsl", name);
        (m.into_iter().map(|x| x.1).collect(), span)
    }

    #[test]
    fn layouts_match_wgsl() {
        let (off, span) = wgsl_layout("Task");
        assert_eq!(span as usize, std::mem::size_of::<Task>());
        let rust = [
            offset_of!(Task, spp),
            offset_of!(Task, sample_offset),
            offset_of!(Task, mode),
            offset_of!(Task, max_depth),
            offset_of!(Task, n_tasks),
            offset_of!(Task, slots),
            offset_of!(Task, env_w),
            offset_of!(Task, env_h),
        ];
        assert_eq!(off.iter().map(|&o| o as usize).collect::<Vec<_>>(), rust);
        let (off, span) = wgsl_layout("LiTask");
        assert_eq!(span as usize, std::mem::size_of::<LiTask>());
        let rust = [
            offset_of!(LiTask, x),
            offset_of!(LiTask, view),
            offset_of!(LiTask, to_light),
        ];
        assert_eq!(off.iter().map(|&o| o as usize).collect::<Vec<_>>(), rust);
    }
}
