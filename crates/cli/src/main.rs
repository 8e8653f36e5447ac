//! `nimbus`: the command line of the Nimbus cloud renderer. Parses arguments and calls the
//! libraries; no rendering logic lives here.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use glam::DVec3;
use nimbus_scene::{CloudKind, Scene, generate, io};
use nimbus_trace::{RenderOptions, compare};

#[derive(Parser)]
#[command(
    name = "nimbus",
    version,
    about = "Physically based rendering of atmospheric clouds"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Command,
}

#[derive(Clone, Copy, ValueEnum)]
enum Method {
    /// Reference volumetric path tracer (CPU).
    Pt,
}

#[derive(Subcommand)]
enum Command {
    /// Render a scene to linear EXR (+ per-pixel variance) and a tone-mapped PNG.
    Render {
        scene: PathBuf,
        #[arg(long, value_enum, default_value = "pt")]
        method: Method,
        /// Samples per pixel (default: the scene's `render.spp`).
        #[arg(long)]
        spp: Option<u32>,
        /// Random seed (default: the scene's `render.seed`).
        #[arg(long)]
        seed: Option<u64>,
        /// Output path; `.exr` and `.png` are written side by side (default: out/<scene>.exr).
        #[arg(long, short)]
        out: Option<PathBuf>,
        /// PNG exposure (default: the 99th-percentile luminance maps to 0.9).
        #[arg(long)]
        exposure: Option<f64>,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Compare against a reference EXR and print the error metrics.
        #[arg(long)]
        reference: Option<PathBuf>,
        /// No progress bar.
        #[arg(long, short)]
        quiet: bool,
    },
    /// Generate a procedural cloud and write it as .vol or .npy.
    Generate {
        /// cumulus, stratus or cirrus
        kind: String,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Resolution X,Y,Z (default: the kind's proportions at 128 along x).
        #[arg(long, value_delimiter = ',')]
        res: Option<Vec<i64>>,
        #[arg(long, short)]
        out: PathBuf,
    },
    /// Print statistics of a volume file.
    Info {
        file: PathBuf,
        /// σ_t per unit grid value, for the optical depths.
        #[arg(long, default_value_t = 1.0)]
        density_scale: f64,
        /// World box min corner X,Y,Z (default: the file's header box, or [0,1]³).
        #[arg(long, value_delimiter = ',')]
        aabb_min: Option<Vec<f64>>,
        #[arg(long, value_delimiter = ',')]
        aabb_max: Option<Vec<f64>>,
    },
    /// Compare a rendered EXR with a reference EXR (metrics of shared/refs/compare.py).
    Compare {
        test: PathBuf,
        reference: PathBuf,
        /// Optical-depth mask (.npy, cloud = τ ≥ 0.1); default: <reference>_tau.npy if present.
        #[arg(long)]
        mask: Option<PathBuf>,
    },
}

fn main() {
    if let Err(e) = run(Cli::parse()) {
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.cmd {
        Command::Render {
            scene,
            method,
            spp,
            seed,
            out,
            exposure,
            threads,
            reference,
            quiet,
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
                if v == 0 {
                    bail!("--spp must be at least 1");
                }
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
            if let Some(dir) = exr.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir)
                    .with_context(|| format!("cannot create {}", dir.display()))?;
            }
            let result = match method {
                Method::Pt => nimbus_trace::render(&s, &opts),
            };
            result.image.write_exr(&exr, Some(&result.variance))?;
            let e = exposure.unwrap_or_else(|| result.image.auto_exposure());
            result.image.write_png(&png, e)?;
            let st = result.stats;
            println!(
                "{}: {}x{} at {} spp in {:.2} s ({:.3e} camera paths/s, {:.1} scatterings/path) -> {}, {}",
                scene.display(),
                s.camera.width,
                s.camera.height,
                opts.spp,
                st.seconds,
                st.paths_per_second(),
                st.scatterings as f64 / st.paths.max(1) as f64,
                exr.display(),
                png.display()
            );
            if let Some(r) = reference {
                print_metrics(&exr, &r, None)?;
            }
        }
        Command::Generate {
            kind,
            seed,
            res,
            out,
        } => {
            let kind: CloudKind = kind.parse().map_err(|e| anyhow::anyhow!("{e}"))?;
            let res = match res {
                Some(r) if r.len() != 3 => bail!("--res needs three values X,Y,Z, got {r:?}"),
                Some(r) => nimbus_scene::grid::check_resolution([r[0], r[1], r[2]], "--res")
                    .map_err(|e| anyhow::anyhow!("{e}"))?,
                None => kind.default_resolution(128),
            };
            let grid = generate::generate(kind, seed, res).map_err(|e| anyhow::anyhow!("{e}"))?;
            io::write_grid(&out, &grid, generate::default_aabb(res))?;
            let st = grid.stats();
            println!(
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
            density_scale,
            aabb_min,
            aabb_max,
        } => {
            let f = io::read_grid(&file)?;
            let (lo, hi) = match (aabb_min, aabb_max) {
                (Some(a), Some(b)) if a.len() != 3 || b.len() != 3 => {
                    bail!("--aabb-min and --aabb-max need three values X,Y,Z")
                }
                (Some(a), Some(b)) => (DVec3::new(a[0], a[1], a[2]), DVec3::new(b[0], b[1], b[2])),
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
            println!("file            {}", file.display());
            println!(
                "resolution      {} x {} x {} ({} voxels)",
                r[0],
                r[1],
                r[2],
                r[0] * r[1] * r[2]
            );
            println!(
                "bounds          {lo} .. {hi}{}",
                if f.bounds.is_some() {
                    " (from file)"
                } else {
                    ""
                }
            );
            println!("cell size       {}", vol.cell_size());
            println!("min/mean/max    {} / {:.6} / {}", st.min, st.mean, st.max);
            println!("non-zero        {:.3} %", 100.0 * st.nonzero_fraction);
            println!(
                "max optical depth along x/y/z at density scale {density_scale}: {:.4} / {:.4} / {:.4}",
                tau[0], tau[1], tau[2]
            );
        }
        Command::Compare {
            test,
            reference,
            mask,
        } => print_metrics(&test, &reference, mask)?,
    }
    Ok(())
}

fn print_metrics(test: &Path, reference: &Path, mask: Option<PathBuf>) -> Result<()> {
    let t = nimbus_scene::Image::read_exr(test)?;
    let r = nimbus_scene::Image::read_exr(reference)?;
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
    let auto = {
        let stem = reference.with_extension("");
        PathBuf::from(format!("{}_tau.npy", stem.display()))
    };
    let mask_path = mask.or_else(|| auto.exists().then_some(auto));
    let m = match &mask_path {
        Some(p) => Some(compare::tau_mask(p, r.width, r.height)?),
        None => None,
    };
    let res = compare::compare(&t, &r, m.as_deref());
    println!("cloud pixels        {}", res.cloud_pixels);
    println!("rmse_rgb            {:.6}", res.rmse_rgb);
    println!("rel_rmse_cloud      {:.4}", res.rel_rmse_cloud);
    println!("rel_rmse_cloud_4x4  {:.4}", res.rel_rmse_cloud_4x4);
    println!("mean_lum_ratio      {:.5}", res.mean_lum_ratio);
    if res.nonfinite > 0 {
        println!("non-finite values   {}", res.nonfinite);
    }
    Ok(())
}
