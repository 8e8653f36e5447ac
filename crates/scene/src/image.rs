//! Linear float RGB images: EXR output (RGB plus an optional per-pixel variance channel), EXR
//! input, and tone-mapped PNG previews.
//!
//! PNG tone curve (the one the Mitsuba reference previews use): `sRGB(clamp(exposure × L, 0, 1))`
//! per channel, with the standard sRGB transfer function. `exposure` defaults to the value that
//! maps the 99th-percentile luminance of the non-black pixels to 0.9.

use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

use crate::error::{Error, Result};

/// A linear RGB float image, row 0 at the top.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    /// RGB triples, row-major.
    pub pixels: Vec<[f32; 3]>,
}

impl Image {
    pub fn new(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            pixels: vec![[0.0; 3]; width * height],
        }
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [f32; 3] {
        self.pixels[y * self.width + x]
    }

    /// Luminance used throughout Nimbus' metrics: the mean of R, G, B (as in the reference
    /// comparison script).
    #[inline]
    pub fn lum(&self, x: usize, y: usize) -> f64 {
        let p = self.get(x, y);
        (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0
    }

    /// An image about to be written to `path` must be finite: NaN or infinite pixels are an
    /// error with their count and the first one, and nothing is written.
    pub fn check_finite(&self, path: &Path) -> Result<()> {
        let bad = |p: &[f32; 3]| p.iter().any(|v| !v.is_finite());
        let n = self.pixels.iter().filter(|p| bad(p)).count();
        if let Some(i) = self.pixels.iter().position(bad) {
            return Err(Error::invalid(
                path,
                format!("pixel[{},{}]", i % self.width, i / self.width),
                format!(
                    "{n} of {} pixels are NaN or infinite (this one: {:?}): a scene value overflows 32-bit floats or the estimator diverged; nothing was written",
                    self.pixels.len(),
                    self.pixels[i]
                ),
            ));
        }
        Ok(())
    }

    /// Writes a float32 EXR with channels R, G, B and, when given, `variance` (the estimated
    /// variance of each pixel's mean luminance).
    pub fn write_exr(&self, path: impl AsRef<Path>, variance: Option<&[f32]>) -> Result<()> {
        use exr::prelude::{
            AnyChannel, AnyChannels, Encoding, FlatSamples, Layer, LayerAttributes, WritableImage,
        };
        let path = path.as_ref();
        self.check_finite(path)?;
        let (w, h) = (self.width, self.height);
        let chan = |name: &str, f: &dyn Fn(usize) -> f32| {
            AnyChannel::new(name, FlatSamples::F32((0..w * h).map(f).collect()))
        };
        let mut list = vec![
            chan("R", &|i| self.pixels[i][0]),
            chan("G", &|i| self.pixels[i][1]),
            chan("B", &|i| self.pixels[i][2]),
        ];
        if let Some(v) = variance {
            assert_eq!(v.len(), w * h);
            list.push(chan("variance", &|i| v[i]));
        }
        let layer = Layer::new(
            (w, h),
            LayerAttributes::named("nimbus"),
            Encoding::FAST_LOSSLESS,
            AnyChannels::sort(list.into()),
        );
        crate::io::write_atomically(path, |tmp| {
            exr::image::Image::from_layer(layer)
                .write()
                .to_file(tmp)
                .map_err(|e| Error::parse(path, format!("cannot write EXR: {e}")))
        })
    }

    /// Reads the RGB channels (float or half) of the first layer of an EXR that has them; a
    /// file without them (Y or alpha alone) or with integer ones is an error naming what it has.
    pub fn read_exr(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        // The data window is checked against the budget before the pixels are allocated.
        let (file, _) = crate::fsio::open(path, crate::fsio::Hold::Streamed)?;
        Self::parse_exr(std::io::BufReader::new(file), path)
    }

    /// [`Image::read_exr`] on a reader (a file, or bytes in memory); `path` only names the
    /// input in errors. Malformed input is an error, never a panic: the reader's own panics
    /// (the `exr` crate's, on some damaged files) are caught and reported as errors.
    pub fn parse_exr(mut reader: impl Read + Seek, path: &Path) -> Result<Self> {
        // The data window sizes the image: checked against the memory budget before the
        // pixels are allocated (a 10 kB file can claim 10⁶ × 10⁶ pixels). Every part counts:
        // the reader takes the first part with RGB channels, which need not be the first.
        let damaged = |e: String| {
            Error::parse(
                path,
                format!("cannot read EXR: the decoder failed on damaged data ({e})"),
            )
        };
        let meta =
            crate::contain::contain(|| exr::meta::MetaData::read_from_buffered(&mut reader, false))
                .map_err(damaged)?
                .map_err(|e| Error::parse(path, format!("cannot read EXR header: {e}")))?;
        for header in &meta.headers {
            let size = header.layer_size;
            crate::memory::check(
                size.width() as u128 * size.height() as u128 * 12,
                "dataWindow",
                &format!(
                    "a {}×{} part read as RGB floats",
                    size.width(),
                    size.height()
                ),
            )
            .map_err(|e| e.at(path))?;
        }
        // Said before the reader's own words ("no layer matched", "invalid decompressed data").
        let is = |n: &exr::meta::attribute::Text, c: &str| {
            let n = n.to_string();
            n == c || n.ends_with(&format!(".{c}"))
        };
        let rgb = meta.headers.iter().find(|h| {
            ["R", "G", "B"]
                .iter()
                .all(|c| h.channels.list.iter().any(|ch| is(&ch.name, c)))
        });
        let Some(rgb) = rgb else {
            let has: Vec<String> = meta
                .headers
                .iter()
                .flat_map(|h| h.channels.list.iter().map(|ch| ch.name.to_string()))
                .collect();
            return Err(Error::invalid(
                path,
                "channels",
                format!(
                    "needs R, G and B channels (float or half); the file has {}",
                    if has.is_empty() {
                        "none".to_string()
                    } else {
                        has.join(", ")
                    }
                ),
            ));
        };
        if let Some(ch) = rgb.channels.list.iter().find(|ch| {
            ["R", "G", "B"].iter().any(|c| is(&ch.name, c))
                && ch.sample_type == exr::meta::attribute::SampleType::U32
        }) {
            return Err(Error::invalid(
                path,
                format!("channel {}", ch.name),
                "holds 32-bit integers; radiance needs float or half",
            ));
        }
        reader
            .seek(SeekFrom::Start(0))
            .map_err(|e| Error::io(path, e))?;
        // Blocks are decoded on this thread (`non_parallel`), where a decoder's panic can be
        // caught: one on the crate's own decoder threads aborts the process.
        use exr::prelude::{ReadChannels as _, ReadLayers as _};
        let img = crate::contain::contain(|| {
            exr::prelude::read()
                .no_deep_data()
                .largest_resolution_level()
                .rgba_channels(
                    |res, _| Image::new(res.width(), res.height()),
                    |img: &mut Image, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                        img.pixels[pos.y() * img.width + pos.x()] = [r, g, b];
                    },
                )
                .first_valid_layer()
                .all_attributes()
                .non_parallel()
                .from_buffered(reader)
        })
        .map_err(damaged)?
        .map_err(|e| Error::parse(path, format!("cannot read EXR: {e}")))?;
        let img = img.layer_data.channel_data.pixels;
        if let Some(i) = img
            .pixels
            .iter()
            .position(|p| p.iter().any(|v| !v.is_finite()))
        {
            return Err(Error::invalid(
                path,
                format!("pixel[{},{}]", i % img.width, i / img.width),
                "value is NaN or infinite",
            ));
        }
        Ok(img)
    }

