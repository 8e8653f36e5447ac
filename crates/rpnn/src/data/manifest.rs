//! What a record set says of itself: `manifest.json` (format, descriptor layout, metadata
//! columns, settings, clouds, shards with their SHA-256) and the parts a set is split into when
//! several machines write it (`datagen --shard K/N`). The files themselves: [`super::dataset`].

use std::path::Path;

use serde::Serialize;

use crate::data::clouds::CloudSpec;
use crate::data::datagen::DatagenError;
use crate::data::shard_files::{META_COLUMNS, write_text};
use crate::descriptor::DESCRIPTOR_LEN;

/// Part `index` (1-based) of `count` of a data set: the shards whose global index g satisfies
/// g mod count = index − 1.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct Part {
    pub index: usize,
    pub count: usize,
}

impl Part {
    /// Parses `K/N` with 1 ≤ K ≤ N.
    pub fn parse(s: &str) -> Result<Self, String> {
        let (k, n) = s
            .split_once('/')
            .ok_or_else(|| format!("`{s}`: expected K/N, e.g. 1/4"))?;
        let parse = |v: &str, what: &str| {
            v.trim()
                .parse::<usize>()
                .map_err(|e| format!("`{s}`: {what} `{v}` is not a whole number ({e})"))
        };
        let (index, count) = (parse(k, "K")?, parse(n, "N")?);
        if count == 0 || index == 0 || index > count {
            return Err(format!("`{s}`: needs 1 <= K <= N"));
        }
        Ok(Self { index, count })
    }

    /// Whether the shard with global index `g` belongs to this part.
    pub fn owns(&self, g: usize) -> bool {
        g % self.count == self.index - 1
    }
}

impl std::fmt::Display for Part {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// One shard of a manifest: its files (relative to the set's folder) and their SHA-256.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct ShardInfo {
    pub split: String,
    pub index: usize,
    pub records: usize,
    pub converged: usize,
    pub x: String,
    pub y: String,
    pub meta: String,
    /// Hex SHA-256 of the x, y and meta files.
    pub sha256: [String; 3],
}

/// The format written in `manifest.json`.
pub const FORMAT: &str = "nimbus-rpnn-records/2";
/// Layout of a descriptor row, as written in `manifest.json`.
pub const DESCRIPTOR_LAYOUT: &str = "level-major: [(k-1)*225 + p] = rho at stencil point p (p = ix + 5 iy + 25 iz) of level k = 1..10; [2250] = gamma (radians)";
/// Names of the sky-transfer columns that follow [`META_NAMES`] with
/// [`DatagenOptions::sky_transfer`](crate::data::dataset::DatagenOptions::sky_transfer): coefficient l² + l + m of `crate::sky`.
pub const SKY_META_NAMES: [&str; crate::sky::SH_COEFFS] = [
    "sky_sh_0",
    "sky_sh_1",
    "sky_sh_2",
    "sky_sh_3",
    "sky_sh_4",
    "sky_sh_5",
    "sky_sh_6",
    "sky_sh_7",
    "sky_sh_8",
    "sky_sh_9",
    "sky_sh_10",
    "sky_sh_11",
    "sky_sh_12",
    "sky_sh_13",
    "sky_sh_14",
    "sky_sh_15",
    "sky_sh_16",
    "sky_sh_17",
    "sky_sh_18",
    "sky_sh_19",
    "sky_sh_20",
    "sky_sh_21",
    "sky_sh_22",
    "sky_sh_23",
    "sky_sh_24",
];

/// Columns of a set's meta rows: [`META_COLUMNS`], and the sky's transfer after them.
pub fn meta_width(sky_transfer: bool) -> usize {
    META_COLUMNS
        + if sky_transfer {
            crate::sky::SH_COEFFS
        } else {
            0
        }
}

/// Names of the `_meta.npy` columns, as written in `manifest.json`.
pub const META_NAMES: [&str; META_COLUMNS] = [
    "cloud",
    "x",
    "y",
    "z",
    "view_x",
    "view_y",
    "view_z",
    "light_x",
    "light_y",
    "light_z",
    "samples",
    "converged",
    "rel_ci95",
    "target_variance",
    "light_weight",
];

#[derive(Debug, Clone, Serialize)]
pub(crate) struct Manifest<S: Serialize> {
    pub format: &'static str,
    pub descriptor_len: usize,
    pub descriptor_layout: &'static str,
    pub meta_columns: Vec<&'static str>,
    pub settings: S,
    pub clouds: Vec<CloudSpec>,
    pub shards: Vec<ShardInfo>,
    pub records: usize,
    pub converged: usize,
    pub convergence_rate: f64,
    pub seconds_this_run: f64,
    pub records_per_second_this_run: f64,
}

impl<S: Serialize> Manifest<S> {
    pub(crate) fn new(
        settings: S,
        clouds: Vec<CloudSpec>,
        shards: Vec<ShardInfo>,
        seconds: f64,
        computed: usize,
        sky_transfer: bool,
    ) -> Self {
        let records = shards.iter().map(|s| s.records).sum();
        let converged = shards.iter().map(|s| s.converged).sum();
        Self {
            format: FORMAT,
            descriptor_len: DESCRIPTOR_LEN,
            descriptor_layout: DESCRIPTOR_LAYOUT,
            meta_columns: META_NAMES
                .iter()
                .chain(if sky_transfer {
                    &SKY_META_NAMES[..]
                } else {
                    &[]
                })
                .copied()
                .collect(),
            settings,
            clouds,
            shards,
            records,
            converged,
            convergence_rate: if records > 0 {
                converged as f64 / records as f64
            } else {
                0.0
            },
            seconds_this_run: seconds,
            records_per_second_this_run: computed as f64 / seconds.max(1e-9),
        }
    }

    /// Writes `dir/manifest.json` whole or not at all.
    pub(crate) fn write(&self, dir: &Path) -> Result<(), DatagenError> {
        let path = dir.join("manifest.json");
        let text = serde_json::to_string_pretty(self).expect("a manifest serialises");
        write_text(&path, &text)
    }
}
