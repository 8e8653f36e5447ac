//! Training data sets on disk: the cloud set, sharded `.npy` records and a JSON manifest.
//!
//! ## Files (readable by numpy/torch without extra dependencies)
//! For split `train`, `val` or `test` and shard k:
//! - `{split}_{k:05}_x.npy`: float32 `[n, 2251]` descriptors (layout in [`crate::descriptor`](mod@crate::descriptor));
//! - `{split}_{k:05}_y.npy`: float32 `[n]` targets L_i (unit irradiance);
//! - `{split}_{k:05}_meta.npy`: float32 `[n, 15]`: cloud index, x (3), ω (3), ω_l (3), sample
//!   count, converged (0/1), relative 95 % half-width, variance of the target (label noise),
//!   light-direction weight relative to sampling on the sphere;
//! - `manifest.json`: settings, clouds (with their split), shards, counts, convergence rate.
//!
//! Record r of a split uses its own random stream (seed, split, r) and cloud r mod (clouds of
//! the split), so a run is deterministic for a seed and resumable: finished shards (all three
//! files present with the right row count) are kept, the rest are recomputed. The manifest
//! lists every shard file's SHA-256.
//!
//! ## Integrity on resume
//! After its three `.npy` files, each shard gets `{split}_{k:05}.sha256` (their SHA-256, one per
//! line). A resumed run keeps a shard only when the sidecar's sums match the files; a shard
//! whose files were truncated, overwritten or changed (NaN written into it, …) is reported and
//! recomputed. Shards of older runs without a sidecar are kept when their row counts agree and
//! every value is finite (the sidecar is then written).
//!
//! ## Parts of a set (`--shard K/N`)
//! A run with [`DatagenOptions::part`] = K/N writes only the shards whose global index (train
//! shards first, then validation, then test) is ≡ K − 1 mod N — byte for byte the files a
//! single run with the same settings writes for them — into its own folder, resumable on its
//! own. [`crate::data::shards::merge`] checks N such folders (same settings, every shard exactly once,
//! checksums) and assembles the single run's folder.
//!
//! ## Labels: converged or fixed-count
//! Converged records (`samples` = 0) are path-traced until the 95 % interval is within ±2 %
//! (capped at `max_samples`): few, precise, but slow, and the sequential stopping rule biases
//! heavy-tailed labels low. Fixed-count records (`samples` = N) take exactly N samples: cheap,
//! noisy and unbiased — with a loss whose minimiser is the conditional mean, many of them teach
//! the network the same function as few converged ones (Kallweit's targets are means). The
//! validation and test splits use `eval_samples` (e.g. 16 384: ≈ 4 % relative noise per record)
//! so that they can tell models apart.
//!
//! ## The generated cloud set (`gen:N`, `gen:N:KIND,KIND,…`)
//! Cloud i: kind cycles cumulus, stratus, cirrus, mixture (max of a cumulus and a 0.6-scaled
//! stratus), or the kinds listed after a second colon (e.g. `gen:150:congestus,stratus,cirrus`,
//! see [`crate::data::clouds::generated_set_of`]); x-resolution cycles 48, 64, 80, 96 (with the kind's proportions),
//! advancing once per cycle of kinds; density scale
//! lo × (hi/lo)^u with u from the seed (default 10 × 2^(3u), 10…80); every fifth cloud
//! (i mod 5 = 4) is a test cloud and every tenth (i mod 10 = 2) a validation cloud; neither
//! enters training.

use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use nimbus_scene::{Cancel, Medium, Phase};
use nimbus_trace::Pcg32;
use nimbus_trace::rng::mix64;
use rayon::prelude::*;
use serde::Serialize;

pub use crate::data::clouds::{
    CloudSource, CloudSpec, DEFAULT_KINDS, build_volume, cloud_set, folder_set, generated_set,
    generated_set_in, generated_set_of,
};
use crate::data::datagen::{CloudData, DatagenError, LightSampling, Record};
pub use crate::data::in_memory::{SplitArrays, in_memory};
pub(crate) use crate::data::manifest::Manifest;
pub use crate::data::manifest::{
    DESCRIPTOR_LAYOUT, FORMAT, META_NAMES, Part, SKY_META_NAMES, ShardInfo, meta_width,
};
pub use crate::data::shard_files::META_COLUMNS;
use crate::data::shard_files::{
    lock_out, sha256_file, verify_shard, write_npy, write_npy_f16, write_sidecar, write_text,
};
use crate::descriptor::DESCRIPTOR_LEN;