    /// Bilinear resize (pixel centres aligned, clamp at the borders), e.g. to upscale a
    /// half-resolution render.
    pub fn resize_bilinear(&self, width: usize, height: usize) -> Image {
        let mut out = Image::new(width, height);
        let sx = self.width as f64 / width as f64;
        let sy = self.height as f64 / height as f64;
        for y in 0..height {
            let fy = ((y as f64 + 0.5) * sy - 0.5).clamp(0.0, (self.height - 1) as f64);
            let y0 = fy.floor() as usize;
            let y1 = (y0 + 1).min(self.height - 1);
            let ty = (fy - y0 as f64) as f32;
            for x in 0..width {
                let fx = ((x as f64 + 0.5) * sx - 0.5).clamp(0.0, (self.width - 1) as f64);
                let x0 = fx.floor() as usize;
                let x1 = (x0 + 1).min(self.width - 1);
                let tx = (fx - x0 as f64) as f32;
                let (a, b, c, d) = (
                    self.get(x0, y0),
                    self.get(x1, y0),
                    self.get(x0, y1),
                    self.get(x1, y1),
                );
                let mut px = [0.0f32; 3];
                for k in 0..3 {
                    let top = a[k] * (1.0 - tx) + b[k] * tx;
                    let bot = c[k] * (1.0 - tx) + d[k] * tx;
                    px[k] = top * (1.0 - ty) + bot * ty;
                }
                out.pixels[y * width + x] = px;
            }
        }
        out
    }

