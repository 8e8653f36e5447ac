//! Rendering with the network (Kallweit 2017 §4.4).
//!
//! Per sample and pixel: delta tracking along the camera ray to the first real collision x
//! (density of the first segment as in the path tracer); there the in-scattered radiance is
//! albedo × (direct + indirect):
//! - **direct** (single scattering) by Monte Carlo: next-event estimation to the sun (a delta
//!   light, or a disc sampled in its cone) with a ratio-tracked shadow ray; the sky's single
//!   scattering by one phase-sampled direction (p / pdf = 1) with its transmittance;
//! - **indirect** predicted by the network: for the sun, E_sun · g(z(x, ω, ω_sun)); for the sky,
//!   the predictions are integrated over the sphere with `sky_dirs` directions per sample —
//!   uniform on the sphere for a constant sky (weight 4π L_sky / N), importance-sampled from
//!   the map for an environment map (weight L(ω_j) / (N pdf(ω_j))). The network predicts
//!   indirect radiance per unit irradiance from one direction (the training data's definition,
//!   `crate::data::datagen`), so integrating L_sky(ω) g dω gives the sky's indirect part.
//!   No sky → no sky directions are queried.
//!
//! Beyond the paper, `traced_bounces` = k traces the path k bounces further before the network
//! is asked (at the last vertex only; single scattering by Monte Carlo at every vertex): on thin
//! clouds, where the network errs most and bounces often leave, it lowers the error for less
//! time; on thick ones it adds noise and keeps the network's bias of high orders
//! (`docs/rpnn.md`, "Traced bounces").
//!
//! Rays that leave the volume see the sky and the sun disc. All queries of one sample pass are
//! batched: descriptors and network on the GPU ([`Backend::Wgpu`], only predictions come
//! back) or descriptors on the CPU and ONNX Runtime ([`Backend::Ort`]: one single-threaded
//! session per core makes and runs its share of the batch in pieces,
//! [`OrtModel::predict_rows`]).

use std::time::Instant;

use glam::DVec3;
use nimbus_scene::frame::uniform_sphere;
use nimbus_scene::volume::MajorantGrid;
use nimbus_scene::{Image, Scene, Sky};
use nimbus_trace::Pcg32;
use nimbus_trace::tracking::Tracker;
use rayon::prelude::*;

use crate::descriptor::{Config, DESCRIPTOR_LEN, descriptor};
use crate::gpu_mlp::GpuRpnn;
use crate::ort_backend::OrtModel;
use crate::pyramid::Pyramid;

/// Where the network runs.
pub enum Backend<'g> {
    /// Descriptors on the CPU, network in ONNX Runtime.
    Ort(OrtModel),
    /// Descriptors and network in WGSL compute shaders.
    Wgpu(Box<GpuRpnn<'g>>),
}

impl Backend<'_> {
    pub fn name(&self) -> &'static str {
        match self {
            Backend::Ort(m) if m.int8 => "ort int8",
            Backend::Ort(_) => "ort",
            Backend::Wgpu(_) => "wgpu",
        }
    }
}

/// Render settings.
#[derive(Debug, Clone)]
pub struct RpnnOptions {
    pub spp: u32,
    pub seed: u64,
    /// Sky directions per shading point and sample (ignored without a sky, and with
    /// `sky_sh`).
    pub sky_dirs: u32,
    /// The sky through the model's sky head (`crate::sky`): one query per shading point gives
    /// the sun's indirect light and the sky's transfer, contracted with these coefficients;
    /// `None`: the paper's directional sampling (`sky_dirs` queries).
    pub sky_sh: Option<SkySh>,
    /// Values per query of the model: the sun head's outputs (1 grey, 3 RGB), then
    /// `sky_sh`'s coefficients when it is set.
    pub sun_outputs: usize,
    /// Bounces traced before the network is asked (0: the paper, §4.4: the network predicts
    /// all multiple scattering at the camera ray's first collision). With k > 0 the path goes
    /// k phase-sampled bounces further, with the sun's and sky's single scattering at every
    /// vertex, and the network is asked at the last one only: its error then enters only light
    /// scattered more than k + 1 times, for the noise of the traced bounces. A bounce that
    /// leaves the cloud asks nothing.
    pub traced_bounces: u32,
    /// One sample in every m of a pixel asks the network (beyond the paper; 1: every sample,
    /// the paper). Every sample still tracks its camera ray and estimates the direct light; the
    /// network's answers are weighted m in the samples that ask, which a pixel picks with a
    /// random offset ([`asks_network`]): unbiased at any number of samples, and in any n
    /// consecutive samples a pixel asks ⌊n/m⌋ or ⌈n/m⌉ times. Where the image's error is the
    /// network's bias (the bench suite's 32 spp) the network's time, most of a sample on a
    /// CPU, falls m-fold for a little more noise (`docs/rpnn.md`, "Fewer queries"). Not for
    /// previews of a few samples: until a pixel has asked once, it shows direct light only.
    pub query_every: u32,
}

