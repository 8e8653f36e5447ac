//! The nimbus-tests integration tests, one file per topic, compiled as one test binary: the
//! dependencies (GPU, ONNX) are linked into one executable instead of one per file.

mod imports;
mod layout;
mod pm_angular;
mod pm_vs_pt;
mod refs;
mod test_script;
