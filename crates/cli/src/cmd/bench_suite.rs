//! `nimbus bench-suite`: the Kallweit 2017 Table 1 analogue over `nimbus_eval::suite`.

use std::path::PathBuf;

use anyhow::{Result, bail};
use nimbus_eval::suite::{self, Lighting, SkyCondition, SuiteOptions};
use nimbus_render::Method;

use crate::args::Device;
use crate::eval::{EvalArgs, log, preflight};

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

pub(crate) fn run(args: &SuiteArgs) -> Result<()> {
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
    let rows = suite::run(&opts, &args.out, &mut log)?;
    say!("{} runs", rows.len());
    Ok(())
}
