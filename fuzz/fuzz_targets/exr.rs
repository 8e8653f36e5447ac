//! The EXR reader (references, environment maps) on arbitrary bytes: an error or an image,
//! never a panic, hang or unbounded allocation. The `exr` crate decodes; a panic of its
//! decoders becomes an error (`nimbus_scene::contain`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // A damaged data window can claim a huge image: refused over 16 MiB before allocation.
    nimbus_scene::memory::set_budget(16 << 20);
    let _ = nimbus_scene::Image::parse_exr(
        std::io::Cursor::new(data),
        std::path::Path::new("fuzz.exr"),
    );
});