impl RpnnOptions {
    /// `spp` samples from `seed` with the paper's directional sky sampling and a grey sun head.
    pub fn new(spp: u32, seed: u64, sky_dirs: u32) -> Self {
        Self {
            spp,
            seed,
            sky_dirs,
            sky_sh: None,
            sun_outputs: 1,
            traced_bounces: 0,
            query_every: 1,
        }
    }
}

/// The longest [`RpnnOptions::query_every`]: beyond, a pixel would wait too many samples
/// for its first answer.
pub const MAX_QUERY_EVERY: u32 = 64;

/// The refusal of a [`RpnnOptions::query_every`] outside 1..=[`MAX_QUERY_EVERY`] (the
/// renderers' and the estimator's check).
pub fn check_query_every(every: u32) -> Result<(), RenderError> {
    if (1..=MAX_QUERY_EVERY).contains(&every) {
        Ok(())
    } else {
        Err(RenderError::Setting(format!(
            "the network's query period (--query-every) must lie in 1..={MAX_QUERY_EVERY}, got {every}"
        )))
    }
}

/// Whether sample `sample` of `pixel` asks the network when one in `every` = m does: when
/// (sample + o) mod m = 0, with the offset o in 0..m per pixel from its own stream of `seed`,
/// o = ⌊u m / 2³²⌋ for a random u32 u: each offset's probability within 2⁻³² of 1/m. Over o each sample asks
/// with probability 1/m (to that precision), so weighting the answers m is unbiased at any
/// number of samples; a pixel asks in every m-th sample, so n consecutive samples hold ⌊n/m⌋
/// or ⌈n/m⌉ of its answers (a Cranley–Patterson rotation of the lattice of multiples of m).
/// m = 1: every sample, drawing nothing. The GPU sample (`shaders/lib/rpnn_sample_core.wgsl`)
/// applies the same rule with offsets from its own random numbers (24 bits: each offset's
/// probability within 2⁻²⁴ of 1/m).
pub fn asks_network(seed: u64, pixel: u64, sample: u64, every: u32) -> bool {
    if every <= 1 {
        return true;
    }
    // The offset's stream: sample index u64::MAX is never rendered.
    let u = Pcg32::for_sample(seed, pixel, u64::MAX).next_u32();
    let offset = (u as u64 * every as u64) >> 32;
    (sample + offset).is_multiple_of(every as u64)
}

/// The sky for the sky head: its coefficients in the world (`crate::sky::project`) and the
/// degree the product keeps.
#[derive(Debug, Clone)]
pub struct SkySh {
    pub world: [[f64; 3]; crate::sky::SH_COEFFS],
    pub degree: usize,
}

impl SkySh {
    /// The scene's sky projected (none without a sky): a constant sky with `n` Gauss–Legendre
    /// nodes (exact), an environment map texel by texel ([`crate::sky::project_env`]).
    pub fn of(scene: &Scene, degree: usize, n: usize) -> Option<Self> {
        let world = match scene.sky.as_ref()? {
            Sky::Env(env) => crate::sky::project_env(env),
            Sky::Constant(_) => crate::sky::project(|d| sky_radiance(scene, d), n),
        };
        Some(Self {
            world,
            degree: degree.min(crate::sky::SH_DEGREE),
        })
    }
}

/// Milliseconds per stage, summed over the samples.
#[derive(Debug, Clone, Default)]
pub struct StageTimes {
    pub descriptor_ms: f64,
    pub inference_ms: f64,
    /// Everything else: camera rays, delta tracking, direct lighting, accumulation.
    pub rest_ms: f64,
    pub total_ms: f64,
    /// Network queries (shading points × light directions).
    pub queries: u64,
}

/// A rendered image, per-pixel variance of the mean luminance, and timings.
pub struct RpnnOutput {
    pub image: Image,
    pub variance: Vec<f32>,
    pub times: StageTimes,
}

