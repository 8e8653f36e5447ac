//! A 40×24 RGB test pattern in every compression the `exr` crate writes, half and float, in
//! memory: the files of `tests/exr.rs`, and (`examples/exr_codecs.rs`) the seeds of the `exr`
//! fuzz target.

use std::io::Cursor;

use exr::prelude::*;

/// The compressions of OpenEXR 3 that the `exr` crate writes (DWAA/DWAB it does not).
pub const CODECS: [(&str, Compression); 8] = [
    ("none", Compression::Uncompressed),
    ("rle", Compression::RLE),
    ("zips", Compression::ZIP1),
    ("zip", Compression::ZIP16),
    ("piz", Compression::PIZ),
    ("pxr24", Compression::PXR24),
    ("b44", Compression::B44),
    ("b44a", Compression::B44A),
];

/// A 40×24 RGB image, half or float, with a smooth ramp and a few sharp edges so that every
/// codec has something to encode; written in memory.
pub fn encoded(compression: Compression, half: bool) -> (Vec<u8>, Vec<[f32; 3]>) {
    let (w, h) = (40usize, 24usize);
    let px = |x: usize, y: usize| {
        let edge = if (x / 7 + y / 5).is_multiple_of(2) {
            4.0
        } else {
            0.25
        };
        [
            0.01 + x as f32 * 0.05 * edge,
            0.5 + y as f32 * 0.1,
            edge * (1.0 + ((x * y) % 3) as f32),
        ]
    };
    let want: Vec<[f32; 3]> = (0..h).flat_map(|y| (0..w).map(move |x| px(x, y))).collect();
    let channel = |name: &str, k: usize| {
        let v: Vec<f32> = want.iter().map(|p| p[k]).collect();
        let samples = if half {
            FlatSamples::F16(v.iter().map(|x| f16::from_f32(*x)).collect())
        } else {
            FlatSamples::F32(v)
        };
        AnyChannel::new(name, samples)
    };
    let layer = Layer::new(
        (w, h),
        LayerAttributes::named("rgb"),
        Encoding {
            compression,
            ..Encoding::default()
        },
        AnyChannels::sort(vec![channel("R", 0), channel("G", 1), channel("B", 2)].into()),
    );
    let mut bytes = Cursor::new(Vec::new());
    exr::image::Image::from_layer(layer)
        .write()
        .non_parallel()
        .to_buffered(&mut bytes)
        .unwrap();
    (bytes.into_inner(), want)
}
