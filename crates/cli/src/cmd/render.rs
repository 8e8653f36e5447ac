//! `nimbus render`: one scene, one method, one budget, to EXR and PNG.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nimbus_render::Method;
use nimbus_scene::{Scene, io};
use nimbus_trace::RenderOptions;

use super::compare::{print_metrics, read_reference};
use crate::args::{Device, GatherArgs, PmArgs, positive_finite, thread_count};
use crate::rpnn::RpnnArgs;
use crate::{flags, interrupt};

fn method_name(s: &str) -> Result<Method, String> {
    s.parse()
}

#[derive(clap::Args)]
pub(crate) struct RenderArgs {
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
    gather: GatherArgs,
    #[command(flatten)]
    rpnn: RpnnArgs,
}

pub(crate) fn run(a: RenderArgs) -> Result<()> {
    let RenderArgs {
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
    } = a;
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
    Ok(())
}
