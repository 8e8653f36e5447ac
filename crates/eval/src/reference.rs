//! The path-traced reference every method is measured against, cached on disk.
//!
//! ## Precise enough for the biases it judges
//! The reference is rendered as two independent halves A and B (disjoint seeds), in rounds of
//! `spp` samples per pixel per half, until its estimated relative noise over 4×4 blocks of cloud
//! pixels is at most `target_rel_noise` (default 1 %) or `time_cap_s` has passed (reported).
//! The noise is estimated from the halves, not from per-pixel sample variances: for the mean
//! (A + B)/2, E[(A − B)²/4] is exactly its variance whatever the distribution, while the sample
//! variance underestimates the heavy-tailed noise of a delta sun seen through an HG g = 0.857
//! lobe (the Mitsuba references in `shared/refs` are made the same way).
//!
//! The cloud mask is geometric: camera optical depth τ ≥ 0.1 ([`nimbus_scene::tau`]), stored
//! with the reference.
//!
//! ## Cache
//! The key is a SHA-256 over everything that determines the reference image: the density
//! grid's values, resolution, box and σ_t scale, the medium (albedo, phase function), sun, sky,
//! camera, path-length limit, samples per round, noise target, time cap, seed and the
//! estimator (CPU f64 or GPU f32 path tracer). Editing any of them, or the scene file pointing
//! at another volume, gives a new key; renaming or moving the scene file does not. A cache
//! entry is four files named by the first 16 hex digits of the key: `<key>.exr` (RGB + variance
//! channel), `<key>_diff.npy` (luminance of half A − half B per pixel), `<key>_tau.npy` (camera
//! optical depth) and `<key>.json` (settings, spp reached, noise, time, the full key). An
//! unreadable or mismatched entry is recomputed, never trusted; with
//! [`ReferenceSettings::cached_only`] (`--ref-cached-only`) it is an error, as is a missing one,
//! before anything renders.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use nimbus_scene::{Image, Scene, io::npy};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::method::GpuSlot;

/// Which path tracer renders the reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RefDevice {
    /// The GPU path tracer on a hardware GPU when it supports the scene, else the CPU one.
    Auto,
    Cpu,
    Gpu,
}

impl RefDevice {
    pub const ALL: [RefDevice; 3] = [RefDevice::Auto, RefDevice::Cpu, RefDevice::Gpu];

    /// The name on the command line (`--ref-device`).
    pub fn name(self) -> &'static str {
        match self {
            RefDevice::Auto => "auto",
            RefDevice::Cpu => "cpu",
            RefDevice::Gpu => "gpu",
        }
    }
}

impl std::str::FromStr for RefDevice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|d| d.name() == s)
            .ok_or_else(|| format!("unknown reference device `{s}` (expected auto, cpu or gpu)"))
    }
}

/// How the reference is made.
#[derive(Debug, Clone)]
pub struct ReferenceSettings {
    /// Samples per pixel of each half per round.
    pub spp: u32,
    /// Stop when the relative noise over 4×4 cloud blocks is at most this (0: one round).
    pub target_rel_noise: f64,
    /// Stop after this many seconds even if the target is not met (checked between rounds).
    pub time_cap_s: f64,
    pub seed: u64,
    pub device: RefDevice,
    /// Cache folder (`None`: no cache).
    pub cache_dir: Option<PathBuf>,
    /// Only cached references: a missing one is an error before anything renders (references
    /// prepared on one machine for a run on another whose time is short, e.g. a lent GPU's).
    pub cached_only: bool,
}

/// A reference image.
#[derive(Debug, Clone)]
pub struct Reference {
    pub image: Image,
    /// Variance of each pixel's mean luminance, (A − B)²/4 from the halves.
    pub variance: Vec<f32>,
    /// Luminance of half A − half B per pixel (the noise estimate's raw material).
    pub half_diff: Vec<f32>,
    /// Camera optical depth per pixel (cloud: τ ≥ 0.1).
    pub tau: Vec<f32>,
    /// Relative noise over 4×4 blocks of cloud pixels reached (from the halves).
    pub rel_noise_4x4: f64,
    /// Whether the noise target was met before the time cap.
    pub target_met: bool,
    /// Full hex SHA-256 cache key.
    pub key: String,
    /// `pt` (CPU) or `pt-gpu`.
    pub estimator: String,
    /// Total samples per pixel (both halves).
    pub spp: u32,
    /// Render time when it was made (not now, if cached).
    pub time_s: f64,
    pub cached: bool,
    /// The cached EXR, when there is a cache.
    pub path: Option<PathBuf>,
}

#[derive(Serialize, Deserialize)]
struct Meta {
    key: String,
    scene: String,
    estimator: String,
    spp: u32,
    rel_noise_4x4: f64,
    target_met: bool,
    seed: u64,
    width: usize,
    height: usize,
    time_s: f64,
}

