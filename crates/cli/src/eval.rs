//! The evaluation's arguments, shared by `compare scene.toml` and `bench-suite`: the methods,
//! their budgets and settings, and the reference; checked before the first render.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use nimbus_eval::{CompareOptions, RefDevice, ReferenceSettings, RunSettings};
use nimbus_render::Method;

use crate::args::{Device, one_of};
use crate::rpnn::RpnnArgs;

/// Settings of the method runs and the reference, shared by `compare` and `bench-suite`.
#[derive(clap::Args)]
pub(crate) struct EvalArgs {
    /// Methods to compare: pt, pt-gpu, pm, pm-march, pm-elek2012 (the paper's photon mapping),
    /// rpnn, rpnn-dirs (the paper's sky directions) (comma-separated; default pt,pm,rpnn, with
    /// `bench-suite --device gpu` pt-gpu,pm,rpnn; under a sky rpnn-dirs as well).
    #[arg(long)]
    methods: Option<String>,
    /// Budget sweep of one method, METHOD=B1,B2,… (spp for pt, pt-gpu, pm, rpnn and rpnn-dirs;
    /// ring frames for pm-march and pm-elek2012); repeat for several methods. Defaults:
    /// pt=2,8,32,128 pt-gpu=4,16,64,256 pm=2,8,32 pm-march=4,16,100 pm-elek2012=4,16,100
    /// rpnn=2,8,32 rpnn-dirs=2,8,32 (a Monte Carlo budget is rendered as two halves for its
    /// noise estimate).
    #[arg(long)]
    budgets: Vec<String>,
    /// Reference samples per pixel per half and round (rounds repeat until --ref-noise or
    /// --ref-time-cap), 1..=1048576.
    #[arg(long, default_value_t = 512, value_parser = crate::flags::int_in(1u32, 1 << 20))]
    ref_spp: u32,
    /// Reference noise target: relative noise of 4×4 cloud blocks, estimated from two
    /// independent halves, in [0, 1) (0: a single round).
    #[arg(long, default_value_t = 0.01, value_parser = crate::args::unit_interval)]
    ref_noise: f64,
    /// Reference time cap in seconds, in [0, 1e9] (the noise reached is reported when it stops
    /// there).
    #[arg(long, default_value_t = 600.0, value_parser = crate::flags::f64_in(0.0, 1e9))]
    ref_time_cap: f64,
    /// Which path tracer renders the reference: `auto` (the GPU path tracer on a hardware GPU
    /// when it supports the scene, else the CPU one), `cpu` or `gpu`.
    #[arg(long, default_value = "auto", value_parser = one_of(RefDevice::ALL, RefDevice::name))]
    ref_device: RefDevice,
    /// Reference cache folder (keyed by a hash of scene content and settings).
    #[arg(long, default_value = "out/cache/reference")]
    cache: PathBuf,
    /// Render the reference even when a cached one exists, and do not store it.
    #[arg(long, conflicts_with = "ref_cached_only")]
    no_cache: bool,
    /// Only references from the cache: a missing one is an error before anything renders
    /// (references prepared here for a run on a machine whose time is short).
    #[arg(long)]
    ref_cached_only: bool,
    /// Seed of the method runs (default: the scene's `render.seed`).
    #[arg(long)]
    seed: Option<u64>,
    /// Photon mapping: beams per frame (n_g; default 8 192, the paper's; with final gathering
    /// 65 536), 1..=16777216.
    #[arg(long, value_parser = crate::flags::int_in(1u32, 1 << 24))]
    beams: Option<u32>,
    /// Photon mapping with final gathering: the ring's generations m, 1..=4096 (default 8; the
    /// ray-marched methods' budgets are their rings).
    #[arg(long, value_parser = crate::flags::int_in(1u32, 4096))]
    ring: Option<u32>,
    #[command(flatten)]
    gather: crate::args::GatherArgs,
    #[command(flatten)]
    rpnn: RpnnArgs,
}

impl EvalArgs {
    /// The settings of `compare` for a scene with a sky or without (`sky`).
    pub(crate) fn options(&self, scene_seed: u64, sky: bool) -> Result<CompareOptions> {
        self.options_on(scene_seed, Device::Cpu, sky)
    }