/// The splits of a data set, in the order they are written.
pub const SPLITS: [&str; 3] = ["train", "val", "test"];

/// Bytes one record holds in memory: its descriptor, a copy in the shard's x matrix, and its
/// label and metadata.
const RECORD_BYTES: u128 = (2 * DESCRIPTOR_LEN * 4 + 256) as u128;

/// Checks what one split holds at once against the memory budget before any of it is built:
/// every cloud of the split (grid, pyramid ≤ 8/7 of it, majorants and the blur's transients:
/// 2.5 × the grid; a file cloud is estimated from its size on disk) and one shard of records.
/// Over the budget the error names the setting to change (`--shard-size`, the cloud set's
/// resolutions or `--max-memory`).
pub(crate) fn check_memory(
    clouds: &[CloudSpec],
    members: &[usize],
    shard: usize,
    split: &str,
) -> Result<(), DatagenError> {
    let cloud_bytes: u128 = members
        .iter()
        .map(|&i| match &clouds[i].source {
            CloudSource::Generated { resolution, .. } => {
                resolution.iter().map(|&r| r as u128).product::<u128>() * 4 * 5 / 2
            }
            CloudSource::File { path } => {
                std::fs::metadata(path).map_or(0, |m| m.len() as u128) * 5 / 2
            }
        })
        .sum();
    let set = |e: nimbus_scene::error::FieldError| DatagenError::Set {
        what: format!("{split} split"),
        msg: format!("field `{}`: {}", e.field, e.msg),
    };
    nimbus_scene::memory::check(
        cloud_bytes,
        "clouds",
        &format!("the {} {split} clouds held at once", members.len()),
    )
    .map_err(set)?;
    nimbus_scene::memory::check(
        cloud_bytes + shard as u128 * RECORD_BYTES,
        "shard_size",
        &format!("the {split} clouds and a shard of {shard} records (--shard-size)"),
    )
    .map_err(set)
}

/// Settings of a data-generation run.
#[derive(Debug, Clone, Serialize)]
pub struct DatagenOptions {
    /// Training records (from the training clouds).
    pub records: usize,
    /// Validation records (from the validation clouds).
    pub val_records: usize,
    /// Test records (from the held-out clouds).
    pub test_records: usize,
    pub shard_size: usize,
    pub seed: u64,
    /// Sample cap of one converged estimate.
    pub max_samples: u64,
    /// Training labels: 0 = converged (±2 %, capped at `max_samples`), N = exactly N samples.
    pub samples: u64,
    /// Validation and test labels: 0 = converged, N = exactly N samples.
    pub eval_samples: u64,
    /// Validation and test labels in two stages when > 0: a pilot of `eval_samples` samples
    /// sets how many fresh samples give this relative standard error (capped at
    /// `max_samples`); the label is their mean ([`crate::data::datagen::precise_count`]).
    #[serde(skip_serializing_if = "is_zero", default)]
    pub eval_noise: f64,
    /// How the light direction of a record is drawn.
    pub light: LightSampling,
    pub albedo: f64,
    /// `hg` (g = 0.857) or `mie` (r_eff 8 µm, chopped at 5°: full function at x, chopped after).
    pub phase: String,
    pub progress: bool,
    /// Estimate L_i on the GPU (`shaders/pt.wgsl`) instead of the CPU path tracer.
    pub gpu: bool,
    /// Store descriptors as float16 (half the disk and page-cache footprint). γ (column 2250)
    /// is then rounded too; the trainer recomputes it in float32 from the meta's directions.
    /// On 2 000 held-out records the shipped network's predictions move by ≤ 7.1e-4 relative
    /// (median 3e-5) with float16 densities and a float32 γ (2.6e-3 if γ stayed float16);
    /// `training/tests/test_f16.py` checks < 1e-3 on fresh records. Values beyond float16's
    /// range (65 504) are refused.
    #[serde(skip_serializing_if = "std::ops::Not::not", default)]
    pub f16_descriptors: bool,
    /// Write only part K of N of the set (see the module docs); `None`: all of it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub part: Option<Part>,
    /// Also label every record with the sky's transfer (`crate::sky`, `Estimate::sky`): the
    /// meta rows get [`crate::sky::SH_COEFFS`] more columns, `sky_sh_0` … (CPU path tracer
    /// only).
    #[serde(skip_serializing_if = "std::ops::Not::not", default)]
    pub sky_transfer: bool,
}

fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// Summary of a run.
#[derive(Debug, Clone, Copy)]
pub struct RunSummary {
    pub records: usize,
    pub computed: usize,
    pub converged: usize,
    pub seconds: f64,
}

pub(crate) fn medium(opts: &DatagenOptions) -> Result<Medium, DatagenError> {
    let err = |msg: String| DatagenError::Set {
        what: "phase".into(),
        msg,
    };
    match opts.phase.as_str() {
        "hg" => Medium::new(
            opts.albedo,
            Phase::HenyeyGreenstein(nimbus_scene::phase::HenyeyGreenstein::new(0.857).unwrap()),
        )
        .map_err(|e| err(e.to_string())),
        "mie" => {
            let m = nimbus_scene::phase::mie::cached(&nimbus_scene::phase::MieParams {
                chop_deg: 5.0,
                ..Default::default()
            })
            .map_err(|e| err(e.to_string()))?;
            Medium::mie(opts.albedo, &m).map_err(|e| err(e.to_string()))
        }
        other => Err(err(format!("unknown phase `{other}` (hg or mie)"))),
    }
}

/// What determines the records of a set: written to `settings.json` when a run starts; a later
/// run in the same folder must agree (it would otherwise mix old shards with new settings).
pub(crate) fn settings_json(clouds: &[CloudSpec], opts: &DatagenOptions) -> serde_json::Value {
    let mut o = serde_json::to_value(opts).expect("options serialise");
    let m = o.as_object_mut().expect("an object");
    // Not part of what a record is: how it was computed or shown.
    for k in ["progress", "gpu", "records", "val_records", "test_records"] {
        m.remove(k);
    }
    serde_json::json!({ "settings": o, "clouds": clouds })
}

