//! The high-spp path-traced reference every method is measured against, cached on disk.
//!
//! The cache key is a SHA-256 over everything that determines the reference image: the density
//! grid's values, resolution, box and σ_t scale, the medium (albedo, phase function), sun, sky,
//! camera, path-length limit, samples per pixel, seed and the estimator (CPU f64 or GPU f32
//! path tracer). Editing any of them, or the scene file pointing at another volume, gives a new
//! key; renaming or moving the scene file does not. A cache entry is three files named by the
//! first 16 hex digits of the key: `<key>.exr` (RGB + variance channel), `<key>_var.npy` (the
//! variance of each pixel's mean luminance) and `<key>.json` (settings, time, the full key).
//! An unreadable or mismatched entry is recomputed, never trusted.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use nimbus_scene::{Image, Scene, Sky, io::npy};
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

/// How the reference is made.
#[derive(Debug, Clone)]
pub struct ReferenceSettings {
    pub spp: u32,
    pub seed: u64,
    pub device: RefDevice,
    /// Cache folder (`None`: no cache).
    pub cache_dir: Option<PathBuf>,
}

/// A reference image.
#[derive(Debug, Clone)]
pub struct Reference {
    pub image: Image,
    /// Variance of each pixel's mean luminance.
    pub variance: Vec<f32>,
    /// Full hex SHA-256 cache key.
    pub key: String,
    /// `pt` (CPU) or `pt-gpu`.
    pub estimator: String,
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
    seed: u64,
    width: usize,
    height: usize,
    time_s: f64,
}

/// Whether the GPU path tracer can render `scene` (HG or isotropic phase, no environment map).
pub fn gpu_supports(scene: &Scene) -> bool {
    !matches!(scene.medium.phase, nimbus_scene::Phase::Tabulated(_))
        && !matches!(scene.sky, Some(Sky::Env(_)))
}

/// The cache key of a reference of `scene` by `estimator` with `spp` samples and `seed`.
pub fn cache_key(scene: &Scene, estimator: &str, spp: u32, seed: u64) -> String {
    let mut h = Sha256::new();
    h.update(b"nimbus-reference/1\n");
    let vol = &scene.volume;
    let text = format!(
        "estimator={estimator}\nspp={spp}\nseed={seed}\nres={:?}\naabb={:?}\nscale={:?}\nmedium={:?}\nsun={:?}\nsky={:?}\ncamera={:?}\nmax_depth={:?}\n",
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
    for v in vol.grid().data() {
        h.update(v.to_le_bytes());
    }
    h.finalize().iter().map(|b| format!("{b:02x}")).collect()
}

/// The reference of `scene`: from the cache when a matching entry exists, else rendered (and
/// stored). `log` receives one line describing what happened.
pub fn reference(
    scene: &Scene,
    settings: &ReferenceSettings,
    gpu: &mut GpuSlot,
    log: &mut dyn FnMut(String),
) -> Result<Reference> {
    let use_gpu = match settings.device {
        RefDevice::Cpu => false,
        RefDevice::Gpu => true,
        RefDevice::Auto => gpu_supports(scene) && gpu.get().is_ok_and(|g| !g.is_software()),
    };
    let estimator = if use_gpu { "pt-gpu" } else { "pt" };
    let key = cache_key(scene, estimator, settings.spp, settings.seed);
    let (w, h) = (scene.camera.width, scene.camera.height);
    let files = settings.cache_dir.as_ref().map(|d| {
        let stem = d.join(&key[..16]);
        (
            stem.with_extension("exr"),
            PathBuf::from(format!("{}_var.npy", stem.display())),
            stem.with_extension("json"),
        )
    });
    if let Some((exr, var, json)) = &files
        && json.exists()
    {
        match load(exr, var, json, &key, w, h) {
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
            Err(e) => log(format!(
                "reference: ignoring cache entry ({e:#}); rendering"
            )),
        }
    }
    let t0 = Instant::now();
    let (image, variance) = if use_gpu {
        let g = gpu.get()?;
        let mut gpt = nimbus_trace::gpu::GpuPathTracer::new(g, scene)?;
        gpt.render(settings.spp, settings.seed)?
    } else {
        let out = nimbus_trace::render(
            scene,
            &nimbus_trace::RenderOptions {
                spp: settings.spp,
                seed: settings.seed,
                progress: false,
            },
        );
        (out.image, out.variance)
    };
    let time_s = t0.elapsed().as_secs_f64();
    log(format!(
        "reference: {estimator} {w}x{h} at {} spp in {time_s:.1} s",
        settings.spp
    ));
    let mut r = Reference {
        image,
        variance,
        key: key.clone(),
        estimator: estimator.into(),
        spp: settings.spp,
        time_s,
        cached: false,
        path: None,
    };
    if let (Some((exr, var, json)), Some(dir)) = (&files, &settings.cache_dir) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        r.image.write_exr(exr, Some(&r.variance))?;
        npy::write_array(var, &[h, w], &r.variance)?;
        let meta = Meta {
            key,
            scene: scene.source.display().to_string(),
            estimator: estimator.into(),
            spp: settings.spp,
            seed: settings.seed,
            width: w,
            height: h,
            time_s,
        };
        std::fs::write(json, serde_json::to_string_pretty(&meta)?)
            .with_context(|| format!("cannot write {}", json.display()))?;
        r.path = Some(exr.clone());
    }
    Ok(r)
}

fn load(exr: &Path, var: &Path, json: &Path, key: &str, w: usize, h: usize) -> Result<Reference> {
    let text = std::fs::read_to_string(json).with_context(|| json.display().to_string())?;
    let meta: Meta =
        serde_json::from_str(&text).with_context(|| format!("{}: bad JSON", json.display()))?;
    if meta.key != key {
        anyhow::bail!("{}: key mismatch", json.display());
    }
    let image = Image::read_exr(exr)?;
    let (shape, variance) = npy::read_array(var)?;
    if (image.width, image.height) != (w, h) || shape != [h, w] {
        anyhow::bail!("{}: size differs from the camera's {w}x{h}", exr.display());
    }
    if variance.iter().any(|v| !v.is_finite() || *v < 0.0) {
        anyhow::bail!("{}: negative or non-finite variance", var.display());
    }
    Ok(Reference {
        image,
        variance,
        key: key.into(),
        estimator: meta.estimator,
        spp: meta.spp,
        time_s: meta.time_s,
        cached: true,
        path: None,
    })
}