/// Errors of the renderer.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    #[error(transparent)]
    Ort(#[from] crate::ort_backend::OrtError),
    #[error(transparent)]
    Gpu(#[from] nimbus_gpu::GpuError),
    #[error("{0}")]
    Setting(String),
}

/// What one camera sample found before the network is asked.
struct Shade {
    pixel: usize,
    /// Radiance known without the network (background, or each vertex's direct light times
    /// the path's throughput: the albedos and phase weights so far).
    known: DVec3,
    /// Queries: (configuration, RGB weight of the sun head's prediction including the path's
    /// throughput, weight of the sky head's contraction (the throughput; 0 without)).
    queries: Vec<(Config, DVec3, f64)>,
}

/// Per-pixel running sums of a progressive RPNN render: Σ RGB and Σ lum² over `samples`
/// samples per pixel.
#[derive(Debug, Clone)]
pub struct RpnnSums {
    pub width: usize,
    pub height: usize,
    pub sum: Vec<DVec3>,
    pub sum_l2: Vec<f64>,
    pub samples: u32,
}

impl RpnnSums {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            sum: vec![DVec3::ZERO; width * height],
            sum_l2: vec![0.0; width * height],
            samples: 0,
        }
    }

    /// The mean image and the variance of each pixel's mean luminance (0 below two samples).
    pub fn image(&self) -> (Image, Vec<f32>) {
        let n = self.samples.max(1) as f64;
        let mut image = Image::new(self.width, self.height);
        let mut variance = vec![0.0f32; self.width * self.height];
        for (p, (px, var)) in image.pixels.iter_mut().zip(&mut variance).enumerate() {
            let m = self.sum[p] / n;
            *px = [m.x as f32, m.y as f32, m.z as f32];
            if self.samples > 1 {
                let ml = (m.x + m.y + m.z) / 3.0;
                *var = ((self.sum_l2[p] / n - ml * ml).max(0.0) / (n - 1.0)) as f32;
            }
        }
        (image, variance)
    }
}

/// Renders `scene` with the network. `pyr` is the scene volume's density pyramid.
pub fn render(
    scene: &Scene,
    pyr: &Pyramid,
    backend: &mut Backend,
    opts: &RpnnOptions,
) -> Result<RpnnOutput, RenderError> {
    let mut sums = RpnnSums::new(scene.camera.width, scene.camera.height);
    let majorants = majorants(scene);
    let times = accumulate(scene, pyr, &majorants, backend, opts, &mut sums)?;
    let (image, variance) = sums.image();
    Ok(RpnnOutput {
        image,
        variance,
        times,
    })
}

/// The majorant grid camera rays are tracked through (the path tracer's).
pub fn majorants(scene: &Scene) -> MajorantGrid {
    MajorantGrid::with_block(&scene.volume, nimbus_trace::integrator::MAJORANT_BLOCK)
}

/// The most bounces [`RpnnOptions::traced_bounces`] may ask for (the CLI's `--traced-bounces`
/// range): beyond, a path in a dense cloud of albedo 1 would hardly end.
pub const MAX_TRACED_BOUNCES: u32 = 16;

