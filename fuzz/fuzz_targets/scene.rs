//! The scene parser on arbitrary text: an error naming the field, or a scene.
//!
//! Generated clouds larger than 64³ voxels are skipped: generating them is legitimate work
//! (the demo cloud, 128×96×128, takes over 10 s in the instrumented build) that would only
//! slow the search; the generator's own size checks have unit tests.
#![no_main]

use libfuzzer_sys::fuzz_target;

fn generated_voxels(text: &str) -> u64 {
    let Ok(v) = text.parse::<toml::Table>() else {
        return 0;
    };
    let res = v
        .get("volume")
        .and_then(|v| v.get("generator"))
        .and_then(|g| g.get("resolution"))
        .and_then(|r| r.as_array());
    res.map_or(0, |r| {
        r.iter()
            .map(|x| x.as_integer().unwrap_or(0).clamp(0, 1 << 20) as u64)
            .product()
    })
}

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        if generated_voxels(text) > 64 * 64 * 64 {
            return;
        }
        // Relative volume paths resolve inside an empty folder: nothing outside is read.
        let base = std::env::temp_dir().join("nimbus-fuzz-empty");
        let _ = std::fs::create_dir_all(&base);
        let _ = nimbus_scene::Scene::from_toml_str(text, &base, std::path::Path::new("fuzz.toml"));
    }
});
