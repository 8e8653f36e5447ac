//! The GPU pipeline of temporally-coherent photon mapping (Elek 2012 §3.2): per frame, trace n_g
//! beams into H_new, update the ring I = I − H_old + H_new; per image, upsample I → J and ray
//! march. Compute pipelines are data: one entry per stage, each with its shader, bindings and
//! CPU twin (`stages.rs`); every buffer is allocated at the size of one plan that the memory
//! checks sum (`plan.rs`).

use std::f64::consts::PI;

use glam::DVec3;
use nimbus_gpu::timing::StageTimer;
use nimbus_gpu::{Gpu, GpuError, shaders};
use nimbus_scene::{Camera, Image, Phase, Scene, Sky};

use nimbus_gpu::params::VolumeParams;

mod changes;
mod gather;
pub mod light;
mod params;
mod plan;
mod raymarch;
mod readback;
pub mod stages;
mod sun;
mod view;

pub use gather::{
    DEFAULT_GATHER_BEAMS, DEFAULT_GATHER_BOUNCES, DEFAULT_GATHER_RING, DEFAULT_GATHER_SPREAD,
    GATHER_MAX_EXTRA, GATHER_MIN_FILL, GatherParams, GatherSettings, SunShadow, Terminal,
};
pub use plan::{Buf, BufferPlan};

pub use crate::cache_layout::{
    CELL_BYTES, CELL_WORDS, SHARED_CELLS, W_SCALE, shared_cells, trace_constants, trace_source,
};

/// Errors of the photon mapper.
#[derive(Debug, thiserror::Error)]
pub enum PmError {
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// The work was cancelled through the token given to [`PhotonMapper::set_cancel`].
    #[error("cancelled")]
    Cancelled(#[from] nimbus_scene::Cancelled),
    #[error("{0}")]
    Unsupported(String),
    #[error("setting `{field}`: {msg}")]
    Setting { field: &'static str, msg: String },
    /// The buffers would exceed the memory budget (`--max-memory`).
    #[error("field `{}`: {}", .0.field, .0.msg)]
    Memory(nimbus_scene::FieldError),
    /// A cache cell's u32 sum would have wrapped: the image would be silently wrong.
    #[error(
        "the photon cache overflowed: a cell of the {cells} received more than 2^32 fixed-point units ({units:.2e} beam weights) in the ring of {ring} frames × {beams} beams; use fewer beams (--beams), a smaller ring (--ring), a finer cache (--cache-res) or a lower density_scale"
    )]
    Overflow {
        cells: String,
        units: f64,
        ring: u32,
        beams: u32,
    },
}

pub use crate::settings::{LobeAxis, PmSettings, PmVariant, default_cache_res, similarity_order};

struct Stage {
    pipeline: wgpu::ComputePipeline,
    bind: wgpu::BindGroup,
}

