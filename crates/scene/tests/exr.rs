//! The EXR reader (references, environment maps) on damaged files: every compression the `exr`
//! crate writes, cut short and with bytes changed. An error naming the file or an image, never a
//! panic, an abort or a hang.

use std::io::Cursor;
use std::path::Path;

use exr::prelude::f16;
use nimbus_scene::image::Image as Rgb;
use proptest::prelude::*;
use proptest::test_runner::{Config, FileFailurePersistence, RngAlgorithm, TestRng, TestRunner};

use crate::exr_pattern::{CODECS, encoded};

fn parse(bytes: &[u8]) -> std::result::Result<Rgb, String> {
    Rgb::parse_exr(Cursor::new(bytes), Path::new("m.exr")).map_err(|e| e.to_string())
}

/// A fixed-seed runner: the same cases on every run, no failure files written.
fn runner(cases: u32, seed: u8) -> TestRunner {
    let config = Config {
        cases,
        failure_persistence: Some(Box::new(FileFailurePersistence::Off)),
        ..Config::default()
    };
    TestRunner::new_with_rng(
        config,
        TestRng::from_seed(RngAlgorithm::ChaCha, &[seed; 32]),
    )
}

#[test]
fn every_codec_reads_the_writers_values() {
    for (name, compression) in CODECS {
        for half in [false, true] {
            let (bytes, want) = encoded(compression, half);
            let img = parse(&bytes).unwrap_or_else(|e| panic!("{name} half={half}: {e}"));
            assert_eq!((img.width, img.height), (40, 24), "{name}");
            // Lossless codecs give the written values back to the bit (half → f32 is exact).
            // PXR24 rounds a float's mantissa to 15 bits (relative error ≤ 2^-16) and keeps
            // halves as they are. B44 is lossy on
            // halves (floats it stores as they are): each 4×4 block's differences share one
            // 6-bit step in the ordered half domain, and with this image's 48× contrast
            // inside a block the worst value is 10.8 % off. 12 % still catches a pixel or a
            // channel out of place: the edges every 7 and 5 pixels are jumps of 16×.
            let tol = match (name, half) {
                ("pxr24", false) => 2f32.powi(-16),
                ("b44" | "b44a", true) => 0.12,
                _ => 0.0,
            };
            for (i, (got, want)) in img.pixels.iter().zip(&want).enumerate() {
                for k in 0..3 {
                    let want = if half {
                        f16::from_f32(want[k]).to_f32()
                    } else {
                        want[k]
                    };
                    assert!(
                        (got[k] - want).abs() <= tol * want.abs(),
                        "{name} half={half} pixel {i} channel {k}: {} vs {want}",
                        got[k]
                    );
                }
            }
        }
    }
}

#[test]
fn cut_short_files_are_errors_that_name_the_file() {
    for (name, compression) in CODECS {
        let (bytes, _) = encoded(compression, true);
        // Every length below 400 bytes (the header), then every 13th.
        for cut in (0..bytes.len()).filter(|c| *c < 400 || c.is_multiple_of(13)) {
            let e = parse(&bytes[..cut]).expect_err("a prefix must fail");
            assert!(e.contains("m.exr"), "{name} cut {cut}: {e}");
        }
    }
}

/// Found by this test: the `exr` crate's B44 decoder subtracts with overflow on some damaged
/// half blocks (about 7 % of these B44 cases, in builds that check overflow; release builds
/// wrap and decode garbage, as any undetected damage does). On the crate's decoder threads
/// that panic aborted the process; the reader now decodes on its own thread and turns it into
/// an error ("the decoder failed on damaged data").
#[test]
fn damaged_files_are_errors_or_images_never_panics() {
    // A changed data window can claim a large image; the budget refuses one over 64 MiB
    // before its pixels are allocated (this test binary's process only).
    nimbus_scene::memory::set_budget(64 << 20);
    for (c, (name, compression)) in CODECS.into_iter().enumerate() {
        for half in [false, true] {
            let (bytes, _) = encoded(compression, half);
            let len = bytes.len();
            // One to four bytes replaced anywhere in the file: headers, offset table, chunks.
            let damage = prop::collection::vec((0..len, any::<u8>()), 1..=4);
            runner(500, c as u8 * 2 + half as u8)
                .run(&damage, |changes| {
                    let mut m = bytes.clone();
                    for (i, v) in changes {
                        m[i] = v;
                    }
                    match parse(&m) {
                        Ok(img) => prop_assert!(img.pixels.iter().flatten().all(|v| v.is_finite())),
                        Err(e) => prop_assert!(e.contains("m.exr"), "{}", e),
                    }
                    Ok(())
                })
                .unwrap_or_else(|e| panic!("{name} half={half}: {e}"));
        }
    }
}
