//! The viewer's state and frame loop, independent of any window: the windowed front end
//! ([`crate::window`]) and the headless one ([`crate::headless`]) both drive a [`Viewer`] with
//! [`Action`]s and call [`Viewer::step`] once per frame.
//!
//! Per frame, in photon-mapping mode (Elek 2012):
//! 1. the sun moves (if playing) and the density sequence advances (if playing);
//! 2. while the ring is not full or holds generations traced before the last light or density
//!    change, one generation of n_g beams replaces the oldest partial cache (§4.1) — so a change
//!    blends in over m frames, and a static scene traces nothing once the ring is fresh; the
//!    ring's view-dependent words (the photon map's default in-scattering) are refreshed the
//!    same way after the camera moved beyond the impostor tolerance (5°, 20 %), the lobes
//!    showing meanwhile (`nimbus_photon::mapper` view.rs);
//! 3. after tracing, I is upsampled to J (§4.3);
//! 4. the impostor criteria (§4.4) decide whether to ray march a new image or to show the last
//!    one as a billboard re-projected to the current camera.
//!
//! In path-tracing mode every frame adds one sample per pixel (the GPU path tracer where it
//! supports the scene, else the CPU one); in RPNN mode one sample of the network renderer
//! (Kallweit §4.4; the model is loaded when the mode is first chosen). Any change of camera,
//! sun, density or size restarts the accumulation.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::{DQuat, DVec3};
use nimbus_gpu::Gpu;
use nimbus_photon::animate::DensitySequence;
use nimbus_photon::impostor::{ImpostorCriteria, ImpostorState, Refresh};
use nimbus_photon::{PhotonMapper, PmSettings};
use nimbus_scene::grid::DensityGrid;
use nimbus_scene::volume::Volume;
use nimbus_scene::{Camera, Image, Scene};

use crate::script::{Action, ViewMode};

/// Errors of the viewer.
#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error(transparent)]
    Pm(#[from] nimbus_photon::PmError),
    #[error(transparent)]
    Gpu(#[from] nimbus_gpu::GpuError),
    #[error("{path}: {msg}")]
    File { path: String, msg: String },
    #[error("{0}")]
    Other(String),
}

/// A scene file's text and the folder its relative paths start from (for `save-scene`).
pub type SceneSource = (String, PathBuf);

/// How the viewer starts.
#[derive(Debug, Clone)]
pub struct ViewerOptions {
    pub pm: PmSettings,
    pub half_res: bool,
    /// Impostor criteria (Elek §4.4); `None` ray marches every frame.
    pub impostors: Option<ImpostorCriteria>,
    pub density: DensitySequence,
    /// Sun angular speed about +y while playing, degrees per second.
    pub sun_speed_deg_s: f64,
    /// Density-sequence frames per second while playing.
    pub density_fps: f64,
    pub play_sun: bool,
    pub play_density: bool,
    pub method: ViewMode,
    /// Display exposure; `None`: fixed from the first image (99th percentile → 0.9).
    pub exposure: Option<f64>,
    /// The RPNN model for RPNN mode (loaded only when that mode is chosen).
    pub rpnn_model: PathBuf,
}

/// Slices of an amortised sun-transmittance rebuild in the viewer: at most 2^16 voxel marches
/// per frame, at most 64 frames of lag (less than the default ring of 100 frames). A rebuild of
/// the demo's 128×96×128 cloud at once takes ≈ 8.5 s on lavapipe (2 cores), so ≈ 0.35 s per
/// frame in 24 slices; on a discrete GPU the whole lag is a fraction of a second.
pub fn sun_chunks(res: [usize; 3]) -> u32 {
    (res.iter().product::<usize>().div_ceil(1 << 16)).clamp(1, 64) as u32
}

impl Default for ViewerOptions {
    fn default() -> Self {
        Self {
            // sun_chunks 0: chosen from the volume by `sun_chunks`.
            pm: PmSettings {
                sun_chunks: 0,
                ..Default::default()
            },
            half_res: false,
            impostors: Some(ImpostorCriteria::default()),
            density: DensitySequence::Static,
            sun_speed_deg_s: 10.0,
            density_fps: 10.0,
            play_sun: false,
            play_density: false,
            method: ViewMode::Pm,
            exposure: None,
            rpnn_model: nimbus_rpnn::model::default_model_path(),
        }
    }
}

/// What the last frame did and cost.
#[derive(Debug, Clone, Default)]
pub struct FrameStats {
    pub frame: u32,
    /// Wall-clock milliseconds per stage, GPU work included.
    pub stages: Vec<(&'static str, f64)>,
    pub wall_ms: f64,
    /// Beams traced this frame (sun, sky).
    pub beams: (u64, u64),
    pub ring_filled: u32,
    /// Why the image was ray marched; `None`: the impostor was re-projected.
    pub refresh: Option<Refresh>,
    /// Samples per pixel accumulated (path tracing).
    pub spp: u32,
    pub note: Option<String>,
}

/// Camera and sun changes since the last frame.
#[derive(Default)]
struct Dirty {
    light: bool,
    density: bool,
    view: bool,
}

/// A running mean of images (progressive estimators).
#[derive(Default)]
struct Accumulator {
    sum: Vec<[f64; 3]>,
    spp: u32,
}

impl Accumulator {
    fn new(pixels: usize) -> Self {
        Self {
            sum: vec![[0.0; 3]; pixels],
            spp: 0,
        }
    }

    /// Adds one sample image; returns the mean so far.
    fn add(&mut self, img: &Image) -> Image {
        for (s, v) in self.sum.iter_mut().zip(&img.pixels) {
            for c in 0..3 {
                s[c] += v[c] as f64;
            }
        }
        self.spp += 1;
        let n = self.spp as f64;
        let mut out = Image::new(img.width, img.height);
        for (o, s) in out.pixels.iter_mut().zip(&self.sum) {
            *o = s.map(|v| (v / n) as f32);
        }
        out
    }
}

/// Progressive path tracing state.
struct Progressive<'g> {
    gpu_pt: Option<nimbus_trace::gpu::GpuPathTracer<'g>>,
    acc: Accumulator,
}

/// Progressive RPNN state (Kallweit §4.4): the network and the scene's density pyramid.
struct RpnnView<'g> {
    backend: nimbus_rpnn::render::Backend<'g>,
    pyr: nimbus_rpnn::Pyramid,
    acc: Accumulator,
}

