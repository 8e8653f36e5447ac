//! The nimbus-rpnn integration tests, one file per topic, compiled as one test binary: the
//! dependencies (GPU, ONNX) are linked into one executable instead of one per file.

mod datagen;
mod descriptor;
mod files;
mod gpu_sample;
mod model;
mod model_damage;
mod precision;
mod render;
mod sky;
