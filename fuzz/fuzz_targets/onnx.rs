//! The ONNX reader on arbitrary bytes: a model that matches the RPNN architecture, or an error.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = nimbus_rpnn::model::Rpnn::from_bytes(data);
});
