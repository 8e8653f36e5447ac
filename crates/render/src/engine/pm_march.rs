//! Ray-marched photon mapping ([`crate::Method::PmMarch`], [`crate::Method::PmElek2012`]):
//! Elek 2012's estimator — the ring of partial caches upsampled to J and ray marched (§4.3–4.4).
//! A render builds a ring of `budget` generations from its seed. Live (the viewer), one
//! generation per frame replaces the oldest while the ring is not full or holds generations
//! traced before the last sun or density change (§4.1) — a static scene traces nothing once the
//! ring is fresh — and the impostor criteria (§4.4) decide whether to ray march a new image or
//! re-project the last one to the current camera. The view-dependent words (the default
//! in-scattering) belong to a camera position: after the camera moved beyond the impostor
//! tolerance the ring is retraced for it, the lobes showing meanwhile.

use nimbus_scene::clock::Instant;

use anyhow::{Context, Result};
use nimbus_gpu::Gpu;
use nimbus_photon::impostor::{ImpostorState, Refresh};
use nimbus_photon::{PhotonMapper, PmSettings, PmVariant};
use nimbus_scene::{Camera, Cancel, Image, Scene};

use super::{Change, Engine, Options, Rendered, Step, ms_since, stage_sum};
use crate::Method;

pub(crate) struct MarchEngine<'g> {
    gpu: &'g Gpu,
    settings: PmSettings,
    half_res: bool,
    density_max: Option<f32>,
    mapper: Option<PhotonMapper<'g>>,
    impostor: Option<ImpostorState>,
    /// The last ray-marched image and the camera it was marched for.
    impostor_image: Option<(Image, Camera)>,
    /// The image last shown.
    image: Option<Image>,
    j_valid: bool,
    /// Generations in the ring traced before the last sun or density change.
    stale: u32,
    seconds: f64,
    /// The density the impostor criteria last saw (its animation criterion compares with it).
    prev_density: Option<Vec<f32>>,
}

impl<'g> MarchEngine<'g> {
    pub(crate) fn new(gpu: &'g Gpu, scene: &Scene, method: Method, opts: &Options) -> Self {
        let mut settings = opts.pm.clone();
        if method == Method::PmElek2012 {
            settings.variant = PmVariant::Elek2012;
        }
        if settings.sun_chunks == 0 {
            settings.sun_chunks = nimbus_photon::settings::sun_chunks(scene.volume.grid().res());
        }
        Self {
            gpu,
            settings,
            half_res: opts.pm_half_res,
            density_max: opts.pm_density_max,
            mapper: None,
            impostor: opts.impostors.map(ImpostorState::new),
            impostor_image: None,
            image: None,
            j_valid: false,
            stale: 0,
            seconds: 0.0,
            prev_density: None,
        }
    }

    fn mapper(&mut self, scene: &Scene) -> Result<&mut PhotonMapper<'g>> {
        if self.mapper.is_none() {
            let mut pm = PhotonMapper::new(self.gpu, scene, self.settings.clone())
                .context("photon mapper")?;
            if let Some(m) = self.density_max.filter(|&m| m > 0.0) {
                pm.set_majorant_value(m);
            }
            self.mapper = Some(pm);
        }
        Ok(self.mapper.as_mut().expect("made above"))
    }

    fn march(&mut self, camera: &Camera) -> Result<Image> {
        let half = self.half_res;
        let pm = self.mapper.as_mut().expect("made by the caller");
        Ok(if half {
            pm.raymarch_half(camera)?
        } else {
            pm.raymarch(camera)?
        })
    }

    /// Waits for the GPU and returns the milliseconds since `t`: stage times are wall-clock
    /// times with the stage's GPU work finished (GPU timestamps are not reliable on every
    /// driver once a window surface presents — lavapipe reports zeros then).
    fn since(&self, t: Instant) -> f64 {
        let _ = self.gpu.device.poll(wgpu::PollType::wait_indefinitely());
        ms_since(t)
    }

    /// One live frame (see the module docs).
    fn frame(&mut self, scene: &Scene) -> Result<Step> {
        let mut step = Step::default();
        let stale = self.stale;
        let camera = scene.camera.clone();
        let pm = self.mapper(scene)?;
        pm.set_view(camera.origin);
        let trace = stale > 0 || !pm.ring_full() || pm.view_pending();
        self.stale = stale.saturating_sub(trace as u32);
        if trace {
            let t = Instant::now();
            self.mapper.as_mut().expect("made").trace_frame(None);
            step.stages.push(("trace", self.since(t)));
            if let Some(s) = self.impostor.as_mut() {
                s.traced();
            }
        }
        let pm = self.mapper.as_mut().expect("made");
        step.beams = if trace {
            pm.last_generation_beams()
        } else {
            (0, 0)
        };
        // J switching between the lobes and the view words (the ring has just been retraced for
        // the camera) changes the image at once: it is ray marched whatever the impostor says.
        let mut switched = false;
        if trace || !self.j_valid {
            let t = Instant::now();
            let pm = self.mapper.as_mut().expect("made");
            let was_view = pm.j_holds_view();
            pm.upsample();
            switched = pm.j_holds_view() != was_view;
            step.stages.push(("upsample", self.since(t)));
            self.j_valid = true;
        }
        let pm = self.mapper.as_mut().expect("made");
        let ring = pm.settings.ring;
        step.ring = Some((pm.frames().min(ring), ring));
        let centre = pm.cloud_center();
        let refresh = match self.impostor.as_mut() {
            Some(s) => s.check(camera.origin, centre, ring),
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
                self.image = Some(if *cam0 == camera {
                    img.clone()
                } else {
                    nimbus_photon::impostor::reproject(img, cam0, &camera, centre)
                });
                step.stages.push(("impostor", ms_since(t)));
            }
            _ => {
                let t = Instant::now();
                let img = self.march(&camera)?;
                step.stages.push(("ray march", self.since(t)));
                self.impostor_image = Some((img.clone(), camera.clone()));
                self.image = Some(img);
            }
        }
        let pm = self.mapper.as_mut().expect("made");
        if trace {
            // A wrapped cache sum is an error, not a silently wrong image (4 bytes read back).
            pm.check_overflow()?;
        }
        pm.last_times.clear();
        step.refresh = refresh;
        step.impostor_counts = self.impostor.as_ref().map(|s| (s.refreshes, s.reuses));
        Ok(step)
    }
}

