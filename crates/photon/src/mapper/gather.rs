//! Final gathering from the photon map (`shaders/lib/photon_gather_core.wgsl`): a progressive
//! estimator over the current J and T_sun. Each call adds samples per pixel to running sums on
//! the GPU; [`PhotonMapper::gather_reset`] starts them again (a change of camera, sun or
//! density), while the ring itself keeps updating underneath.
//!
//! Jensen's final gather applied to Elek 2012's cache: the cache's spatial blotches (its cells
//! are several voxels wide) and the lobes' angular error are seen only through k phase-sampled
//! bounces, and every sun order up to k + 1 is computed exactly (see the shader's header).

use bytemuck::{Pod, Zeroable};

use super::*;

/// The gather's uniform block (`struct Gather` in `shaders/lib/photon_gather_core.wgsl`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable, Default, PartialEq)]
pub struct GatherParams {
    /// Gather bounces k: the cache is read at the (k + 1)-th collision.
    pub bounces: u32,
    /// 1: next-event estimation of the sun with ratio-tracked shadow rays; 0: from the
    /// sun-transmittance volume.
    pub shadow_rays: u32,
    /// Index of the first sample of this dispatch (each sample has its own random stream).
    pub sample: u32,
    pub seed: u32,
    /// Majorant of the density the gather tracks (the grid at its own resolution).
    pub sigma_max: f32,
    /// 1: J holds the view-dependent in-scattering, used at the camera vertex (k = 0).
    pub view_words: u32,
    /// Samples per pixel this dispatch adds.
    pub count: u32,
    /// Factor on the running sums before this dispatch adds to them (1: a plain sum; below 1
    /// while a live view's ring is being replaced, so the image follows it).
    pub decay: f32,
    /// A path ends with the cache only in a cell filled at least this much
    /// ([`GATHER_MIN_FILL`]); elsewhere it bounces on.
    pub min_fill: f32,
    /// Most bounces beyond k a path takes looking for such a cell.
    pub max_extra: u32,
    pub _pad: [u32; 2],
}

/// Fill (`mapper::light::cell_fills`: the cell's mean density over its largest) below which a
/// gather path does not end in a cache cell but bounces on: there the cloud's features are
/// smaller than the cell and its words average their light over mostly empty space. Cells of a
/// cache at the light volumes' resolution are full (one light voxel each); a far-spheres cell
/// 34 voxels wide holding a 12-voxel sphere is 6 % filled.
pub const GATHER_MIN_FILL: f32 = 0.25;

/// Most bounces beyond k a path takes through thinly filled cells before it reads the cache
/// anyway.
pub const GATHER_MAX_EXTRA: u32 = 64;

/// How the sun is next-event estimated at each collision of a gather path.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SunShadow {
    /// [`SunShadow::Volume`] where the light volumes have the grid's resolution, else
    /// [`SunShadow::Rays`]: coarser light volumes hold T_sun of the grid's block means, too
    /// smooth for features of a few light voxels (the far-spheres file, 12 grid voxels wide in
    /// light voxels of 4: its image 17 % bright with the volume, 5 % with rays).
    #[default]
    Auto,
    /// The sun-transmittance volume (trilinear at light resolution; a disc sun as a delta
    /// light): no shadow ray, the transmittance the ray marcher uses.
    Volume,
    /// A ratio-tracked shadow ray through the grid per collision (a disc sun sampled in its
    /// cone): exact, noisier and slower.
    Rays,
}

impl SunShadow {
    pub const ALL: [SunShadow; 3] = [SunShadow::Auto, SunShadow::Volume, SunShadow::Rays];

    /// The name on the command line (`--pm-shadow`).
    pub fn name(self) -> &'static str {
        match self {
            SunShadow::Auto => "auto",
            SunShadow::Volume => "volume",
            SunShadow::Rays => "rays",
        }
    }
}

