//! `nimbus datagen` and `nimbus datagen merge`: arguments, checked and handed to
//! [`nimbus_rpnn::data::dataset`] and [`nimbus_rpnn::data::shards`].

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Args, Subcommand};
use nimbus_rpnn::data::datagen::LightSampling;
use nimbus_rpnn::data::dataset::{self, Part};

use crate::args::Device;

#[derive(Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
pub(crate) struct DatagenArgs {
    #[command(subcommand)]
    action: Option<DatagenAction>,
    /// `gen:N` for N generated clouds (kinds cumulus, stratus, cirrus, mixture in turn),
    /// `gen:N:KIND,KIND,…` to choose the kinds (cumulus, stratus, cirrus, congestus,
    /// mixture), or a folder of .vol/.npy/.vdb files.
    #[arg(long, default_value = "gen:40")]
    clouds: String,
    /// Training records (0..=2⁴⁰).
    #[arg(long, required = true, value_parser = crate::flags::int_in(0, crate::flags::MAX_RECORDS))]
    records: Option<usize>,
    /// Records from the held-out test clouds (default: a quarter of --records).
    #[arg(long, value_parser = crate::flags::int_in(0, crate::flags::MAX_RECORDS))]
    test_records: Option<usize>,
    /// Records from the validation clouds (default: as many as --test-records).
    #[arg(long, value_parser = crate::flags::int_in(0, crate::flags::MAX_RECORDS))]
    val_records: Option<usize>,
    /// Training labels with exactly N samples each (unbiased, noisy; train with the
    /// relative L2 loss). Default: to ±2 % at 95 % confidence, capped at --max-samples.
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1 << 24))]
    samples: Option<u64>,
    /// Validation and test labels with exactly N samples each (default: converged).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=1 << 24))]
    eval_samples: Option<u64>,
    /// Precise validation and test labels in two stages: a pilot of --eval-samples samples
    /// sets how many fresh samples reach this relative standard error (capped at
    /// --max-samples); the label is their mean alone, so it stays unbiased (e.g. 0.025; in
    /// [0, 1), 0: off).
    #[arg(long, value_parser = crate::args::unit_interval)]
    eval_noise: Option<f64>,
    /// Light directions: `sphere` (uniform, Kallweit §5.1) or `uniform-gamma` (the angle
    /// to the view direction uniform in [0, π]).
    #[arg(long, default_value = "sphere")]
    light: String,
    /// Density scales of generated clouds LO,HI (log-uniform; 0 < LO <= HI <= 1e30).
    #[arg(long, default_value = "10,80",
          value_parser = crate::flags::f64_pair_above(0.0, crate::flags::MAX_DENSITY_SCALE))]
    density_range: (f64, f64),
    #[arg(long, short, required = true)]
    out: Option<PathBuf>,
    /// Phase function: hg (g = 0.857) or mie (chopped, r_eff 8 µm).
    #[arg(long, default_value = "hg")]
    phase: String,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Records per shard file, 1..=2³⁰.
    #[arg(long, default_value_t = 1000, value_parser = crate::flags::int_in(1usize, 1 << 30))]
    shard_size: usize,
    /// Write part K of N of the set: the shards whose global index is K − 1 mod N, exactly the
    /// files a single run writes for them (run the N parts on N machines, then
    /// `nimbus datagen merge`).
    #[arg(long, value_parser = Part::parse)]
    shard: Option<Part>,
    /// Store descriptors as float16 (half the size; γ is recomputed in float32 by the trainer;
    /// predictions move by < 1e-3 relative).
    #[arg(long)]
    f16: bool,
    /// Also label every record with the sky's transfer: spherical-harmonic coefficients (degree
    /// ≤ 4, the descriptor's frame) of the radiance per unit sky radiance from each direction,
    /// from the same paths (25 more meta columns; CPU only).
    #[arg(long)]
    sky_transfer: bool,
    /// Sample cap per record (records that reach it are kept and flagged as not converged).
    #[arg(long, default_value_t = 1 << 18, value_parser = clap::value_parser!(u64).range(1..))]
    max_samples: u64,
    /// σ_t per unit grid value for clouds read from a folder, in (0, 1e30].
    #[arg(long, default_value_t = 30.0,
          value_parser = crate::flags::f64_above(0.0, crate::flags::MAX_DENSITY_SCALE))]
    density_scale: f64,
    /// Estimate L_i on the CPU or the GPU (default: the GPU when a hardware adapter is
    /// available and the phase function is HG; a software rasteriser is slower than the CPU
    /// path tracer).
    #[arg(long, value_enum)]
    device: Option<Device>,
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Subcommand)]
enum DatagenAction {
    /// Check the parts written by `datagen --shard K/N` (same settings, every shard exactly once,
    /// checksums) and assemble them in OUT as one single run's set.
    Merge {
        /// The N part folders.
        #[arg(required = true)]
        parts: Vec<PathBuf>,
        #[arg(long, short)]
        out: PathBuf,
        #[arg(long, short)]
        quiet: bool,
    },
}

