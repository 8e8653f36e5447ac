//! `nimbus`: the command line of the Nimbus cloud renderer. Parses arguments and calls the
//! libraries; no rendering logic lives here. Each subcommand is a module of `cmd/` (its
//! arguments and its `run`); this file parses, checks flag combinations and dispatches.

use anyhow::Result;
use clap::{Parser, Subcommand};

/// Prints a line to stdout, ignoring a closed pipe (`nimbus … | head` must not panic).
macro_rules! say {
    ($($t:tt)*) => {{
        use std::io::Write;
        let _ = writeln!(std::io::stdout(), $($t)*);
    }};
}

mod args;
mod cmd;
mod eval;
mod flags;
mod interrupt;
mod rpnn;

use cmd::{animate, bench_suite, compare, datagen, generate, info, render, stress, view};

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

#[derive(Subcommand)]
enum Command {
    /// Render a scene to linear EXR (+ per-pixel variance) and a tone-mapped PNG.
    Render(render::RenderArgs),
    /// Render an animation with photon mapping: moving sun and/or evolving density; numbered
    /// PNG frames and per-frame timings (CSV).
    Animate(animate::AnimateArgs),
    /// Interactive viewer: the photon-mapped cloud in a window, following sun, camera and
    /// density changes (Elek 2012); progressive path tracing and RPNN on keys 2 and 3. Without a scene: a
    /// generated cumulus. `--headless` runs the same loop without a window.
    View(view::ViewArgs),
    /// Generate RPNN training records (Kallweit 2017 §5.1): descriptors and path-traced indirect
    /// radiance, sharded .npy files and manifest.json; resumable. `--shard K/N` writes part K of
    /// N (one machine's share); `datagen merge PART… --out DIR` assembles the parts.
    Datagen(datagen::DatagenArgs),
    /// Generate a procedural cloud and write it as .vol or .npy.
    Generate(generate::GenerateArgs),
    /// Kallweit 2017 Table 1 analogue: held-out generated clouds × front/side/back light ×
    /// (sun, sun + sky), every method against the path-traced reference; writes
    /// OUT/results.md and OUT/results/.
    BenchSuite(bench_suite::SuiteArgs),
    /// Stiff and extreme inputs (phase asymmetry, density, albedo, sun placement, degenerate
    /// grids, invalid voxels) × every method, each under a time limit; writes OUT/stability.md.
    Stress(stress::StressArgs),
    /// Print statistics of a volume file; `--gpu`: the GPU adapters wgpu sees.
    Info(info::InfoArgs),
    /// `compare scene.toml --methods pt,pm,rpnn --out report/`: error against render time of
    /// each method's budget sweep versus a cached high-spp path-traced reference (report.csv,
    /// .json, .md, error_vs_time.png/.svg, strip.png). `compare test.exr reference.exr`: the
    /// metrics of shared/refs/compare.py for two images.
    Compare(compare::CompareArgs),
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
        Command::Animate(a) => a.check_flag_combinations().map_err(|e| ("animate", e)),
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
        Command::Render(a) => render::run(a),
        Command::Animate(a) => animate::run(a),
        Command::View(a) => view::run(a),
        Command::Datagen(a) => datagen::run(a),
        Command::Generate(a) => generate::run(a),
        Command::BenchSuite(a) => bench_suite::run(&a),
        Command::Stress(a) => stress::run(&a),
        Command::Info(a) => info::run(a),
        Command::Compare(a) => compare::run(a),
    }
}
