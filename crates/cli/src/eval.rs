//! `compare scene.toml`, `bench-suite` and `stress`: argument parsing over `nimbus-eval`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::ValueEnum;
use nimbus_eval::{CompareOptions, GpuSlot, RefDevice, ReferenceSettings, RunSettings};
use nimbus_render::Method;

use crate::rpnn::RpnnArgs;

#[derive(Clone, Copy, ValueEnum)]
pub(crate) enum RefDeviceArg {
    /// The GPU path tracer on a hardware GPU when it supports the scene, else the CPU one.
    Auto,
    Cpu,
    Gpu,
}

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
    /// Which path tracer renders the reference.
    #[arg(long, value_enum, default_value = "auto")]
    ref_device: RefDeviceArg,
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
    fn options_on(&self, scene_seed: u64, device: Device, sky: bool) -> Result<CompareOptions> {
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
                    (Device::Gpu, crate::rpnn::NetBackend::Auto) => nimbus_render::NetBackend::Wgpu,
                    (_, b) => b.into(),
                },
                sky_dirs: self.rpnn.sky_dirs,
                sky_degree: self.rpnn.sky_degree as usize,
                cpu_shading: self.rpnn.cpu_shading,
                rpnn_precision: self.rpnn.net_precision.into(),
                rpnn_tiles: self.rpnn.net_tiles.into(),
                traced_bounces: self.rpnn.traced_bounces,
                query_every: self.rpnn.query_every,
            },
            reference: ReferenceSettings {
                spp: self.ref_spp,
                target_rel_noise: self.ref_noise,
                time_cap_s: self.ref_time_cap,
                seed: CompareOptions::reference_seed(seed),
                device: match self.ref_device {
                    RefDeviceArg::Auto => RefDevice::Auto,
                    RefDeviceArg::Cpu => RefDevice::Cpu,
                    RefDeviceArg::Gpu => RefDevice::Gpu,
                },
                cache_dir: (!self.no_cache).then(|| self.cache.clone()),
                cached_only: self.ref_cached_only,
            },
        })
    }
}

fn log(line: String) {
    say!("{line}");
}

/// What a comparison writes and reads at its end, checked before its first render (a reference
/// and the runs can take an hour): `--out` (and `--cache`) can be written, and every RPNN model
/// the runs will load (`models(method)`: the paths for `rpnn` or `rpnn-dirs`) reads, so a
/// missing or malformed model is named at once, not after the references.
fn preflight(
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

/// `nimbus compare scene.toml --methods … --out DIR`.
pub(crate) fn compare_scene(scene: &Path, args: &EvalArgs, out: &Path) -> Result<()> {
    let s = nimbus_scene::Scene::load(scene)?;
    let opts = args.options(s.render.seed, s.sky.is_some())?;
    let name = scene
        .file_stem()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned();
    preflight(&opts, out, |m| {
        Ok(vec![nimbus_render::rpnn_model_path(
            opts.run.model.as_deref(),
            m,
            &s.phase_desc,
            s.sky.is_some(),
        )])
    })?;
    let mut gpu = GpuSlot::default();
    let c = nimbus_eval::compare_scene(&s, &name, &opts, out, &mut gpu, &mut log)?;
    say!(
        "{}",
        nimbus_eval::report::markdown_table(&c.report.rows, false)
    );
    for f in &c.files {
        say!("wrote {}", f.display());
    }
    Ok(())
}

/// `nimbus bench-suite`.
#[derive(clap::Args)]
pub(crate) struct SuiteArgs {
    /// Held-out clouds (1..=8: the test split of the 40-cloud training set).
    #[arg(long, default_value_t = 3, value_parser = crate::flags::int_in(1usize, 8))]
    clouds: usize,
    /// Sun placements: front (behind the camera), side, back (behind the cloud).
    #[arg(long, default_value = "front,side,back")]
    lights: String,
    /// Lighting conditions: sun (sun only), sun+sky (a constant sky), sun+env (an environment
    /// map: a clear sky with a ground; photon mapping cannot take one and is left out of it).
    #[arg(long, default_value = "sun,sun+sky")]
    skies: String,
    /// Image size WxH, each side 4..=4096 (a 4×4 block of cloud pixels at least).
    #[arg(long, default_value = "128x72", value_parser = crate::flags::image_size(4, 4096))]
    size: (usize, usize),
    /// Writes OUT/results.md and OUT/results/ (per-scene reports, figure).
    #[arg(long, short, default_value = "docs")]
    out: PathBuf,
    /// Folder for the held-out clouds and the generated scene files.
    #[arg(long, default_value = "out/bench-suite")]
    work: PathBuf,
    /// Where the estimators run: `gpu` compares pt-gpu, pm and rpnn with the WGSL network
    /// (the whole sample on the GPU), with pt-gpu as the speed-ups' baseline: the table for
    /// choosing an estimator on a GPU.
    #[arg(long, value_enum, default_value = "cpu")]
    device: Device,
    #[command(flatten)]
    eval: EvalArgs,
}

/// `bench-suite --device`.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub(crate) enum Device {
    Cpu,
    Gpu,
}