/// The viewer.
pub struct Viewer<'g> {
    gpu: &'g Gpu,
    scene: Scene,
    /// The scene file's text and folder (for `save-scene`).
    source: Option<SceneSource>,
    opts: ViewerOptions,
    pm: PhotonMapper<'g>,
    camera: Camera,
    method: ViewMode,
    play_sun: bool,
    play_density: bool,
    density_clock: f64,
    density_frame: Option<u32>,
    prev_density: Option<Vec<f32>>,
    impostor: Option<ImpostorState>,
    impostor_image: Option<(Image, Camera)>,
    j_valid: bool,
    /// Generations in the ring traced before the last light or density change.
    stale: u32,
    dirty: Dirty,
    pt: Option<Progressive<'g>>,
    rpnn: Option<RpnnView<'g>>,
    image: Image,
    exposure: Option<f64>,
    frame: u32,
    stats: FrameStats,
    note: Option<String>,
    quit: bool,
}

impl<'g> Viewer<'g> {
    /// A viewer of `scene`; `source` is the scene file's text and folder, for saving the view
    /// back to TOML.
    pub fn new(
        gpu: &'g Gpu,
        scene: Scene,
        source: Option<SceneSource>,
        opts: ViewerOptions,
    ) -> Result<Self, ViewerError> {
        let mut pm_settings = opts.pm.clone();
        if pm_settings.sun_chunks == 0 {
            pm_settings.sun_chunks = sun_chunks(scene.volume.grid().res());
        }
        let mut pm = PhotonMapper::new(gpu, &scene, pm_settings)?;
        let seq_max = opts.density.max_value(scene.volume.grid().res())?;
        if seq_max > 0.0 {
            pm.set_majorant_value(seq_max);
        }
        let camera = scene.camera.clone();
        Ok(Self {
            gpu,
            pm,
            image: Image::new(camera.width, camera.height),
            camera,
            method: opts.method,
            play_sun: opts.play_sun,
            play_density: opts.play_density,
            density_clock: 0.0,
            density_frame: None,
            prev_density: None,
            impostor: opts.impostors.map(ImpostorState::new),
            impostor_image: None,
            j_valid: false,
            stale: 0,
            dirty: Dirty::default(),
            pt: None,
            rpnn: None,
            exposure: opts.exposure,
            frame: 0,
            stats: FrameStats::default(),
            note: None,
            quit: false,
            scene,
            source,
            opts,
        })
    }

