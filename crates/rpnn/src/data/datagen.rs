//! Training records for RPNN (Kallweit 2017 §5.1): shading configurations sampled like camera
//! rays hitting the cloud, their hierarchical descriptors, and the indirect in-scattered
//! radiance L_i estimated by path tracing until the 95 % confidence interval is within ±2 %.
//!
//! ## Sampling a configuration
//! ω uniform on the sphere; the ray origin uniform over the bounding sphere's cross-section
//! perpendicular to ω (a disc of the sphere's radius, placed outside it); free flight by delta
//! tracking into the cloud with the full density; a miss starts over (up to [`MAX_TRIES`]
//! tries, then an error naming the cloud). ω_l, the direction towards the light, is uniform on
//! the sphere.
//!
//! ## The target
//! L_i(x, ω) = ∫ p(ω · ω̂) (L(x, ω̂) − L_d(x, ω̂)) dω̂ for a directional light of unit irradiance
//! from ω_l, no sky: each sample draws ω̂ from the phase function at x and follows the path with
//! the reference path tracer ([`nimbus_trace::PathTracer::radiance_after`], x counted as the
//! first scattering vertex), whose next-event estimates at later vertices are exactly the
//! collided light; the uncollided light at x (L_d) is never added. The albedo at x is not applied
//! (the renderer multiplies by σ_s). Samples are drawn in batches of [`BATCH`] until
//! 1.96 · s/√n ≤ 0.02 · mean (at least [`MIN_SAMPLES`]), or until the cap; the record keeps the
//! sample count and whether it converged.

use std::sync::Arc;

use glam::{DVec3, Vec3};
use nimbus_scene::frame::uniform_sphere;
use nimbus_scene::{Medium, RenderSettings, Scene, Sun, Volume, VolumeSource};
use nimbus_trace::{PathTracer, Pcg32, integrator::PathStats, tracking::Tracker};

use crate::descriptor::{DESCRIPTOR_LEN, descriptor};
use crate::pyramid::Pyramid;

/// Tries to find a configuration inside the cloud before giving up.
pub const MAX_TRIES: u32 = 100_000;
/// Samples per batch of the progressive estimate.
pub const BATCH: u64 = 256;
/// Least number of samples before the stopping rule is checked.
pub const MIN_SAMPLES: u64 = 1024;

/// Estimates L_i for many configurations of one cloud on the GPU, progressively: rounds of
/// [`BATCH`] samples per still-open configuration until each meets the ±`rel_target` / 95 %
/// rule (after [`MIN_SAMPLES`]) or reaches `max_samples` (`rel_target` = 0: exactly
/// `max_samples`). Same quantity as [`CloudData::estimate`].
pub fn estimate_gpu(
    gpt: &mut nimbus_trace::gpu::GpuPathTracer,
    configs: &[(DVec3, DVec3, DVec3)],
    max_samples: u64,
    rel_target: f64,
    seed: u64,
) -> Result<Vec<Estimate>, nimbus_trace::gpu::GpuPtError> {
    let tasks: Vec<nimbus_trace::gpu::LiTask> = configs
        .iter()
        .map(|(x, v, l)| nimbus_trace::gpu::LiTask {
            x: x.as_vec3().extend(0.0).to_array(),
            view: v.as_vec3().extend(0.0).to_array(),
            to_light: l.as_vec3().extend(0.0).to_array(),
        })
        .collect();
    let max_samples = max_samples.max(1);
    let mut sums = vec![[0.0f64; 3]; configs.len()];
    let mut result = vec![None; configs.len()];
    let mut round = 0u32;
    loop {
        let open: Vec<usize> = (0..configs.len())
            .filter(|&i| result[i].is_none())
            .collect();
        if open.is_empty() {
            break;
        }
        let batch: Vec<_> = open.iter().map(|&i| tasks[i]).collect();
        // Every open configuration has the same count so far (they start together).
        let done = sums[open[0]][2] as u64;
        let per = if rel_target <= 0.0 {
            (max_samples - done).min(1 << 16)
        } else if round == 0 {
            MIN_SAMPLES
        } else {
            BATCH * 4
        };
        let r = gpt.indirect(&batch, per as u32, round, seed)?;
        for (k, &i) in open.iter().enumerate() {
            for c in 0..3 {
                sums[i][c] += r[k][c];
            }
            let [s, s2, n] = sums[i];
            let e = Estimate::from_sums(s, s2, n as u64, rel_target);
            if e.converged || e.samples >= max_samples {
                result[i] = Some(e);
            }
        }
        round += 1;
    }
    Ok(result.into_iter().map(|r| r.unwrap()).collect())
}