    /// [`EvalArgs::options`] for the estimators of `device`: on the GPU the path tracer is
    /// `pt-gpu` and the network runs in WGSL unless `--methods` and `--backend` say otherwise.
    /// Without `--methods`, a sky (`sky`: some run has one) adds `rpnn-dirs`, the paper's sky
    /// directions, beside `rpnn`'s sky head; without a sky the two are one estimator.
    pub(crate) fn options_on(
        &self,
        scene_seed: u64,
        device: Device,
        sky: bool,
    ) -> Result<CompareOptions> {
        let default = match (device, sky) {
            (Device::Cpu, false) => "pt,pm,rpnn",
            (Device::Cpu, true) => "pt,pm,rpnn,rpnn-dirs",
            (Device::Gpu, false) => "pt-gpu,pm,rpnn",
            (Device::Gpu, true) => "pt-gpu,pm,rpnn,rpnn-dirs",
        };
        let methods =
            nimbus_eval::method::parse_methods(self.methods.as_deref().unwrap_or(default))?;
        let mut budgets = BTreeMap::new();
        for b in &self.budgets {
            let (m, list) = nimbus_eval::method::parse_budgets(b)?;
            if !methods.contains(&m) {
                bail!("--budgets names `{m}`, which --methods does not list");
            }
            budgets.insert(m, list);
        }
        let seed = self.seed.unwrap_or(scene_seed);
        Ok(CompareOptions {
            methods,
            budgets,
            run: RunSettings {
                seed,
                pm_beams: self.beams.unwrap_or(8192),
                pm_gather: self.gather.settings(self.ring, self.beams),
                model: self.rpnn.model.clone(),
                rpnn_backend: match (device, self.rpnn.backend) {
                    (Device::Gpu, nimbus_render::NetBackend::Auto) => {
                        nimbus_render::NetBackend::Wgpu
                    }
                    (_, b) => b,
                },
                sky_dirs: self.rpnn.sky_dirs,
                sky_degree: self.rpnn.sky_degree as usize,
                cpu_shading: self.rpnn.cpu_shading,
                rpnn_precision: self.rpnn.net_precision,
                rpnn_tiles: self.rpnn.net_tiles,
                traced_bounces: self.rpnn.traced_bounces,
                query_every: self.rpnn.query_every,
            },
            reference: ReferenceSettings {
                spp: self.ref_spp,
                target_rel_noise: self.ref_noise,
                time_cap_s: self.ref_time_cap,
                seed: CompareOptions::reference_seed(seed),
                device: self.ref_device,
                cache_dir: (!self.no_cache).then(|| self.cache.clone()),
                cached_only: self.ref_cached_only,
            },
        })
    }
}

/// Prints one line of the evaluation's progress.
pub(crate) fn log(line: String) {
    say!("{line}");
}

/// What a comparison writes and reads at its end, checked before its first render (a reference
/// and the runs can take an hour): `--out` (and `--cache`) can be written, and every RPNN model
/// the runs will load (`models(method)`: the paths for `rpnn` or `rpnn-dirs`) reads, so a
/// missing or malformed model is named at once, not after the references.
pub(crate) fn preflight(
    opts: &CompareOptions,
    out: &Path,
    models: impl Fn(Method) -> Result<Vec<PathBuf>>,
) -> Result<()> {
    use anyhow::Context;
    nimbus_scene::io::check_writable(out.join("report.md")).context("--out")?;
    // With --ref-cached-only nothing is stored: the folder is only read (a mistyped one is
    // named with the references it lacks, not created).
    if let Some(cache) = &opts.reference.cache_dir
        && !opts.reference.cached_only
        && let Err(e) = nimbus_scene::io::check_writable(cache.join("reference.exr"))
    {
        // A read-only cache still serves the references it holds.
        if !cache.is_dir() {
            return Err(e).context("--cache");
        }
        say!(
            "warning: --cache {}: not writable ({e}); references rendered now are not stored",
            cache.display()
        );
    }
    let mut paths: Vec<PathBuf> = Vec::new();
    for &m in opts.methods.iter().filter(|m| m.is_rpnn()) {
        for p in models(m)? {
            if !paths.contains(&p) {
                paths.push(p);
            }
        }
    }
    for p in &paths {
        nimbus_rpnn::model::Rpnn::load(p)?;
        // The int8 copy beside it as well: missing, made from another model or damaged, it
        // was found only after the references and the other methods had run.
        if opts.run.rpnn_backend == nimbus_render::NetBackend::OrtInt8 {
            nimbus_rpnn::ort_backend::OrtModel::load_int8(p, 1)?;
        }
    }
    Ok(())
}
