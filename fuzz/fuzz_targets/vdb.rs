//! The .vdb reader on arbitrary bytes: an error or a valid grid, never a panic, hang or
//! unbounded allocation.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = nimbus_scene::io::vdb::parse(data, std::path::Path::new("fuzz.vdb"));
});