/// Whether the GPU path tracer can render `scene` (HG or isotropic phase, f32 scales).
pub fn gpu_supports(scene: &Scene) -> bool {
    !matches!(scene.medium.phase, nimbus_scene::Phase::Tabulated(_))
        && nimbus_render::check_f32_scale(scene, nimbus_render::Method::PtGpu).is_ok()
}

/// The cache key of a reference of `scene` by `estimator` with `settings`.
pub fn cache_key(scene: &Scene, estimator: &str, settings: &ReferenceSettings) -> String {
    let mut h = Sha256::new();
    h.update(b"nimbus-reference/2\n");
    let vol = &scene.volume;
    let (spp, seed) = (settings.spp, settings.seed);
    let text = format!(
        "estimator={estimator}\nspp={spp}\ntarget={:?}\ncap={:?}\nseed={seed}\nres={:?}\naabb={:?}\nscale={:?}\nmedium={:?}\nsun={:?}\nsky={:?}\ncamera={:?}\nmax_depth={:?}\n",
        settings.target_rel_noise,
        settings.time_cap_s,
        vol.grid().res(),
        vol.aabb(),
        vol.density_scale(),
        scene.medium,
        scene.sun,
        scene.sky,
        scene.camera,
        scene.render.max_depth,
    );
    h.update(text.as_bytes());
    vol.grid().hash_into(|b| h.update(b));
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// A reference's four cache files: image, half difference, optical depth, metadata.
type CacheFiles = (PathBuf, PathBuf, PathBuf, PathBuf);

/// Whether `scene`'s reference is rendered on the GPU, its cache key and its cache files.
fn cache_entry(
    scene: &Scene,
    settings: &ReferenceSettings,
    gpu: &mut GpuSlot,
) -> Result<(bool, String, Option<CacheFiles>)> {
    let use_gpu = match settings.device {
        RefDevice::Cpu => false,
        RefDevice::Gpu => {
            // Asked for by name: a scene beyond f32 is an error, not a wrong reference.
            nimbus_render::check_f32_scale(scene, nimbus_render::Method::PtGpu)?;
            true
        }
        RefDevice::Auto => gpu_supports(scene) && gpu.get().is_ok_and(|g| !g.is_software()),
    };
    let estimator = if use_gpu { "pt-gpu" } else { "pt" };
    let key = cache_key(scene, estimator, settings);
    let files = settings.cache_dir.as_ref().map(|d| {
        let stem = d.join(&key[..16]);
        (
            stem.with_extension("exr"),
            PathBuf::from(format!("{}_diff.npy", stem.display())),
            PathBuf::from(format!("{}_tau.npy", stem.display())),
            stem.with_extension("json"),
        )
    });
    Ok((use_gpu, key, files))
}

/// With [`ReferenceSettings::cached_only`]: an error naming every scene of `scenes` whose
/// reference is not in the cache, before anything renders (none with it off).
pub fn require_cached(
    scenes: &[&Scene],
    settings: &ReferenceSettings,
    gpu: &mut GpuSlot,
) -> Result<()> {
    if !settings.cached_only {
        return Ok(());
    }
    let mut missing = Vec::new();
    for s in scenes {
        let (_, key, files) = cache_entry(s, settings, gpu)?;
        if !files.is_some_and(|f| present(&f.3)) {
            missing.push(format!("{} (key {}…)", s.source.display(), &key[..16]));
        }
    }
    if !missing.is_empty() {
        anyhow::bail!(
            "--ref-cached-only: {} of {} references are not in {}: {}; render them first with \
             the same flags without --ref-cached-only",
            missing.len(),
            scenes.len(),
            settings
                .cache_dir
                .as_ref()
                .map_or("a cache (--no-cache)".into(), |d| d.display().to_string()),
            missing.join(", ")
        );
    }
    Ok(())
}

/// The reference of `scene`: from the cache when a matching entry exists, else rendered (and
/// stored). `log` receives one line describing what happened.
pub fn reference(
    scene: &Scene,
    settings: &ReferenceSettings,
    gpu: &mut GpuSlot,
    log: &mut dyn FnMut(String),
) -> Result<Reference> {
    let (use_gpu, key, files) = cache_entry(scene, settings, gpu)?;
    let estimator = if use_gpu { "pt-gpu" } else { "pt" };
    let (w, h) = (scene.camera.width, scene.camera.height);
    if let Some((exr, diff, tau, json)) = &files
        && present(json)
    {
        match load([exr, diff, tau, json], &key, w, h) {
            Ok(mut r) => {
                r.path = Some(exr.clone());
                log(format!(
                    "reference: cached {} ({} spp, {})",
                    exr.display(),
                    r.spp,
                    r.estimator
                ));
                return Ok(r);
            }
            Err(e) if settings.cached_only => {
                return Err(e.context(format!(
                    "the cached reference {} of {} is unreadable (--ref-cached-only)",
                    json.display(),
                    scene.source.display()
                )));
            }
            Err(e) => log(format!(
                "reference: ignoring cache entry ({e:#}); rendering"
            )),
        }
    }
    if settings.cached_only {
        anyhow::bail!(
            "--ref-cached-only: no cached reference of {} ({w}x{h}, {estimator}, key {}…) in {}; \
             render it first with the same flags without --ref-cached-only",
            scene.source.display(),
            &key[..16],
            settings
                .cache_dir
                .as_ref()
                .map_or("no cache (--no-cache)".into(), |d| d.display().to_string())
        );
    }
    let t0 = Instant::now();
    let tau = nimbus_scene::tau::optical_depth_image(scene);
    let mask = nimbus_scene::tau::cloud_mask(&tau);
    let mut gpt = if use_gpu {
        Some(nimbus_trace::gpu::GpuPathTracer::new(gpu.get()?, scene)?)
    } else {
        None
    };
    let tracer = (!use_gpu).then(|| nimbus_trace::PathTracer::new(scene));
    let mut half = |seed: u64| -> Result<Image> {
        Ok(match (&mut gpt, &tracer) {
            (Some(g), _) => g.render(settings.spp, seed)?.0,
            (None, Some(t)) => {
                nimbus_trace::render_with(
                    t,
                    &nimbus_trace::RenderOptions {
                        spp: settings.spp,
                        seed,
                        progress: false,
                    },
                )
                .image
            }
            (None, None) => unreachable!("one tracer is set"),
        })
    };
    // Running sums of both halves over rounds (equal weights: every round has `spp` samples).
    let mut sum = [vec![[0.0f64; 3]; w * h], vec![[0.0f64; 3]; w * h]];
    let mut rounds = 0u32;
    let (noise, met) = loop {
        for (k, acc) in sum.iter_mut().enumerate() {
            let img = half(round_seed(settings.seed, rounds, k))?;
            for (a, p) in acc.iter_mut().zip(&img.pixels) {
                for c in 0..3 {
                    a[c] += p[c] as f64;
                }
            }
        }
        rounds += 1;
        let n = rounds as f64;
        let lum = |acc: &[[f64; 3]]| -> Vec<f64> {
            acc.iter()
                .map(|p| (p[0] + p[1] + p[2]) / (3.0 * n))
                .collect()
        };
        let noise = block_noise(&lum(&sum[0]), &lum(&sum[1]), &mask, w, h);
        let met = noise <= settings.target_rel_noise;
        // Target 0: one round, whatever its noise.
        if met
            || settings.target_rel_noise <= 0.0
            || t0.elapsed().as_secs_f64() >= settings.time_cap_s
            || rounds >= MAX_ROUNDS
        {
            break (noise, met);
        }
    };
    let n = 2.0 * rounds as f64;
    let mut image = Image::new(w, h);
    let mut half_diff = vec![0.0f32; w * h];
    for i in 0..w * h {
        let (a, b) = (sum[0][i], sum[1][i]);
        image.pixels[i] = [0, 1, 2].map(|c| ((a[c] + b[c]) / n) as f32);
        half_diff[i] =
            (((a[0] + a[1] + a[2]) - (b[0] + b[1] + b[2])) / (3.0 * rounds as f64)) as f32;
    }
    let variance: Vec<f32> = half_diff.iter().map(|d| d * d / 4.0).collect();
    let spp = 2 * rounds * settings.spp;
    let time_s = t0.elapsed().as_secs_f64();
    log(format!(
        "reference: {estimator} {w}x{h} at {spp} spp in {time_s:.1} s, relative 4x4 noise {:.2} % ({})",
        100.0 * noise,
        if met {
            "target met".to_string()
        } else if settings.target_rel_noise <= 0.0 {
            "one round: no noise target".to_string()
        } else if rounds >= MAX_ROUNDS {
            format!(
                "target {:.1} % not met within {MAX_ROUNDS} rounds",
                100.0 * settings.target_rel_noise
            )
        } else {
            format!(
                "target {:.1} % not met within the {} s cap",
                100.0 * settings.target_rel_noise,
                fmt_seconds(settings.time_cap_s)
            )
        }
    ));
    let mut r = Reference {
        image,
        variance,
        half_diff,
        tau,
        rel_noise_4x4: noise,
        target_met: met,
        key: key.clone(),
        estimator: estimator.into(),
        spp,
        time_s,
        cached: false,
        path: None,
    };
    if let (Some((exr, diff, tau, json)), Some(dir)) = (&files, &settings.cache_dir) {
        // A cache that cannot take the entry (read-only, full) costs the next run a render,
        // not this run its reference.
        let store = || -> Result<()> {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create {}", dir.display()))?;
            r.image.write_exr(exr, Some(&r.variance))?;
            npy::write_array(diff, &[h, w], &r.half_diff)?;
            npy::write_array(tau, &[h, w], &r.tau)?;
            let meta = Meta {
                key,
                scene: scene.source.display().to_string(),
                estimator: estimator.into(),
                spp,
                rel_noise_4x4: noise,
                target_met: met,
                seed: settings.seed,
                width: w,
                height: h,
                time_s,
            };
            // The JSON last: an entry without it is never read.
            nimbus_scene::fsio::write_bytes(json, serde_json::to_string_pretty(&meta)?.as_bytes())?;
            Ok(())
        };
        match store() {
            Ok(()) => r.path = Some(exr.clone()),
            Err(e) => log(format!(
                "warning: reference not stored in the cache ({e:#})"
            )),
        }
    }
    Ok(r)
}

/// Rounds at most (a guard when the time cap is huge and the target unreachable).
const MAX_ROUNDS: u32 = 4096;

/// The seed of half `k` (0 = A, 1 = B) in round `round`: disjoint streams.
fn round_seed(seed: u64, round: u32, k: usize) -> u64 {
    nimbus_trace::rng::mix64(seed ^ nimbus_trace::rng::mix64(((round as u64) << 1) | k as u64))
}

/// Relative noise of the mean (A + B)/2 over 4×4 blocks at least half in the cloud
/// ([`crate::blocks::cloud_blocks`]): √(mean over blocks of (Ā_b − B̄_b)²/4) / mean cloud
/// luminance. Without such a block
/// (a tiny or thin cloud) the same per pixel; without cloud pixels 0 (nothing to converge).
pub fn block_noise(a: &[f64], b: &[f64], mask: &[bool], w: usize, h: usize) -> f64 {
    let cloud: Vec<usize> = (0..w * h).filter(|&i| mask[i]).collect();
    if cloud.is_empty() {
        return 0.0;
    }
    let mean_cloud = cloud.iter().map(|&i| 0.5 * (a[i] + b[i])).sum::<f64>() / cloud.len() as f64;
    if mean_cloud <= 0.0 {
        return 0.0;
    }
    let blocks = crate::blocks::cloud_blocks(mask, w, h);
    if blocks.is_empty() {
        let px = cloud
            .iter()
            .map(|&i| (a[i] - b[i]).powi(2) / 4.0)
            .sum::<f64>();
        return (px / cloud.len() as f64).sqrt() / mean_cloud;
    }
    (crate::blocks::block_mean_square(|i| a[i] - b[i], &blocks) / 4.0).sqrt() / mean_cloud
}

/// `true` when something is at `path`, whatever it is: a cache entry that is a dangling link, a
/// loop or a pipe is read (and refused, naming it), not taken for a missing one.
fn present(path: &std::path::Path) -> bool {
    std::fs::symlink_metadata(path).is_ok()
}

fn load(files: [&PathBuf; 4], key: &str, w: usize, h: usize) -> Result<Reference> {
    let [exr, diff, tau, json] = files;
    let text = nimbus_scene::fsio::read_to_string(json)?;
    let meta: Meta =
        serde_json::from_str(&text).with_context(|| format!("{}: bad JSON", json.display()))?;
    if meta.key != key {
        anyhow::bail!("{}: key mismatch", json.display());
    }
    let image = Image::read_exr(exr)?;
    let (shape_d, half_diff) = npy::read_array(diff)?;
    let (shape_t, tau) = npy::read_array(tau)?;
    if (image.width, image.height) != (w, h) || shape_d != [h, w] || shape_t != [h, w] {
        anyhow::bail!("{}: size differs from the camera's {w}x{h}", exr.display());
    }
    if half_diff.iter().chain(&tau).any(|v| !v.is_finite()) || tau.iter().any(|t| *t < 0.0) {
        anyhow::bail!("{}: non-finite or negative values", diff.display());
    }
    let variance = half_diff.iter().map(|d| d * d / 4.0).collect();
    Ok(Reference {
        image,
        variance,
        half_diff,
        tau,
        rel_noise_4x4: meta.rel_noise_4x4,
        target_met: meta.target_met,
        key: key.into(),
        estimator: meta.estimator,
        spp: meta.spp,
        time_s: meta.time_s,
        cached: true,
        path: None,
    })
}

/// A time cap as the log prints it: whole seconds, or in scientific notation beyond 10⁹ s
/// (`--ref-time-cap 1e300` once printed 301 digits).
fn fmt_seconds(s: f64) -> String {
    if s < 1e9 {
        format!("{s:.0}")
    } else {
        format!("{s:.1e}")
    }
}
