//! `nimbus`: the command line of the Nimbus cloud renderer. Parses arguments and calls the
//! libraries; no rendering logic lives here.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use glam::DVec3;
use nimbus_scene::compare;
use nimbus_scene::{CloudKind, Scene, generate, io};
use nimbus_trace::RenderOptions;

/// Prints a line to stdout, ignoring a closed pipe (`nimbus … | head` must not panic).
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write;
        let _ = writeln!(std::io::stdout(), $($t)*);
    }};
}

mod args;
mod datagen;
mod eval;
mod flags;
mod interrupt;
mod rpnn;
mod view;

use args::{PmArgs, positive_finite, thread_count};

use datagen::{DatagenArgs, datagen};
use eval::{EvalArgs, StressArgs, SuiteArgs, bench_suite, compare_scene, stress};

use nimbus_render::Method;
use rpnn::RpnnArgs;
use view::{ViewArgs, view};

#[derive(Parser)]
#[command(
    name = "nimbus",
    version,
    about = "Physically based rendering of atmospheric clouds"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Command,
    /// Memory budget for any allocation sized by input (grids, images, files read whole),
    /// e.g. 6G or 512M; over it, a clear error instead of an abort. Default: NIMBUS_MAX_MEMORY,
    /// else 3/4 of the physical memory.
    #[arg(long, global = true, value_parser = memory_size)]
    max_memory: Option<u64>,
}

fn memory_size(s: &str) -> Result<u64, String> {
    nimbus_scene::memory::parse_size(s)
}

#[derive(Clone, Copy, ValueEnum, PartialEq)]
enum Device {
    Cpu,
    Gpu,
}