/// Adds `opts.spp` samples per pixel to `sums` (progressive rendering): sample s is sample
/// `sums.samples + s` of each pixel's stream, so steps give the image one call gives.
/// `majorants` is [`majorants`] of the scene's volume.
pub fn accumulate(
    scene: &Scene,
    pyr: &Pyramid,
    majorants: &MajorantGrid,
    backend: &mut Backend,
    opts: &RpnnOptions,
    sums: &mut RpnnSums,
) -> Result<StageTimes, RenderError> {
    if opts.spp == 0 {
        return Err(RenderError::Setting("spp must be at least 1".into()));
    }
    check_query_every(opts.query_every)?;
    if opts.traced_bounces > MAX_TRACED_BOUNCES {
        return Err(RenderError::Setting(format!(
            "traced bounces must lie in 0..={MAX_TRACED_BOUNCES}, got {}",
            opts.traced_bounces
        )));
    }
    let t_all = Instant::now();
    let (w, h) = (scene.camera.width, scene.camera.height);
    if (sums.width, sums.height) != (w, h) {
        return Err(RenderError::Setting(format!(
            "running sums of {}x{} for a {w}x{h} camera",
            sums.width, sums.height
        )));
    }
    let first = sums.samples as u64;
    let tracker = Tracker::new(&scene.volume, majorants);
    let sum = &mut sums.sum;
    let sum_l2 = &mut sums.sum_l2;
    let mut times = StageTimes::default();
    for s in 0..opts.spp {
        let shades: Vec<Shade> = (0..w * h)
            .into_par_iter()
            .map(|p| {
                let i = first + s as u64;
                let mut rng = Pcg32::for_sample(opts.seed, p as u64, i);
                // A sample that does not ask still builds its queries: its random numbers,
                // and with them its direct light, are those of m = 1.
                let mut sh = shade(scene, &tracker, p, opts, &mut rng);
                if opts.query_every > 1 {
                    if asks_network(opts.seed, p as u64, i, opts.query_every) {
                        let weight = opts.query_every as f64;
                        for q in &mut sh.queries {
                            q.1 *= weight;
                            q.2 *= weight;
                        }
                    } else {
                        sh.queries.clear();
                    }
                }
                sh
            })
            .collect();
        let configs: Vec<Config> = shades
            .iter()
            .flat_map(|sh| sh.queries.iter().map(|q| q.0))
            .collect();
        times.queries += configs.len() as u64;
        let y = match backend {
            Backend::Ort(m) => {
                let (y, t) = m.predict_rows(configs.len(), DESCRIPTOR_LEN, |i, row| {
                    let c = &configs[i];
                    descriptor(pyr, c.x, c.view, c.to_light, row)
                })?;
                times.descriptor_ms += t.rows_ms;
                times.inference_ms += t.network_ms;
                y
            }
            Backend::Wgpu(g) => {
                let t = Instant::now();
                let y = g.predict(&configs)?;
                let wall = t.elapsed().as_secs_f64() * 1e3;
                let (dm, im) = g.last_ms;
                if dm + im > 0.0 {
                    // GPU timestamps split the GPU part; transfers count as inference.
                    times.descriptor_ms += dm;
                    times.inference_ms += wall - dm;
                } else {
                    times.inference_ms += wall;
                }
                y
            }
        };
        let outputs = if configs.is_empty() {
            1
        } else {
            y.len() / configs.len()
        };
        // A sky head's columns follow the sun's; without `sky_sh` (no sky, or the paper's
        // directions) they are not read — the sun column of a sky model is the sun model's.
        let sky_cols = opts.sky_sh.as_ref().map_or(0, |_| crate::sky::SH_COEFFS);
        let fits = outputs == opts.sun_outputs + sky_cols
            || (sky_cols == 0 && outputs == opts.sun_outputs + crate::sky::SH_COEFFS);
        if !configs.is_empty() && !fits {
            return Err(RenderError::Setting(format!(
                "the network gave {outputs} values per query, expected {} ({} of the sun{})",
                opts.sun_outputs + sky_cols,
                opts.sun_outputs,
                if sky_cols > 0 {
                    " and 25 sky coefficients"
                } else {
                    ""
                }
            )));
        }
        // A NaN or infinite answer is the model's fault (the f32 model's weights are checked
        // on load, an int8 copy's are not): an error naming the file, never a black pixel.
        if let Some(i) = y.iter().position(|v| !v.is_finite()) {
            let (model, why) = match backend {
                Backend::Ort(m) if m.int8 => (
                    m.model.display().to_string(),
                    "its int8 copy's weights are not a trained network's (make the copy again: \
                     training/quantize.py)",
                ),
                Backend::Ort(m) => (
                    m.model.display().to_string(),
                    "its activations overflow float32 (its weights passed the load checks)",
                ),
                Backend::Wgpu(_) => (
                    "the network on the GPU".into(),
                    "its activations overflow (with --net-precision f16: try f32)",
                ),
            };
            return Err(RenderError::Setting(format!(
                "{model}: the network answered {} for query {} (output {} of {outputs}); {why}",
                y[i],
                i / outputs.max(1),
                i % outputs.max(1),
            )));
        }
        let mut k = 0;
        for sh in &shades {
            let mut l = sh.known;
            for (cfg, wgt, sky_w) in &sh.queries {
                let row = &y[k * outputs..(k + 1) * outputs];
                let pred = if opts.sun_outputs >= 3 {
                    DVec3::new(row[0] as f64, row[1] as f64, row[2] as f64)
                } else {
                    DVec3::splat(row[0] as f64)
                };
                l += *wgt * pred;
                if let Some(s) = &opts.sky_sh
                    && *sky_w != 0.0
                {
                    l += *sky_w * sky_product(s, cfg, &row[opts.sun_outputs..]);
                }
                k += 1;
            }
            if !l.is_finite() {
                l = DVec3::ZERO;
            }
            sum[sh.pixel] += l;
            let lum = (l.x + l.y + l.z) / 3.0;
            sum_l2[sh.pixel] += lum * lum;
        }
    }
    sums.samples += opts.spp;
    times.total_ms = t_all.elapsed().as_secs_f64() * 1e3;
    times.rest_ms = (times.total_ms - times.descriptor_ms - times.inference_ms).max(0.0);
    Ok(times)
}

