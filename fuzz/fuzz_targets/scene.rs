//! The scene parser on arbitrary text: an error naming the field, or a scene.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    if let Ok(text) = std::str::from_utf8(data) {
        // Relative volume paths resolve inside an empty folder: nothing outside is read.
        let base = std::env::temp_dir().join("nimbus-fuzz-empty");
        let _ = std::fs::create_dir_all(&base);
        let _ = nimbus_scene::Scene::from_toml_str(text, &base, std::path::Path::new("fuzz.toml"));
    }
});
