//! The training-data pipeline (Kallweit 2017 §5.1): everything that makes records for the
//! bundled PyTorch script, none of it needed to render.
//!
//! - [`clouds`]: the clouds of a set (generated `gen:N`, or a folder) with their splits;
//! - [`datagen`]: one record — a shading configuration, its descriptor and the indirect
//!   radiance L_i path-traced to a stated confidence (the sun's, and with `--sky-transfer` the
//!   sky's spherical-harmonic transfer from the same paths);
//! - [`dataset`]: a set on disk — sharded `.npy` records, deterministic resume;
//! - [`manifest`]: what a set says of itself (`manifest.json`) and the parts it is written in;
//! - [`shards`]: sets assembled from parts written on several machines (`datagen --part`,
//!   `datagen --merge`);
//! - `shard_files`: the file-level helpers the two share (locks, row counts, SHA-256 sidecars).

pub mod clouds;
pub mod datagen;
pub mod dataset;
mod in_memory;
pub mod manifest;
mod shard_files;
pub(crate) use shard_files::sha256_file;
pub mod shards;