/// What a gather path reads from the photon map where it ends.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Terminal {
    /// View-dependent words traced with the phase function HG(g^(1 + k c)) towards the camera
    /// (c = [`GatherSettings::spread`]). After k phase-sampled bounces a path's direction is
    /// distributed as HG(g^k) about the camera ray's (HG's Legendre coefficients g^l multiply
    /// under convolution), so, were its end point independent of that direction, its
    /// in-scattering at the end averaged over the direction would be the in-scattering towards
    /// the camera through HG(g^(k+1)) (c = 1). It is not: where a path ends tells which way it
    /// went (a path deflected far ends beside the camera ray, near its start), so the spread
    /// that matters is narrower; c = 0 would be no spread at all. For k = 0 every c gives the
    /// view-dependent words themselves, exact in angle.
    #[default]
    View,
    /// Each cell's two flux lobes (Elek 2012 Appendix C, per-cell axes) evaluated towards the
    /// path's previous vertex: view-independent, but one HG lobe per order group misses light
    /// flowing two ways at once (near lit surfaces), an error the bounces shrink as g^k.
    Lobes,
}

impl Terminal {
    pub const ALL: [Terminal; 2] = [Terminal::View, Terminal::Lobes];

    /// The name on the command line (`--gather-terminal`).
    pub fn name(self) -> &'static str {
        match self {
            Terminal::View => "view",
            Terminal::Lobes => "lobes",
        }
    }
}

impl std::str::FromStr for SunShadow {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| format!("unknown sun shadow `{s}` (expected auto, volume or rays)"))
    }
}

impl std::str::FromStr for Terminal {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| format!("unknown gather terminal `{s}` (expected view or lobes)"))
    }
}

/// Settings of the final gathering.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GatherSettings {
    /// Gather bounces k (0: the cache at the camera ray's collision, a smooth biased preview).
    pub bounces: u32,
    pub shadow: SunShadow,
    pub terminal: Terminal,
    /// The photon map's ring m: fewer, larger generations than the ray marcher's (the cache's
    /// ring then fits one storage binding at the light resolution).
    pub ring: u32,
    /// Beams per generation n_g.
    pub beams: u32,
    /// c of [`Terminal::View`]: the share of the k bounces' angular spread the end point's
    /// in-scattering is averaged over, in [0, 1].
    pub spread: f64,
    /// Gathered samples per new generation of the ring (0: the ring stays as built). With r > 0
    /// a render traces a new generation into the ring's oldest slot after every r samples, so
    /// the image averages over the photon map's noise too, which a fixed ring keeps at any
    /// sample count ([`PhotonMapper::gather_refreshing`]).
    pub ring_refresh: u32,
}

/// Default [`GatherSettings::spread`]: measured on the held-out bench clouds under sun light
/// (BENCHMARKS.md, "Final gathering"): with k = 1 the mean ratio over the nine cases is
/// 1.005 [0.977, 1.042] for c = 1, 0.997 [0.971, 1.006] for ½, 0.975 [0.955, 0.998] for 0;
/// with k = 2, 0.998 [0.961, 1.012] for ½ and 1.008 [0.965, 1.043] for ¾.
pub const DEFAULT_GATHER_SPREAD: f64 = 0.5;

/// Default ring of the final gathering.
pub const DEFAULT_GATHER_RING: u32 = 8;
/// Default beams per generation of the final gathering (m · n_g = 524 288 beams).
pub const DEFAULT_GATHER_BEAMS: u32 = 65_536;

impl GatherSettings {
    /// The anisotropy of the view-dependent words for medium anisotropy `g`: g^(1 + k c).
    pub fn terminal_g(&self, g: f64) -> f64 {
        let k = self.bounces.min(1 << 20) as f64;
        let e = 1.0 + k * self.spread.clamp(0.0, 1.0);
        g.signum() * g.abs().powf(e)
    }

