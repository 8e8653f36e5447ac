//! The nimbus-cli integration tests, one file per topic, compiled as one test binary: the
//! dependencies (GPU, ONNX) are linked into one executable instead of one per file.

mod bad_inputs;
mod budget;
mod cli;
mod common;
mod device;
mod eval;
mod flags;
mod interface;
mod secondary_files;
mod secondary_rpnn;
mod view;
mod volumes;