    /// Exposure that maps the 99th-percentile luminance of the non-black pixels to 0.9.
    pub fn auto_exposure(&self) -> f64 {
        let mut l: Vec<f64> = (0..self.pixels.len())
            .map(|i| self.lum(i % self.width, i / self.width))
            .filter(|v| *v > 0.0 && v.is_finite())
            .collect();
        if l.is_empty() {
            return 1.0;
        }
        l.sort_by(f64::total_cmp);
        let p = l[((l.len() - 1) as f64 * 0.99) as usize];
        0.9 / p
    }

    /// 8-bit sRGB preview: `sRGB(clamp(exposure × L, 0, 1))`.
    pub fn to_srgb8(&self, exposure: f64) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.pixels.len() * 3);
        for p in &self.pixels {
            for c in p {
                out.push((srgb_oetf((*c as f64 * exposure).clamp(0.0, 1.0)) * 255.0).round() as u8);
            }
        }
        out
    }

    pub fn write_png(&self, path: impl AsRef<Path>, exposure: f64) -> Result<()> {
        let path = path.as_ref();
        self.check_finite(path)?;
        let px = self.to_srgb8(exposure);
        crate::io::write_atomically(path, |tmp| {
            image::save_buffer(
                tmp,
                &px,
                self.width as u32,
                self.height as u32,
                image::ColorType::Rgb8,
            )
            .map_err(|e| Error::parse(path, format!("cannot write PNG: {e}")))
        })
    }
}

impl Image {
    /// Why the PNG at `exposure` would show nothing, if it would: every pixel black or every
    /// pixel white. A black EXR (no light reaches the camera: a sun below the atmosphere's
    /// horizon and no sky, say) is said apart from an exposure that clips.
    pub fn png_warning(&self, exposure: f64) -> Option<String> {
        let px = self.to_srgb8(exposure);
        if px.iter().all(|&v| v == 0) {
            if self.pixels.iter().all(|p| p.iter().all(|&c| c == 0.0)) {
                return Some(
                    "every pixel is black: no light reaches the camera (is the sun below the \
                     horizon of an atmosphere, or are sun and sky zero?)"
                        .into(),
                );
            }
            return Some(format!(
                "every pixel of the PNG is black at exposure {exposure:e} (the EXR holds the \
                 values)"
            ));
        }
        // Every lit pixel clipped (a black background stays black at any exposure).
        if px.iter().all(|&v| v == 0 || v == 255) {
            return Some(format!(
                "every pixel of the PNG is black or white at exposure {exposure:e}: the exposure \
                 clips (the EXR holds the values)"
            ));
        }
        None
    }
}