/// Σ t_lm c_lm for the transfer `t` the sky head predicted in `cfg`'s frame, up to
/// `s.degree`: the sky's world coefficients rotated into that frame and contracted with `t`
/// ([`crate::sky::product_in_frame`], the whole-sample GPU renderer's contraction; equal to
/// taking `t` to the world and contracting there, without forming a rotation matrix or
/// allocating per query).
fn sky_product(s: &SkySh, cfg: &Config, t: &[f32]) -> DVec3 {
    let (ex, ey, ez) = crate::descriptor::frame(cfg.view, cfg.to_light);
    let frame = (ex.as_dvec3(), ey.as_dvec3(), ez.as_dvec3());
    crate::sky::product_in_frame(t, &s.world, frame, s.degree)
}

/// Sky radiance seen along `d` (no sun).
fn sky_radiance(scene: &Scene, d: DVec3) -> DVec3 {
    match &scene.sky {
        Some(Sky::Constant(c)) => *c,
        Some(Sky::Env(env)) => env.radiance(d),
        None => DVec3::ZERO,
    }
}

fn shade(
    scene: &Scene,
    tracker: &Tracker,
    pixel: usize,
    opts: &RpnnOptions,
    rng: &mut Pcg32,
) -> Shade {
    let cam = &scene.camera;
    let (px, py) = (pixel % cam.width, pixel / cam.width);
    let u = rng.next2();
    let d = cam.ray_dir(px as f64 + u[0], py as f64 + u[1]);
    let o = cam.origin;
    let aabb = scene.volume.aabb();
    let medium = &scene.medium;
    let collision = aabb
        .intersect(o, d)
        .and_then(|(t0, t1)| tracker.sample_collision(o, d, t0, t1, medium.density_factor(0), rng));
    let Some(t) = collision else {
        let mut bg = sky_radiance(scene, d);
        if let Some(sun) = &scene.sun
            && !sun.is_delta()
            && sun.contains(d)
        {
            bg += sun.radiance();
        }
        return Shade {
            pixel,
            known: bg,
            queries: Vec::new(),
        };
    };
    let mut known = DVec3::ZERO;
    let mut queries: Vec<(Config, DVec3, f64)> = Vec::new();
    let (mut x, mut dir) = (o + d * t, d);
    // Product of the albedos and phase weights of the vertices so far.
    let mut throughput = 1.0;
    let last = opts.traced_bounces.saturating_add(1);
    for vertex in 1..=last {
        let (albedo, phase) = medium.vertex(vertex);
        throughput *= albedo;
        let ends = vertex == last;
        let (direct, q) = light_vertex(scene, tracker, x, dir, vertex, ends, opts, rng);
        known += throughput * direct;
        queries.extend(
            q.into_iter()
                .map(|(c, w, sky_w)| (c, throughput * w, throughput * sky_w)),
        );
        if ends {
            break;
        }
        // A traced bounce: light scattered at least once reaches x along a phase-sampled
        // direction only from a further collision (what arrives unscattered is the sky's
        // single scattering, counted above).
        let smp = phase.sample(dir, rng.next2());
        if smp.pdf.is_nan() || smp.pdf <= 0.0 {
            break;
        }
        let next = aabb.intersect(x, smp.dir).and_then(|(t0, t1)| {
            tracker.sample_collision(x, smp.dir, t0, t1, medium.density_factor(vertex), rng)
        });
        let Some(tn) = next else { break };
        throughput *= phase.eval(dir.dot(smp.dir)) / smp.pdf;
        x += smp.dir * tn;
        dir = smp.dir;
    }
    Shade {
        pixel,
        known,
        queries,
    }
}

