//! Assembling a data set from parts written on several machines (`nimbus datagen --shard K/N`,
//! then `nimbus datagen merge`).
//!
//! Each part folder holds `settings.json` (what determines the records, with its part K/N) and
//! `manifest.json` (its shards with their SHA-256). [`merge`] checks, before it writes anything:
//! every part has the same settings and cloud set apart from K; the parts are 1…N, each once;
//! every shard of every split is held by exactly one part (no gaps, no overlaps); every file
//! exists, has the rows the manifest says and the checksum it lists. It then hard-links (or
//! copies, across file systems) the shard files into the output folder and writes the
//! `settings.json` and `manifest.json` a single run with the same settings writes — so the
//! trainer cannot tell a merged set from a single run's.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::data::datagen::DatagenError;
use crate::data::dataset::{CloudSpec, Manifest, Part, SPLITS, ShardInfo};
use crate::data::shard_files::{lock_out, present, rows_of, sha256_file, write_text};

/// What [`merge`] assembled.
#[derive(Debug, Clone, PartialEq)]
pub struct MergeSummary {
    pub parts: usize,
    pub shards: usize,
    pub records: usize,
    /// Files hard-linked (the rest were copied).
    pub linked: usize,
}

fn fail(what: impl std::fmt::Display, msg: impl Into<String>) -> DatagenError {
    DatagenError::Set {
        what: what.to_string(),
        msg: msg.into(),
    }
}

fn read_json(path: &Path) -> Result<Value, DatagenError> {
    let text =
        nimbus_scene::fsio::read_to_string(path).map_err(|e| match DatagenError::from(e) {
            DatagenError::Set { what, msg } => DatagenError::Set {
                what,
                msg: format!("{msg} (is this a `nimbus datagen --out` folder?)"),
            },
            other => other,
        })?;
    serde_json::from_str(&text).map_err(|e| fail(path.display(), format!("not valid JSON ({e})")))
}

/// Copies `src` (a regular file, streamed) to `dst` whole or not at all
/// ([`nimbus_scene::fsio::write_atomically`]).
fn copy(src: &Path, dst: &Path) -> Result<(), DatagenError> {
    use nimbus_scene::fsio;
    use std::io::Read;
    let (mut from, len) = fsio::open(src, fsio::Hold::Streamed)?;
    fsio::write_atomically(dst, |tmp| {
        let mut to = fsio::create(tmp)?;
        let copied = std::io::copy(&mut (&mut from).take(len), &mut to).map_err(|e| {
            nimbus_scene::Error::parse(dst, format!("copying {}: {e}", src.display()))
        })?;
        if copied != len {
            return Err(nimbus_scene::Error::parse(
                dst,
                format!("copying {}: {copied} of {len} bytes read", src.display()),
            ));
        }
        Ok(())
    })?;
    Ok(())
}

/// One part folder, read and checked on its own.
struct PartDir {
    dir: PathBuf,
    part: Part,
    /// `settings.json` without the part.
    settings: Value,
    /// The manifest's full settings (record counts, shard size) without the part.
    run_settings: Value,
    clouds: Value,
    shards: Vec<ShardInfo>,
    seconds: f64,
}

fn read_part(dir: &Path) -> Result<PartDir, DatagenError> {
    let sp = dir.join("settings.json");
    let mp = dir.join("manifest.json");
    let mut settings = read_json(&sp)?;
    let manifest = read_json(&mp)?;
    let field = |name: &str| {
        manifest
            .get(name)
            .ok_or_else(|| fail(mp.display(), format!("field `{name}` is missing")))
    };
    if field("format")? != crate::data::dataset::FORMAT {
        return Err(fail(
            mp.display(),
            format!(
                "field `format` is {}, expected \"{}\"",
                field("format")?,
                crate::data::dataset::FORMAT
            ),
        ));
    }
    let mut run_settings = field("settings")?.clone();
    let part = match run_settings.get("part") {
        None | Some(Value::Null) => Part { index: 1, count: 1 },
        Some(v) => serde_json::from_value::<Part>(v.clone())
            .ok()
            .filter(|p| p.index >= 1 && p.index <= p.count)
            .ok_or_else(|| {
                fail(
                    mp.display(),
                    format!("field `settings.part` is {v}, expected {{index: K, count: N}} with 1 <= K <= N"),
                )
            })?,
    };
    let set_part = settings
        .get("settings")
        .and_then(|s| s.get("part"))
        .cloned()
        .unwrap_or(Value::Null);
    if set_part != run_settings.get("part").cloned().unwrap_or(Value::Null) {
        return Err(fail(
            sp.display(),
            format!(
                "field `settings.part` is {set_part}, but manifest.json was written for part {part}"
            ),
        ));
    }
    for v in [&mut settings["settings"], &mut run_settings] {
        if let Some(o) = v.as_object_mut() {
            o.remove("part");
            // How a part was computed or shown, not what it holds.
            o.remove("progress");
            o.remove("gpu");
        }
    }
    let shards: Vec<ShardInfo> = serde_json::from_value(field("shards")?.clone())
        .map_err(|e| fail(mp.display(), format!("field `shards`: {e}")))?;
    Ok(PartDir {
        dir: dir.to_path_buf(),
        part,
        settings,
        run_settings,
        clouds: field("clouds")?.clone(),
        shards,
        seconds: manifest
            .get("seconds_this_run")
            .and_then(Value::as_f64)
            .unwrap_or(0.0),
    })
}