/// The sRGB transfer function (linear → encoded), input in [0, 1].
pub fn srgb_oetf(v: f64) -> f64 {
    if v <= 0.0031308 {
        12.92 * v
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_finite_images_are_not_written() {
        let dir = std::env::temp_dir().join(format!("nimbus-img-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut img = Image::new(4, 2);
        img.pixels[5] = [f32::NAN, 0.0, 0.0];
        img.pixels[6] = [f32::INFINITY, 1.0, 1.0];
        for path in [dir.join("bad.exr"), dir.join("bad.png")] {
            let e = if path.extension().unwrap() == "exr" {
                img.write_exr(&path, None)
            } else {
                img.write_png(&path, 1.0)
            }
            .unwrap_err()
            .to_string();
            assert!(
                e.contains("pixel[1,1]") && e.contains("2 of 8 pixels"),
                "{e}"
            );
            assert!(!path.exists());
        }
    }

    #[test]
    fn png_warnings() {
        let mut img = Image::new(2, 2);
        assert!(img.png_warning(1.0).unwrap().contains("no light reaches"));
        img.pixels[0] = [0.5, 0.5, 0.5];
        assert_eq!(img.png_warning(1.0), None);
        assert!(
            img.png_warning(1e-30)
                .unwrap()
                .contains("black at exposure")
        );
        for p in img.pixels.iter_mut() {
            *p = [0.5, 0.5, 0.5];
        }
        assert!(
            img.png_warning(1e308)
                .unwrap()
                .contains("white at exposure")
        );
    }

    /// EXRs without float RGB (luminance alone, alpha alone, integer channels) are refused,
    /// naming the channels the file has; the reader's own words said neither ("no layer in the
    /// image matched", "invalid: decompressed data").
    #[test]
    fn exr_without_float_rgb_is_refused_by_its_channels() {
        use exr::prelude::*;
        let dir = std::env::temp_dir().join(format!("nimbus-img-ch-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let write = |name: &str, channels: Vec<AnyChannel<FlatSamples>>| {
            let layer = Layer::new(
                (3, 2),
                LayerAttributes::default(),
                Encoding::FAST_LOSSLESS,
                AnyChannels::sort(channels.into()),
            );
            let path = dir.join(name);
            exr::image::Image::from_layer(layer)
                .write()
                .to_file(&path)
                .unwrap();
            path
        };
        let f = |c: &str| AnyChannel::new(c, FlatSamples::F32(vec![0.5; 6]));
        let u = |c: &str| AnyChannel::new(c, FlatSamples::U32(vec![1; 6]));
        for (name, channels, says) in [
            (
                "y.exr",
                vec![f("Y")],
                "needs R, G and B channels (float or half); the file has Y",
            ),
            ("a.exr", vec![f("A")], "the file has A"),
            ("u32.exr", vec![u("B"), u("G"), u("R")], "32-bit integers"),
        ] {
            let e = super::Image::read_exr(write(name, channels))
                .unwrap_err()
                .to_string();
            assert!(e.contains(name) && e.contains(says), "{name}: {e}");
        }
        // Float RGB with alpha reads.
        let ok = write("rgba.exr", vec![f("A"), f("B"), f("G"), f("R")]);
        assert_eq!(super::Image::read_exr(ok).unwrap().pixels[5], [0.5; 3]);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn exr_round_trip() {
        let dir = std::env::temp_dir().join(format!("nimbus-img-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut img = Image::new(3, 2);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = [i as f32, 0.5 * i as f32, 0.25];
        }
        let path = dir.join("a.exr");
        img.write_exr(&path, Some(&[1.0; 6])).unwrap();
        assert_eq!(Image::read_exr(&path).unwrap(), img);
        img.write_png(dir.join("a.png"), img.auto_exposure())
            .unwrap();
        assert!(Image::read_exr(dir.join("a.png")).is_err());
        assert!((srgb_oetf(1.0) - 1.0).abs() < 1e-12);
        // A write that cannot complete (the target is a folder: the final rename fails) is an
        // error naming the path and leaves neither a file nor a temporary behind.
        let folder = dir.join("taken.png");
        std::fs::create_dir_all(&folder).unwrap();
        let e = img.write_png(&folder, 1.0).unwrap_err().to_string();
        assert!(e.contains("taken.png"), "{e}");
        let e = img
            .write_exr(dir.join("no/such/dir/x.exr"), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("x.exr"), "{e}");
        let leftovers: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().contains(".partial-"))
            .collect();
        assert!(leftovers.is_empty(), "{leftovers:?}");
        // Resizing a constant image keeps it constant; 2× up then down returns the original
        // for a linear ramp away from the borders.
        let up = img.resize_bilinear(6, 4);
        assert_eq!((up.width, up.height), (6, 4));
        assert!(up.pixels.iter().all(|p| (p[2] - 0.25).abs() < 1e-6));
    }
}
