//! Writes the EXR test pattern of `tests/exr.rs` in every compression, half and float, into a
//! folder: the seeds of the `exr` fuzz target (`fuzz/seed.sh`).
//!
//!     cargo run -p nimbus-scene --example exr_codecs -- fuzz/corpus/exr

#[path = "../tests/exr_pattern.rs"]
mod exr_pattern;

fn main() -> std::io::Result<()> {
    let dir = std::path::PathBuf::from(std::env::args().nth(1).unwrap_or_else(|| ".".into()));
    std::fs::create_dir_all(&dir)?;
    for (name, compression) in exr_pattern::CODECS {
        for (half, kind) in [(false, "f32"), (true, "f16")] {
            let (bytes, _) = exr_pattern::encoded(compression, half);
            std::fs::write(dir.join(format!("{name}_{kind}.exr")), bytes)?;
        }
    }
    Ok(())
}
