//! Photon mapping with final gathering ([`crate::Method::Pm`]): the photon map of the default
//! variant (Elek 2012 §3–4: beams into a ring of partial caches, upsampled to J) read at the
//! end of k phase-sampled bounces (`nimbus_photon::mapper` gather.rs). A render builds the ring
//! from its seed and gathers its budget of samples per pixel; progressively (the viewer) the
//! ring keeps following the sun and the density one generation per frame while each frame
//! adds one sample to the image, which starts again whenever J or the camera changes.

use nimbus_scene::clock::Instant;

use anyhow::{Context, Result, bail};
use nimbus_gpu::Gpu;
use nimbus_photon::{GatherSettings, PhotonMapper, PmSettings};
use nimbus_scene::{Cancel, Scene, Sky};

use super::{Change, Engine, Options, Rendered, Step, ms_since, stage_sum};

pub(crate) struct GatherEngine<'g> {
    gpu: &'g Gpu,
    settings: PmSettings,
    gather: GatherSettings,
    density_max: Option<f32>,
    mapper: Option<PhotonMapper<'g>>,
    /// Generations in the ring traced before the last sun or density change.
    stale: u32,
    /// The last live frame traced a generation (J is changing).
    refreshing: bool,
    /// Seconds spent on the ring (tracing, upsampling) and on gathering since the image began.
    ring_s: f64,
    gather_s: f64,
    gpu_ms: f64,
}

/// The medium's HG anisotropy (0 for isotropic; photon mapping refuses tabulated phases).
fn medium_g(scene: &Scene) -> f64 {
    match &scene.medium.phase {
        nimbus_scene::Phase::HenyeyGreenstein(hg) => hg.g(),
        _ => 0.0,
    }
}

impl<'g> GatherEngine<'g> {
    pub(crate) fn new(gpu: &'g Gpu, scene: &Scene, opts: &Options) -> Result<Self> {
        let mut settings = opts.pm_gather.pm_settings(&opts.pm, medium_g(scene));
        if settings.sun_chunks == 0 {
            settings.sun_chunks = nimbus_photon::settings::sun_chunks(scene.volume.grid().res());
        }
        Ok(Self {
            gpu,
            settings,
            gather: opts.pm_gather,
            density_max: opts.pm_density_max,
            mapper: None,
            stale: 0,
            refreshing: false,
            ring_s: 0.0,
            gather_s: 0.0,
            gpu_ms: 0.0,
        })
    }

    fn mapper(&mut self, scene: &Scene) -> Result<&mut PhotonMapper<'g>> {
        if self.mapper.is_none() {
            let mut pm = PhotonMapper::new(self.gpu, scene, self.settings.clone())
                .context("photon mapper")?;
            if let Some(m) = self.density_max.filter(|&m| m > 0.0) {
                pm.set_majorant_value(m);
            }
            pm.set_view(scene.camera.origin);
            self.mapper = Some(pm);
        }
        Ok(self.mapper.as_mut().expect("made above"))
    }

    /// The image with what it cost since it began.
    fn rendered(
        &mut self,
        scene: &Scene,
        device: &str,
        image: nimbus_scene::Image,
        variance: Vec<f32>,
    ) -> Result<Rendered> {
        let (gs, ring_s, gather_s, gpu_ms) = (self.gather, self.ring_s, self.gather_s, self.gpu_ms);
        let pm = self.mapper(scene)?;
        let cam = &scene.camera;
        let spp = pm.gather_samples();
        let notes: String = [pm.light_note(), pm.cache_note()]
            .into_iter()
            .flatten()
            .map(|n| format!(", {n}"))
            .collect();
        Ok(Rendered {
            image,
            variance: Some(variance),
            seconds: ring_s + gather_s,
            setup_s: 0.0,
            gpu_ms: (gpu_ms > 0.0).then_some(gpu_ms),
            summary: format!(
                "photon mapping with final gathering on {device} — ring {} frames × {} beams{}, cache {:?}{notes}, k = {} bounces, sun by {}, {}x{} at {spp} spp in {:.2} s (ring {:.2} s, gathering {:.2} s)",
                pm.frames().min(pm.settings.ring),
                pm.settings.beams_per_frame,
                if gs.ring_refresh > 0 {
                    format!(" (a new one every {} spp)", gs.ring_refresh)
                } else {
                    String::new()
                },
                pm.cache_res(),
                gs.bounces,
                pm.sun_shadow(gs.shadow).name(),
                cam.width,
                cam.height,
                ring_s + gather_s,
                ring_s,
                gather_s,
            ),
            timing_lines: vec![
                format!("  ring + upsampling {:9.1} ms", ring_s * 1e3),
                format!(
                    "  gathering         {:9.3} ms per spp",
                    gather_s * 1e3 / spp.max(1) as f64
                ),
            ],
        })
    }
}

/// Samples the live image averages over while the ring is being replaced (J changes each
/// frame): the image follows the ring with a lag of about this many frames.
pub(crate) const REFRESH_WINDOW: u32 = 8;