/// Per-stage GPU time of the last frame/image, milliseconds (when timestamps are available).
pub type StageTimes = Vec<(&'static str, f64)>;

/// The photon mapper for one scene on one device.
pub struct PhotonMapper<'g> {
    gpu: &'g Gpu,
    /// Checked between generations and gather dispatches ([`Self::set_cancel`]).
    cancel: nimbus_scene::Cancel,
    pub params: VolumeParams,
    pub settings: PmSettings,
    cells: u32,
    /// Entries of each light-volume pool (`crate::light_map`: 512 zeros, then the stored voxels).
    voxels: u32,
    /// The light volumes' layout (its work density uploaded and dropped).
    map: crate::light_map::LightMap,
    /// The light bricks' index and slots (`shaders/lib/light_bricks.wgsl`).
    light_map: wgpu::Buffer,
    trace: Stage,
    update: Stage,
    /// Per-cell values of I (computed once per upsampling).
    cells_stage: Stage,
    upsample: Stage,
    raymarch: Option<(Stage, usize, usize)>,
    params_buf: wgpu::Buffer,
    slot_buf: wgpu::Buffer,
    h_new: wgpu::Buffer,
    density: wgpu::Buffer,
    j: wgpu::Buffer,
    total: wgpu::Buffer,
    ring: wgpu::Buffer,
    /// Beams (sun, sky) held by each ring slot.
    slot_beams: Vec<(u64, u64)>,
    frame: u32,
    sun_fraction: f64,
    cell_volume: f64,
    timer: StageTimer,
    pub last_times: StageTimes,
    raymarch_pipeline: wgpu::ComputePipeline,
    image_buf: Option<wgpu::Buffer>,
    /// Sun transmittance per density voxel (exact single scattering) and its pass.
    t_sun: wgpu::Buffer,
    sun_stage: Stage,
    /// The amortised rebuild's state (see `mapper/sun.rs`).
    sun: sun::SunRebuild,
    cell_vals: wgpu::Buffer,
    cell_aux: wgpu::Buffer,
    cell_dir: wgpu::Buffer,
    j_dir: wgpu::Buffer,
    j_hi: wgpu::Buffer,
    overflow: wgpu::Buffer,
    /// The view point each ring slot's view-dependent words were traced for (`mapper/view.rs`).
    slot_view: Vec<Option<[f32; 3]>>,
    /// The view point J's in-scattering was upsampled for; `None`: J holds fluences and lobes.
    j_view: Option<[f32; 3]>,
    /// The density grid's resolution (`params.d_res` is the light resolution the photon
    /// stages work at: `mapper/light.rs`).
    fine_res: [u32; 3],
    /// Per cache cell, 1 where beams skip ahead (`params.skip_empty`; `light::skippable_cells`).
    cell_skip: wgpu::Buffer,
    /// The grid's largest value (the work density's is `params.d_max`).
    grid_max: f64,
    /// The densest cache cell's fill (`light::cache_fill`).
    cache_fill: f64,
    /// Each cache cell's fill (`light::cell_fills`), read by the final gathering.
    cell_fill: wgpu::Buffer,
    /// The ray marcher's uniform block (`params` with `d_res = fine_res`) and density.
    march_buf: wgpu::Buffer,
    march_density: light::MarchDensity,
    /// The final gathering's pipeline and running sums (`mapper/gather.rs`), made on first use.
    gather: Option<gather::GatherState>,
    /// Every buffer's planned size (`mapper/plan.rs`).
    plan: BufferPlan,
}

fn f3(v: DVec3) -> [f32; 3] {
    v.as_vec3().to_array()
}

/// `r` (a resolution setting named `field`) with every axis in 1..=`limit`'s, or the error.
fn check_axes(
    field: &'static str,
    r: [u32; 3],
    limit: [usize; 3],
    what: &str,
) -> Result<[u32; 3], PmError> {
    if r.contains(&0) || r.iter().zip(limit).any(|(&a, b)| a as usize > b) {
        return Err(PmError::Setting {
            field,
            msg: format!("each axis must lie in 1..={what} {limit:?}, got {r:?}"),
        });
    }
    Ok(r)
}

