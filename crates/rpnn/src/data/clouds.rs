//! The clouds of a data set: generated (`gen:N`, `gen:N:KIND,…`; see [`crate::data::dataset`]'s
//! module docs for the set's rules) or read from a folder, with the split each belongs to, and
//! the volume each is built into.

use std::path::{Path, PathBuf};

use nimbus_scene::{Aabb, CloudKind, DensityGrid, Volume, generate, io};
use nimbus_trace::rng::mix64;
use serde::Serialize;

use crate::data::datagen::DatagenError;

/// The split of generated or folder cloud i (see the module docs).
fn split_of(i: usize) -> String {
    if i % 5 == 4 {
        "test".into()
    } else if i % 10 == 2 {
        "val".into()
    } else {
        "train".into()
    }
}

/// Where a cloud comes from.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
#[serde(tag = "source")]
pub enum CloudSource {
    Generated {
        kind: String,
        seed: u64,
        resolution: [usize; 3],
    },
    File {
        path: PathBuf,
    },
}

/// A cloud of the set.
#[derive(Debug, Clone, Serialize, serde::Deserialize, PartialEq)]
pub struct CloudSpec {
    pub name: String,
    #[serde(flatten)]
    pub source: CloudSource,
    pub density_scale: f64,
    pub split: String,
}

/// The generated set of `n` clouds (see the module docs), density scales 10…80.
pub fn generated_set(n: usize, seed: u64) -> Vec<CloudSpec> {
    generated_set_in(n, seed, [10.0, 80.0])
}

/// The kinds `gen:N` cycles through (the shipped model's training set).
pub const DEFAULT_KINDS: [&str; 4] = ["cumulus", "stratus", "cirrus", "mixture"];

/// The generated set of `n` clouds with density scales log-uniform in `density` = [lo, hi].
pub fn generated_set_in(n: usize, seed: u64, density: [f64; 2]) -> Vec<CloudSpec> {
    generated_set_of(n, seed, density, &DEFAULT_KINDS).expect("the default kinds are valid")
}

/// Like [`generated_set_in`], cycling through `kinds` (generator names as in the scene format
/// — `cumulus`, `stratus`, `cirrus`, `congestus` — or `mixture`; a kind named twice comes twice
/// as often). With [`DEFAULT_KINDS`] it is [`generated_set_in`]'s set, cloud for cloud. An unknown
/// or missing kind is an error naming `--clouds`.
pub fn generated_set_of(
    n: usize,
    seed: u64,
    density: [f64; 2],
    kinds: &[&str],
) -> Result<Vec<CloudSpec>, DatagenError> {
    let err = |msg: String| DatagenError::Set {
        what: "--clouds".into(),
        msg,
    };
    if kinds.is_empty() {
        return Err(err("the list of cloud kinds is empty".into()));
    }
    // The list itself is sized by N (gen:10¹¹ once aborted on allocating it); each cloud's grid
    // is checked when its split is built.
    nimbus_scene::memory::check(
        n as u128 * std::mem::size_of::<CloudSpec>() as u128,
        "gen:N",
        &format!("the list of {n} clouds"),
    )
    .map_err(|e| err(e.to_string()))?;
    let mut tall = Vec::with_capacity(kinds.len());
    for k in kinds {
        if *k == "mixture" {
            tall.push(true);
            continue;
        }
        let kind: CloudKind = k
            .parse()
            .map_err(|e: nimbus_scene::FieldError| err(format!("{e}, or mixture")))?;
        tall.push(matches!(kind, CloudKind::Cumulus | CloudKind::Congestus));
    }
    let sizes = [48, 64, 80, 96];
    Ok((0..n)
        .map(|i| {
            let kind = kinds[i % kinds.len()];
            let nx = sizes[(i / kinds.len()) % 4];
            let res = if tall[i % kinds.len()] {
                [nx, nx * 3 / 4, nx]
            } else {
                [nx, (nx / 4).max(8), nx]
            };
            let s = mix64(seed ^ (i as u64).wrapping_mul(0x9e37_79b9));
            let u = (s >> 11) as f64 / (1u64 << 53) as f64;
            CloudSpec {
                name: format!("{kind}_{i:03}"),
                source: CloudSource::Generated {
                    kind: kind.into(),
                    seed: s % 1_000_000,
                    resolution: res,
                },
                density_scale: density[0] * (density[1] / density[0]).powf(u),
                split: split_of(i),
            }
        })
        .collect())
}

