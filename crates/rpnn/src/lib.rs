//! # nimbus-rpnn
//!
//! Radiance-predicting neural networks (Kallweit et al. 2017): the Gaussian density pyramid and
//! the hierarchical stencil descriptor (§4.2) on the CPU ([`descriptor`](mod@descriptor)) and the GPU
//! ([`gpu`]); the network ([`model`], [`ort_backend`], [`gpu_mlp`]) and rendering with it
//! ([`render`], the sky head's basis in [`sky`]); the training-data pipeline — records, sharded
//! data sets, sets assembled from parts — in [`data`].

pub mod data;
pub mod descriptor;
pub mod gpu;
pub mod gpu_mlp;
pub mod gpu_sample;
pub mod model;
pub mod ort_backend;
pub mod pyramid;
pub mod render;
pub mod sky;

pub use descriptor::{Config, DESCRIPTOR_LEN, LEVELS, POINTS, descriptor, descriptors};
pub use pyramid::{Pyramid, PyramidError};

/// Reads an optional text file (a model card, a data set's `settings.json` or `manifest.json`):
/// `Ok(None)` only when nothing at all is at `path`. Anything that is there — a pipe, a device,
/// a folder, a dangling or looping link, a file over the memory budget — is an error naming it
/// ([`nimbus_scene::fsio::read_to_string`]), never taken for an absent file.
pub(crate) fn read_optional_text(path: &std::path::Path) -> nimbus_scene::Result<Option<String>> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        _ => nimbus_scene::fsio::read_to_string(path).map(Some),
    }
}
