//! The nimbus-photon integration tests, one file per topic, compiled as one test binary: the
//! dependencies (GPU, ONNX) are linked into one executable instead of one per file.

mod buffers;
mod common;
mod gather;
mod gpu;
mod scale;
mod temporal;
mod view;