    pub fn camera(&self) -> &Camera {
        &self.camera
    }

    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    pub fn method(&self) -> ViewMode {
        self.method
    }

    /// The last frame's linear RGB image.
    pub fn image(&self) -> &Image {
        &self.image
    }

    pub fn stats(&self) -> &FrameStats {
        &self.stats
    }

    pub fn impostor_counts(&self) -> Option<([u32; 5], u32)> {
        self.impostor.as_ref().map(|s| (s.refreshes, s.reuses))
    }

    pub fn quit_requested(&self) -> bool {
        self.quit
    }

    /// Display exposure (fixed after the first frame unless given).
    pub fn exposure(&self) -> f64 {
        self.exposure.unwrap_or(1.0)
    }

    pub fn scale_exposure(&mut self, factor: f64) {
        self.exposure = Some(self.exposure() * factor);
    }

    /// The sun's (azimuth, elevation) in degrees: azimuth about +y from +z towards +x.
    pub fn sun_angles(&self) -> Option<(f64, f64)> {
        self.scene.sun.as_ref().map(|s| {
            let d = s.dir;
            (
                d.x.atan2(d.z).to_degrees(),
                d.y.clamp(-1.0, 1.0).asin().to_degrees(),
            )
        })
    }

    fn set_sun_dir(&mut self, dir: DVec3) {
        if self.scene.sun.is_none() {
            return;
        }
        self.scene.set_sun_dir(dir);
        let sun = self.scene.sun.as_ref().expect("checked");
        self.pm.set_sun_dir(sun.dir);
        if self.scene.atmosphere.is_some() {
            let sky = match &self.scene.sky {
                Some(nimbus_scene::Sky::Constant(c)) => *c,
                _ => DVec3::ZERO,
            };
            self.pm.set_lighting(sun.irradiance, sky);
        }
        self.dirty.light = true;
    }