/// The clouds of a folder (.vol/.npy/.vdb, sorted); splits as for generated sets. The grids are
/// placed in a box 2 units wide with cubic voxels (`.npy` has no box of its own).
pub fn folder_set(dir: &Path, density_scale: f64) -> Result<Vec<CloudSpec>, DatagenError> {
    let err = |msg: String| DatagenError::Set {
        what: dir.display().to_string(),
        msg,
    };
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| err(e.to_string()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            // Hidden files (e.g. an interrupted write's `.name.partial-PID.vol`) are not clouds.
            !p.file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with('.'))
                && matches!(
                    p.extension().and_then(|e| e.to_str()),
                    Some("vol" | "npy" | "vdb")
                )
        })
        .collect();
    files.sort();
    if files.is_empty() {
        return Err(err("no .vol, .npy or .vdb files".into()));
    }
    Ok(files
        .into_iter()
        .enumerate()
        .map(|(i, p)| CloudSpec {
            name: p
                .file_stem()
                .unwrap_or_default()
                .to_string_lossy()
                .into_owned(),
            source: CloudSource::File { path: p },
            density_scale,
            split: split_of(i),
        })
        .collect())
}

/// Builds the volume of a cloud.
pub fn build_volume(spec: &CloudSpec) -> Result<Volume, DatagenError> {
    let err = |msg: String| DatagenError::Cloud {
        cloud: spec.name.clone(),
        msg,
    };
    let grid = match &spec.source {
        CloudSource::Generated {
            kind,
            seed,
            resolution,
        } => {
            let make = |k: CloudKind, s: u64| {
                generate::generate(k, s, *resolution).map_err(|e| err(e.to_string()))
            };
            if kind == "mixture" {
                let a = make(CloudKind::Cumulus, *seed)?;
                let b = make(CloudKind::Stratus, *seed + 1000)?;
                let (a, b) = (a.dense(), b.dense());
                let (a, b) = (
                    a.map_err(|e| err(e.to_string()))?,
                    b.map_err(|e| err(e.to_string()))?,
                );
                let data = a
                    .iter()
                    .zip(b.iter())
                    .map(|(x, y)| x.max(0.6 * y))
                    .collect();
                DensityGrid::new(*resolution, data).map_err(|e| err(e.to_string()))?
            } else {
                make(
                    kind.parse()
                        .map_err(|e: nimbus_scene::FieldError| err(e.to_string()))?,
                    *seed,
                )?
            }
        }
        CloudSource::File { path } => io::read_grid(path).map_err(|e| err(e.to_string()))?.grid,
    };
    let (lo, hi) = generate::default_aabb(grid.res());
    Volume::new(grid, Aabb::new(lo, hi).unwrap(), spec.density_scale)
        .map_err(|e| err(e.to_string()))
}

/// The cloud set named by `--clouds`: `gen:N` (the [`DEFAULT_KINDS`] in turn), `gen:N:KIND,…`
/// ([`generated_set_of`], density scales log-uniform in `density`), or a folder of
/// `.vol`/`.npy`/`.vdb` files ([`folder_set`], σ_t = `density_scale` × grid value).
pub fn cloud_set(
    spec: &str,
    seed: u64,
    density: [f64; 2],
    density_scale: f64,
) -> Result<Vec<CloudSpec>, DatagenError> {
    let Some(gen_spec) = spec.strip_prefix("gen:") else {
        return folder_set(Path::new(spec), density_scale);
    };
    let (n, kinds) = match gen_spec.split_once(':') {
        Some((n, kinds)) => (n, kinds.split(',').map(str::trim).collect()),
        None => (gen_spec, DEFAULT_KINDS.to_vec()),
    };
    let err = |msg: String| DatagenError::Set {
        what: format!("--clouds {spec}"),
        msg,
    };
    let n: usize = n
        .parse()
        .map_err(|e| err(format!("expected gen:N or gen:N:KIND,… ({e})")))?;
    if n == 0 {
        return Err(err("gen:N needs N ≥ 1".into()));
    }
    generated_set_of(n, seed, density, &kinds)
}