fn check_settings(
    clouds: &[CloudSpec],
    opts: &DatagenOptions,
    out: &Path,
) -> Result<(), DatagenError> {
    let path = out.join("settings.json");
    let want_text = serde_json::to_string_pretty(&settings_json(clouds, opts)).expect("json");
    // Compared as text: a parsed f64 need not round-trip bit for bit through serde_json.
    let want: serde_json::Value = serde_json::from_str(&want_text).expect("json");
    // Only a missing settings.json is absent: a pipe, a device, a dangling or looping link at
    // its name is an error naming it.
    let found = match crate::read_optional_text(&path) {
        Ok(Some(text)) => Some(text),
        // Records without the settings that made them cannot be resumed under new ones (they
        // would keep their old labels under the new settings' name).
        Ok(None) => {
            let holds_records = std::fs::read_dir(out).is_ok_and(|d| {
                d.filter_map(|e| e.ok()).any(|e| {
                    // Shard files (`train_00000_x.npy`, …) or a manifest: not any .npy.
                    let n = e.file_name();
                    let n = n.to_string_lossy();
                    n == "manifest.json"
                        || (SPLITS.iter().any(|s| n.starts_with(&format!("{s}_")))
                            && n.ends_with(".npy"))
                })
            });
            if holds_records {
                return Err(DatagenError::Set {
                    what: out.display().to_string(),
                    msg: "holds records but no settings.json, so the settings that made them \
                          are unknown; use a new --out (or remove the folder)"
                        .into(),
                });
            }
            None
        }
        Err(e) => {
            return Err(match DatagenError::from(e) {
                DatagenError::Set { what, msg } => DatagenError::Set {
                    what,
                    msg: format!("cannot be read ({msg}); remove the folder or use a new --out"),
                },
                other => other,
            });
        }
    };
    if let Some(text) = found {
        if text == want_text {
            return Ok(());
        }
        let have: serde_json::Value =
            serde_json::from_str(&text).map_err(|e| DatagenError::Set {
                what: path.display().to_string(),
                msg: format!("not valid JSON ({e}); remove it or use a new --out"),
            })?;
        {
            let differs = ["settings", "clouds"]
                .iter()
                .flat_map(|sec| {
                    let (a, b) = (&have[sec], &want[sec]);
                    match (a.as_object(), b.as_object()) {
                        (Some(a), Some(b)) => b
                            .keys()
                            .chain(a.keys())
                            .collect::<std::collections::BTreeSet<_>>()
                            .into_iter()
                            .filter(|k| a.get(*k) != b.get(*k))
                            .map(|k| {
                                format!(
                                    "{k} (was {}, now {})",
                                    a.get(k).unwrap_or(&serde_json::Value::Null),
                                    b.get(k).unwrap_or(&serde_json::Value::Null)
                                )
                            })
                            .collect::<Vec<_>>(),
                        _ if a != b => vec![sec.to_string()],
                        _ => vec![],
                    }
                })
                .collect::<Vec<_>>();
            return Err(DatagenError::Set {
                what: out.display().to_string(),
                msg: format!(
                    "holds records made with other settings: {}; use a new --out (or remove the folder)",
                    if differs.is_empty() {
                        "the cloud set".to_string()
                    } else {
                        differs.join(", ")
                    }
                ),
            });
        }
    }
    write_text(&path, &want_text)
}

/// The second stage of precise labels on the GPU: configurations grouped by their fresh
/// sample count ([`crate::data::datagen::precise_count`] of their pilot), each group estimated with
/// its own random streams (independent of the pilot's).
fn precise_gpu(
    gpt: &mut nimbus_trace::gpu::GpuPathTracer,
    cfgs: &[(glam::DVec3, glam::DVec3, glam::DVec3)],
    pilots: &[crate::data::datagen::Estimate],
    rel: f64,
    max_samples: u64,
    seed: u64,
) -> Result<Vec<crate::data::datagen::Estimate>, nimbus_trace::gpu::GpuPtError> {
    let counts: Vec<u64> = pilots
        .iter()
        .map(|p| crate::data::datagen::precise_count(p, rel, max_samples))
        .collect();
    let mut out = pilots.to_vec();
    let mut distinct = counts.clone();
    distinct.sort_unstable();
    distinct.dedup();
    for n in distinct {
        let idx: Vec<usize> = (0..cfgs.len()).filter(|&i| counts[i] == n).collect();
        let group: Vec<_> = idx.iter().map(|&i| cfgs[i]).collect();
        let est = crate::data::datagen::estimate_gpu(gpt, &group, n, 0.0, mix64(seed ^ mix64(n)))?;
        for (&i, mut e) in idx.iter().zip(est) {
            e.converged = e.rel_noise() <= rel;
            out[i] = e;
        }
    }
    Ok(out)
}

/// What one split's records are computed with: its clouds, label sample counts.
pub(crate) struct SplitPlan {
    /// The clouds of the split (indices into the set).
    pub(crate) members: Vec<usize>,
    /// Samples per label (fixed) or the cap of a converged one.
    pub(crate) cap: u64,
    pub(crate) fixed: bool,
    /// Two-stage precise labels (validation and test only): pilot `cap`, then fresh samples.
    pub(crate) precise: Option<f64>,
}

pub(crate) fn plan_split(
    clouds: &[CloudSpec],
    opts: &DatagenOptions,
    split: &str,
) -> Result<SplitPlan, &'static str> {
    let n_samples = if split == "train" {
        opts.samples
    } else {
        opts.eval_samples
    };
    let (cap, fixed) = if n_samples > 0 {
        (n_samples, true)
    } else {
        (opts.max_samples, false)
    };
    let precise = (split != "train" && opts.eval_noise > 0.0).then_some(opts.eval_noise);
    if precise.is_some() && n_samples == 0 {
        return Err("precise labels (eval_noise) need a pilot count (eval_samples > 0)");
    }
    let members = (0..clouds.len())
        .filter(|&i| clouds[i].split == split)
        .collect();
    Ok(SplitPlan {
        members,
        cap,
        fixed,
        precise,
    })
}