/// A Monte Carlo estimate of L_i.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Estimate {
    pub mean: f64,
    pub samples: u64,
    /// Met the ±2 % / 95 % rule; for a two-stage estimate ([`precise_count`]) the target
    /// relative noise; always false for fixed-count estimates.
    pub converged: bool,
    /// Half-width of the 95 % interval relative to the mean (∞ for a zero mean).
    pub rel_ci: f64,
    /// Estimated variance of `mean` (sample variance / samples): the label noise of a record.
    pub var_mean: f64,
    /// With [`CloudData::sky_transfer`]: the sky's transfer t_lm in the descriptor's frame
    /// (`crate::sky`), from the same paths: Σ β Y_lm(ω_esc) / n over the paths that leave the
    /// cloud after at least one scattering beyond x (β their throughput, ω_esc the direction
    /// they leave along); the paths that leave straight from x are the sky's single scattering,
    /// which the renderer estimates itself.
    pub sky: Option<[f32; crate::sky::SH_COEFFS]>,
}

/// Sample count of the second stage of a precise label: enough fresh samples for a relative
/// standard error of `rel_noise`, judged by the per-sample relative variance of the `pilot`
/// estimate, rounded up to a multiple of the pilot's count and capped at `max_samples`.
///
/// The label is the mean of the fresh samples alone: their count depends on the pilot only,
/// so the label stays unbiased (a sequential rule that stops on the samples it averages is
/// biased low for heavy-tailed samples, see [`CloudData::estimate_to`]). A pilot with a zero
/// mean gives no relative scale: one pilot's count.
pub fn precise_count(pilot: &Estimate, rel_noise: f64, max_samples: u64) -> u64 {
    let per = pilot.samples.max(1);
    let mut n = per;
    if pilot.mean > 0.0 && rel_noise > 0.0 {
        let rel_var = pilot.var_mean * per as f64 / (pilot.mean * pilot.mean);
        let need = (rel_var / (rel_noise * rel_noise)).ceil();
        if need.is_finite() {
            n = ((need / per as f64).ceil().max(1.0) * per as f64).min(u64::MAX as f64 / 2.0)
                as u64;
        }
    }
    n.min(max_samples.max(1))
}

impl Estimate {
    /// Relative standard error of the mean (∞ for a zero mean).
    pub fn rel_noise(&self) -> f64 {
        if self.mean > 0.0 {
            self.var_mean.sqrt() / self.mean
        } else {
            f64::INFINITY
        }
    }

    fn from_sums(s: f64, s2: f64, n: u64, converged_if_within: f64) -> Self {
        let nf = n as f64;
        let mean = s / nf;
        let var = if n > 1 {
            ((s2 / nf - mean * mean) * nf / (nf - 1.0)).max(0.0)
        } else {
            0.0
        };
        let half = 1.96 * (var / nf).sqrt();
        let rel_ci = if mean > 0.0 {
            half / mean
        } else {
            f64::INFINITY
        };
        Self {
            mean,
            samples: n,
            converged: n >= MIN_SAMPLES && rel_ci <= converged_if_within,
            rel_ci,
            var_mean: var / nf,
            sky: None,
        }
    }
}

/// How the direction towards the light is drawn for a record.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum LightSampling {
    /// ω_l uniform on the sphere (Kallweit §5.1): γ has density sin γ / 2, so few records are
    /// nearly front-lit (γ → π) or back-lit (γ → 0).
    Sphere,
    /// γ = angle(ω, ω_l) uniform in [0, π], azimuth uniform about ω: every lighting angle gets
    /// the same share of records. The target is a function of (descriptor, γ), and γ is an input
    /// of the network, so the conditional mean the loss converges to is the same for any density
    /// of γ; the density only moves the network's accuracy between angles. Each record stores
    /// the weight π sin γ / 2 that would restore the sphere's distribution.
    UniformGamma,
}

