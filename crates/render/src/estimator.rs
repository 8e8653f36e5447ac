//! [`prepare`] an estimator once per scene, then [`Estimator::render`] it for any budget, or
//! drive it progressively: [`Estimator::accumulate`] adds samples (or photon-map generations)
//! to the image, [`Estimator::change`] takes a new camera, sun or density and starts the image
//! again, [`Estimator::image`] reads it. The command line, the evaluation and the viewer all go
//! through this one dispatch; each estimator is one `engine/` module.

use nimbus_scene::clock::Instant;

use anyhow::{Context, Result, bail};
use nimbus_scene::{Cancel, Cancelled, Scene};

use crate::Method;
pub use crate::backend::GpuSource;
#[cfg(feature = "rpnn")]
pub use crate::engine::rpnn::{RpnnSettings, rpnn_backend, rpnn_model_path};
use crate::engine::{self, Engine};
pub use crate::engine::{Change, Options, Rendered, Step};

/// A prepared estimator: the work a scene needs once is done, renders are cheap to repeat.
pub struct Estimator<'g> {
    method: Method,
    scene: Scene,
    /// Seconds [`prepare`] took.
    pub prepare_s: f64,
    /// Where it runs (`cpu (2 threads)`, the adapter, `ort (cpu: 2 sessions)`, …).
    pub device: String,
    /// Warnings for the user (an RPNN model trained for another medium).
    pub warnings: Vec<String>,
    engine: Box<dyn Engine + Send + 'g>,
    /// Seed of the progressive images and how many restarts drew from it.
    seed: u64,
    restarts: u64,
}

/// The range of coordinates and box extents (`F32_SCALE`) and of the largest extinction
/// (`F32_SIGMA`) the 32-bit estimators are given: pt-gpu, pm and RPNN's descriptors compute in
/// f32. Measured on one cloud rescaled by 10^E (box ±10^E, density scale 10^−E, so the largest
/// extinction is 5·10^−(E+1); the same image in f64): correct for −38 ≤ E ≤ 33, pt-gpu 64 % dark
/// at E = 34 and black from 35, pm 27 % dark from 34. The bounds keep margins of 10³ and more.
const F32_SCALE: [f64; 2] = [1e-30, 1e30];
const F32_SIGMA: [f64; 2] = [1e-32, 1e32];

/// Refuses a scene modelled at a scale the f32 estimators cannot represent (it would render
/// black or without its cloud, without a word); `pt` (f64) renders it.
pub fn check_f32_scale(scene: &Scene, method: Method) -> Result<()> {
    let [lo, hi] = F32_SCALE;
    let [slo, shi] = F32_SIGMA;
    let aabb = scene.volume.aabb();
    let coord = |v: glam::DVec3| v.abs().max_element();
    let sigma = scene.volume.max_sigma_t();
    let box_coord = coord(aabb.min).max(coord(aabb.max));
    let bad = if box_coord > hi {
        Some(("volume.aabb_min/aabb_max", "a coordinate", box_coord))
    } else if aabb.extent().min_element() < lo {
        Some((
            "volume.aabb_min/aabb_max",
            "the box's smallest extent",
            aabb.extent().min_element(),
        ))
    } else if coord(scene.camera.origin) > hi {
        Some(("camera.origin", "a coordinate", coord(scene.camera.origin)))
    } else if sigma > 0.0 && !(slo..=shi).contains(&sigma) {
        Some((
            "volume.density_scale",
            "the largest extinction (density scale × the grid's maximum)",
            sigma,
        ))
    } else {
        None
    };
    if let Some((field, what, v)) = bad {
        bail!(
            "{}: field `{field}`: {what} is {v:e}; {method} computes in 32-bit floats and needs \
             coordinates and extents within [{lo:e}, {hi:e}] and extinctions within \
             [{slo:e}, {shi:e}] (rescale the scene, or render it with pt, which computes in \
             64-bit floats)",
            scene.source.display()
        );
    }
    Ok(())
}