    /// The photon map's settings for gathering from it: view-dependent words with the phase
    /// function HG(g^(1 + k c)) ([`Terminal::View`]), or none (the lobes).
    pub fn pm_settings(&self, pm: &PmSettings, g: f64) -> PmSettings {
        let mut s = pm.clone();
        s.ring = self.ring;
        s.beams_per_frame = self.beams;
        match self.terminal {
            Terminal::View => {
                s.view_dependent = Some(true);
                s.view_g = Some(self.terminal_g(g));
                s.fine_cache = true;
            }
            Terminal::Lobes => {
                s.view_dependent = Some(false);
                s.view_g = None;
            }
        }
        s
    }
}

impl Default for GatherSettings {
    fn default() -> Self {
        Self {
            bounces: DEFAULT_GATHER_BOUNCES,
            shadow: SunShadow::Auto,
            terminal: Terminal::View,
            ring: DEFAULT_GATHER_RING,
            beams: DEFAULT_GATHER_BEAMS,
            spread: DEFAULT_GATHER_SPREAD,
            ring_refresh: 0,
        }
    }
}

/// Default gather bounces.
pub const DEFAULT_GATHER_BOUNCES: u32 = 1;

/// Most samples per pixel one dispatch computes (one invocation loops over them; longer
/// dispatches risk a driver's watchdog on large images).
const MAX_SAMPLES_PER_DISPATCH: u32 = 8;

/// The gather stage for one image size: pipeline, bindings, running sums.
pub(super) struct GatherState {
    stage: Stage,
    acc: wgpu::Buffer,
    uniform: wgpu::Buffer,
    width: usize,
    height: usize,
    /// Samples per pixel added to the running sums since they were emptied.
    samples: u32,
    /// The sums' weight: `samples`, unless decayed (`PhotonMapper::gather_window`).
    weight: f64,
    /// Samples drawn since the state was made: each sample's random stream, never reused, so
    /// images after a restart are independent of those before.
    stream: u32,
}

