//! The viewer's state and frame loop, independent of any window: the windowed front end
//! ([`crate::window`]) and the headless one ([`crate::headless`]) both drive a [`Viewer`] with
//! [`Action`]s and call [`Viewer::step`] once per frame.
//!
//! The viewer holds one [`nimbus_render::Estimator`] for the method shown and drives it like the
//! command line does: every edit (camera, sun, density) is a [`Change`], every frame one
//! [`Estimator::accumulate`] and one [`Estimator::image`]. What a frame does is the estimator's:
//! - photon mapping with final gathering (`pm`, the default): the ring follows the sun and the
//!   density one generation per frame (Elek 2012 §4.1) while each frame adds a gathered sample;
//!   a change of camera, sun or density starts the image again;
//! - ray-marched photon mapping (`pm-march`): the ring as above, I upsampled to J (§4.3), and the
//!   impostor criteria (§4.4) deciding whether to ray march or re-project the last image;
//! - path tracing (`pt`: the GPU path tracer where it supports the scene, else the CPU one) and
//!   RPNN (`rpnn`, Kallweit §4.4; the model is loaded when the mode is first chosen): one sample
//!   per pixel per frame, restarted on any change.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use glam::{DQuat, DVec3};
use nimbus_gpu::Gpu;
use nimbus_photon::animate::DensitySequence;
use nimbus_photon::impostor::{ImpostorCriteria, Refresh};
use nimbus_photon::{GatherSettings, PmSettings};
use nimbus_render::{Change, Estimator, Method, NetBackend, Options, RpnnSettings};
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

impl From<anyhow::Error> for ViewerError {
    fn from(e: anyhow::Error) -> Self {
        ViewerError::Other(format!("{e:#}"))
    }
}

/// A scene file's text and the folder its relative paths start from (for `save-scene`).
pub type SceneSource = (String, PathBuf);

/// How the viewer starts.
#[derive(Debug, Clone)]
pub struct ViewerOptions {
    pub pm: PmSettings,
    /// Photon mapping with final gathering (`pm`): bounces and the sun's shadows.
    pub gather: GatherSettings,
    pub half_res: bool,
    /// Impostor criteria of the ray-marched photon map (Elek §4.4); `None` ray marches every
    /// frame.
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
    /// The RPNN model for RPNN mode (loaded only when that mode is chosen); `None`: the shipped
    /// model for the scene (the sky head's under a sky), as `nimbus render` chooses it.
    pub rpnn_model: Option<PathBuf>,
    /// RPNN mode: where the network runs ([`NetBackend`]; with the network on the GPU the
    /// whole sample runs there, `nimbus_rpnn::gpu_sample`).
    pub rpnn_backend: NetBackend,
}