impl LightSampling {
    /// A direction towards the light for view direction `view` from two uniform numbers.
    pub fn sample(self, view: DVec3, u: [f64; 2]) -> DVec3 {
        match self {
            Self::Sphere => uniform_sphere(u),
            Self::UniformGamma => {
                let gamma = std::f64::consts::PI * u[0];
                let phi = std::f64::consts::TAU * u[1];
                let (t, b) = nimbus_scene::frame::orthonormal_basis(view);
                (view * gamma.cos() + (t * phi.cos() + b * phi.sin()) * gamma.sin()).normalize()
            }
        }
    }

    /// The record's weight relative to sampling on the sphere (see [`LightSampling::UniformGamma`]).
    pub fn weight(self, view: DVec3, to_light: DVec3) -> f32 {
        match self {
            Self::Sphere => 1.0,
            Self::UniformGamma => {
                let s = view.cross(to_light).length().min(1.0);
                (std::f64::consts::FRAC_PI_2 * s) as f32
            }
        }
    }
}

/// One training record.
#[derive(Debug, Clone)]
pub struct Record {
    pub x: Vec3,
    pub view: Vec3,
    pub to_light: Vec3,
    pub descriptor: Vec<f32>,
    pub target: f32,
    pub samples: u64,
    pub converged: bool,
    /// Half-width of the 95 % interval relative to the mean.
    pub rel_ci: f32,
    /// Estimated variance of `target` (label noise).
    pub var_mean: f32,
    /// Importance weight of the light direction relative to uniform sampling on the sphere
    /// (1 for uniform ω_l; π sin γ / 2 when γ is drawn uniformly in [0, π]).
    pub light_weight: f32,
    /// The sky's transfer ([`Estimate::sky`]), when estimated.
    pub sky: Option<[f32; crate::sky::SH_COEFFS]>,
}

/// Errors of data generation.
#[derive(Debug, thiserror::Error)]
pub enum DatagenError {
    #[error("cloud `{cloud}`: {msg}")]
    Cloud { cloud: String, msg: String },
    /// A data-set folder or file (`what` names it).
    #[error("{what}: {msg}")]
    Set { what: String, msg: String },
    /// Stopped by its cancellation token ([`crate::data::dataset::run_cancellable`]).
    #[error("cancelled")]
    Cancelled(#[from] nimbus_scene::Cancelled),
}

/// A file error ([`nimbus_scene::fsio`]) as the error of the data-set file it names.
impl From<nimbus_scene::Error> for DatagenError {
    fn from(e: nimbus_scene::Error) -> Self {
        let (path, msg) = match e {
            nimbus_scene::Error::Io { path, err } => (path, err.to_string()),
            nimbus_scene::Error::Invalid { path, field, msg } => {
                (path, format!("field `{field}`: {msg}"))
            }
            nimbus_scene::Error::Parse { path, msg } => (path, msg),
        };
        DatagenError::Set {
            what: path.display().to_string(),
            msg,
        }
    }
}

/// A cloud prepared for data generation: the path tracer's scene and the descriptor pyramid.
pub struct CloudData {
    pub name: String,
    pub scene: Scene,
    pub pyramid: Pyramid,
    majorants: nimbus_scene::MajorantGrid,
    /// Estimate the sky's transfer with every label (`crate::sky`).
    pub sky_transfer: bool,
}

impl CloudData {
    /// Prepares a cloud. Zero-density clouds are refused (one mean free path is undefined).
    pub fn new(name: &str, volume: Volume, medium: Medium) -> Result<Self, DatagenError> {
        let err = |msg: String| DatagenError::Cloud {
            cloud: name.to_string(),
            msg,
        };
        let pyramid = Pyramid::new(&volume).map_err(|e| err(e.to_string()))?;
        let camera = nimbus_scene::Camera::new(DVec3::Z * 5.0, DVec3::ZERO, DVec3::Y, 30.0, 1, 1)
            .map_err(|e| err(e.to_string()))?;
        let scene = Scene {
            source: name.into(),
            volume: Arc::new(volume),
            volume_source: VolumeSource::Memory,
            medium,
            phase_desc: String::new(),
            sun: Some(Sun::new(DVec3::Y, DVec3::ONE, 0.0).map_err(|e| err(e.to_string()))?),
            sky: None,
            camera,
            render: RenderSettings::default(),
            atmosphere: None,
        };
        let majorants = nimbus_scene::MajorantGrid::with_block(&scene.volume, 8);
        Ok(Self {
            name: name.into(),
            scene,
            pyramid,
            majorants,
            sky_transfer: false,
        })
    }