impl<'g> PhotonMapper<'g> {
    pub fn new(gpu: &'g Gpu, scene: &Scene, settings: PmSettings) -> Result<Self, PmError> {
        let g = match &scene.medium.phase {
            Phase::HenyeyGreenstein(hg) => hg.g(),
            Phase::Isotropic => 0.0,
            Phase::Tabulated(_) => {
                return Err(PmError::Unsupported(format!(
                    "{}: photon mapping represents light with Henyey–Greenstein lobes (Elek 2012 §4.1.2); use phase = {{ kind = \"hg\", g = … }} (a Mie cloud is close to g = 0.86)",
                    scene.source.display()
                )));
            }
        };
        if matches!(scene.sky, Some(Sky::Env(_))) {
            return Err(PmError::Unsupported(format!(
                "{}: photon mapping supports a constant sky radiance, not an environment map",
                scene.source.display()
            )));
        }
        if settings.ring == 0 || settings.ring > 4096 {
            return Err(PmError::Setting {
                field: "ring",
                msg: format!("must lie in 1..=4096, got {}", settings.ring),
            });
        }
        if !(settings.detail_noise.is_finite() && (0.0..=16.0).contains(&settings.detail_noise)) {
            return Err(PmError::Setting {
                field: "detail_noise",
                msg: format!("must lie in [0, 16] voxels, got {}", settings.detail_noise),
            });
        }
        if settings.beams_per_frame > 1 << 26 {
            return Err(PmError::Setting {
                field: "beams_per_frame",
                msg: format!(
                    "at most {} per frame, got {}",
                    1u32 << 26,
                    settings.beams_per_frame
                ),
            });
        }
        let vol = &scene.volume;
        // The photon stages work at the light resolution (the grid's unless J would not fit
        // one storage binding: `mapper/light.rs`); the ray marcher reads the grid itself.
        let fine_res = vol.grid().res().map(|v| v as u32);
        let grid_max = vol.grid().stats().max as f64;
        let mut map = light::light_map(gpu, vol, grid_max, &settings)?;
        let d_res = map.res();
        let light_res = d_res.map(|v| v as u32);
        let i_res = match settings.cache_res {
            Some(r) => check_axes(
                "cache_res",
                r,
                d_res,
                "light resolution (the density's unless --light-res)",
            )?,
            None => default_cache_res(
                d_res,
                settings.default_max_cells(d_res, gpu.limits.max_storage_buffer_binding_size),
            ),
        };
        let cells = i_res.iter().product::<u32>();
        if cells as u64 > crate::cache_layout::MAX_CACHE_CELLS {
            return Err(PmError::Setting {
                field: "cache_res",
                msg: format!(
                    "{i_res:?} = {cells} cells; at most {} (the ring update's dispatch limit)",
                    crate::cache_layout::MAX_CACHE_CELLS
                ),
            });
        }
        // The pools' entries: J (16 bytes each) was checked against one binding and 2^32
        // entries by `light::light_map`.
        let voxels = map.pool_len() as u32;
        gpu.check_storage("the photon stages' density", voxels as u64 * 4)?;
        let (march_plan, march_bytes) = light::march_plan(gpu, vol.grid(), light_res);
        let aabb = vol.aabb();
        let d_max = map.max() as f64;
        let radius = 0.5 * aabb.extent().length();
        let cell = aabb.extent() / DVec3::new(i_res[0] as f64, i_res[1] as f64, i_res[2] as f64);
        // Beam budget split by incident power (per unit area of the bounding sphere).
        let lum = |v: DVec3| (v.x + v.y + v.z) / 3.0;
        let p_sun = scene
            .sun
            .as_ref()
            .map_or(0.0, |s| lum(s.irradiance) * PI * radius * radius);
        let p_sky = match &scene.sky {
            Some(Sky::Constant(c)) => lum(*c) * 4.0 * PI * PI * radius * radius,
            _ => 0.0,
        };
        let sun_fraction = if p_sun + p_sky > 0.0 {
            p_sun / (p_sun + p_sky)
        } else {
            0.0
        };
        let shared_cap = shared_cells(gpu.limits.max_compute_workgroup_storage_size);
        let use_shared = !settings.force_global_atomics && cells <= shared_cap;
        let params = params::volume_params(
            scene,
            &settings,
            g,
            &params::Layout {
                d_res: d_res.map(|v| v as u32),
                i_res,
                light_res,
                fine_res,
                d_max,
                use_shared,
                light_full: map.is_full(),
                light_voxels: map.light_voxels(),
            },
        );
        let plan = BufferPlan::new(&settings, &params, voxels, map.words() as u64, march_bytes);
        plan.check(gpu, &settings, voxels)?;
        let march_density = light::march_density(gpu, vol.grid(), march_plan)?;
        let params_buf = gpu.uniform("pm params", &params);
        let march_buf = gpu.uniform("pm ray-marcher params", &params::march(&params, fine_res));
        let density = gpu.storage("density D (light bricks)", &map.density);
        let light_map = gpu.storage("light bricks", &map.gpu_words());
        let cell_skip = if params.skip_empty != 0 {
            gpu.storage(
                "skippable cache cells",
                &light::skippable_cells(&map, i_res),
            )
        } else {
            gpu.zeroed("skippable cache cells (unused)", 4)
        };
        let cache_fill = light::cache_fill(&map, i_res);
        let cell_fill = gpu.storage("cache cell fills", &light::cell_fills(&map, i_res));
        map.drop_values();
        let h_new = gpu.zeroed("H_new", plan.bytes(Buf::HNew));
        let ring = gpu.zeroed("ring H_0..H_m-1", plan.bytes(Buf::Ring));
        let total = gpu.zeroed("I", plan.bytes(Buf::Total));
        let overflow = gpu.zeroed("cache overflow flag", plan.bytes(Buf::Overflow));
        let j = gpu.zeroed("J", plan.bytes(Buf::J));
        // Bound by the ray marcher in both variants (4 bytes when unused).
        let t_sun = gpu.zeroed("sun transmittance", plan.bytes(Buf::SunT));
        let cell_vals = gpu.zeroed("cache cells", plan.bytes(Buf::CellVals));
        let cell_aux = gpu.zeroed("cache cell aux", plan.bytes(Buf::CellAux));
        let cell_dir = gpu.zeroed("cache cell flux directions", plan.bytes(Buf::CellDir));
        // Bound by the upsampling and the ray marcher in both variants (16 bytes when unused).
        let j_dir = gpu.zeroed("J flux directions", plan.bytes(Buf::JDir));
        let j_hi = gpu.zeroed("J high-order flux directions", plan.bytes(Buf::JHigh));
        let slot_buf = gpu.uniform("ring slot", &[0u32; 4]);
        // The light volumes' layout, compiled into every stage that reads them.
        let sparse = ("LIGHT_SPARSE", if map.is_full() { 0.0 } else { 1.0 });
        // Workgroup memory sized to the cache (one cell when unused): more workgroups resident.
        let shared = trace_constants(if use_shared { cells.max(1) } else { 1 })[0];
        // The stage table (`mapper/stages.rs`), each binding resolved to its buffer.
        let buffer = |b: stages::Binding| -> &wgpu::Buffer {
            match b {
                stages::Binding::Params => &params_buf,
                stages::Binding::Slot => &slot_buf,
                stages::Binding::Buf(b) => match b {
                    Buf::Density => &density,
                    Buf::LightIndex => &light_map,
                    Buf::J => &j,
                    Buf::JDir => &j_dir,
                    Buf::JHigh => &j_hi,
                    Buf::SunT => &t_sun,
                    Buf::HNew => &h_new,
                    Buf::Ring => &ring,
                    Buf::Total => &total,
                    Buf::CellVals => &cell_vals,
                    Buf::CellAux => &cell_aux,
                    Buf::CellDir => &cell_dir,
                    Buf::CellSkip => &cell_skip,
                    Buf::CellFill => &cell_fill,
                    Buf::Overflow => &overflow,
                    // Bound only by the image stages and the amortised sun rebuild.
                    Buf::March | Buf::SunTBack | Buf::Image => {
                        unreachable!("{b:?} is in no row of the stage table")
                    }
                },
            }
        };
        let stage = |id: stages::StageId| -> Stage {
            let spec = stages::spec(id);
            let mut constants = Vec::new();
            if spec.sparse {
                constants.push(sparse);
            }
            if id == stages::StageId::Trace {
                constants.push(shared);
            }
            let pipeline = gpu.pipeline_with_constants(
                spec.label,
                &shaders::source(spec.shader),
                spec.entry,
                &constants,
            );
            let bindings: Vec<(u32, &wgpu::Buffer)> =
                spec.bindings.iter().map(|&(i, b)| (i, buffer(b))).collect();
            Stage {
                bind: gpu.bind(&pipeline, &bindings),
                pipeline,
            }
        };
        let sun_stage = stage(stages::StageId::Sun);
        let sun = sun::SunRebuild::new(
            gpu,
            &settings,
            &sun_stage.pipeline,
            [&params_buf, &density, &light_map],
            voxels,
            plan.bytes(Buf::SunTBack),
        );
        let trace = stage(stages::StageId::Trace);
        let update = stage(stages::StageId::Update);
        let cells_stage = stage(stages::StageId::Cells);
        let upsample = stage(stages::StageId::Upsample);
        let raymarch_pipeline = gpu.pipeline_with_constants(
            "photon raymarch",
            &shaders::source(march_density.stage()),
            "raymarch",
            &[
                (
                    "DETAIL_NOISE",
                    if settings.detail_noise > 0.0 {
                        1.0
                    } else {
                        0.0
                    },
                ),
                sparse,
            ],
        );
        Ok(Self {
            gpu,
            params,
            cells,
            voxels,
            map,
            light_map,
            trace,
            update,
            cells_stage,
            upsample,
            raymarch: None,
            params_buf,
            slot_buf,
            h_new,
            density,
            j,
            total,
            ring,
            slot_beams: vec![(0, 0); settings.ring as usize],
            frame: 0,
            sun_fraction,
            cell_volume: cell.x * cell.y * cell.z,
            timer: StageTimer::new(gpu, 8),
            last_times: Vec::new(),
            raymarch_pipeline,
            image_buf: None,
            t_sun,
            sun_stage,
            sun,
            cell_vals,
            cell_aux,
            cell_dir,
            j_dir,
            j_hi,
            overflow,
            fine_res,
            cell_skip,
            grid_max,
            cache_fill,
            cell_fill,
            march_buf,
            march_density,
            gather: None,
            plan,
            slot_view: vec![None; settings.ring as usize],
            j_view: None,
            settings,
            cancel: nimbus_scene::Cancel::never(),
        })
    }