/// The light of the scattering vertex x reached along `d` after `vertex − 1` earlier
/// scatterings, per unit albedo and path weight: the single scattering of sun and sky by Monte
/// Carlo, and, where the path `ends`, the network's queries for the rest, as (configuration,
/// RGB weight of the sun head's prediction, weight of the sky head's contraction).
#[allow(clippy::too_many_arguments)]
fn light_vertex(
    scene: &Scene,
    tracker: &Tracker,
    x: DVec3,
    d: DVec3,
    vertex: u32,
    ends: bool,
    opts: &RpnnOptions,
    rng: &mut Pcg32,
) -> (DVec3, Vec<(Config, DVec3, f64)>) {
    let aabb = scene.volume.aabb();
    let (_, phase) = scene.medium.vertex(vertex);
    let shadow_factor = scene.medium.density_factor(vertex);
    let shadow = |wi: DVec3, rng: &mut Pcg32| -> f64 {
        match aabb.intersect(x, wi) {
            Some((t0, t1)) => tracker.transmittance(x, wi, t0, t1, shadow_factor, rng),
            None => 1.0,
        }
    };
    let mut direct = DVec3::ZERO;
    let mut queries: Vec<(Config, DVec3, f64)> = Vec::new();
    let cfg = |to_light: DVec3| Config {
        x: x.as_vec3(),
        view: d.as_vec3(),
        to_light: to_light.as_vec3(),
    };
    if let Some(sun) = &scene.sun {
        if sun.is_delta() {
            direct += phase.eval(d.dot(sun.dir)) * shadow(sun.dir, rng) * sun.irradiance;
        } else {
            // Only light sampling reaches the disc (the sky term below excludes it): weight 1.
            let (wi, pdf) = sun.sample_cone(rng.next2());
            direct += phase.eval(d.dot(wi)) / pdf * shadow(wi, rng) * sun.radiance();
        }
        if ends && sun.irradiance.max_element() > 0.0 {
            queries.push((cfg(sun.dir), sun.irradiance, 0.0));
        }
    }
    if let Some(sky) = &scene.sky {
        // Single scattering of sky light: one phase-sampled direction.
        let smp = phase.sample(d, rng.next2());
        let l = sky_radiance(scene, smp.dir);
        if l.max_element() > 0.0 {
            direct += shadow(smp.dir, rng) * l;
        }
        if !ends {
            return (direct, queries);
        }
        // Multiple scattering of sky light through the sky head: the sun's query when there is
        // one (its frame), else one in the frame of the zenith; the paper's directional
        // sampling otherwise.
        if opts.sky_sh.is_some() {
            match queries.first_mut() {
                Some(q) => q.2 = 1.0,
                None => queries.push((cfg(DVec3::Y), DVec3::ZERO, 1.0)),
            }
        }
        let n = opts.sky_dirs.max(1) as f64;
        let dirs = if opts.sky_sh.is_some() {
            0
        } else {
            opts.sky_dirs
        };
        for _ in 0..dirs {
            let (wi, weight) = match sky {
                Sky::Constant(c) => (
                    uniform_sphere(rng.next2()),
                    *c * (4.0 * std::f64::consts::PI),
                ),
                Sky::Env(env) => match env.sample(rng.next2()) {
                    Some((wi, pdf)) if pdf > 0.0 => (wi, env.radiance(wi) / pdf),
                    _ => continue,
                },
            };
            if weight.max_element() > 0.0 {
                queries.push((cfg(wi), weight / n, 0.0));
            }
        }
    }
    (direct, queries)
}

/// Whether the scene's phase function matches the model's training phase function
/// (`nimbus.rpnn.phase` metadata: `hg` = HG g = 0.857, `mie` = chopped Mie); the message to
/// show when it does not.
pub fn phase_mismatch(scene: &Scene, model_phase: &str) -> Option<String> {
    let ok = match model_phase {
        "hg" => matches!(scene.medium.vertex(1).1,
            nimbus_scene::Phase::HenyeyGreenstein(hg) if (hg.g() - 0.857).abs() < 1e-6),
        "mie" => scene.phase_desc.starts_with("mie"),
        _ => false,
    };
    (!ok).then(|| {
        format!(
            "warning: the model was trained for phase function `{model_phase}` (hg = HG g 0.857), the scene uses `{}`; predictions may be biased",
            scene.phase_desc
        )
    })
}