/// Prepares `method` on `scene`: the majorant grid (path tracer), the GPU pipelines and
/// buffers (GPU path tracer), the device (photon mapping), or the model, density pyramid and
/// network backend (RPNN). A GPU is opened through `gpu` only when the method needs one.
pub fn prepare<'g>(
    scene: &Scene,
    method: Method,
    opts: &Options,
    gpu: impl GpuSource<'g>,
) -> Result<Estimator<'g>> {
    let t0 = Instant::now();
    let label = scene.source.display().to_string();
    let mut warnings = Vec::new();
    if let Some(d) = scene.render.max_depth
        && !matches!(method, Method::Pt | Method::PtGpu)
    {
        warnings.push(format!(
            "warning: {label}: render.max_depth = {d} is honoured by pt and pt-gpu only; \
             {method} computes every order of scattering"
        ));
    }
    // Every estimator reads an environment map as latitude–longitude (2:1); another layout
    // (a mirror ball, a cube cross) would light the cloud wrongly without a word.
    if let Some(nimbus_scene::Sky::Env(env)) = &scene.sky {
        let (w, h) = (env.image().width, env.image().height);
        if w != 2 * h {
            warnings.push(format!(
                "warning: {label}: sky.envmap is {w}×{h}, not 2:1; it is read as a \
                 latitude–longitude map (a mirror ball or a cube cross would light the cloud \
                 wrongly)"
            ));
        }
    }
    if method != Method::Pt {
        check_f32_scale(scene, method)?;
    }
    let (engine, device) = engine::prepare(scene, method, opts, gpu, &label, &mut warnings)?;
    Ok(Estimator {
        method,
        scene: scene.clone(),
        prepare_s: t0.elapsed().as_secs_f64(),
        device,
        warnings,
        engine,
        seed: scene.render.seed,
        restarts: 0,
    })
}

/// Whether `err` comes from a cancelled call ([`Estimator::render_with`]).
pub fn is_cancelled(err: &anyhow::Error) -> bool {
    err.chain().any(|e| e.downcast_ref::<Cancelled>().is_some())
}

impl<'g> Estimator<'g> {
    pub fn method(&self) -> Method {
        self.method
    }

    /// The scene as the estimator sees it now (after its [`Change`]s).
    pub fn scene(&self) -> &Scene {
        &self.scene
    }

    /// Renders with `budget` samples per pixel (Monte Carlo methods and the final gathering)
    /// or a ring of `budget` frames (the ray-marched photon maps), from `seed`, from scratch.
    pub fn render(&mut self, budget: u32, seed: u64) -> Result<Rendered> {
        self.render_with(budget, seed, &Cancel::never())
    }

    /// [`Self::render`], stopped when `cancel` is set: the path tracer checks it before each
    /// pixel, the GPU path tracer after each dispatch, the photon map after each generation
    /// and gather dispatch, RPNN after each sample. A cancelled call returns an error for
    /// which [`is_cancelled`] holds, and the estimator stays usable (the next render starts
    /// from scratch). The image is the same with any token.
    pub fn render_with(&mut self, budget: u32, seed: u64, cancel: &Cancel) -> Result<Rendered> {
        let label = self.scene.source.display().to_string();
        self.engine
            .render(
                &self.scene,
                &self.device,
                self.prepare_s,
                budget,
                seed,
                cancel,
            )
            .with_context(|| format!("{label}: {}", self.method))
    }

    /// Starts the progressive image again from `seed`.
    pub fn restart(&mut self, seed: u64) -> Result<()> {
        self.seed = seed;
        self.restarts = 0;
        self.engine.restart(&self.scene, seed)
    }

    /// Takes `change` into the scene and starts the image again. Samples after a restart are
    /// independent of those before it (each restart draws from its own seed).
    pub fn change(&mut self, change: Change) -> Result<()> {
        match &change {
            Change::Camera(c) => self.scene.camera = c.clone(),
            Change::SunDir(d) => self.scene.set_sun_dir(*d),
            Change::Density(v) => self.scene.volume = v.clone(),
        }
        self.engine.apply(&self.scene, &change)?;
        self.restarts += 1;
        let seed = self
            .seed
            .wrapping_add(self.restarts.wrapping_mul(0x9E37_79B9_7F4A_7C15));
        self.engine.restart(&self.scene, seed)
    }

    /// Adds `n` samples per pixel to the progressive image (ray-marched photon maps: traces up
    /// to `n` generations where the ring needs them, then ray marches or re-projects).
    pub fn accumulate(&mut self, n: u32) -> Result<Step> {
        self.accumulate_with(n, &Cancel::never())
    }

    /// [`Self::accumulate`], stopped when `cancel` is set (as [`Self::render_with`]); the
    /// samples added before the cancel stay in the image, which remains consistent with
    /// [`Self::samples`].
    pub fn accumulate_with(&mut self, n: u32, cancel: &Cancel) -> Result<Step> {
        self.engine.accumulate(&self.scene, n, cancel)
    }

    /// The progressive image so far.
    pub fn image(&mut self) -> Result<Rendered> {
        self.engine.image(&self.scene, &self.device)
    }

    /// Samples per pixel in the progressive image.
    pub fn samples(&self) -> u32 {
        self.engine.samples()
    }
}