    /// With `on`, every estimate also estimates the sky's transfer ([`Estimate::sky`]).
    pub fn with_sky_transfer(mut self, on: bool) -> Self {
        self.sky_transfer = on;
        self
    }

    /// Samples a shading position and view direction as a camera ray entering the cloud would.
    pub fn sample_position(&self, rng: &mut Pcg32) -> Result<(DVec3, DVec3), DatagenError> {
        let aabb = *self.scene.volume.aabb();
        let centre = aabb.center();
        let radius = 0.5 * aabb.extent().length();
        let tracker = Tracker::new(&self.scene.volume, &self.majorants);
        for _ in 0..MAX_TRIES {
            let w = uniform_sphere(rng.next2());
            let (t, b) = nimbus_scene::frame::orthonormal_basis(w);
            let r = radius * rng.next_f64().sqrt();
            let phi = std::f64::consts::TAU * rng.next_f64();
            let o = centre + (t * phi.cos() + b * phi.sin()) * r - w * (2.0 * radius);
            if let Some((t0, t1)) = aabb.intersect(o, w)
                && let Some(t) = tracker.sample_collision(o, w, t0, t1, 1.0, rng)
            {
                return Ok((o + w * t, w));
            }
        }
        Err(DatagenError::Cloud {
            cloud: self.name.clone(),
            msg: format!("no ray entered the cloud in {MAX_TRIES} tries (is it empty?)"),
        })
    }

    /// Estimates L_i(x, ω) for unit irradiance from `to_light` with the ±2 % / 95 % rule.
    pub fn estimate(
        &self,
        x: DVec3,
        view: DVec3,
        to_light: DVec3,
        max_samples: u64,
        rng: &mut Pcg32,
    ) -> Estimate {
        self.estimate_to(x, view, to_light, max_samples, 0.02, rng)
    }

    /// Like [`CloudData::estimate`] with a relative half-width target `rel_target`; 0 takes
    /// exactly `max_samples` samples (a fixed-count, unbiased estimate: no stopping rule, whose
    /// decision would correlate with the heavy-tailed samples and bias the mean low).
    pub fn estimate_to(
        &self,
        x: DVec3,
        view: DVec3,
        to_light: DVec3,
        max_samples: u64,
        rel_target: f64,
        rng: &mut Pcg32,
    ) -> Estimate {
        let mut scene = self.scene.clone();
        scene.sun = Some(Sun::new(to_light, DVec3::ONE, 0.0).expect("unit direction"));
        let tracer = PathTracer::with_majorants(&scene, self.majorants.clone());
        let (_, phase) = scene.medium.vertex(1);
        let (mut n, mut s, mut s2) = (0u64, 0.0f64, 0.0f64);
        let mut stats = PathStats::default();
        let max_samples = max_samples.max(1);
        // The sky's transfer in the descriptor's frame (the same frame the network sees).
        let frame = crate::descriptor::frame(view.as_vec3(), to_light.as_vec3());
        let (ex, ey, ez) = (frame.0.as_dvec3(), frame.1.as_dvec3(), frame.2.as_dvec3());
        let mut t = [0.0f64; crate::sky::SH_COEFFS];
        loop {
            for _ in 0..BATCH.min(max_samples - n) {
                let smp = phase.sample(view, rng.next2());
                let mut esc = None;
                let l = tracer.radiance_after_escape(
                    x,
                    smp.dir,
                    1,
                    Some(smp.pdf),
                    rng,
                    &mut stats,
                    &mut esc,
                );
                if self.sky_transfer
                    && let Some(e) = esc
                    && e.scatterings >= 2
                {
                    let local = DVec3::new(ex.dot(e.dir), ey.dot(e.dir), ez.dot(e.dir));
                    for (tj, yj) in t.iter_mut().zip(crate::sky::eval(local)) {
                        *tj += e.beta * yj;
                    }
                }
                let v = (l.x + l.y + l.z) / 3.0;
                s += v;
                s2 += v * v;
                n += 1;
            }
            let mut e = Estimate::from_sums(s, s2, n, rel_target);
            if e.converged || n >= max_samples {
                if self.sky_transfer {
                    e.sky = Some(t.map(|v| (v / n as f64) as f32));
                }
                return e;
            }
        }
    }

