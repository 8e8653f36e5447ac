//! The path tracer on the GPU (`nimbus_trace::gpu`, `shaders/pt.wgsl`): running sums on the
//! device, a new camera or sun without a new upload, a new density with one.

use nimbus_scene::clock::Instant;

use anyhow::{Context, Result};
use nimbus_gpu::Gpu;
use nimbus_scene::{Cancel, Scene};
use nimbus_trace::gpu::GpuPathTracer;

use super::{Change, Engine, Rendered, Step, ms_since};

pub(crate) struct PtGpuEngine<'g> {
    gpu: &'g Gpu,
    tracer: GpuPathTracer<'g>,
    /// Seconds of sampling since the last restart.
    seconds: f64,
}

impl<'g> PtGpuEngine<'g> {
    pub(crate) fn new(gpu: &'g Gpu, scene: &Scene) -> Result<Self> {
        let tracer = GpuPathTracer::new(gpu, scene)
            .with_context(|| format!("{}: GPU path tracer", scene.source.display()))?;
        Ok(Self {
            gpu,
            tracer,
            seconds: 0.0,
        })
    }

    /// Adds `spp` samples; with a live `cancel`, one dispatch's worth at a time, waiting for
    /// the device after each so that a cancel is seen within one (the same dispatches, the
    /// same pixels).
    fn add(&mut self, spp: u32, cancel: &Cancel) -> Result<()> {
        if !cancel.is_live() {
            return Ok(self.tracer.add(spp)?);
        }
        let mut left = spp;
        while left > 0 {
            cancel.check()?;
            let n = left.min(nimbus_trace::gpu::SPP_PER_DISPATCH);
            self.tracer.add(n)?;
            let _ = self.gpu.device.poll(wgpu::PollType::wait_indefinitely());
            left -= n;
        }
        Ok(cancel.check()?)
    }
}

impl Engine for PtGpuEngine<'_> {
    fn render(
        &mut self,
        scene: &Scene,
        device: &str,
        prepare_s: f64,
        budget: u32,
        seed: u64,
        cancel: &Cancel,
    ) -> Result<Rendered> {
        let t0 = Instant::now();
        self.tracer.reset(seed)?;
        self.add(budget, cancel)?;
        let (image, variance) = self.tracer.image()?;
        let seconds = t0.elapsed().as_secs_f64();
        self.seconds = seconds;
        let cam = &scene.camera;
        // As the command line has always reported it: set-up and render together.
        let total = prepare_s + seconds;
        Ok(Rendered {
            image,
            variance: Some(variance),
            seconds,
            setup_s: 0.0,
            gpu_ms: None,
            summary: format!(
                "GPU path tracing on {} — {}x{} at {} spp in {:.2} s ({:.3e} camera paths/s)",
                device,
                cam.width,
                cam.height,
                budget,
                total,
                (cam.width * cam.height) as f64 * budget as f64 / total.max(1e-9)
            ),
            timing_lines: Vec::new(),
        })
    }

    fn restart(&mut self, _scene: &Scene, seed: u64) -> Result<()> {
        self.seconds = 0.0;
        Ok(self.tracer.reset(seed)?)
    }

    fn apply(&mut self, scene: &Scene, change: &Change) -> Result<()> {
        match change {
            Change::Camera(c) => self.tracer.set_camera(c),
            Change::SunDir(_) => self.tracer.set_lights(scene),
            Change::Density(_) => *self = Self::new(self.gpu, scene)?,
        }
        Ok(())
    }

    fn accumulate(&mut self, _scene: &Scene, n: u32, cancel: &Cancel) -> Result<Step> {
        let t = Instant::now();
        self.add(n, cancel)?;
        let _ = self.gpu.device.poll(wgpu::PollType::wait_indefinitely());
        let ms = ms_since(t);
        self.seconds += ms / 1e3;
        Ok(Step {
            stages: vec![("path tracing (GPU)", ms)],
            spp: self.tracer.samples(),
            ..Default::default()
        })
    }

    fn image(&mut self, scene: &Scene, device: &str) -> Result<Rendered> {
        let (image, variance) = self.tracer.image()?;
        let cam = &scene.camera;
        Ok(Rendered {
            image,
            variance: Some(variance),
            seconds: self.seconds,
            setup_s: 0.0,
            gpu_ms: None,
            summary: format!(
                "GPU path tracing on {} — {}x{} at {} spp in {:.2} s",
                device,
                cam.width,
                cam.height,
                self.tracer.samples(),
                self.seconds
            ),
            timing_lines: Vec::new(),
        })
    }

    fn samples(&self) -> u32 {
        self.tracer.samples()
    }
}