pub(crate) fn run(a: DatagenArgs) -> Result<()> {
    if let Some(DatagenAction::Merge { parts, out, quiet }) = a.action {
        let m = nimbus_rpnn::data::shards::merge(&parts, &out)?;
        if !quiet {
            say!(
                "{} parts, {} shards, {} records ({} files linked, {} copied) -> {}",
                m.parts,
                m.shards,
                m.records,
                m.linked,
                3 * m.shards - m.linked,
                out.join("manifest.json").display()
            );
        }
        return Ok(());
    }
    let (Some(records), Some(out)) = (a.records, a.out) else {
        bail!("datagen needs --records and --out");
    };
    let (lo, hi) = a.density_range;
    let set = dataset::cloud_set(&a.clouds, a.seed, [lo, hi], a.density_scale)?;
    let light = match a.light.as_str() {
        "sphere" => LightSampling::Sphere,
        "uniform-gamma" => LightSampling::UniformGamma,
        other => bail!("--light {other}: expected sphere or uniform-gamma"),
    };
    let test_records = a.test_records.unwrap_or(records / 4);
    // A set of no records at all once finished with exit status 0 and an empty manifest (a
    // test set alone, `--records 0 --test-records N`, is one of the training scripts').
    if records == 0 && test_records == 0 && a.val_records.unwrap_or(test_records) == 0 {
        bail!(
            "--records 0 with no --test-records or --val-records: a set of no records (a test \
             set alone: --records 0 --test-records N)"
        );
    }
    if a.test_records.is_none() && test_records == 0 {
        say!(
            "note: --records {records}: a quarter of it is 0, so the set has no test records{} \
             (--test-records and --val-records set them)",
            if a.val_records.is_none() {
                " and no validation records"
            } else {
                ""
            }
        );
    }
    let eval_noise = a.eval_noise.unwrap_or(0.0);
    if eval_noise > 0.0 && a.eval_samples.is_none() {
        bail!("--eval-noise needs --eval-samples N (the pilot's sample count)");
    }
    let opts = dataset::DatagenOptions {
        records,
        test_records,
        val_records: a.val_records.unwrap_or(test_records),
        samples: a.samples.unwrap_or(0),
        eval_samples: a.eval_samples.unwrap_or(0),
        eval_noise,
        light,
        shard_size: a.shard_size,
        seed: a.seed,
        max_samples: a.max_samples,
        albedo: 1.0,
        // The sky's transfer is estimated on the CPU only: chosen automatically with it.
        gpu: if a.sky_transfer && a.device.is_none() {
            false
        } else {
            dataset::datagen_on_gpu(a.device.map(|d| d == Device::Gpu), &a.phase)
        },
        phase: a.phase,
        progress: !a.quiet,
        part: a.shard,
        f16_descriptors: a.f16,
        sky_transfer: a.sky_transfer,
    };
    let r = dataset::run(&set, &opts, &out)?;
    if let Some(p) = a.shard
        && r.records == 0
    {
        say!(
            "note: --shard {p}: the set has fewer shards than parts, and this part holds none \
             (merge accepts it; fewer parts, or a smaller --shard-size, would use every one)"
        );
    }
    {
        say!(
            "{}{} records ({} computed now in {:.1} s, {:.2} records/s), {:.1} % converged -> {}",
            a.shard.map(|p| format!("part {p}: ")).unwrap_or_default(),
            r.records,
            r.computed,
            r.seconds,
            r.computed as f64 / r.seconds.max(1e-9),
            100.0 * r.converged as f64 / r.records.max(1) as f64,
            out.join("manifest.json").display()
        );
    }
    Ok(())
}