fn method_name(s: &str) -> Result<Method, String> {
    s.parse()
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to linear EXR (+ per-pixel variance) and a tone-mapped PNG.
    Render {
        scene: PathBuf,
        /// pt (reference path tracer, CPU), pt-gpu (the path tracer in WGSL: f32, HG/isotropic,
        /// any sun, constant sky or environment map), pm (photon mapping, Elek 2012, with final
        /// gathering), pm-march (its ray-marched image), pm-elek2012 (the paper's photon mapping
        /// as published), rpnn (Kallweit 2017: MC direct light, network indirect light; a sky
        /// through the model's sky head where it has one), rpnn-dirs (the paper's sky: network
        /// queries in `--sky-dirs` sampled sky directions).
        #[arg(long, default_value = "pt", value_parser = method_name)]
        method: Method,
        /// `--device gpu` with `--method pt` is `--method pt-gpu`.
        #[arg(long, value_enum, default_value = "cpu")]
        device: Device,
        /// Samples per pixel, 1..=16777216 as `render.spp` (default: the scene's).
        #[arg(long, value_parser = flags::int_in(1u32, 1 << 24))]
        spp: Option<u32>,
        /// Random seed (default: the scene's `render.seed`).
        #[arg(long)]
        seed: Option<u64>,
        /// Output path; `.exr` and `.png` are written side by side (default: `out/<scene>.exr`).
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// PNG exposure (default: the 99th-percentile luminance maps to 0.9).
        #[arg(long, value_parser = positive_finite)]
        exposure: Option<f64>,
        /// Worker threads, 1..=1024 (default: all cores).
        #[arg(long, value_parser = thread_count)]
        threads: Option<usize>,
        /// Compare against a reference EXR and print the error metrics.
        #[arg(long)]
        reference: Option<PathBuf>,
        /// No progress bar.
        #[arg(long, short)]
        quiet: bool,
        /// Print time per stage (photon mapping: GPU; RPNN: descriptor, inference, rest).
        #[arg(long)]
        timings: bool,
        #[command(flatten)]
        pm: PmArgs,
        #[command(flatten)]
        gather: args::GatherArgs,
        #[command(flatten)]
        rpnn: RpnnArgs,
    },
    /// Render an animation with photon mapping: moving sun and/or evolving density; numbered
    /// PNG frames and per-frame timings (CSV).
    Animate {
        scene: PathBuf,
        /// Frames to render and write (at least 1).
        #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..))]
        frames: u32,
        /// Sun angular speed about +y, degrees per simulated second (|v| ≤ 36000; at most a
        /// whole turn per frame).
        #[arg(long, default_value_t = 0.0, allow_negative_numbers = true,
              value_parser = flags::f64_in(-flags::MAX_SUN_SPEED, flags::MAX_SUN_SPEED))]
        sun_speed: f64,
        /// Simulated frames per second, in (0, 1000] (the sun moves sun_speed / fps degrees per
        /// frame).
        #[arg(long, default_value_t = 30.0, value_parser = flags::f64_above(0.0, flags::MAX_FPS))]
        fps: f64,
        /// Folder of volume files, one per frame (same resolution as the scene's volume).
        #[arg(long)]
        density_seq: Option<PathBuf>,
        /// Morph the scene's generated cloud into the next seed and back over N ≥ 1 frames.
        #[arg(long, value_parser = flags::int_in(1u32, u32::MAX))]
        evolve: Option<u32>,
        /// Reuse the last image while Elek's four impostor criteria allow.
        #[arg(long)]
        impostors: bool,
        #[command(flatten)]
        pm: PmArgs,
        /// Output folder (frames frame_00000.png …, timings.csv).
        #[arg(long, short, default_value = "out/animation")]
        out: PathBuf,
        /// PNG exposure (default: fixed from the first frame's 99th-percentile luminance).
        #[arg(long, value_parser = positive_finite)]
        exposure: Option<f64>,
    },
    /// Interactive viewer: the photon-mapped cloud in a window, following sun, camera and
    /// density changes (Elek 2012); progressive path tracing and RPNN on keys 2 and 3. Without a scene: a
    /// generated cumulus. `--headless` runs the same loop without a window.
    View(ViewArgs),
    /// Generate RPNN training records (Kallweit 2017 §5.1): descriptors and path-traced indirect
    /// radiance, sharded .npy files and manifest.json; resumable. `--shard K/N` writes part K of
    /// N (one machine's share); `datagen merge PART… --out DIR` assembles the parts.
    Datagen(DatagenArgs),
    /// Generate a procedural cloud and write it as .vol or .npy.
    Generate {
        /// cumulus, congestus, stratus or cirrus
        kind: String,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Resolution X,Y,Z (default: the kind's proportions at 128 along x).
        #[arg(long, value_delimiter = ',')]
        res: Option<Vec<i64>>,
        #[arg(long, short)]
        out: PathBuf,
    },
    /// Kallweit 2017 Table 1 analogue: held-out generated clouds × front/side/back light ×
    /// (sun, sun + sky), every method against the path-traced reference; writes
    /// OUT/results.md and OUT/results/.
    BenchSuite(SuiteArgs),
    /// Stiff and extreme inputs (phase asymmetry, density, albedo, sun placement, degenerate
    /// grids, invalid voxels) × every method, each under a time limit; writes OUT/stability.md.
    Stress(StressArgs),
    /// Print statistics of a volume file; `--gpu`: the GPU adapters wgpu sees.
    Info {
        /// A volume file (.vol, .npy, .vdb, .nvdb).
        #[arg(required_unless_present = "gpu")]
        file: Option<PathBuf>,
        /// List the GPU adapters wgpu sees, best first (the first is the one Nimbus opens).
        #[arg(long)]
        gpu: bool,
        /// σ_t per unit grid value, for the optical depths (finite, in [0, 1e30]).
        #[arg(long, default_value_t = 1.0,
              value_parser = flags::f64_in(0.0, flags::MAX_DENSITY_SCALE))]
        density_scale: f64,
        /// World box min corner X,Y,Z (default: the file's header box, or `[0,1]³`).
        #[arg(long, allow_hyphen_values = true, value_parser = flags::f64_triple(1e15))]
        aabb_min: Option<[f64; 3]>,
        #[arg(long, allow_hyphen_values = true, value_parser = flags::f64_triple(1e15))]
        aabb_max: Option<[f64; 3]>,
        /// The float grid of a .vdb or .nvdb file to read (default: `density`).
        #[arg(long)]
        grid: Option<String>,
    },
    /// `compare scene.toml --methods pt,pm,rpnn --out report/`: error against render time of
    /// each method's budget sweep versus a cached high-spp path-traced reference (report.csv,
    /// .json, .md, error_vs_time.png/.svg, strip.png). `compare test.exr reference.exr`: the
    /// metrics of shared/refs/compare.py for two images.
    Compare {
        /// A scene (.toml), or a test EXR followed by a reference EXR.
        #[arg(required = true, num_args = 1..=2)]
        inputs: Vec<PathBuf>,
        /// Scene mode: report folder.
        #[arg(long, short, default_value = "report")]
        out: PathBuf,
        #[command(flatten)]
        eval: EvalArgs,
        /// Optical-depth mask (.npy, cloud = τ ≥ 0.1); default: `<reference>_tau.npy` if present.
        #[arg(long)]
        mask: Option<PathBuf>,
        /// Write the panels reference | test | relative difference (false colour) as PNG.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Full scale of the difference panel (0.2 = ±20 %), in (0, 1e6].
        #[arg(long, default_value_t = 0.2, value_parser = flags::f64_above(0.0, 1e6))]
        range: f64,
    },
}