/// The first top-level key of two JSON objects whose values differ.
fn first_difference(a: &Value, b: &Value) -> String {
    match (a.as_object(), b.as_object()) {
        (Some(a), Some(b)) => a
            .keys()
            .chain(b.keys())
            .find(|k| a.get(*k) != b.get(*k))
            .map(|k| {
                format!(
                    "`{k}` is {} there and {} here",
                    a.get(k).unwrap_or(&Value::Null),
                    b.get(k).unwrap_or(&Value::Null)
                )
            })
            .unwrap_or_else(|| "they differ".into()),
        _ => "they differ".into(),
    }
}

/// Checks the part folders `parts` and assembles the whole set in `out` (see the module docs).
/// Nothing is written to `out` unless every check passes.
pub fn merge(parts: &[PathBuf], out: &Path) -> Result<MergeSummary, DatagenError> {
    if parts.is_empty() {
        return Err(fail("datagen merge", "no part folders given"));
    }
    let dirs: Vec<PartDir> = parts
        .iter()
        .map(|d| read_part(d))
        .collect::<Result<_, _>>()?;
    let first = &dirs[0];
    let n = first.part.count;
    // Checked before any part's shard files are read: a folder that already holds another set
    // is not overwritten (a plain datagen run into it would be refused); one holding this
    // merge's earlier, interrupted run is completed.
    let text = serde_json::to_string_pretty(&first.settings).expect("json");
    if present(&out.join("manifest.json")) || present(&out.join("settings.json")) {
        let same = crate::read_optional_text(&out.join("settings.json"))
            .map_err(DatagenError::from)?
            .is_some_and(|t| t == text);
        if !same {
            return Err(fail(
                out.display(),
                "holds another data set (its settings.json differs or is missing); merge into a \
                 new folder (or remove it)",
            ));
        }
    }

    for d in &dirs[1..] {
        for (what, a, b) in [
            ("settings.json", &first.settings, &d.settings),
            (
                "manifest.json field `settings`",
                &first.run_settings,
                &d.run_settings,
            ),
        ] {
            if a != b {
                let detail = if what == "settings.json" {
                    let (sa, sb) = (&a["settings"], &b["settings"]);
                    if sa != sb {
                        first_difference(sa, sb)
                    } else {
                        "the cloud sets differ".into()
                    }
                } else {
                    first_difference(a, b)
                };
                return Err(fail(
                    d.dir.join(what.split(' ').next().unwrap_or(what)).display(),
                    format!(
                        "was made with other settings than {} ({detail}); parts of one set share every setting but --shard",
                        first.dir.display()
                    ),
                ));
            }
        }
        if d.clouds != first.clouds {
            return Err(fail(
                d.dir.join("manifest.json").display(),
                format!("field `clouds` differs from {}", first.dir.display()),
            ));
        }
        if d.part.count != n {
            return Err(fail(
                d.dir.join("manifest.json").display(),
                format!(
                    "is part {} but {} is part {} (the parts of one set have the same N)",
                    d.part,
                    first.dir.display(),
                    first.part
                ),
            ));
        }
    }
    let mut by_index: BTreeMap<usize, &PartDir> = BTreeMap::new();
    for d in &dirs {
        if let Some(other) = by_index.insert(d.part.index, d) {
            return Err(fail(
                d.dir.display(),
                format!(
                    "holds part {} as does {}: each part is given once",
                    d.part,
                    other.dir.display()
                ),
            ));
        }
    }
    if let Some(missing) = (1..=n).find(|k| !by_index.contains_key(k)) {
        return Err(fail(
            "datagen merge",
            format!(
                "part {missing}/{n} is missing: {} of {n} parts given",
                dirs.len()
            ),
        ));
    }

    // Every shard of every split exactly once, in the part that owns it.
    let settings = &first.run_settings;
    let count = |key: &str| settings.get(key).and_then(Value::as_u64).unwrap_or(0) as usize;
    let shard_size = count("shard_size");
    if shard_size == 0 {
        return Err(fail(
            first.dir.join("manifest.json").display(),
            "field `settings.shard_size` is missing or 0",
        ));
    }
    let counts = [
        count("records"),
        count("val_records"),
        count("test_records"),
    ];
    let mut held: BTreeMap<(usize, usize), (&PartDir, &ShardInfo)> = BTreeMap::new();
    for d in &dirs {
        for s in &d.shards {
            let split = SPLITS.iter().position(|x| *x == s.split).ok_or_else(|| {
                fail(
                    d.dir.join("manifest.json").display(),
                    format!(
                        "shard {} has split `{}` (train, val or test)",
                        s.index, s.split
                    ),
                )
            })?;
            if let Some((other, _)) = held.insert((split, s.index), (d, s)) {
                return Err(fail(
                    d.dir.display(),
                    format!(
                        "{} shard {} is also in {}: overlapping parts",
                        s.split,
                        s.index,
                        other.dir.display()
                    ),
                ));
            }
        }
    }
    let mut global = 0usize;
    let mut order = Vec::new();
    for (si, (&split, &c)) in SPLITS.iter().zip(&counts).enumerate() {
        let n_shards = c.div_ceil(shard_size);
        for k in 0..n_shards {
            let owner = global % n + 1;
            global += 1;
            let Some(&(d, s)) = held.get(&(si, k)) else {
                return Err(fail(
                    by_index[&owner].dir.display(),
                    format!(
                        "{split} shard {k} is missing (part {owner}/{n} writes it): finish that part (run it again to resume)"
                    ),
                ));
            };
            let want = ((k + 1) * shard_size).min(c) - k * shard_size;
            if s.records != want {
                return Err(fail(
                    d.dir.join("manifest.json").display(),
                    format!(
                        "{split} shard {k} lists {} records, expected {want}",
                        s.records
                    ),
                ));
            }
            order.push((d, s));
        }
    }
    if held.len() != order.len() {
        let extra = held
            .iter()
            .find(|((si, k), _)| *k >= counts[*si].div_ceil(shard_size))
            .map(|((si, k), (d, _))| format!("{} shard {k} in {}", SPLITS[*si], d.dir.display()))
            .unwrap_or_default();
        return Err(fail(
            "datagen merge",
            format!("a shard beyond the set's record counts: {extra}"),
        ));
    }
    // Files: rows and checksums.
    for (d, s) in &order {
        for (file, sum) in [&s.x, &s.y, &s.meta].into_iter().zip(&s.sha256) {
            let path = d.dir.join(file);
            if file.contains('/') || file.contains('\\') || file.starts_with('.') {
                return Err(fail(
                    d.dir.join("manifest.json").display(),
                    format!("shard file name `{file}` is not a plain file name"),
                ));
            }
            if rows_of(&path)? != Some(s.records as u64) {
                return Err(fail(
                    path.display(),
                    format!(
                        "not an .npy file of {} rows as manifest.json says",
                        s.records
                    ),
                ));
            }
            let have = sha256_file(&path)?;
            if &have != sum {
                return Err(fail(
                    path.display(),
                    format!(
                        "SHA-256 is {have}, manifest.json lists {sum}: the file changed after it was written"
                    ),
                ));
            }
        }
    }

    // Write.
    std::fs::create_dir_all(out).map_err(|e| fail(out.display(), e.to_string()))?;
    let _lock = lock_out(out)?;
    let mut linked = 0;
    for (d, s) in &order {
        for (file, sum) in [&s.x, &s.y, &s.meta].into_iter().zip(&s.sha256) {
            let (src, dst) = (d.dir.join(file), out.join(file));
            if src.canonicalize().ok() == dst.canonicalize().ok() && dst.exists() {
                continue;
            }
            if dst.exists() {
                if &sha256_file(&dst)? == sum {
                    continue;
                }
                std::fs::remove_file(&dst).map_err(|e| fail(dst.display(), e.to_string()))?;
            }
            if std::fs::hard_link(&src, &dst).is_ok() {
                linked += 1;
            } else {
                copy(&src, &dst)?;
            }
        }
    }
    // settings.json as a single run writes it; the manifest's settings without the part (and
    // without how the parts were computed or shown).
    write_text(&out.join("settings.json"), &text)?;
    let clouds: Vec<CloudSpec> = serde_json::from_value(first.clouds.clone()).map_err(|e| {
        fail(
            first.dir.join("manifest.json").display(),
            format!("field `clouds`: {e}"),
        )
    })?;
    let shards: Vec<ShardInfo> = order.iter().map(|(_, s)| (*s).clone()).collect();
    let seconds = dirs.iter().map(|d| d.seconds).sum();
    let records = shards.iter().map(|s| s.records).sum();
    let sky = first
        .run_settings
        .get("sky_transfer")
        .and_then(Value::as_bool)
        .unwrap_or(false);
    Manifest::new(first.run_settings.clone(), clouds, shards, seconds, 0, sky).write(out)?;
    Ok(MergeSummary {
        parts: dirs.len(),
        shards: order.len(),
        records,
        linked,
    })
}