/// The clouds of a split (volume + pyramid), built in parallel.
pub(crate) fn build_clouds(
    clouds: &[CloudSpec],
    members: &[usize],
    medium: &Medium,
    opts: &DatagenOptions,
) -> Result<Vec<CloudData>, DatagenError> {
    members
        .par_iter()
        .map(|&i| {
            CloudData::new(&clouds[i].name, build_volume(&clouds[i])?, medium.clone())
                .map(|c| c.with_sky_transfer(opts.sky_transfer))
        })
        .collect()
}

/// Everything one shard's records depend on besides their range.
pub(crate) struct ShardJob<'a> {
    pub(crate) opts: &'a DatagenOptions,
    pub(crate) data: &'a [CloudData],
    pub(crate) members: &'a [usize],
    pub(crate) gpu: Option<&'a nimbus_gpu::Gpu>,
    pub(crate) split: &'a str,
    pub(crate) cap: u64,
    pub(crate) fixed: bool,
    pub(crate) precise: Option<f64>,
    /// What errors name (the output folder).
    pub(crate) what: String,
    pub(crate) cancel: &'a Cancel,
}

/// Records `lo..hi` of shard `k` of a split, each with the index of its cloud in the set:
/// record r uses its own random stream (seed, split, r) on the CPU; on the GPU the shard's
/// records of one cloud share a batch seeded by (seed, k, cloud).
pub(crate) fn shard_records(
    job: &ShardJob,
    k: usize,
    lo: usize,
    hi: usize,
    bar: &ProgressBar,
) -> Result<Vec<(usize, Record)>, DatagenError> {
    let ShardJob {
        opts,
        data,
        members,
        cap,
        fixed,
        precise,
        cancel,
        ..
    } = *job;
    let err = |msg: String| DatagenError::Set {
        what: job.what.clone(),
        msg,
    };
    // train 0 and test 1 as before the validation split existed (same records).
    let split_id = match job.split {
        "train" => 0u64,
        "test" => 1,
        _ => 2,
    };
    let rng_of = |r: usize| Pcg32::new(mix64(opts.seed ^ mix64(split_id)), mix64(r as u64));
    Ok(match job.gpu {
        None => (lo..hi)
            .into_par_iter()
            .map(|r| {
                cancel.check()?;
                let ci = r % data.len();
                let rng = &mut rng_of(r);
                let rec = match precise {
                    Some(rel) => {
                        data[ci].record_precise(opts.light, cap, rel, opts.max_samples, rng)?
                    }
                    None => data[ci].record(opts.light, cap, fixed, rng)?,
                };
                bar.inc(1);
                Ok((members[ci], rec))
            })
            .collect::<Result<_, DatagenError>>()?,
        Some(gpu) => {
            let mut out: Vec<Option<(usize, Record)>> = vec![None; hi - lo];
            for (ci, cloud) in data.iter().enumerate() {
                cancel.check()?;
                let rs: Vec<usize> = (lo..hi).filter(|r| r % data.len() == ci).collect();
                if rs.is_empty() {
                    continue;
                }
                let cfgs: Vec<_> = rs
                    .par_iter()
                    .map(|&r| cloud.sample_config_with(opts.light, &mut rng_of(r)))
                    .collect::<Result<_, _>>()?;
                let mut gpt = nimbus_trace::gpu::GpuPathTracer::new(gpu, &cloud.scene)
                    .map_err(|e| err(e.to_string()))?;
                let seed = mix64(opts.seed ^ (k as u64) ^ ((ci as u64) << 32));
                let mut est = crate::data::datagen::estimate_gpu(
                    &mut gpt,
                    &cfgs,
                    cap,
                    if fixed { 0.0 } else { 0.02 },
                    seed,
                )
                .map_err(|e| err(e.to_string()))?;
                if let Some(rel) = precise {
                    est = precise_gpu(&mut gpt, &cfgs, &est, rel, opts.max_samples, seed)
                        .map_err(|e| err(e.to_string()))?;
                }
                for ((&r, c), e) in rs.iter().zip(&cfgs).zip(est) {
                    out[r - lo] = Some((members[ci], cloud.finish(c.0, c.1, c.2, e, opts.light)?));
                    bar.inc(1);
                }
            }
            out.into_iter()
                .map(|o| o.expect("every record assigned"))
                .collect()
        }
    })
}

