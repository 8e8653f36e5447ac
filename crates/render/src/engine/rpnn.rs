//! RPNN (Kallweit 2017 §4.4): Monte Carlo direct light, the network's indirect light. The
//! density pyramid, majorant grid and network backend are built once per density; the image
//! is a running sum of samples.

use std::path::PathBuf;

use anyhow::{Context, Result};
use nimbus_gpu::Gpu;
use nimbus_rpnn::Pyramid;
use nimbus_rpnn::model::Rpnn;
use nimbus_rpnn::render::{Backend, RpnnOptions, RpnnSums, SkySh, StageTimes};
use nimbus_scene::Scene;
use nimbus_scene::volume::MajorantGrid;

use super::Engine;
use crate::estimator::{Change, Rendered, RpnnSettings, Step};
use crate::{NetBackend, rpnn_backend};

pub(crate) struct RpnnEngine<'g> {
    model_path: PathBuf,
    model: Rpnn,
    pyramid: Pyramid,
    backend: Backend<'g>,
    /// The adapter the backend was chosen with (rebuilt on a new density).
    adapter: Option<&'g Gpu>,
    choice: NetBackend,
    majorants: MajorantGrid,
    sums: RpnnSums,
    seed: u64,
    sky_dirs: u32,
    /// The sky through the sky head (`None`: the paper's directions).
    sky_sh: Option<SkySh>,
    /// Stage times since the last restart.
    times: StageTimes,
}

/// The network an [`RpnnEngine`] runs: the model, its file, where it runs and on which
/// adapter it was chosen.
pub(crate) struct Network<'g> {
    pub path: PathBuf,
    pub model: Rpnn,
    pub backend: Backend<'g>,
    pub adapter: Option<&'g Gpu>,
}

impl<'g> RpnnEngine<'g> {
    pub(crate) fn new(
        scene: &Scene,
        net: Network<'g>,
        pyramid: Pyramid,
        settings: &RpnnSettings,
        sky_sh: Option<SkySh>,
    ) -> Self {
        Self {
            model_path: net.path,
            model: net.model,
            pyramid,
            backend: net.backend,
            adapter: net.adapter,
            choice: settings.backend,
            majorants: nimbus_rpnn::render::majorants(scene),
            sums: RpnnSums::new(scene.camera.width, scene.camera.height),
            seed: scene.render.seed,
            sky_dirs: settings.sky_dirs,
            sky_sh,
            times: StageTimes::default(),
        }
    }

    fn add(&mut self, scene: &Scene, spp: u32) -> Result<()> {
        let ro = RpnnOptions {
            sky_sh: self.sky_sh.clone(),
            sun_outputs: self.model.outputs,
            ..RpnnOptions::new(spp, self.seed, self.sky_dirs)
        };
        let t = nimbus_rpnn::render::accumulate(
            scene,
            &self.pyramid,
            &self.majorants,
            &mut self.backend,
            &ro,
            &mut self.sums,
        )
        .context("RPNN render")?;
        let a = &mut self.times;
        a.descriptor_ms += t.descriptor_ms;
        a.inference_ms += t.inference_ms;
        a.rest_ms += t.rest_ms;
        a.total_ms += t.total_ms;
        a.queries += t.queries;
        Ok(())
    }
}

impl Engine for RpnnEngine<'_> {
    fn render(
        &mut self,
        scene: &Scene,
        device: &str,
        _prepare_s: f64,
        budget: u32,
        seed: u64,
    ) -> Result<Rendered> {
        self.restart(scene, seed)?;
        self.add(scene, budget)?;
        self.image(scene, device)
    }

    fn restart(&mut self, scene: &Scene, seed: u64) -> Result<()> {
        self.sums = RpnnSums::new(scene.camera.width, scene.camera.height);
        self.seed = seed;
        self.times = StageTimes::default();
        Ok(())
    }

    fn apply(&mut self, scene: &Scene, change: &Change) -> Result<()> {
        if let Change::Density(_) = change {
            let label = scene.source.display();
            self.pyramid = Pyramid::for_rendering(&scene.volume)
                .map_err(|e| anyhow::anyhow!("{label}: {e}"))?;
            self.majorants = nimbus_rpnn::render::majorants(scene);
            // The WGSL backend holds the pyramid on the GPU; ONNX Runtime reads descriptors
            // made on the CPU and keeps its session.
            if let Backend::Wgpu(_) = self.backend {
                self.backend = rpnn_backend(
                    self.choice,
                    self.adapter,
                    &self.model_path,
                    &self.model,
                    &self.pyramid,
                )?
                .0;
            }
        }
        Ok(())
    }

    fn accumulate(&mut self, scene: &Scene, n: u32) -> Result<Step> {
        let before = self.times.clone();
        self.add(scene, n)?;
        let t = &self.times;
        Ok(Step {
            stages: vec![
                ("descriptor", t.descriptor_ms - before.descriptor_ms),
                ("inference", t.inference_ms - before.inference_ms),
                ("rest", t.rest_ms - before.rest_ms),
            ],
            spp: self.sums.samples,
            ..Default::default()
        })
    }

    fn image(&mut self, scene: &Scene, _device: &str) -> Result<Rendered> {
        let (image, variance) = self.sums.image();
        let t = &self.times;
        let cam = &scene.camera;
        let budget = self.sums.samples;
        let n = budget.max(1) as f64;
        Ok(Rendered {
            summary: format!(
                "RPNN ({}, {}{}) {}x{} at {} spp in {:.2} s — {:.1} ms per spp, {} network queries",
                self.model_path.display(),
                self.backend.name(),
                match &self.sky_sh {
                    Some(s) => format!(", sky head of degree {}", s.degree),
                    None if scene.sky.is_some() => format!(", {} sky directions", self.sky_dirs),
                    None => String::new(),
                },
                cam.width,
                cam.height,
                budget,
                t.total_ms / 1e3,
                t.total_ms / n,
                t.queries
            ),
            timing_lines: vec![
                format!("  descriptor {:9.2} ms per spp", t.descriptor_ms / n),
                format!("  inference  {:9.2} ms per spp", t.inference_ms / n),
                format!("  rest       {:9.2} ms per spp", t.rest_ms / n),
            ],
            seconds: t.total_ms / 1e3,
            setup_s: 0.0,
            gpu_ms: None,
            variance: Some(variance),
            image,
        })
    }

    fn samples(&self) -> u32 {
        self.sums.samples
    }
}
