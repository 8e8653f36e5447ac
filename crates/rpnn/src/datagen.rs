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
/// [`BATCH`] samples per still-open configuration until each meets the ±2 % / 95 % rule (after
/// [`MIN_SAMPLES`]) or reaches `max_samples`. Same quantity as [`CloudData::estimate`].
pub fn estimate_gpu(
    gpt: &mut nimbus_trace::gpu::GpuPathTracer,
    configs: &[(DVec3, DVec3, DVec3)],
    max_samples: u64,
    seed: u64,
) -> Result<Vec<(f64, u64, bool, f64)>, nimbus_trace::gpu::GpuPtError> {
    let tasks: Vec<nimbus_trace::gpu::LiTask> = configs
        .iter()
        .map(|(x, v, l)| nimbus_trace::gpu::LiTask {
            x: x.as_vec3().extend(0.0).to_array(),
            view: v.as_vec3().extend(0.0).to_array(),
            to_light: l.as_vec3().extend(0.0).to_array(),
        })
        .collect();
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
        let per = if round == 0 { MIN_SAMPLES } else { BATCH * 4 };
        let r = gpt.indirect(&batch, per as u32, round, seed)?;
        for (k, &i) in open.iter().enumerate() {
            for c in 0..3 {
                sums[i][c] += r[k][c];
            }
            let [s, s2, n] = sums[i];
            let mean = s / n;
            let var = ((s2 / n - mean * mean) * n / (n - 1.0)).max(0.0);
            let rel = if mean > 0.0 {
                1.96 * (var / n).sqrt() / mean
            } else {
                f64::INFINITY
            };
            if rel <= 0.02 {
                result[i] = Some((mean, n as u64, true, rel));
            } else if n as u64 >= max_samples {
                result[i] = Some((mean, n as u64, false, rel));
            }
        }
        round += 1;
    }
    Ok(result.into_iter().map(|r| r.unwrap()).collect())
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
}

/// Errors of data generation.
#[derive(Debug, thiserror::Error)]
pub enum DatagenError {
    #[error("cloud `{cloud}`: {msg}")]
    Cloud { cloud: String, msg: String },
}

/// A cloud prepared for data generation: the path tracer's scene and the descriptor pyramid.
pub struct CloudData {
    pub name: String,
    pub scene: Scene,
    pub pyramid: Pyramid,
    majorants: nimbus_scene::MajorantGrid,
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
        })
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
    /// Returns (mean, samples, converged, relative CI half-width).
    pub fn estimate(
        &self,
        x: DVec3,
        view: DVec3,
        to_light: DVec3,
        max_samples: u64,
        rng: &mut Pcg32,
    ) -> (f64, u64, bool, f64) {
        self.estimate_to(x, view, to_light, max_samples, 0.02, rng)
    }

    /// Like [`CloudData::estimate`] with a relative half-width target `rel_target` (0 runs to
    /// `max_samples`, rounded up to whole batches).
    pub fn estimate_to(
        &self,
        x: DVec3,
        view: DVec3,
        to_light: DVec3,
        max_samples: u64,
        rel_target: f64,
        rng: &mut Pcg32,
    ) -> (f64, u64, bool, f64) {
        let mut scene = self.scene.clone();
        scene.sun = Some(Sun::new(to_light, DVec3::ONE, 0.0).expect("unit direction"));
        let tracer = PathTracer::with_majorants(&scene, self.majorants.clone());
        let (_, phase) = scene.medium.vertex(1);
        let (mut n, mut s, mut s2) = (0u64, 0.0f64, 0.0f64);
        let mut stats = PathStats::default();
        loop {
            for _ in 0..BATCH {
                let smp = phase.sample(view, rng.next2());
                let l = tracer.radiance_after(x, smp.dir, 1, Some(smp.pdf), rng, &mut stats);
                let v = (l.x + l.y + l.z) / 3.0;
                s += v;
                s2 += v * v;
                n += 1;
            }
            let mean = s / n as f64;
            let var = ((s2 / n as f64 - mean * mean) * n as f64 / (n - 1) as f64).max(0.0);
            let half = 1.96 * (var / n as f64).sqrt();
            let rel = if mean > 0.0 {
                half / mean
            } else {
                f64::INFINITY
            };
            if n >= MIN_SAMPLES && rel <= rel_target {
                return (mean, n, true, rel);
            }
            if n >= max_samples {
                return (mean, n, false, rel);
            }
        }
    }

    /// A shading configuration (x, ω, ω_l) from `rng` (§5.1).
    pub fn sample_config(&self, rng: &mut Pcg32) -> Result<(DVec3, DVec3, DVec3), DatagenError> {
        let (x, view) = self.sample_position(rng)?;
        Ok((x, view, uniform_sphere(rng.next2())))
    }

    /// One complete record from `rng`.
    pub fn record(&self, max_samples: u64, rng: &mut Pcg32) -> Result<Record, DatagenError> {
        let (x, view, to_light) = self.sample_config(rng)?;
        let (mean, samples, converged, rel) = self.estimate(x, view, to_light, max_samples, rng);
        self.finish(x, view, to_light, (mean, samples, converged, rel))
    }

    /// Builds the record (descriptor, checks) for an estimate.
    pub fn finish(
        &self,
        x: DVec3,
        view: DVec3,
        to_light: DVec3,
        (mean, samples, converged, rel): (f64, u64, bool, f64),
    ) -> Result<Record, DatagenError> {
        let mut d = vec![0.0f32; DESCRIPTOR_LEN];
        descriptor(
            &self.pyramid,
            x.as_vec3(),
            view.as_vec3(),
            to_light.as_vec3(),
            &mut d,
        );
        if !mean.is_finite() || d.iter().any(|v| !v.is_finite()) {
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
            samples,
            converged,
            rel_ci: rel.min(f32::MAX as f64) as f32,
        })
    }
}