    /// A precise, unbiased label in two stages: a pilot of `pilot` samples sets the count
    /// ([`precise_count`]) of a fresh estimate, which is the label; `converged` says whether
    /// its relative standard error met `rel_noise`.
    #[allow(clippy::too_many_arguments)]
    pub fn estimate_precise(
        &self,
        x: DVec3,
        view: DVec3,
        to_light: DVec3,
        pilot: u64,
        rel_noise: f64,
        max_samples: u64,
        rng: &mut Pcg32,
    ) -> Estimate {
        let p = self.estimate_to(x, view, to_light, pilot, 0.0, rng);
        let n = precise_count(&p, rel_noise, max_samples);
        let mut e = self.estimate_to(x, view, to_light, n, 0.0, rng);
        e.converged = e.rel_noise() <= rel_noise;
        e
    }

    /// A shading configuration (x, ω, ω_l) from `rng` (§5.1), ω_l uniform on the sphere.
    pub fn sample_config(&self, rng: &mut Pcg32) -> Result<(DVec3, DVec3, DVec3), DatagenError> {
        self.sample_config_with(LightSampling::Sphere, rng)
    }

    /// A shading configuration with the light direction drawn by `light`.
    pub fn sample_config_with(
        &self,
        light: LightSampling,
        rng: &mut Pcg32,
    ) -> Result<(DVec3, DVec3, DVec3), DatagenError> {
        let (x, view) = self.sample_position(rng)?;
        Ok((x, view, light.sample(view, rng.next2())))
    }

    /// One complete record from `rng`: ω_l by `light`, L_i to ±2 % (capped at `max_samples`)
    /// when `fixed` is false, else with exactly `max_samples` samples.
    pub fn record(
        &self,
        light: LightSampling,
        max_samples: u64,
        fixed: bool,
        rng: &mut Pcg32,
    ) -> Result<Record, DatagenError> {
        let (x, view, to_light) = self.sample_config_with(light, rng)?;
        let target = if fixed { 0.0 } else { 0.02 };
        let e = self.estimate_to(x, view, to_light, max_samples, target, rng);
        self.finish(x, view, to_light, e, light)
    }

    /// One record with a two-stage precise label ([`CloudData::estimate_precise`]).
    pub fn record_precise(
        &self,
        light: LightSampling,
        pilot: u64,
        rel_noise: f64,
        max_samples: u64,
        rng: &mut Pcg32,
    ) -> Result<Record, DatagenError> {
        let (x, view, to_light) = self.sample_config_with(light, rng)?;
        let e = self.estimate_precise(x, view, to_light, pilot, rel_noise, max_samples, rng);
        self.finish(x, view, to_light, e, light)
    }

    /// Builds the record (descriptor, checks) for an estimate.
    pub fn finish(
        &self,
        x: DVec3,
        view: DVec3,
        to_light: DVec3,
        e: Estimate,
        light: LightSampling,
    ) -> Result<Record, DatagenError> {
        let mean = e.mean;
        let mut d = vec![0.0f32; DESCRIPTOR_LEN];
        descriptor(
            &self.pyramid,
            x.as_vec3(),
            view.as_vec3(),
            to_light.as_vec3(),
            &mut d,
        );
        if !mean.is_finite()
            || d.iter().any(|v| !v.is_finite())
            || e.sky.is_some_and(|t| t.iter().any(|v| !v.is_finite()))
        {
            return Err(DatagenError::Cloud {
                cloud: self.name.clone(),
                msg: "a non-finite value was produced; the record is not written".into(),
            });
        }
        Ok(Record {
            x: x.as_vec3(),
            view: view.as_vec3(),
            to_light: to_light.as_vec3(),
            descriptor: d,
            target: mean as f32,
            samples: e.samples,
            converged: e.converged,
            rel_ci: e.rel_ci.min(f32::MAX as f64) as f32,
            var_mean: e.var_mean.min(f32::MAX as f64) as f32,
            light_weight: light.weight(view, to_light),
            sky: e.sky,
        })
    }
}
