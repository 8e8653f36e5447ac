//! The .vdb reader on arbitrary bytes: an error or a valid grid, never a panic, crash, hang or
//! unbounded allocation. The reader is our own (`io::vdb`): any panic is a finding.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(
    init: {
        // Dense grids beyond 16 MiB are refused by the memory budget, as `--max-memory 16M` would
        // (larger ones only zero-fill more memory per run).
        nimbus_scene::memory::set_budget(16 << 20);
    },
    |data: &[u8]| {
        let _ = nimbus_scene::io::vdb::parse(data, std::path::Path::new("fuzz.vdb"));
    }
);