    fn set_sun_angles(&mut self, azimuth_deg: f64, elevation_deg: f64) {
        let (a, e) = (
            azimuth_deg.to_radians(),
            elevation_deg.clamp(-90.0, 90.0).to_radians(),
        );
        self.set_sun_dir(DVec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos()));
    }

    fn set_camera(&mut self, origin: DVec3, target: DVec3, width: usize, height: usize) {
        let up = self.camera.up_hint();
        // Looking straight along the up hint: keep the old camera (the orbit clamps pitch, so
        // this only happens for a degenerate pan or zoom).
        if let Ok(c) = Camera::new(origin, target, up, self.camera.vfov_deg(), width, height) {
            self.camera = c;
            self.dirty.view = true;
        }
    }

    /// Applies one action.
    pub fn apply(&mut self, action: &Action) -> Result<(), ViewerError> {
        let (o, t) = (self.camera.origin, self.camera.target());
        let (w, h) = (self.camera.width, self.camera.height);
        match action {
            Action::Orbit { yaw_deg, pitch_deg } => {
                let v = o - t;
                let dist = v.length();
                let yaw = v.x.atan2(v.z) + yaw_deg.to_radians();
                let pitch = ((v.y / dist).clamp(-1.0, 1.0).asin() + pitch_deg.to_radians())
                    .clamp(-89f64.to_radians(), 89f64.to_radians());
                let dir = DVec3::new(
                    pitch.cos() * yaw.sin(),
                    pitch.sin(),
                    pitch.cos() * yaw.cos(),
                );
                self.set_camera(t + dir * dist, t, w, h);
            }
            Action::Pan { right, up } => {
                let (_, r, u, _) = self.camera.basis();
                let s = (o - t).length();
                let d = (r * *right + u * *up) * s;
                self.set_camera(o + d, t + d, w, h);
            }
            Action::Zoom { factor } => {
                let v = o - t;
                let dist = (v.length() * factor).clamp(1e-3, 1e6);
                self.set_camera(t + v.normalize() * dist, t, w, h);
            }
            Action::SetSun {
                azimuth_deg,
                elevation_deg,
            } => self.set_sun_angles(*azimuth_deg, *elevation_deg),
            Action::MoveSun {
                azimuth_deg,
                elevation_deg,
            } => {
                if let Some((a, e)) = self.sun_angles() {
                    self.set_sun_angles(a + azimuth_deg, e + elevation_deg);
                }
            }
            Action::ToggleSunMotion => self.play_sun = !self.play_sun,
            Action::ToggleDensityAnimation => {
                if matches!(self.opts.density, DensitySequence::Static) {
                    self.note = Some("no density animation (use --density-seq or --evolve)".into());
                } else {
                    self.play_density = !self.play_density;
                }
            }
            Action::Method(m) => {
                if *m == ViewMode::Rpnn && self.method != ViewMode::Rpnn {
                    match self.start_rpnn() {
                        Ok(r) => self.rpnn = Some(r),
                        Err(e) => {
                            self.note = Some(format!("RPNN unavailable ({e}); method unchanged"));
                            return Ok(());
                        }
                    }
                }
                if *m != self.method {
                    self.method = *m;
                    self.pt = None;
                    if *m != ViewMode::Rpnn {
                        self.rpnn = None;
                    }
                    self.impostor_image = None;
                    self.impostor = self.opts.impostors.map(ImpostorState::new);
                }
            }
            Action::Resize { width, height } => {
                let (w, h) = (*width as usize, *height as usize);
                if w > 0 && h > 0 && (w, h) != (self.camera.width, self.camera.height) {
                    self.set_camera(o, t, w, h);
                }
            }
            Action::Screenshot(path) => self.screenshot(path)?,
            Action::SaveScene(path) => self.save_scene(path)?,
            Action::Quit => self.quit = true,
        }
        Ok(())
    }

    /// Writes the current image: `.exr` linear (+ nothing else), anything else as PNG with the
    /// display exposure.
    pub fn screenshot(&self, path: &Path) -> Result<(), ViewerError> {
        let file_err = |e: nimbus_scene::error::Error| ViewerError::File {
            path: path.display().to_string(),
            msg: e.to_string(),
        };
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).map_err(|e| ViewerError::File {
                path: dir.display().to_string(),
                msg: e.to_string(),
            })?;
        }
        if path.extension().is_some_and(|e| e == "exr") {
            self.image.write_exr(path, None).map_err(file_err)
        } else {
            self.image
                .write_png(path, self.exposure())
                .map_err(file_err)
        }
    }

    /// Writes the scene with the current camera and sun to `path` (TOML). Relative file paths of
    /// the original are made absolute so the copy works from any folder.
    pub fn save_scene(&self, path: &Path) -> Result<(), ViewerError> {
        let perr = |msg: String| ViewerError::File {
            path: path.display().to_string(),
            msg,
        };
        let (text, dir) = self
            .source
            .clone()
            .ok_or_else(|| perr("this scene has no TOML source to save".into()))?;
        let mut doc: toml::Table = text
            .parse()
            .map_err(|e| perr(format!("re-reading the scene: {e}")))?;
        let arr = |v: DVec3| toml::Value::Array(v.to_array().map(toml::Value::Float).to_vec());
        let c = &self.camera;
        let cam = doc
            .entry("camera")
            .or_insert_with(|| toml::Value::Table(Default::default()));
        if let toml::Value::Table(t) = cam {
            t.insert("origin".into(), arr(c.origin));
            t.insert("target".into(), arr(c.target()));
            t.insert("up".into(), arr(c.up_hint()));
            t.insert("vfov_deg".into(), toml::Value::Float(c.vfov_deg()));
            t.insert("width".into(), toml::Value::Integer(c.width as i64));
            t.insert("height".into(), toml::Value::Integer(c.height as i64));
        }
        if let (Some(sun), Some(toml::Value::Table(t))) = (&self.scene.sun, doc.get_mut("sun")) {
            t.insert("direction".into(), arr(sun.dir));
        }
        for (table, key) in [("volume", "file"), ("sky", "file")] {
            if let Some(toml::Value::Table(t)) = doc.get_mut(table)
                && let Some(toml::Value::String(p)) = t.get_mut(key)
                && Path::new(p.as_str()).is_relative()
            {
                *p = dir.join(p.as_str()).display().to_string();
            }
        }
        let out = format!(
            "# Saved by `nimbus view` (camera and sun as last shown).\n{}",
            toml::to_string(&doc).map_err(|e| perr(e.to_string()))?
        );
        if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(d).map_err(|e| perr(e.to_string()))?;
        }
        std::fs::write(path, out).map_err(|e| perr(e.to_string()))
    }

    /// Advances the simulation by `dt` seconds and renders one frame.
    pub fn step(&mut self, dt: f64) -> Result<&Image, ViewerError> {
        let t0 = Instant::now();
        if self.play_sun
            && self.opts.sun_speed_deg_s != 0.0
            && let Some(sun) = &self.scene.sun
        {
            let turn =
                DQuat::from_axis_angle(DVec3::Y, (self.opts.sun_speed_deg_s * dt).to_radians());
            self.set_sun_dir(turn * sun.dir);
        }
        self.advance_density(dt)?;
        let mut stats = FrameStats {
            frame: self.frame,
            note: self.note.take(),
            ..Default::default()
        };
        match self.method {
            ViewMode::Pm => self.frame_pm(&mut stats)?,
            ViewMode::Pt => self.frame_pt(&mut stats)?,
            ViewMode::Rpnn => self.frame_rpnn(&mut stats)?,
        }
        if self.exposure.is_none() {
            self.exposure = Some(self.image.auto_exposure());
        }
        self.dirty = Dirty::default();
        stats.wall_ms = t0.elapsed().as_secs_f64() * 1e3;
        self.stats = stats;
        self.frame += 1;
        Ok(&self.image)
    }

    fn advance_density(&mut self, dt: f64) -> Result<(), ViewerError> {
        if matches!(self.opts.density, DensitySequence::Static) {
            return Ok(());
        }
        if self.play_density {
            self.density_clock += dt * self.opts.density_fps;
        }
        let f = self.density_clock.floor() as u32;
        if self.density_frame == Some(f) {
            return Ok(());
        }
        let Some(d) = self.opts.density.frame(f)? else {
            return Ok(());
        };
        if let (Some(state), Some(prev)) = (self.impostor.as_mut(), self.prev_density.as_ref()) {
            let diff: f64 = d.iter().zip(prev).map(|(a, b)| (a - b).abs() as f64).sum();
            let base: f64 = prev.iter().map(|v| *v as f64).sum::<f64>().max(1e-30);
            state.density_changed(diff / base);
        }
        self.pm.set_density(&d)?;
        // The path tracer reads the scene's volume: give it this frame's grid.
        let v = self.scene.volume.as_ref();
        let grid = DensityGrid::new(v.grid().res(), d.clone())
            .map_err(|e| ViewerError::Other(format!("density frame {f}: {e}")))?;
        let vol = Volume::new(grid, *v.aabb(), v.density_scale())
            .map_err(|e| ViewerError::Other(format!("density frame {f}: {e}")))?;
        self.scene.volume = Arc::new(vol);
        self.prev_density = Some(d);
        self.density_frame = Some(f);
        self.dirty.density = true;
        Ok(())
    }

    /// Waits for the GPU and returns the milliseconds since `t`: stage times are wall-clock
    /// times with the stage's GPU work finished (GPU timestamps are not reliable on every
    /// driver once a window surface presents — lavapipe reports zeros then).
    fn since(&self, t: Instant) -> f64 {
        let _ = self.gpu.device.poll(wgpu::PollType::wait_indefinitely());
        t.elapsed().as_secs_f64() * 1e3
    }

    fn frame_pm(&mut self, stats: &mut FrameStats) -> Result<(), ViewerError> {
        let mut stages: Vec<(&'static str, f64)> = Vec::new();
        if self.dirty.light || self.dirty.density {
            // Every generation in the ring is now stale: replace them all, one per frame.
            self.stale = self.pm.settings.ring;
        }
        // View-dependent words (the default) belong to a camera position: after the camera
        // moved beyond the impostor tolerance the ring is retraced for it (the lobes show
        // meanwhile); a still camera with a converged ring traces nothing.
        self.pm.set_view(self.camera.origin);
        let trace = self.stale > 0 || !self.pm.ring_full() || self.pm.view_pending();
        self.stale = self.stale.saturating_sub(trace as u32);
        if trace {
            let t = Instant::now();
            self.pm.trace_frame(None);
            stages.push(("trace", self.since(t)));
            if let Some(s) = self.impostor.as_mut() {
                s.traced();
            }
        }
        stats.beams = if trace {
            self.pm.last_generation_beams()
        } else {
            (0, 0)
        };
        // J switching between the lobes and the view words (the ring has just been retraced for
        // the camera) changes the image at once: it is ray marched whatever the impostor says.
        let mut switched = false;
        if trace || !self.j_valid {
            let t = Instant::now();
            let was_view = self.pm.j_holds_view();
            self.pm.upsample();
            switched = self.pm.j_holds_view() != was_view;
            stages.push(("upsample", self.since(t)));
            self.j_valid = true;
        }
        stats.ring_filled = self.pm.frames().min(self.pm.settings.ring);
        let refresh = match self.impostor.as_mut() {
            Some(s) => s.check(
                self.camera.origin,
                self.pm.cloud_center(),
                self.pm.settings.ring,
            ),
            None => Some(Refresh::First),
        };
        let refresh = match refresh {
            None if switched => Some(Refresh::Illumination),
            r => r,
        };
        // No image to re-project yet: ray march whatever the criteria say.
        let refresh = match &self.impostor_image {
            None => Some(refresh.unwrap_or(Refresh::First)),
            Some(_) => refresh,
        };
        match (&refresh, &self.impostor_image) {
            (None, Some((img, cam0))) => {
                let t = Instant::now();
                self.image = if *cam0 == self.camera {
                    img.clone()
                } else {
                    nimbus_photon::impostor::reproject(
                        img,
                        cam0,
                        &self.camera,
                        self.pm.cloud_center(),
                    )
                };
                stages.push(("impostor", t.elapsed().as_secs_f64() * 1e3));
            }
            _ => {
                let t = Instant::now();
                let img = if self.opts.half_res {
                    self.pm.raymarch_half(&self.camera)?
                } else {
                    self.pm.raymarch(&self.camera)?
                };
                stages.push(("ray march", self.since(t)));
                self.impostor_image = Some((img.clone(), self.camera.clone()));
                self.image = img;
            }
        }
        if trace {
            // A wrapped cache sum is an error, not a silently wrong image (4 bytes read back).
            self.pm.check_overflow()?;
        }
        self.pm.last_times.clear();
        stats.stages = stages;
        stats.refresh = refresh;
        Ok(())
    }

    fn frame_pt(&mut self, stats: &mut FrameStats) -> Result<(), ViewerError> {
        let restart = self.dirty.light || self.dirty.density || self.dirty.view;
        let (w, h) = (self.camera.width, self.camera.height);
        if restart || self.pt.as_ref().is_none_or(|p| p.acc.sum.len() != w * h) {
            self.scene.camera = self.camera.clone();
            let gpu_pt = nimbus_trace::gpu::GpuPathTracer::new(self.gpu, &self.scene).ok();
            self.pt = Some(Progressive {
                gpu_pt,
                acc: Accumulator::new(w * h),
            });
        }
        let p = self.pt.as_mut().expect("set above");
        let t = Instant::now();
        let seed = self.scene.render.seed.wrapping_add(p.acc.spp as u64);
        let (img, stage) = match p.gpu_pt.as_mut() {
            Some(g) => (
                g.render(1, seed)
                    .map_err(|e| ViewerError::Other(e.to_string()))?
                    .0,
                "path tracing (GPU)",
            ),
            None => {
                let opts = nimbus_trace::render::RenderOptions {
                    spp: 1,
                    seed,
                    progress: false,
                };
                (
                    nimbus_trace::render::render(&self.scene, &opts).image,
                    "path tracing (CPU)",
                )
            }
        };
        self.image = p.acc.add(&img);
        stats.stages = vec![(stage, t.elapsed().as_secs_f64() * 1e3)];
        stats.spp = p.acc.spp;
        Ok(())
    }

    /// Loads the model and builds the backend where `nimbus_render` chooses it automatically
    /// (WGSL on a hardware GPU, ONNX Runtime on a software rasteriser).
    fn start_rpnn(&self) -> Result<RpnnView<'g>, String> {
        let model =
            nimbus_rpnn::model::Rpnn::load(&self.opts.rpnn_model).map_err(|e| e.to_string())?;
        let pyr =
            nimbus_rpnn::Pyramid::for_rendering(&self.scene.volume).map_err(|e| e.to_string())?;
        let (backend, _) = nimbus_render::rpnn_backend(
            nimbus_render::NetBackend::Auto,
            Some(self.gpu),
            &self.opts.rpnn_model,
            &model,
            &pyr,
        )
        .map_err(|e| format!("{e:#}"))?;
        Ok(RpnnView {
            backend,
            pyr,
            acc: Accumulator::default(),
        })
    }

    fn frame_rpnn(&mut self, stats: &mut FrameStats) -> Result<(), ViewerError> {
        let restart = self.dirty.light || self.dirty.density || self.dirty.view;
        if self.dirty.density {
            // New density: new pyramid (and GPU descriptor state).
            self.rpnn = Some(self.start_rpnn().map_err(ViewerError::Other)?);
        }
        let (w, h) = (self.camera.width, self.camera.height);
        self.scene.camera = self.camera.clone();
        let r = self.rpnn.as_mut().expect("RPNN mode has its state");
        if restart || r.acc.sum.len() != w * h {
            r.acc = Accumulator::new(w * h);
        }
        let opts = nimbus_rpnn::render::RpnnOptions {
            spp: 1,
            seed: self
                .scene
                .render
                .seed
                .wrapping_add(r.acc.spp as u64 * 0x9E37),
            sky_dirs: 4,
        };
        let out = nimbus_rpnn::render::render(&self.scene, &r.pyr, &mut r.backend, &opts)
            .map_err(|e| ViewerError::Other(e.to_string()))?;
        self.image = r.acc.add(&out.image);
        let t = &out.times;
        stats.stages = vec![
            ("descriptor", t.descriptor_ms),
            ("inference", t.inference_ms),
            ("rest", t.rest_ms),
        ];
        stats.spp = r.acc.spp;
        Ok(())
    }

    /// One line for the window title or a log: method, frame time per stage, photons per frame,
    /// ring fill and the impostor criteria's counts.
    pub fn status_line(&self) -> String {
        let s = &self.stats;
        let mut line = format!("{} | {:.1} ms", self.method.name(), s.wall_ms);
        if !s.stages.is_empty() {
            let parts: Vec<String> = s
                .stages
                .iter()
                .map(|(n, ms)| format!("{n} {ms:.1}"))
                .collect();
            line += &format!(" ({})", parts.join(", "));
        }
        match self.method {
            ViewMode::Pt | ViewMode::Rpnn => line += &format!(" | {} spp", s.spp),
            _ => {
                line += &format!(
                    " | {} photon beams this frame (sun {}, sky {}) | ring {}/{}",
                    s.beams.0 + s.beams.1,
                    s.beams.0,
                    s.beams.1,
                    s.ring_filled,
                    self.pm.settings.ring
                );
                if let Some((r, reuses)) = self.impostor_counts() {
                    line += &format!(
                        " | impostor {} (reused {reuses}; refreshed: first {}, angle {}, distance {}, illumination {}, animation {})",
                        s.refresh.map_or("reused", |r| r.name()),
                        r[0],
                        r[1],
                        r[2],
                        r[3],
                        r[4]
                    );
                }
            }
        }
        if let Some((a, e)) = self.sun_angles() {
            line += &format!(
                " | sun az {a:.0}° el {e:.0}°{}",
                if self.play_sun { " ▶" } else { "" }
            );
        }
        if let Some(n) = &s.note {
            line += &format!(" | {n}");
        }
        line
    }
}
