//! The nimbus-scene integration tests, one file per topic, compiled as one test binary: the
//! dependencies (GPU, ONNX) are linked into one executable instead of one per file.

mod exr;
mod exr_pattern;
mod formats;
mod vdb;