    /// The token that long calls ([`Self::converge`], the gathers) check between generations
    /// and dispatches; with a live token they wait for the device after each, so that a cancel
    /// stops the work within one of them ([`PmError::Cancelled`]). The default never cancels
    /// and changes nothing.
    pub fn set_cancel(&mut self, cancel: nimbus_scene::Cancel) {
        self.cancel = cancel;
    }

    /// Empties the ring and the total cache.
    pub fn reset(&mut self) {
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.ring, 0, None);
        enc.clear_buffer(&self.total, 0, None);
        enc.clear_buffer(&self.overflow, 0, None);
        self.gpu.queue.submit([enc.finish()]);
        self.slot_beams.iter_mut().for_each(|s| *s = (0, 0));
        self.frame = 0;
        self.slot_view.iter_mut().for_each(|v| *v = None);
        self.j_view = None;
    }

    /// Whether any light reaches the cloud (no light → no photons are traced at all).
    pub fn has_light(&self) -> bool {
        self.sun_fraction > 0.0 || self.params.sky_radiance.iter().any(|&v| v > 0.0)
    }

    pub fn uses_shared_memory(&self) -> bool {
        self.params.use_shared != 0
    }

    pub fn cache_res(&self) -> [u32; 3] {
        self.params.i_res
    }

    /// Frames traced so far.
    pub fn frames(&self) -> u32 {
        self.frame
    }

    /// Whether every ring slot holds a traced generation.
    pub fn ring_full(&self) -> bool {
        self.frame >= self.settings.ring
    }

    /// One frame of illumination: traces `beams` (default n_g) beams into H_new and replaces the
    /// oldest partial cache. The per-beam flux stays constant whatever the budget (Elek §4.1.1):
    /// each cache remembers its beam count and the normalisation uses the ring's total.
    pub fn trace_frame(&mut self, beams: Option<u32>) {
        let n = beams.unwrap_or(self.settings.beams_per_frame);
        let (n_sun, n_sky) = if self.has_light() {
            let s = (n as f64 * self.sun_fraction).round() as u32;
            (s, n - s)
        } else {
            (0, 0)
        };
        self.params.n_sun = n_sun;
        self.params.n_sky = n_sky;
        self.params.frame = self.frame;
        self.params.view_mode = self.settings.effective_view() as u32;
        let slot = (self.frame % self.settings.ring) as usize;
        self.slot_beams[slot] = (n_sun as u64, n_sky as u64);
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let count = self.cells * CELL_WORDS as u32;
        self.gpu.queue.write_buffer(
            &self.slot_buf,
            0,
            bytemuck::cast_slice(&[slot as u32 * count, count, 0, 0]),
        );
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        enc.clear_buffer(&self.h_new, 0, None);
        if n_sun + n_sky > 0 {
            let (x, y) = Gpu::workgroups_1d(n_sun + n_sky);
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("trace"),
                timestamp_writes: self.timer.pass("tracing"),
            });
            pass.set_pipeline(&self.trace.pipeline);
            pass.set_bind_group(0, &self.trace.bind, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("update"),
                timestamp_writes: self.timer.pass("update"),
            });
            pass.set_pipeline(&self.update.pipeline);
            pass.set_bind_group(0, &self.update.bind, &[]);
            pass.dispatch_workgroups(count.div_ceil(nimbus_gpu::consts::WG), 1, 1);
        }
        self.timer.resolve(&mut enc);
        self.gpu.queue.submit([enc.finish()]);
        self.last_times = self.timer.read(self.gpu);
        self.slot_view[slot] = self
            .settings
            .effective_view()
            .then_some(self.params.view_origin);
        self.frame += 1;
    }

    /// Traces until every ring slot holds a generation (m frames) — with view-dependent words,
    /// one traced for the current view point.
    ///
    /// The overflow flag is read after every generation (one 4-byte read back each), so a
    /// cache that overflows stops the fill at once with [`PmError::Overflow`] instead of after
    /// the whole ring (on a very dense medium one generation can take tens of seconds).
    pub fn converge(&mut self) -> Result<(), PmError> {
        while !self.ring_full() || self.view_pending() {
            self.cancel.check()?;
            self.trace_frame(None);
            self.check_overflow()?;
        }
        Ok(())
    }

    fn update_norms(&mut self) {
        let (s, k) = self
            .slot_beams
            .iter()
            .fold((0u64, 0u64), |a, b| (a.0 + b.0, a.1 + b.1));
        let r = self.params.bound_radius as f64;
        let denom = W_SCALE * self.params.sigma_max as f64 * self.cell_volume;
        self.params.sun_norm = if s > 0 {
            (PI * r * r / (s as f64 * denom)) as f32
        } else {
            0.0
        };
        self.params.sky_norm = if k > 0 {
            (4.0 * PI * PI * r * r / (k as f64 * denom)) as f32
        } else {
            0.0
        };
    }

    /// Upsamples I → J (Elek §4.3).
    pub fn upsample(&mut self) {
        self.update_norms();
        self.j_view = self.view_ready().then_some(self.params.view_origin);
        self.params.view_mode = self.j_view_mode();
        self.gpu
            .queue
            .write_buffer(&self.params_buf, 0, bytemuck::bytes_of(&self.params));
        let mut enc = self.gpu.device.create_command_encoder(&Default::default());
        {
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("cache cells"),
                timestamp_writes: self.timer.pass(if self.params.filtered != 0 {
                    "upsampling"
                } else {
                    "conversion"
                }),
            });
            pass.set_pipeline(&self.cells_stage.pipeline);
            pass.set_bind_group(0, &self.cells_stage.bind, &[]);
            pass.dispatch_workgroups(self.cells.div_ceil(64), 1, 1);
        }
        {
            let (x, y) = Gpu::workgroups_1d(self.params.light_voxels.max(1));
            let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("upsample"),
                timestamp_writes: self.timer.pass(if self.params.filtered != 0 {
                    "upsampling"
                } else {
                    "conversion"
                }),
            });
            pass.set_pipeline(&self.upsample.pipeline);
            pass.set_bind_group(0, &self.upsample.bind, &[]);
            pass.dispatch_workgroups(x, y, 1);
        }
        self.timer.resolve(&mut enc);
        self.gpu.queue.submit([enc.finish()]);
        let t = self.timer.read(self.gpu);
        self.last_times.extend(t);
    }

    /// Volume centre (for impostor criteria).
    pub fn cloud_center(&self) -> DVec3 {
        (DVec3::from_array(self.params.aabb_min.map(|v| v as f64))
            + DVec3::from_array(self.params.aabb_max.map(|v| v as f64)))
            * 0.5
    }

    /// Converged render: fills the ring, upsamples, ray marches; an overflowed cache is an
    /// error.
    pub fn render(&mut self, camera: &Camera) -> Result<Image, PmError> {
        self.set_view(camera.origin);
        self.converge()?;
        self.upsample();
        self.raymarch(camera)
    }
}