/// A shard's records as the rows of its three files: descriptors `[n, DESCRIPTOR_LEN]`, labels
/// `[n]`, metadata `[n, width]` ([`META_NAMES`], then the sky's transfer when labelled).
pub struct ShardArrays {
    pub x: Vec<f32>,
    pub y: Vec<f32>,
    pub meta: Vec<f32>,
    /// Columns of `meta` ([`meta_width`]).
    pub width: usize,
    /// Records whose label converged.
    pub converged: usize,
}

pub(crate) fn shard_arrays(
    records: &[(usize, Record)],
    sky: bool,
) -> Result<ShardArrays, &'static str> {
    let width = meta_width(sky);
    let mut xs = Vec::with_capacity(records.len() * DESCRIPTOR_LEN);
    let mut ys = Vec::with_capacity(records.len());
    let mut ms = Vec::with_capacity(records.len() * width);
    let mut conv = 0;
    for (ci, r) in records {
        xs.extend_from_slice(&r.descriptor);
        ys.push(r.target);
        ms.push(*ci as f32);
        ms.extend_from_slice(&r.x.to_array());
        ms.extend_from_slice(&r.view.to_array());
        ms.extend_from_slice(&r.to_light.to_array());
        ms.extend_from_slice(&[
            r.samples as f32,
            r.converged as u8 as f32,
            r.rel_ci,
            r.var_mean,
            r.light_weight,
        ]);
        if sky {
            let Some(t) = r.sky else {
                return Err("a record has no sky transfer");
            };
            ms.extend_from_slice(&t);
        }
        conv += r.converged as usize;
    }
    Ok(ShardArrays {
        x: xs,
        y: ys,
        meta: ms,
        width,
        converged: conv,
    })
}

/// Whether `datagen` estimates labels on the GPU: `choice` when given (`--device`), else the
/// GPU when the phase function is HG (the WGSL tracer's) and the adapter is real hardware
/// (on lavapipe the CPU path tracer is faster).
pub fn datagen_on_gpu(choice: Option<bool>, phase: &str) -> bool {
    choice
        .unwrap_or_else(|| phase == "hg" && nimbus_gpu::Gpu::new().is_ok_and(|g| !g.is_software()))
}

/// Generates (or completes) a data set in `out`.
pub fn run(
    clouds: &[CloudSpec],
    opts: &DatagenOptions,
    out: &Path,
) -> Result<RunSummary, DatagenError> {
    run_cancellable(clouds, opts, out, &Cancel::never())
}