pub(crate) fn bench_suite(args: &SuiteArgs) -> Result<()> {
    use nimbus_eval::suite::{Lighting, SkyCondition, SuiteOptions, run};
    let (width, height) = args.size;
    let lightings = args
        .lights
        .split(',')
        .map(Lighting::parse)
        .collect::<Result<Vec<_>>>()?;
    let skies = args
        .skies
        .split(',')
        .map(SkyCondition::parse)
        .collect::<Result<Vec<_>>>()?;
    let twice = |names: Vec<&str>| (1..names.len()).any(|i| names[..i].contains(&names[i]));
    if twice(lightings.iter().map(|l| l.name()).collect()) {
        bail!("--lights names a condition twice (each runs once)");
    }
    if twice(args.skies.split(',').map(str::trim).collect()) {
        bail!("--skies names a condition twice (each runs once)");
    }
    let any_sky = skies.iter().any(|&c| c != SkyCondition::Sun);
    let opts = SuiteOptions {
        clouds: args.clouds,
        lightings,
        skies,
        width,
        height,
        compare: args.eval.options_on(1, args.device, any_sky)?,
        work_dir: args.work.clone(),
    };
    // The suite's clouds scatter with the shipped HG phase function. `rpnn` under a sky
    // reads the sky head's model: without it the runs would fall back to the paper's sky
    // directions and the table's `rpnn` rows would be `rpnn-dirs` under another name.
    let explicit = opts.compare.run.model.as_deref();
    preflight(&opts.compare, &args.out, |m| {
        let mut v = Vec::new();
        for &sky in &opts.skies {
            let has_sky = sky != SkyCondition::Sun;
            if m == Method::Rpnn
                && has_sky
                && explicit.is_none()
                && nimbus_rpnn::model::sky_model_path_for("hg").is_none()
            {
                bail!(
                    "--skies {}: `rpnn` under a sky needs the shipped sky-head model models/rpnn-hg-sky.onnx, which is not beside the working directory or the executable (`--methods rpnn-dirs` runs the paper's sky directions without it)",
                    sky.name()
                );
            }
            v.push(nimbus_render::rpnn_model_path(explicit, m, "hg", has_sky));
        }
        Ok(v)
    })?;
    let rows = run(&opts, &args.out, &mut log)?;
    say!("{} runs", rows.len());
    Ok(())
}

/// `nimbus stress`.
#[derive(clap::Args)]
pub(crate) struct StressArgs {
    /// Methods: pt, pt-gpu, pm, pm-march, pm-elek2012 (the paper's photon mapping), rpnn,
    /// rpnn-dirs (comma-separated).
    #[arg(long, default_value = "pt,pt-gpu,pm,rpnn")]
    methods: String,
    /// `all`, `subset` (the one stiffest case per axis that the tests run), or case ids.
    #[arg(long, default_value = "all")]
    cases: String,
    /// Seconds one method may take on one case before it counts as a hang, 1..=86400.
    #[arg(long, default_value_t = 120, value_parser = crate::flags::int_in(1u64, 86_400))]
    time_limit: u64,
    /// Writes OUT/stability.md and the case scenes to OUT/stability/cases/.
    #[arg(long, short, default_value = "docs")]
    out: PathBuf,
}

pub(crate) fn stress(args: &StressArgs) -> Result<()> {
    use nimbus_eval::stress;
    let methods = nimbus_eval::method::parse_methods(&args.methods)?;
    let cases = match args.cases.as_str() {
        "all" => stress::cases(),
        "subset" => stress::subset(),
        list => {
            let all = stress::cases();
            list.split(',')
                .map(|id| {
                    all.iter()
                        .find(|c| c.id == id.trim())
                        .cloned()
                        .ok_or_else(|| anyhow::anyhow!("--cases: no case `{id}`"))
                })
                .collect::<Result<Vec<_>>>()?
        }
    };
    let exe = std::env::current_exe()?;
    let limit = std::time::Duration::from_secs(args.time_limit);
    let dir = args.out.join("stability").join("cases");
    let outcomes = stress::run_matrix(&exe, &cases, &methods, &dir, limit, &mut |o| {
        say!(
            "{:38} {:7} {} {} ({:.1} s) {}",
            o.case,
            o.method.name(),
            if o.pass { "pass" } else { "FAIL" },
            o.verdict,
            o.time_s,
            o.detail.lines().next().unwrap_or("")
        )
    })?;
    let p = stress::write_markdown(&outcomes, &methods, limit, &args.out)?;
    let fails = outcomes.iter().filter(|o| !o.pass).count();
    say!(
        "{} of {} runs pass -> {}",
        outcomes.len() - fails,
        outcomes.len(),
        p.display()
    );
    if fails > 0 {
        bail!("{fails} stress runs failed (see {})", p.display());
    }
    Ok(())
}
