//! The CPU reference path tracer (`nimbus_trace`): its majorant grid is built once per density,
//! the image is a running sum of samples.

use anyhow::Result;
use nimbus_scene::volume::MajorantGrid;
use nimbus_scene::{Cancel, Scene};
use nimbus_trace::{PathTracer, RenderOptions, RenderStats, Sums};

use super::{Change, Engine, Rendered, Step, ms_since};

pub(crate) struct PtEngine {
    majorants: MajorantGrid,
    sums: Sums,
    seed: u64,
    progress: bool,
    /// Work and time since the last restart.
    stats: RenderStats,
}

impl PtEngine {
    pub(crate) fn new(scene: &Scene, progress: bool) -> Self {
        Self {
            majorants: MajorantGrid::with_block(
                &scene.volume,
                nimbus_trace::integrator::MAJORANT_BLOCK,
            ),
            sums: Sums::new(scene.camera.width, scene.camera.height),
            seed: scene.render.seed,
            progress,
            stats: RenderStats::default(),
        }
    }

    fn add(&mut self, scene: &Scene, spp: u32, cancel: &Cancel) -> Result<()> {
        let tracer = PathTracer::borrowing(scene, &self.majorants);
        let opts = RenderOptions {
            spp,
            seed: self.seed,
            progress: self.progress,
        };
        let st = nimbus_trace::accumulate_cancellable(&tracer, &opts, &mut self.sums, cancel)?;
        self.stats.paths += st.paths;
        self.stats.scatterings += st.scatterings;
        self.stats.seconds += st.seconds;
        Ok(())
    }
}

impl Engine for PtEngine {
    fn render(
        &mut self,
        scene: &Scene,
        device: &str,
        _prepare_s: f64,
        budget: u32,
        seed: u64,
        cancel: &Cancel,
    ) -> Result<Rendered> {
        self.restart(scene, seed)?;
        self.add(scene, budget, cancel)?;
        self.image(scene, device)
    }

    fn restart(&mut self, scene: &Scene, seed: u64) -> Result<()> {
        self.sums = Sums::new(scene.camera.width, scene.camera.height);
        self.seed = seed;
        self.stats = RenderStats::default();
        Ok(())
    }

    fn apply(&mut self, scene: &Scene, change: &Change) -> Result<()> {
        if let Change::Density(_) = change {
            self.majorants =
                MajorantGrid::with_block(&scene.volume, nimbus_trace::integrator::MAJORANT_BLOCK);
        }
        Ok(())
    }

    fn accumulate(&mut self, scene: &Scene, n: u32, cancel: &Cancel) -> Result<Step> {
        let t = nimbus_scene::clock::Instant::now();
        self.add(scene, n, cancel)?;
        Ok(Step {
            stages: vec![("path tracing (CPU)", ms_since(t))],
            spp: self.samples(),
            ..Default::default()
        })
    }

    fn image(&mut self, scene: &Scene, _device: &str) -> Result<Rendered> {
        let (image, variance) = self.sums.image();
        let st = self.stats;
        let cam = &scene.camera;
        Ok(Rendered {
            image,
            variance: Some(variance),
            seconds: st.seconds,
            setup_s: 0.0,
            gpu_ms: None,
            summary: format!(
                "path tracing {}x{} at {} spp in {:.2} s ({:.3e} camera paths/s, {:.1} scatterings/path)",
                cam.width,
                cam.height,
                self.sums.samples,
                st.seconds,
                st.paths_per_second(),
                st.scatterings as f64 / st.paths.max(1) as f64,
            ),
            timing_lines: Vec::new(),
        })
    }

    fn samples(&self) -> u32 {
        self.sums.samples as u32
    }
}