/// A change of sun or density taken into a photon map (both photon-mapping engines): `true`
/// when the ring's generations no longer hold the scene's light.
pub(super) fn apply_to_ring(pm: &mut PhotonMapper, scene: &Scene, change: &Change) -> Result<bool> {
    match change {
        Change::Camera(_) => Ok(false),
        Change::SunDir(_) => {
            let Some(sun) = scene.sun.as_ref() else {
                return Ok(false);
            };
            pm.set_sun_dir(sun.dir);
            if scene.atmosphere.is_some() {
                let sky = match &scene.sky {
                    Some(Sky::Constant(c)) => *c,
                    _ => glam::DVec3::ZERO,
                };
                pm.set_lighting(sun.irradiance, sky);
            }
            Ok(true)
        }
        Change::Density(v) => {
            let Some(d) = v.grid().as_dense() else {
                bail!("photon mapping takes a new density as a dense grid");
            };
            pm.set_density(d)?;
            Ok(true)
        }
    }
}

impl Engine for GatherEngine<'_> {
    fn render(
        &mut self,
        scene: &Scene,
        device: &str,
        _prepare_s: f64,
        budget: u32,
        seed: u64,
        cancel: &Cancel,
    ) -> Result<Rendered> {
        let t0 = Instant::now();
        let gather = self.gather;
        self.settings.seed = seed as u32;
        self.mapper = None;
        let pm = self.mapper(scene)?;
        pm.set_cancel(cancel.clone());
        let setup_s = t0.elapsed().as_secs_f64();
        let t1 = Instant::now();
        pm.converge()?;
        pm.upsample();
        let mut gpu_ms = stage_sum(&pm.last_times);
        let ring_s = t1.elapsed().as_secs_f64();
        let t2 = Instant::now();
        let refresh_s = pm.gather_refreshing(&scene.camera, &gather, budget)?;
        gpu_ms += stage_sum(&pm.last_times);
        pm.set_cancel(Cancel::never());
        let (image, variance) = pm.gather_image()?;
        self.ring_s = ring_s + refresh_s;
        self.gather_s = t2.elapsed().as_secs_f64() - refresh_s;
        self.gpu_ms = gpu_ms;
        let mut r = self.rendered(scene, device, image, variance)?;
        r.setup_s = setup_s;
        Ok(r)
    }

    fn restart(&mut self, scene: &Scene, _seed: u64) -> Result<()> {
        // The gather's random streams never repeat (`PhotonMapper::gather`), so a restart only
        // empties the running sums; the ring and its seed stay.
        self.mapper(scene)?.gather_reset();
        self.gather_s = 0.0;
        self.ring_s = 0.0;
        self.gpu_ms = 0.0;
        Ok(())
    }

    fn apply(&mut self, scene: &Scene, change: &Change) -> Result<()> {
        let ring = self.settings.ring;
        let pm = self.mapper(scene)?;
        if let Change::Camera(c) = change {
            pm.set_view(c.origin);
        }
        if apply_to_ring(pm, scene, change)? {
            self.stale = ring;
        }
        Ok(())
    }

    fn accumulate(&mut self, scene: &Scene, n: u32, cancel: &Cancel) -> Result<Step> {
        let gather = self.gather;
        let gpu = self.gpu;
        let mut step = Step::default();
        self.mapper(scene)?;
        for _ in 0..n {
            cancel.check()?;
            let stale = self.stale;
            let pm = self.mapper.as_mut().expect("made above");
            let trace = stale > 0 || !pm.ring_full() || pm.view_pending();
            if trace {
                let t = Instant::now();
                pm.trace_frame(None);
                pm.check_overflow()?;
                step.beams = pm.last_generation_beams();
                let ms = ms_since(t);
                step.stages.push(("trace", ms));
                let t = Instant::now();
                pm.upsample();
                let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
                let up = ms_since(t);
                step.stages.push(("upsample", up));
                self.ring_s += (ms + up) / 1e3;
                self.stale = stale.saturating_sub(1);
            } else if self.refreshing {
                // The ring is fresh again: the image starts over from it alone.
                pm.gather_reset();
            } else if gather.ring_refresh > 0
                && pm.gather_samples() > 0
                && pm.gather_samples().is_multiple_of(gather.ring_refresh)
            {
                // A still scene with a renewed ring (`GatherSettings::ring_refresh`): a new
                // generation replaces the oldest and the sums go on averaging, over the photon
                // map's noise too.
                let t = Instant::now();
                pm.trace_frame(None);
                pm.check_overflow()?;
                step.beams = pm.last_generation_beams();
                pm.upsample();
                let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
                let ms = ms_since(t);
                step.stages.push(("renew", ms));
                self.ring_s += ms / 1e3;
            }
            self.refreshing = trace;
            let t = Instant::now();
            if trace {
                // J changes every frame: a mean over the last few samples follows it.
                pm.gather_window(&scene.camera, &gather, REFRESH_WINDOW)?;
            } else {
                pm.gather(&scene.camera, &gather, 1)?;
            }
            let _ = gpu.device.poll(wgpu::PollType::wait_indefinitely());
            let ms = ms_since(t);
            self.gather_s += ms / 1e3;
            step.stages.push(("gather", ms));
        }
        let pm = self.mapper(scene)?;
        step.ring = Some((pm.frames().min(pm.settings.ring), pm.settings.ring));
        step.spp = pm.gather_samples();
        Ok(step)
    }

    fn image(&mut self, scene: &Scene, device: &str) -> Result<Rendered> {
        let (image, variance) = self.mapper(scene)?.gather_image()?;
        self.rendered(scene, device, image, variance)
    }

    fn samples(&self) -> u32 {
        self.mapper.as_ref().map_or(0, |p| p.gather_samples())
    }
}