impl Engine for MarchEngine<'_> {
    fn render(
        &mut self,
        scene: &Scene,
        device: &str,
        _prepare_s: f64,
        budget: u32,
        seed: u64,
        cancel: &Cancel,
    ) -> Result<Rendered> {
        let cam = &scene.camera;
        let t0 = Instant::now();
        let settings = PmSettings {
            ring: budget,
            seed: seed as u32,
            ..self.settings.clone()
        };
        let beams = settings.beams_per_frame;
        let mut pm = PhotonMapper::new(self.gpu, scene, settings).context("photon mapper")?;
        let setup_s = t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        let mut gpu_ms = 0.0;
        while !pm.ring_full() {
            cancel.check()?;
            pm.trace_frame(None);
            gpu_ms += stage_sum(&pm.last_times);
            if cancel.is_live() {
                let _ = self.gpu.device.poll(wgpu::PollType::wait_indefinitely());
            }
        }
        cancel.check()?;
        pm.upsample();
        gpu_ms += stage_sum(&pm.last_times);
        let image = if self.half_res {
            pm.raymarch_half(cam)?
        } else {
            pm.raymarch(cam)?
        };
        gpu_ms += stage_sum(&pm.last_times);
        let seconds = t1.elapsed().as_secs_f64();
        let mut timing_lines = Vec::new();
        if pm.last_times.is_empty() {
            timing_lines.push("GPU timestamps are not available on this adapter".into());
        }
        for (stage, ms) in &pm.last_times {
            timing_lines.push(format!("  {stage:14} {ms:9.3} ms (last frame)"));
        }
        let summary = format!(
            "photon mapping on {} — {} frames × {} beams, cache {:?} ({}){}, {}x{} in {:.2} s",
            device,
            pm.frames(),
            beams,
            pm.cache_res(),
            if pm.uses_shared_memory() {
                "workgroup memory"
            } else {
                "global atomics"
            },
            [pm.light_note(), pm.cache_note()]
                .into_iter()
                .flatten()
                .map(|n| format!(", {n}"))
                .collect::<String>(),
            cam.width,
            cam.height,
            setup_s + seconds
        );
        self.seconds = seconds;
        self.image = Some(image.clone());
        Ok(Rendered {
            image,
            variance: None,
            seconds,
            setup_s,
            gpu_ms: self
                .gpu
                .has_timestamps()
                .then_some(gpu_ms)
                .filter(|&v| v > 0.0),
            summary,
            timing_lines,
        })
    }

    fn restart(&mut self, scene: &Scene, _seed: u64) -> Result<()> {
        // The ray-marched image has no samples to drop: the next frame shows the ring as it is.
        self.mapper(scene)?;
        Ok(())
    }

    fn apply(&mut self, scene: &Scene, change: &Change) -> Result<()> {
        let ring = self.settings.ring;
        let pm = self.mapper(scene)?;
        if super::pm::apply_to_ring(pm, scene, change)? {
            self.stale = ring;
        }
        // The animation criterion: the relative L1 change since the last frame.
        if let Change::Density(v) = change
            && let Some(d) = v.grid().as_dense()
            && let Some(state) = self.impostor.as_mut()
        {
            if let Some(prev) = &self.prev_density {
                let diff: f64 = d.iter().zip(prev).map(|(a, b)| (a - b).abs() as f64).sum();
                let base: f64 = prev.iter().map(|v| *v as f64).sum::<f64>().max(1e-30);
                state.density_changed(diff / base);
            }
            self.prev_density = Some(d.to_vec());
        }
        Ok(())
    }

    fn accumulate(&mut self, scene: &Scene, n: u32, cancel: &Cancel) -> Result<Step> {
        let t = Instant::now();
        let mut step = Step::default();
        for _ in 0..n.max(1) {
            cancel.check()?;
            step = self.frame(scene)?;
        }
        self.seconds += t.elapsed().as_secs_f64();
        Ok(step)
    }

    fn image(&mut self, scene: &Scene, device: &str) -> Result<Rendered> {
        if self.image.is_none() {
            self.frame(scene)?;
        }
        let pm = self.mapper(scene)?;
        let summary = format!(
            "photon mapping (ray marched) on {device} — ring {}/{} frames × {} beams, cache {:?}",
            pm.frames().min(pm.settings.ring),
            pm.settings.ring,
            pm.settings.beams_per_frame,
            pm.cache_res()
        );
        Ok(Rendered {
            image: self.image.clone().expect("made above"),
            variance: None,
            seconds: self.seconds,
            setup_s: 0.0,
            gpu_ms: None,
            summary,
            timing_lines: Vec::new(),
        })
    }

    fn samples(&self) -> u32 {
        0
    }
}