impl PhotonMapper<'_> {
    /// Empties the gather's running sums (the next sample starts a new image).
    pub fn gather_reset(&mut self) {
        if let Some(g) = &mut self.gather {
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            enc.clear_buffer(&g.acc, 0, None);
            self.gpu.queue.submit([enc.finish()]);
            g.samples = 0;
            g.weight = 0.0;
        }
    }

    /// Samples per pixel in the gather's running sums.
    pub fn gather_samples(&self) -> u32 {
        self.gather.as_ref().map_or(0, |g| g.samples)
    }

    /// Adds `samples` samples per pixel like [`Self::gather`], with a new generation traced
    /// into the ring (and J upsampled again) after every `settings.ring_refresh` of them; 0
    /// is [`Self::gather`]. The running sums then average over J's of overlapping rings: the
    /// photon map's noise falls as the generations used grow, m + samples / r of them instead
    /// of m, while each J stays an estimate of the same light (Elek 2012 §3.2's ring, here
    /// replaced while the scene stands still). Returns the seconds spent on the ring.
    pub fn gather_refreshing(
        &mut self,
        camera: &Camera,
        settings: &GatherSettings,
        samples: u32,
    ) -> Result<f64, PmError> {
        let r = settings.ring_refresh;
        if r == 0 {
            self.gather(camera, settings, samples)?;
            return Ok(0.0);
        }
        let mut ring_s = 0.0;
        let mut left = samples;
        while left > 0 {
            let n = left.min(r);
            self.gather(camera, settings, n)?;
            left -= n;
            if left > 0 {
                let t = nimbus_scene::clock::Instant::now();
                self.trace_frame(None);
                self.check_overflow()?;
                self.upsample();
                let _ = self.gpu.device.poll(wgpu::PollType::wait_indefinitely());
                ring_s += t.elapsed().as_secs_f64();
                self.cancel.check()?;
            }
        }
        Ok(ring_s)
    }

    /// Adds `samples` samples per pixel of the final gathering for `camera` (whose size must
    /// match the running sums', else they start again) from the current J and T_sun. With
    /// `bounces` ≥ 1 J must hold fluences and lobes (view-dependent words off); with 0 the
    /// view words are used where J holds them.
    pub fn gather(
        &mut self,
        camera: &Camera,
        settings: &GatherSettings,
        samples: u32,
    ) -> Result<(), PmError> {
        self.gather_with(camera, settings, samples, None)
    }

    /// Adds one sample per pixel like [`Self::gather`], first scaling the running sums so they
    /// weigh at most `window − 1` samples: the image is then a mean over about the last `window`
    /// samples, and follows a J that changes from frame to frame (a live view while its ring is
    /// being replaced) with that lag.
    pub fn gather_window(
        &mut self,
        camera: &Camera,
        settings: &GatherSettings,
        window: u32,
    ) -> Result<(), PmError> {
        self.gather_with(camera, settings, 1, Some(window.max(1)))
    }

    fn gather_with(
        &mut self,
        camera: &Camera,
        settings: &GatherSettings,
        samples: u32,
        window: Option<u32>,
    ) -> Result<(), PmError> {
        self.update_sun_transmittance();
        self.params.view_mode = self.j_view_mode();
        self.set_camera_params(camera);
        self.gpu
            .queue
            .write_buffer(&self.march_buf, 0, bytemuck::bytes_of(&self.march_params()));
        let (w, h) = (camera.width, camera.height);
        if !matches!(&self.gather, Some(g) if g.width == w && g.height == h) {
            self.gather = Some(self.gather_state(w, h)?);
        }
        let base = self.gather_params(settings);
        let g = self.gather.as_mut().expect("made above");
        let mut left = samples;
        while left > 0 {
            let count = left.min(MAX_SAMPLES_PER_DISPATCH);
            let decay = match window {
                Some(w) if g.weight > (w - 1) as f64 => (w - 1) as f64 / g.weight,
                _ => 1.0,
            };
            let u = GatherParams {
                sample: g.stream,
                count,
                decay: decay as f32,
                ..base
            };
            self.gpu
                .queue
                .write_buffer(&g.uniform, 0, bytemuck::bytes_of(&u));
            let mut enc = self.gpu.device.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                    label: Some("gather"),
                    timestamp_writes: self.timer.pass("gathering"),
                });
                pass.set_pipeline(&g.stage.pipeline);
                pass.set_bind_group(0, &g.stage.bind, &[]);
                pass.dispatch_workgroups((w as u32).div_ceil(8), (h as u32).div_ceil(8), 1);
            }
            self.timer.resolve(&mut enc);
            self.gpu.queue.submit([enc.finish()]);
            let t = self.timer.read(self.gpu);
            self.last_times.extend(t);
            g.samples += count;
            g.weight = g.weight * decay as f32 as f64 + count as f64;
            g.stream = g.stream.wrapping_add(count);
            left -= count;
            if self.cancel.is_live() {
                let _ = self.gpu.device.poll(wgpu::PollType::wait_indefinitely());
                self.cancel.check()?;
            }
        }
        Ok(())
    }

    /// The uniform block of the next gather dispatch (one sample from the current stream; the
    /// CPU twin `cpu::gather` reads the same).
    pub fn gather_params(&self, settings: &GatherSettings) -> GatherParams {
        GatherParams {
            bounces: settings.bounces,
            shadow_rays: (self.sun_shadow(settings.shadow) == SunShadow::Rays) as u32,
            sample: self.gather.as_ref().map_or(0, |g| g.stream),
            seed: self.settings.seed ^ 0x6a09_e667,
            sigma_max: (self.params.density_scale as f64 * self.grid_max).max(1e-30) as f32,
            view_words: self.j_view.is_some() as u32,
            count: 1,
            decay: 1.0,
            min_fill: GATHER_MIN_FILL,
            max_extra: GATHER_MAX_EXTRA,
            _pad: [0; 2],
        }
    }

    /// What [`SunShadow::Auto`] means for this photon map (the others as they are).
    pub fn sun_shadow(&self, s: SunShadow) -> SunShadow {
        match s {
            SunShadow::Auto if self.light_is_coarse() => SunShadow::Rays,
            SunShadow::Auto => SunShadow::Volume,
            other => other,
        }
    }

    /// The gather's mean image and the per-pixel variance of its mean luminance (zero before
    /// two samples).
    pub fn gather_image(&self) -> Result<(Image, Vec<f32>), PmError> {
        let Some(g) = &self.gather else {
            return Err(PmError::Unsupported(
                "no gather samples yet (PhotonMapper::gather first)".into(),
            ));
        };
        let sums: Vec<[f32; 4]> = self.gpu.read(&g.acc)?;
        let n = g.weight.max(1.0);
        let mut img = Image::new(g.width, g.height);
        let mut var = vec![0.0f32; g.width * g.height];
        for ((o, v), s) in img.pixels.iter_mut().zip(&mut var).zip(&sums) {
            let m = [0, 1, 2].map(|c| s[c] as f64 / n);
            *o = m.map(|c| c as f32);
            if g.weight > 1.0 {
                let ml = (m[0] + m[1] + m[2]) / 3.0;
                *v = ((s[3] as f64 / n - ml * ml).max(0.0) / (n - 1.0)) as f32;
            }
        }
        Ok((img, var))
    }

    /// The gather pipeline and running sums for a `w`×`h` image.
    fn gather_state(&self, w: usize, h: usize) -> Result<GatherState, PmError> {
        self.gpu
            .check_storage("the gather's running sums", w as u64 * h as u64 * 16)?;
        let stage = self.march_density.gather_stage();
        let sparse = ("LIGHT_SPARSE", if self.map.is_full() { 0.0 } else { 1.0 });
        let pipeline = self.gpu.pipeline_with_constants(
            "photon gather",
            &shaders::source(stage),
            "gather",
            &[sparse],
        );
        let acc = self.gpu.zeroed("gather sums", w as u64 * h as u64 * 16);
        let uniform = self.gpu.uniform("gather params", &GatherParams::default());
        let mut buffers = vec![
            (0, &self.march_buf),
            (2, &self.j),
            (3, &acc),
            (4, &self.t_sun),
            (5, &self.j_dir),
            (6, &self.j_hi),
            (9, &self.light_map),
            (10, &uniform),
            (11, &self.cell_fill),
        ];
        let bind = match &self.march_density {
            light::MarchDensity::Work => {
                buffers.push((1, &self.density));
                self.gpu.bind(&pipeline, &buffers)
            }
            light::MarchDensity::Dense(d) => {
                buffers.push((1, d));
                self.gpu.bind(&pipeline, &buffers)
            }
            light::MarchDensity::Bricks(k) => {
                buffers.extend([(1, &k.index), (7, &k.info)]);
                self.gpu.bind_with(&pipeline, &buffers, &[(8, &k.view)])
            }
        };
        Ok(GatherState {
            stage: Stage { pipeline, bind },
            acc,
            uniform,
            width: w,
            height: h,
            samples: 0,
            weight: 0.0,
            stream: 0,
        })
    }
}

impl GatherState {
    /// The running sums (the planned [`super::plan::Buf::Image`]).
    pub(super) fn sums(&self) -> &wgpu::Buffer {
        &self.acc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `GatherParams` matches `struct Gather` of the WGSL module field by field.
    #[test]
    fn gather_params_layout_matches_wgsl() {
        let (members, size) = shaders::struct_layout("photon_gather.wgsl", "Gather");
        let want = [
            ("bounces", 0),
            ("shadow_rays", 4),
            ("sample", 8),
            ("seed", 12),
            ("sigma_max", 16),
            ("view_words", 20),
            ("count", 24),
            ("decay", 28),
            ("min_fill", 32),
            ("max_extra", 36),
        ];
        assert_eq!(size as usize, std::mem::size_of::<GatherParams>());
        for ((name, off), (m, o)) in want.iter().zip(&members) {
            assert_eq!((*name, *off), (m.as_str(), *o));
        }
        assert_eq!(
            std::mem::offset_of!(GatherParams, sigma_max),
            16,
            "Rust layout"
        );
    }
}
