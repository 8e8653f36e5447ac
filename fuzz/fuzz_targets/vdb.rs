//! The .vdb reader on arbitrary bytes: an error or a valid grid, never a crash, hang or
//! unbounded allocation. The third-party OpenVDB decoder (vdb-rs) panics on malformed input;
//! `io::vdb::parse` catches those panics and reports them as errors naming the file, so the
//! fuzzer's abort-on-panic hook is replaced by a silent one: a panic that escapes the reader
//! still aborts (it cannot unwind out of the fuzz target), a caught one is an error.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(
    init: {
        std::panic::set_hook(Box::new(|_| {}));
    },
    |data: &[u8]| {
        let _ = nimbus_scene::io::vdb::parse(data, std::path::Path::new("fuzz.vdb"));
    }
);
