//! A data set held in memory: the records [`super::dataset::run`] writes, computed by the same
//! code (cloud set, split plan, shard jobs) with nothing written — the Python module's
//! `nimbus.datagen` without a folder.

use indicatif::{ProgressBar, ProgressDrawTarget};
use nimbus_scene::Cancel;
use nimbus_scene::clock::Instant;

use crate::data::clouds::CloudSpec;
use crate::data::datagen::DatagenError;
use crate::data::dataset::{
    DatagenOptions, RunSummary, SPLITS, ShardArrays, ShardJob, build_clouds, check_memory, medium,
    plan_split, shard_arrays, shard_records,
};
use crate::data::manifest::meta_width;

/// One split of a set held in memory ([`in_memory`]): the rows its shards would hold, in order.
pub struct SplitArrays {
    pub split: &'static str,
    pub records: usize,
    pub arrays: ShardArrays,
}

/// The records [`run`] writes for `clouds` and `opts` (every split, every shard in order: the
/// rows of `{split}_*_x.npy` etc. concatenated, float32 descriptors whatever
/// `f16_descriptors` says), computed in memory with nothing written; `cancel` stops it at the
/// next record ([`DatagenError::Cancelled`]). `opts.part` must be `None`.
pub fn in_memory(
    clouds: &[CloudSpec],
    opts: &DatagenOptions,
    cancel: &Cancel,
) -> Result<(Vec<SplitArrays>, RunSummary), DatagenError> {
    let err = |msg: String| DatagenError::Set {
        what: "datagen".into(),
        msg,
    };
    if opts.shard_size == 0 {
        return Err(err("shard size must be at least 1".into()));
    }
    if opts.part.is_some() {
        return Err(err(
            "a part of a set (shard K/N) is written to a folder, not held in memory".into(),
        ));
    }
    if opts.sky_transfer && opts.gpu {
        return Err(err(
            "sky transfer needs the CPU path tracer (device cpu)".into()
        ));
    }
    let counts = [opts.records, opts.val_records, opts.test_records];
    for (split, &count) in SPLITS.iter().zip(&counts) {
        if count > 0 && !clouds.iter().any(|c| c.split == *split) {
            return Err(err(format!(
                "{count} {split} records requested but the set has no {split} clouds"
            )));
        }
    }
    let medium = medium(opts)?;
    let gpu = if opts.gpu {
        Some(nimbus_gpu::Gpu::new().map_err(|e| err(e.to_string()))?)
    } else {
        None
    };
    let start = Instant::now();
    let (mut total, mut converged) = (0usize, 0usize);
    let mut splits = Vec::new();
    for (split, count) in SPLITS.into_iter().zip(counts) {
        let plan = plan_split(clouds, opts, split).map_err(|m| err(m.into()))?;
        let mut all = ShardArrays {
            x: Vec::new(),
            y: Vec::new(),
            meta: Vec::new(),
            width: meta_width(opts.sky_transfer),
            converged: 0,
        };
        if count > 0 {
            // The whole split is held at once.
            check_memory(clouds, &plan.members, count, split)?;
            let data = build_clouds(clouds, &plan.members, &medium, opts)?;
            let bar = if opts.progress {
                ProgressBar::with_draw_target(Some(count as u64), ProgressDrawTarget::stderr())
            } else {
                ProgressBar::hidden()
            };
            bar.set_prefix(split);
            let job = ShardJob {
                opts,
                data: &data,
                members: &plan.members,
                gpu: gpu.as_ref(),
                split,
                cap: plan.cap,
                fixed: plan.fixed,
                precise: plan.precise,
                what: "datagen".into(),
                cancel,
            };
            for k in 0..count.div_ceil(opts.shard_size) {
                let lo = k * opts.shard_size;
                let hi = ((k + 1) * opts.shard_size).min(count);
                let records = shard_records(&job, k, lo, hi, &bar)?;
                let a = shard_arrays(&records, opts.sky_transfer).map_err(|m| err(m.into()))?;
                all.x.extend_from_slice(&a.x);
                all.y.extend_from_slice(&a.y);
                all.meta.extend_from_slice(&a.meta);
                all.converged += a.converged;
            }
            bar.finish_and_clear();
        }
        total += count;
        converged += all.converged;
        splits.push(SplitArrays {
            split,
            records: count,
            arrays: all,
        });
    }
    Ok((
        splits,
        RunSummary {
            records: total,
            computed: total,
            converged,
            seconds: start.elapsed().as_secs_f64(),
        },
    ))
}
