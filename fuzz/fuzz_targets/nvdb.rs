//! The .nvdb reader on arbitrary bytes: an error or a valid grid, never a panic, crash, hang or
//! unbounded allocation.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(
    init: {
        // Dense grids beyond this are refused by the memory budget, as `--max-memory` would.
        nimbus_scene::memory::set_budget(256 << 20);
    },
    |data: &[u8]| {
        let _ = nimbus_scene::io::nvdb::parse(data, std::path::Path::new("fuzz.nvdb"));
    }
);
