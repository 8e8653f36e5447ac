//! # nimbus-rpnn
//!
//! Radiance-predicting neural networks (Kallweit et al. 2017): the Gaussian density pyramid and
//! the hierarchical stencil descriptor (§4.2) on the CPU ([`descriptor`]) and the GPU
//! ([`gpu`]); training records ([`datagen`]), sharded data sets ([`dataset`]) and sets assembled from
//! parts written on several machines ([`shards`]).

pub mod clouds;
pub mod datagen;
pub mod dataset;
pub mod descriptor;
pub mod gpu;
pub mod gpu_mlp;
pub mod model;
pub mod ort_backend;
pub mod pyramid;
pub mod render;
mod shard_files;
pub mod shards;
pub mod sky;

pub use descriptor::{Config, DESCRIPTOR_LEN, LEVELS, POINTS, descriptor, descriptors};
pub use pyramid::{Pyramid, PyramidError};