impl Default for ViewerOptions {
    fn default() -> Self {
        Self {
            // sun_chunks 0: chosen from the volume (`nimbus_photon::settings::sun_chunks`).
            pm: PmSettings {
                sun_chunks: 0,
                ..Default::default()
            },
            gather: GatherSettings::default(),
            half_res: false,
            impostors: Some(ImpostorCriteria::default()),
            density: DensitySequence::Static,
            sun_speed_deg_s: 10.0,
            density_fps: 10.0,
            play_sun: false,
            play_density: false,
            method: ViewMode::Pm,
            exposure: None,
            rpnn_model: None,
            rpnn_backend: NetBackend::Auto,
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
    /// Samples per pixel accumulated (progressive estimators).
    pub spp: u32,
    pub note: Option<String>,
}

/// The viewer.
pub struct Viewer<'g> {
    gpu: &'g Gpu,
    scene: Scene,
    /// The scene file's text and folder (for `save-scene`).
    source: Option<SceneSource>,
    opts: ViewerOptions,
    /// The estimator of the method shown; it holds its own copy of the scene, kept in step
    /// through [`Change`]s.
    est: Estimator<'g>,
    method: ViewMode,
    play_sun: bool,
    play_density: bool,
    density_clock: f64,
    density_frame: Option<u32>,
    /// Changes since the last frame, handed to the estimator before it renders.
    pending: Vec<Change>,
    image: Image,
    exposure: Option<f64>,
    frame: u32,
    stats: FrameStats,
    impostor_counts: Option<([u32; 5], u32)>,
    ring: Option<(u32, u32)>,
    note: Option<String>,
    quit: bool,
}

/// The estimator's options for the viewer's settings.
fn options(opts: &ViewerOptions, density_max: Option<f32>) -> Options {
    Options {
        progress: false,
        pm: opts.pm.clone(),
        pm_half_res: opts.half_res,
        pm_gather: opts.gather,
        impostors: opts.impostors,
        pm_density_max: density_max,
        rpnn: RpnnSettings {
            model: opts.rpnn_model.clone(),
            backend: opts.rpnn_backend,
            ..Default::default()
        },
    }
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
        let method = opts.method;
        let (est, note) = Self::prepare(gpu, &scene, &opts, method)?;
        let camera = scene.camera.clone();
        Ok(Self {
            gpu,
            est,
            image: Image::new(camera.width, camera.height),
            method,
            play_sun: opts.play_sun,
            play_density: opts.play_density,
            density_clock: 0.0,
            density_frame: None,
            pending: Vec::new(),
            exposure: opts.exposure,
            frame: 0,
            stats: FrameStats::default(),
            impostor_counts: None,
            ring: None,
            note,
            quit: false,
            scene,
            source,
            opts,
        })
    }

    /// The estimator for `mode` on the scene as it is now, and what the user should know about
    /// it (a model trained for another medium).
    fn prepare(
        gpu: &'g Gpu,
        scene: &Scene,
        opts: &ViewerOptions,
        mode: ViewMode,
    ) -> Result<(Estimator<'g>, Option<String>), ViewerError> {
        let seq_max = opts.density.max_value(scene.volume.grid().res())?;
        let o = options(opts, (seq_max > 0.0).then_some(seq_max));
        let est = match mode.method() {
            // The GPU path tracer where it supports the scene, else the CPU one.
            Method::PtGpu => match nimbus_render::prepare(scene, Method::PtGpu, &o, gpu) {
                Ok(e) => e,
                Err(_) => nimbus_render::prepare(scene, Method::Pt, &o, gpu)?,
            },
            m => nimbus_render::prepare(scene, m, &o, gpu)?,
        };
        let note = (!est.warnings.is_empty()).then(|| {
            est.warnings
                .iter()
                .map(|w| w.trim_start_matches("warning: "))
                .collect::<Vec<_>>()
                .join("; ")
        });
        Ok((est, note))
    }