fn main() {
    // First, while this is the only thread (it may set an environment variable).
    nimbus_gpu::quiet_headless_vulkan();
    // `nimbus stress` starts this executable as its child (nimbus_eval::stress::CHILD_ENV).
    if let Some(code) = nimbus_eval::stress::serve_child_if_requested() {
        std::process::exit(code);
    }
    let cmd = <Cli as clap::CommandFactory>::command();
    let matches = cmd.clone().get_matches();
    let cli =
        <Cli as clap::FromArgMatches>::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    if let Err((sub, msg)) = check_flag_combinations(&cli.cmd) {
        let mut c = (cmd.find_subcommand(sub).cloned())
            .map_or(cmd.clone(), |c| c.bin_name(format!("nimbus {sub}")));
        c.error(clap::error::ErrorKind::ArgumentConflict, msg)
            .exit();
    }
    for w in args::flags_for_other_methods(&cmd, &matches) {
        eprintln!("{w}");
    }
    if let Err(e) = run(cli) {
        if nimbus_render::is_cancelled(&e) {
            eprintln!("cancelled: nothing was written");
            std::process::exit(interrupt::EXIT);
        }
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

/// The ranges that depend on two flags, checked right after parsing (before any work): the
/// subcommand and the message, which names both flags.
fn check_flag_combinations(cmd: &Command) -> Result<(), (&'static str, String)> {
    match cmd {
        Command::Animate { sun_speed, fps, .. } => {
            flags::check_turn_per_frame(*sun_speed, 1.0 / fps, "--sun-speed / --fps")
                .map_err(|e| ("animate", e))
        }
        Command::View(v) => v.check_flag_combinations().map_err(|e| ("view", e)),
        _ => Ok(()),
    }
}

fn run(cli: Cli) -> Result<()> {
    if let Some(b) = cli.max_memory {
        nimbus_scene::memory::set_budget(b);
    } else if let Ok(v) = std::env::var(nimbus_scene::memory::ENV) {
        let b = nimbus_scene::memory::parse_size(&v)
            .map_err(|e| anyhow::anyhow!("{}={v}: {e}", nimbus_scene::memory::ENV))?;
        nimbus_scene::memory::set_budget(b);
    }
    match cli.cmd {
        Command::Render {
            scene,
            method,
            device,
            spp,
            seed,
            out,
            exposure,
            threads,
            reference,
            quiet,
            timings,
            pm: pm_args,
            gather,
            rpnn: rpnn_args,
        } => {
            if let Some(n) = threads {
                rayon::ThreadPoolBuilder::new()
                    .num_threads(n)
                    .build_global()
                    .context("cannot set the thread count")?;
            }
            let s = Scene::load(&scene)?;
            let mut opts = RenderOptions::from_scene(&s);
            if let Some(v) = spp {
                opts.spp = v;
            }
            if let Some(v) = seed {
                opts.seed = v;
            }
            opts.progress = !quiet;
            let out = out.unwrap_or_else(|| {
                Path::new("out")
                    .join(scene.file_stem().unwrap_or_default())
                    .with_extension("exr")
            });
            let (exr, png) = (out.with_extension("exr"), out.with_extension("png"));
            // Checked (and the folder made) before the render, not after it; so is the
            // reference to compare with.
            io::check_writable(&exr)?;
            let reference = match reference {
                Some(r) => Some((read_reference(&r).context("--reference")?, r)),
                None => None,
            };
            if let Some((img, r)) = &reference
                && (img.width, img.height) != (s.camera.width, s.camera.height)
            {
                bail!(
                    "--reference {}: {}x{}, but the render will be {}x{}",
                    r.display(),
                    img.width,
                    img.height,
                    s.camera.width,
                    s.camera.height
                );
            }
            let method = match (method, device) {
                (m, Device::Cpu) => m,
                (Method::Pt | Method::PtGpu, Device::Gpu) => Method::PtGpu,
                (m, Device::Gpu) => bail!(
                    "--device gpu applies to --method pt (as pt-gpu); `{m}` chooses its own device{}",
                    if m.is_rpnn() { " (see --backend)" } else { "" }
                ),
            };
            let options = nimbus_render::Options {
                progress: !quiet,
                pm: pm_args.settings(opts.seed as u32)?,
                pm_half_res: pm_args.half_res,
                pm_gather: gather.settings(pm_args.ring, pm_args.beams),
                impostors: None,
                pm_density_max: None,
                rpnn: rpnn_args.settings(),
            };
            let budget = if method.budget_is_ring() {
                options.pm.ring
            } else {
                opts.spp
            };
            let gpu = nimbus_render::GpuSlot::new();
            let mut estimator = nimbus_render::prepare(&s, method, &options, &gpu)?;
            for w in &estimator.warnings {
                say!("{w}");
            }
            let r = estimator.render_with(budget, opts.seed, &interrupt::token())?;
            r.image.write_exr(&exr, r.variance.as_deref())?;
            say!("{}: {}", scene.display(), r.summary);
            if timings {
                for line in &r.timing_lines {
                    say!("{line}");
                }
            }
            let image = r.image;
            let e = exposure.unwrap_or_else(|| image.auto_exposure());
            image.write_png(&png, e)?;
            say!("wrote {} and {}", exr.display(), png.display());
            if let Some(w) = image.png_warning(e) {
                eprintln!("warning: {}: {w}", png.display());
            }
            if let Some((img, r)) = reference {
                // Cloud pixels from the scene's own camera optical depth (τ ≥ 0.1), unless the
                // reference comes with its `_tau.npy`.
                let tau = nimbus_scene::tau::optical_depth_image(&s);
                let mask = Some(nimbus_scene::tau::cloud_mask(&tau));
                print_metrics(&exr, &r, img, None, mask)?;
            }
        }
        Command::View(args) => view(args)?,
        Command::BenchSuite(args) => bench_suite(&args)?,
        Command::Stress(args) => stress(&args)?,
        Command::Animate {
            scene,
            frames,
            sun_speed,
            fps,
            density_seq,
            evolve,
            impostors,
            pm: pm_args,
            out,
            exposure,
        } => {
            use nimbus_photon::animate::AnimateOptions;
            let s = Scene::load(&scene)?;
            let density = density_sequence(&s, density_seq, evolve)?;
            // The folder is made and checked before any GPU work.
            io::check_writable(out.join("timings.csv"))?;
            let gpu = nimbus_gpu::Gpu::new()?;
            let settings = pm_args.settings(s.render.seed as u32)?;
            let mut pm = nimbus_photon::PhotonMapper::new(&gpu, &s, settings)?;
            let opts = AnimateOptions {
                frames,
                sun_speed_deg_s: sun_speed,
                fps,
                density,
                impostors: impostors.then(Default::default),
                half_res: pm_args.half_res,
            };
            nimbus_photon::animate::animate_to_dir(&mut pm, &s, &opts, &out, exposure)?;
            say!(
                "{} frames on {} -> {}",
                frames,
                gpu.describe(),
                out.display()
            );
        }
        Command::Datagen(args) => datagen(args)?,
        Command::Generate {
            kind,
            seed,
            res,
            out,
        } => {
            let kind: CloudKind = kind.parse().map_err(|e| anyhow::anyhow!("{e}"))?;
            // The output is checked before the (possibly long) generation.
            io::check_grid_output(&out)?;
            let res = match res {
                Some(r) if r.len() != 3 => bail!("--res needs three values X,Y,Z, got {r:?}"),
                // The generator's own limits, said for --res before the output file is opened
                // (a .vol is streamed: sparse).
                Some(r) => generate::check_generator_resolution(
                    [r[0], r[1], r[2]],
                    out.extension().is_some_and(|e| e == "vol"),
                    "--res",
                )
                .map_err(|e| anyhow::anyhow!("{e}"))?,
                None => kind.default_resolution(128),
            };
            let bounds = generate::default_aabb(res);
            let st = if out.extension().is_some_and(|e| e == "vol") {
                // Streamed into the file while it is generated (no grid in memory).
                let mut st = None;
                io::write_atomically(&out, |t| {
                    st = Some(generate::generate_vol(kind, seed, res, t, bounds)?);
                    Ok(())
                })?;
                st.expect("written")
            } else {
                let grid =
                    generate::generate(kind, seed, res).map_err(|e| anyhow::anyhow!("{e}"))?;
                io::write_grid(&out, &grid, bounds)?;
                grid.stats()
            };
            say!(
                "{} seed {seed}: {}x{}x{}, mean {:.4}, non-zero {:.1} % -> {}",
                kind.name(),
                res[0],
                res[1],
                res[2],
                st.mean,
                100.0 * st.nonzero_fraction,
                out.display()
            );
        }
        Command::Info {
            file,
            gpu,
            density_scale,
            aabb_min,
            aabb_max,
            grid,
        } => {
            if gpu {
                let adapters = nimbus_gpu::list_adapters();
                if adapters.is_empty() {
                    say!(
                        "no GPU adapter (install a Vulkan driver; without a GPU: `apt-get install mesa-vulkan-drivers`)"
                    );
                }
                for (i, a) in adapters.iter().enumerate() {
                    say!("{} {a}", if i == 0 { "used " } else { "     " });
                }
            }
            let Some(file) = file else {
                return Ok(());
            };
            let f = io::read_grid_named(&file, grid.as_deref())?;
            let (lo, hi) = match (aabb_min, aabb_max) {
                (Some(a), Some(b)) => (DVec3::from_array(a), DVec3::from_array(b)),
                (None, None) => f.bounds.unwrap_or((DVec3::ZERO, DVec3::ONE)),
                _ => bail!("give both --aabb-min and --aabb-max, or neither"),
            };
            let aabb = nimbus_scene::Aabb::new(lo, hi).map_err(|e| anyhow::anyhow!("{e}"))?;
            let vol = nimbus_scene::Volume::new(f.grid, aabb, density_scale)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            let g = vol.grid();
            let st = g.stats();
            let r = g.res();
            let tau = vol.max_axis_optical_depth();
            say!("file            {}", file.display());
            say!(
                "resolution      {} x {} x {} ({} voxels)",
                r[0],
                r[1],
                r[2],
                r[0] * r[1] * r[2]
            );
            say!(
                "bounds          {lo} .. {hi}{}",
                if f.bounds.is_some() {
                    " (from file)"
                } else {
                    ""
                }
            );
            match g.as_bricks() {
                Some(b) => {
                    let (stored, constant, absent) = b.counts();
                    say!(
                        "storage         sparse: {stored} stored, {constant} constant, {absent} absent bricks of 8³ ({})",
                        nimbus_scene::memory::human(g.bytes() as u128)
                    );
                }
                None => say!(
                    "storage         dense ({})",
                    nimbus_scene::memory::human(g.bytes() as u128)
                ),
            }
            say!("cell size       {}", vol.cell_size());
            say!("min/mean/max    {} / {:.6} / {}", st.min, st.mean, st.max);
            say!("non-zero        {:.3} %", 100.0 * st.nonzero_fraction);
            say!(
                "max optical depth along x/y/z at density scale {density_scale}: {:.4} / {:.4} / {:.4}",
                tau[0],
                tau[1],
                tau[2]
            );
        }
        Command::Compare {
            inputs,
            out,
            eval,
            mask,
            png,
            range,
        } => {
            if inputs[0].extension().is_some_and(|e| e == "toml") {
                if inputs.len() > 1 {
                    bail!("compare with a scene takes one input, got {}", inputs.len());
                }
                return compare_scene(&inputs[0], &eval, &out);
            }
            let [test, reference] = inputs.as_slice() else {
                bail!("compare needs a scene (.toml), or a test EXR and a reference EXR");
            };
            let (test, reference) = (test.clone(), reference.clone());
            print_metrics(
                &test,
                &reference,
                read_reference(&reference)?,
                mask.clone(),
                None,
            )?;
            if let Some(out) = png {
                let t = nimbus_scene::Image::read_exr(&test)?;
                let r = nimbus_scene::Image::read_exr(&reference)?;
                let m = match mask_for(&reference, mask) {
                    Some(p) => Some(compare::tau_mask(&p, r.width, r.height)?),
                    None => None,
                };
                // The reference's auto exposure (99th-percentile luminance → 0.9) for both panels.
                let e = r.auto_exposure();
                compare::diff_panels(&t, &r, m.as_deref(), range, e).write_png(&out, 1.0)?;
                say!(
                    "diff panels (reference | test | (test−ref)/ref, ±{range}) -> {}",
                    out.display()
                );
            }
        }
    }
    Ok(())
}

/// The density animation asked for by `--density-seq` / `--evolve`.
fn density_sequence(
    s: &Scene,
    density_seq: Option<PathBuf>,
    evolve: Option<u32>,
) -> Result<nimbus_photon::animate::DensitySequence> {
    use nimbus_photon::animate::DensitySequence;
    Ok(match (density_seq, evolve) {
        (Some(_), Some(_)) => bail!("give --density-seq or --evolve, not both"),
        (Some(d), None) => DensitySequence::from_dir(&d)?,
        (None, Some(n)) => match &s.volume_source {
            nimbus_scene::VolumeSource::Generated { kind, seed } => {
                DensitySequence::morph(*kind, *seed, s.volume.grid().res(), n)?
            }
            _ => bail!("--evolve needs a scene whose volume uses `generator`"),
        },
        (None, None) => DensitySequence::Static,
    })
}

/// The cloud mask to use: the given one, else `<reference>_tau.npy` when it exists.
fn mask_for(reference: &Path, mask: Option<PathBuf>) -> Option<PathBuf> {
    let auto = PathBuf::from(format!(
        "{}_tau.npy",
        reference.with_extension("").display()
    ));
    mask.or_else(|| auto.exists().then_some(auto))
}

/// Error metrics of `test` against `reference` over the cloud pixels: the mask file given, else
/// `<reference>_tau.npy`, else `scene_mask` (the scene's camera optical depth), else the
/// reference's bright pixels.
/// A reference image: an EXR whose pixels are finite and ≥ 0.
fn read_reference(reference: &Path) -> Result<nimbus_scene::Image> {
    let r = nimbus_scene::Image::read_exr(reference)?;
    // A radiance reference has no negative or non-finite pixel: one would be dropped from the
    // metrics without a word (the cloud mask skips pixels of non-positive luminance).
    let bad: Vec<usize> = (0..r.pixels.len())
        .filter(|&i| r.pixels[i].iter().any(|c| !(c.is_finite() && *c >= 0.0)))
        .collect();
    if let Some(&i) = bad.first() {
        bail!(
            "{}: {} of {} pixels are negative or not finite (the first at x = {}, y = {}: {:?}); \
             a radiance reference has none",
            reference.display(),
            bad.len(),
            r.pixels.len(),
            i % r.width,
            i / r.width,
            r.pixels[i]
        );
    }
    Ok(r)
}

/// The error metrics of the EXR `test` against `r`, the reference read from `reference`.
fn print_metrics(
    test: &Path,
    reference: &Path,
    r: nimbus_scene::Image,
    mask: Option<PathBuf>,
    scene_mask: Option<Vec<bool>>,
) -> Result<()> {
    let t = nimbus_scene::Image::read_exr(test)?;
    if (t.width, t.height) != (r.width, r.height) {
        bail!(
            "{} is {}x{} but {} is {}x{}",
            test.display(),
            t.width,
            t.height,
            reference.display(),
            r.width,
            r.height
        );
    }
    let mask_path = mask_for(reference, mask);
    let m = match &mask_path {
        Some(p) => Some(compare::tau_mask(p, r.width, r.height)?),
        None => scene_mask.filter(|m| m.len() == r.width * r.height),
    };
    let res = compare::compare(&t, &r, m.as_deref());
    if res.cloud_pixels == 0 || !res.mean_lum_ratio.is_finite() && res.nonfinite == 0 {
        bail!(
            "{}: the reference has no cloud pixels with positive luminance{}; relative metrics are undefined",
            reference.display(),
            if mask_path.is_some() {
                " inside the mask"
            } else {
                ""
            }
        );
    }
    say!("cloud pixels        {}", res.cloud_pixels);
    say!("rmse_rgb            {:.6}", res.rmse_rgb);
    say!("rel_rmse_cloud      {:.4}", res.rel_rmse_cloud);
    say!("rel_rmse_cloud_4x4  {:.4}", res.rel_rmse_cloud_4x4);
    say!("mean_lum_ratio      {:.5}", res.mean_lum_ratio);
    if res.nonfinite > 0 {
        say!("non-finite values   {}", res.nonfinite);
    }
    Ok(())
}