/// [`run`], stopping with [`DatagenError::Cancelled`] at the next record once `cancel` is set
/// (the shards finished until then are kept, so a rerun resumes).
pub fn run_cancellable(
    clouds: &[CloudSpec],
    opts: &DatagenOptions,
    out: &Path,
    cancel: &Cancel,
) -> Result<RunSummary, DatagenError> {
    let err = |msg: String| DatagenError::Set {
        what: out.display().to_string(),
        msg,
    };
    if opts.shard_size == 0 {
        return Err(err("shard size must be at least 1".into()));
    }
    if opts.sky_transfer && opts.gpu {
        return Err(err(
            "--sky-transfer needs the CPU path tracer (--device cpu): the GPU's indirect-radiance \
             pass estimates the sun's label only"
                .into(),
        ));
    }
    let counts = [opts.records, opts.val_records, opts.test_records];
    // Every requested split must have clouds: said before any work (and before the folder and
    // its settings.json exist, so a corrected rerun into it is not refused).
    for (split, &count) in SPLITS.iter().zip(&counts) {
        if count > 0 && !clouds.iter().any(|c| c.split == *split) {
            return Err(err(format!(
                "{count} {split} records requested but the set has no {split} clouds"
            )));
        }
    }
    let part = opts.part.unwrap_or(Part { index: 1, count: 1 });
    if part.index == 0 || part.index > part.count {
        return Err(err(format!("part {part}: needs 1 <= K <= N")));
    }
    let medium = medium(opts)?;
    let all: u128 = counts.iter().map(|&c| c as u128).sum();
    let what = if part.count > 1 {
        format!("this part's share, {part}")
    } else {
        "training, validation and test".into()
    };
    // The folder is made first, so that a path where none can be made (`/proc/x`, a file's
    // child, no permission) is named as such; the folders made here go again if that or the
    // disk check fails.
    let mut made: Vec<PathBuf> = Vec::new();
    let undo = |made: &[PathBuf]| {
        for dir in made.iter().rev() {
            let _ = std::fs::remove_dir(dir);
        }
    };
    let missing: Vec<&Path> = out
        .ancestors()
        .take_while(|p| !p.as_os_str().is_empty() && !p.exists())
        .collect();
    for dir in missing.iter().rev() {
        if let Err(e) = std::fs::create_dir(dir) {
            undo(&made);
            return Err(err(format!(
                "cannot create the folder {}: {e}",
                dir.display()
            )));
        }
        made.push(dir.to_path_buf());
    }
    if !out.is_dir() {
        undo(&made);
        return Err(err(
            "cannot create the folder: a file of that name is in the way".into(),
        ));
    }
    if let Err(e) = crate::data::shard_files::check_disk(
        out,
        all.div_ceil(part.count as u128),
        &what,
        opts.f16_descriptors,
    ) {
        undo(&made);
        return Err(e);
    }
    let _lock = lock_out(out)?;
    check_settings(clouds, opts, out)?;
    let gpu = if opts.gpu {
        Some(nimbus_gpu::Gpu::new().map_err(|e| err(e.to_string()))?)
    } else {
        None
    };
    // The shards an earlier run's manifest lists, with their checksums: a shard whose checksum
    // file is gone is still checked against them.
    // A manifest that is not valid JSON is rewritten; one that cannot be read as a file (a pipe,
    // a device, a dangling or looping link) is an error naming it.
    let recorded: std::collections::HashMap<String, ShardInfo> =
        crate::read_optional_text(&out.join("manifest.json"))
            .map_err(DatagenError::from)?
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .and_then(|v| serde_json::from_value::<Vec<ShardInfo>>(v["shards"].clone()).ok())
            .unwrap_or_default()
            .into_iter()
            .map(|s| (s.x.clone(), s))
            .collect();
    let start = Instant::now();
    let mut shards = Vec::new();
    let (mut computed, mut total, mut converged) = (0usize, 0usize, 0usize);
    // Global index of each split's first shard (train, then validation, then test).
    let mut first_shard = 0usize;
    for (split, count) in SPLITS.into_iter().zip(counts) {
        let n_shards = count.div_ceil(opts.shard_size);
        let shard0 = first_shard;
        first_shard += n_shards;
        let owned: Vec<usize> = (0..n_shards).filter(|k| part.owns(shard0 + k)).collect();
        let SplitPlan {
            members,
            cap,
            fixed,
            precise,
        } = plan_split(clouds, opts, split).map_err(|m| err(m.into()))?;
        if owned.is_empty() {
            continue;
        }
        check_memory(clouds, &members, opts.shard_size.min(count), split)?;
        let data = build_clouds(clouds, &members, &medium, opts)?;
        let owned_records: usize = owned
            .iter()
            .map(|k| ((k + 1) * opts.shard_size).min(count) - k * opts.shard_size)
            .sum();
        let bar = if opts.progress {
            ProgressBar::with_draw_target(Some(owned_records as u64), ProgressDrawTarget::stderr())
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template(
                "{prefix} [{bar:40}] {pos}/{len} records, {per_sec}, eta {eta}",
            )
            .unwrap()
            .progress_chars("=> "),
        );
        bar.set_prefix(split);
        for k in owned {
            let lo = k * opts.shard_size;
            let hi = ((k + 1) * opts.shard_size).min(count);
            let name = |what: &str| format!("{split}_{k:05}_{what}.npy");
            let (px, py, pm) = (
                out.join(name("x")),
                out.join(name("y")),
                out.join(name("meta")),
            );
            let n = (hi - lo) as u64;
            let shard = |converged| -> Result<ShardInfo, DatagenError> {
                Ok(ShardInfo {
                    split: split.into(),
                    index: k,
                    records: n as usize,
                    converged,
                    x: name("x"),
                    y: name("y"),
                    meta: name("meta"),
                    sha256: [sha256_file(&px)?, sha256_file(&py)?, sha256_file(&pm)?],
                })
            };
            let sidecar = out.join(format!("{split}_{k:05}.sha256"));
            let listed = recorded.get(&name("x")).filter(|r| r.y == name("y"));
            match verify_shard([&px, &py, &pm], &sidecar, listed.map(|r| &r.sha256), n)? {
                Ok(Some((sums, conv))) => {
                    converged += conv;
                    total += n as usize;
                    shards.push(ShardInfo {
                        split: split.into(),
                        index: k,
                        records: n as usize,
                        converged: conv,
                        x: name("x"),
                        y: name("y"),
                        meta: name("meta"),
                        sha256: sums,
                    });
                    bar.inc(n);
                    continue;
                }
                Ok(None) => {}
                Err(why) => bar.suspend(|| {
                    eprintln!("{split} shard {k}: {why}; recomputing it");
                }),
            }
            let job = ShardJob {
                opts,
                data: &data,
                members: &members,
                gpu: gpu.as_ref(),
                split,
                cap,
                fixed,
                precise,
                what: out.display().to_string(),
                cancel,
            };
            let records = shard_records(&job, k, lo, hi, &bar)?;
            let ShardArrays {
                x: xs,
                y: ys,
                meta: ms,
                converged: conv,
                width,
            } = shard_arrays(&records, opts.sky_transfer).map_err(|m| err(m.into()))?;
            let _ = std::fs::remove_file(&sidecar);
            if opts.f16_descriptors {
                write_npy_f16(&px, &[n, DESCRIPTOR_LEN as u64], &xs)?;
            } else {
                write_npy(&px, &[n, DESCRIPTOR_LEN as u64], &xs)?;
            }
            write_npy(&py, &[n], &ys)?;
            write_npy(&pm, &[n, width as u64], &ms)?;
            let info = shard(conv)?;
            write_sidecar(&sidecar, &info.sha256)?;
            computed += n as usize;
            total += n as usize;
            converged += conv;
            shards.push(info);
        }
        bar.finish_and_clear();
    }
    let seconds = start.elapsed().as_secs_f64();
    let manifest = Manifest::new(
        opts.clone(),
        clouds.to_vec(),
        shards,
        seconds,
        computed,
        opts.sky_transfer,
    );
    // A run that found every record in place keeps the manifest as it was: model cards name
    // its sha256, and a run that changed no record must not change it.
    if computed > 0 || !same_set(&manifest, out) {
        manifest.write(out)?;
    }
    Ok(RunSummary {
        records: total,
        computed,
        converged,
        seconds,
    })
}

/// Whether `out/manifest.json` describes the same records as `m` (all but the run's timing).
fn same_set<S: Serialize>(m: &Manifest<S>, out: &Path) -> bool {
    let strip = |mut v: serde_json::Value| {
        if let Some(o) = v.as_object_mut() {
            o.remove("seconds_this_run");
            o.remove("records_per_second_this_run");
        }
        v
    };
    let Ok(Some(text)) = crate::read_optional_text(&out.join("manifest.json")) else {
        return false;
    };
    let Ok(old) = serde_json::from_str::<serde_json::Value>(&text) else {
        return false;
    };
    let new = serde_json::to_value(m).expect("a manifest serialises");
    strip(old) == strip(new)
}