    pub fn camera(&self) -> &Camera {
        &self.scene.camera
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

    /// The ray-marched photon map's impostor counts: refreshes per reason and reuses.
    pub fn impostor_counts(&self) -> Option<([u32; 5], u32)> {
        self.impostor_counts
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
        self.pending.push(Change::SunDir(dir));
    }

    fn set_sun_angles(&mut self, azimuth_deg: f64, elevation_deg: f64) {
        let (a, e) = (
            azimuth_deg.to_radians(),
            elevation_deg.clamp(-90.0, 90.0).to_radians(),
        );
        self.set_sun_dir(DVec3::new(e.cos() * a.sin(), e.sin(), e.cos() * a.cos()));
    }

    fn set_camera(&mut self, origin: DVec3, target: DVec3, width: usize, height: usize) {
        let c = &self.scene.camera;
        let up = c.up_hint();
        // Looking straight along the up hint: keep the old camera (the orbit clamps pitch, so
        // this only happens for a degenerate pan or zoom).
        if let Ok(c) = Camera::new(origin, target, up, c.vfov_deg(), width, height) {
            self.scene.camera = c.clone();
            self.pending.push(Change::Camera(c));
        }
    }

    /// Applies one action.
    pub fn apply(&mut self, action: &Action) -> Result<(), ViewerError> {
        let cam = &self.scene.camera;
        let (o, t) = (cam.origin, cam.target());
        let (w, h) = (cam.width, cam.height);
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
                let (_, r, u, _) = cam.basis();
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
                if *m != self.method {
                    // The changes not yet rendered are in the scene the new estimator starts
                    // from.
                    match Self::prepare(self.gpu, &self.scene, &self.opts, *m) {
                        Ok((est, note)) => {
                            self.est = est;
                            self.method = *m;
                            self.pending.clear();
                            self.impostor_counts = None;
                            self.note = note;
                        }
                        Err(e) => {
                            self.note = Some(format!(
                                "{} unavailable ({e}); method unchanged",
                                m.method().describe()
                            ));
                        }
                    }
                }
            }
            Action::Resize { width, height } => {
                let (w, h) = (*width as usize, *height as usize);
                if w > 0 && h > 0 && (w, h) != (cam.width, cam.height) {
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

    /// Writes the scene with the current camera and sun to `path` (TOML), atomically
    /// ([`nimbus_scene::fsio::write_bytes`]). Every file path of the original
    /// ([`nimbus_scene::scene_paths::PATH_FIELDS`]) is rewritten for `path`'s folder
    /// ([`nimbus_scene::scene_paths::rebase_paths`]: relative under it, absolute elsewhere), so
    /// the copy reads the same files wherever it is opened from.
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
        let c = &self.scene.camera;
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
        if let Some(d) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(d).map_err(|e| perr(e.to_string()))?;
        }
        // Every path field, for the folder saved into (after it exists: a file under it is
        // recognised through links too).
        let scene_err = |e: nimbus_scene::Error| ViewerError::Other(e.to_string());
        nimbus_scene::scene_paths::rebase_paths(&mut doc, &dir, path).map_err(scene_err)?;
        let out = format!(
            "# Saved by `nimbus view` (camera and sun as last shown).\n{}",
            toml::to_string(&doc).map_err(|e| perr(e.to_string()))?
        );
        // Whole or not at all: a full disk leaves an existing file as it was.
        nimbus_scene::fsio::write_bytes(path, out.as_bytes()).map_err(scene_err)
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
        for c in std::mem::take(&mut self.pending) {
            self.est.change(c)?;
        }
        let step = self.est.accumulate(1)?;
        self.image = self.est.image()?.image;
        if self.exposure.is_none() {
            self.exposure = Some(self.image.auto_exposure());
        }
        stats.stages = step.stages;
        stats.beams = step.beams;
        stats.ring_filled = step.ring.map_or(0, |r| r.0);
        stats.refresh = step.refresh;
        stats.spp = step.spp;
        if let Some(n) = step.note {
            stats.note = Some(n);
        }
        self.ring = step.ring;
        self.impostor_counts = step.impostor_counts;
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
        let v = self.scene.volume.as_ref();
        let grid = DensityGrid::new(v.grid().res(), d)
            .map_err(|e| ViewerError::Other(format!("density frame {f}: {e}")))?;
        let vol = Volume::new(grid, *v.aabb(), v.density_scale())
            .map_err(|e| ViewerError::Other(format!("density frame {f}: {e}")))?;
        let vol = Arc::new(vol);
        self.scene.volume = vol.clone();
        self.pending.push(Change::Density(vol));
        self.density_frame = Some(f);
        Ok(())
    }

    /// One line for the window title or a log: method, frame time per stage, samples or photons
    /// per frame, ring fill and the impostor criteria's counts.
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
        if let Some((filled, ring)) = self.ring {
            line += &format!(
                " | {} photon beams this frame (sun {}, sky {}) | ring {filled}/{ring}",
                s.beams.0 + s.beams.1,
                s.beams.0,
                s.beams.1,
            );
        }
        if self.method != ViewMode::PmMarch {
            line += &format!(" | {} spp", s.spp);
        }
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