/// Whether the scene's single-scattering albedo matches the model's training albedo; the
/// message to show when it does not (or when the model does not say). The network predicts
/// multiply scattered light, which depends on the albedo at every later vertex: a model trained
/// at albedo 1 renders an albedo-0.8 cloud ≈ 40 % too bright in its indirect part.
pub fn albedo_mismatch(scene: &Scene, model_albedo: Option<f64>) -> Option<String> {
    let a = scene.medium.albedo;
    match model_albedo {
        Some(m) if (m - a).abs() <= 1e-6 => None,
        Some(m) => Some(format!(
            "warning: the model was trained at albedo {m}, the scene has albedo {a}; its indirect light will be wrong (Kallweit's network is trained per medium)"
        )),
        None => Some(format!(
            "warning: the model does not state its training albedo; the scene has albedo {a}"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A pixel asks in exactly one of every m consecutive samples (any start), and its offset
    /// is uniform over pixels: for m = 4, 8 000 pixels ask in sample 0 in 2 000 ± 4σ (σ = 39)
    /// of them, and every offset occurs. m = 1 asks always.
    #[test]
    fn one_sample_in_every_m_asks() {
        for m in [2u32, 3, 4, 7, 64] {
            for p in 0..200u64 {
                for start in [0u64, 5, 1_000_003] {
                    let asks = (start..start + m as u64)
                        .filter(|&i| asks_network(9, p, i, m))
                        .count();
                    assert_eq!(asks, 1, "m {m}, pixel {p}, from {start}");
                }
            }
        }
        let m = 4;
        let mut per_offset = [0usize; 4];
        for p in 0..8000u64 {
            let first = (0..m as u64).find(|&i| asks_network(9, p, i, m)).unwrap();
            per_offset[first as usize] += 1;
        }
        let sd = (8000.0f64 * 0.25 * 0.75).sqrt();
        for c in per_offset {
            assert!((c as f64 - 2000.0).abs() < 4.0 * sd, "{per_offset:?}");
        }
        assert!((0..10).all(|i| asks_network(9, 3, i, 1)));
    }

    /// The contraction takes the transfer from the query's frame to the world: for a transfer
    /// T given as a band-limited function of the local direction and a band-limited sky L,
    /// `sky_product` equals ∫ T(local(ω)) L(ω) dω by quadrature (to 1e-6 relative).
    #[test]
    fn sky_product_is_the_integral_in_the_world() {
        let cfg = Config {
            x: glam::Vec3::ZERO,
            view: glam::Vec3::new(0.3, -0.2, -1.0).normalize(),
            to_light: glam::Vec3::new(0.5, 0.7, 0.1).normalize(),
        };
        let (ex, ey, ez) = crate::descriptor::frame(cfg.view, cfg.to_light);
        let (ex, ey, ez) = (ex.as_dvec3(), ey.as_dvec3(), ez.as_dvec3());
        let t_fn = |l: DVec3| 0.8 + 0.3 * l.z + 0.1 * l.x * l.y - 0.05 * l.z * l.z * l.x;
        let l_fn = |w: DVec3| DVec3::new(1.0 + 0.5 * w.y, 0.7 - 0.2 * w.x * w.z, 0.3 + w.y * w.y);
        let t: Vec<f32> = crate::sky::project(|l| DVec3::splat(t_fn(l)), 16)
            .iter()
            .map(|v| v[0] as f32)
            .collect();
        let s = SkySh {
            world: crate::sky::project(l_fn, 16),
            degree: crate::sky::SH_DEGREE,
        };
        let got = sky_product(&s, &cfg, &t);
        // ∫ T(local(ω)) L(ω) dω over a fine Fibonacci set.
        let n = 200_000;
        let mut want = DVec3::ZERO;
        for i in 0..n {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let r = (1.0 - z * z).sqrt();
            let p = std::f64::consts::PI * (3.0 - 5f64.sqrt()) * i as f64;
            let w = DVec3::new(r * p.cos(), r * p.sin(), z);
            let local = DVec3::new(ex.dot(w), ey.dot(w), ez.dot(w));
            want += l_fn(w) * t_fn(local);
        }
        want *= 4.0 * std::f64::consts::PI / n as f64;
        for c in 0..3 {
            assert!(
                (got[c] / want[c] - 1.0).abs() < 1e-4,
                "channel {c}: {} vs {}",
                got[c],
                want[c]
            );
        }
    }
}
