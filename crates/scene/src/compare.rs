//! Image error metrics, identical in definition to `shared/refs/compare.py` (luminance = mean of
//! R, G, B; cloud pixels from the reference's optical-depth mask τ ≥ 0.1, or, without one,
//! reference luminance > 10⁻³ × max).

use std::path::Path;

use crate::{Image, Result};

/// Errors of a test image against a reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Metrics {
    pub cloud_pixels: usize,
    /// RMSE over all pixels and channels.
    pub rmse_rgb: f64,
    /// RMSE(lum) / mean(lum_ref) over cloud pixels.
    pub rel_rmse_cloud: f64,
    /// The same after averaging 4×4 blocks lying fully in the cloud (exposes bias under noise).
    pub rel_rmse_cloud_4x4: f64,
    /// mean(lum_test) / mean(lum_ref) over cloud pixels.
    pub mean_lum_ratio: f64,
    /// Number of NaN or infinite test values.
    pub nonfinite: usize,
}

/// Cloud mask from a reference optical-depth array (`<case>_tau.npy`).
pub fn tau_mask(path: &Path, width: usize, height: usize) -> Result<Vec<bool>> {
    let (shape, data) = crate::io::npy::read_array(path)?;
    if shape != [height, width] {
        return Err(crate::Error::invalid(
            path,
            "header.shape",
            format!("expected [{height}, {width}], found {shape:?}"),
        ));
    }
    Ok(data.iter().map(|&t| t >= 0.1).collect())
}

fn block_means(v: &[f64], w: usize, h: usize) -> (Vec<f64>, usize, usize) {
    let (bw, bh) = (w / 4, h / 4);
    let mut out = vec![0.0; bw * bh];
    for by in 0..bh {
        for bx in 0..bw {
            let mut s = 0.0;
            for y in 0..4 {
                for x in 0..4 {
                    s += v[(by * 4 + y) * w + bx * 4 + x];
                }
            }
            out[by * bw + bx] = s / 16.0;
        }
    }
    (out, bw, bh)
}

/// Computes the metrics; `mask` defaults to reference luminance > 10⁻³ × max.
pub fn compare(test: &Image, reference: &Image, mask: Option<&[bool]>) -> Metrics {
    assert_eq!(
        (test.width, test.height),
        (reference.width, reference.height)
    );
    let (w, h) = (test.width, test.height);
    let n = w * h;
    let mut nonfinite = 0;
    let lum = |img: &Image, count: &mut usize| -> Vec<f64> {
        img.pixels
            .iter()
            .map(|p| {
                let v: Vec<f64> = p
                    .iter()
                    .map(|&c| {
                        if c.is_finite() {
                            c as f64
                        } else {
                            *count += 1;
                            0.0
                        }
                    })
                    .collect();
                (v[0] + v[1] + v[2]) / 3.0
            })
            .collect()
    };
    let lt = lum(test, &mut nonfinite);
    let mut dummy = 0;
    let lr = lum(reference, &mut dummy);
    let default_mask: Vec<bool>;
    let mask = match mask {
        Some(m) => m,
        None => {
            let max = lr.iter().cloned().fold(0.0, f64::max);
            default_mask = lr.iter().map(|&v| v > 1e-3 * max).collect();
            &default_mask
        }
    };
    let mut se_rgb = 0.0;
    for (a, b) in test.pixels.iter().zip(&reference.pixels) {
        for c in 0..3 {
            let ta = if a[c].is_finite() { a[c] as f64 } else { 0.0 };
            se_rgb += (ta - b[c] as f64).powi(2);
        }
    }
    let idx: Vec<usize> = (0..n).filter(|&i| mask[i]).collect();
    let cloud = idx.len().max(1) as f64;
    let mref = idx.iter().map(|&i| lr[i]).sum::<f64>() / cloud;
    let mtest = idx.iter().map(|&i| lt[i]).sum::<f64>() / cloud;
    let se = idx.iter().map(|&i| (lt[i] - lr[i]).powi(2)).sum::<f64>() / cloud;
    let maskf: Vec<f64> = mask.iter().map(|&m| m as u8 as f64).collect();
    let (bm, _, _) = block_means(&maskf, w, h);
    let (bt, _, _) = block_means(&lt, w, h);
    let (br, _, _) = block_means(&lr, w, h);
    let full: Vec<usize> = (0..bm.len()).filter(|&i| bm[i] > 0.999).collect();
    let rel4 = if full.is_empty() {
        f64::NAN
    } else {
        let k = full.len() as f64;
        let se4 = full.iter().map(|&i| (bt[i] - br[i]).powi(2)).sum::<f64>() / k;
        let m4 = full.iter().map(|&i| br[i]).sum::<f64>() / k;
        se4.sqrt() / m4
    };
    Metrics {
        cloud_pixels: idx.len(),
        rmse_rgb: (se_rgb / (3 * n) as f64).sqrt(),
        rel_rmse_cloud: se.sqrt() / mref,
        rel_rmse_cloud_4x4: rel4,
        mean_lum_ratio: mtest / mref,
        nonfinite,
    }
}

/// The signed relative difference (test − ref) / max(ref, 0.05 · mean ref over cloud pixels)
/// in false colour (blue: test darker, white: equal, red: test brighter; saturated at
/// ±`range`), pixels outside the cloud mask dimmed to 35 %. The values are display-referred,
/// stored pre-linearised so that [`Image::write_png`] with exposure 1 reproduces them.
pub fn diff_false_colour(
    test: &Image,
    reference: &Image,
    mask: Option<&[bool]>,
    range: f64,
) -> Image {
    let (w, h) = (reference.width, reference.height);
    let lum = |img: &Image, i: usize| {
        let p = img.pixels[i];
        (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0
    };
    let default_mask: Vec<bool>;
    let mask = match mask {
        Some(m) => m,
        None => {
            let max = (0..w * h).map(|i| lum(reference, i)).fold(0.0, f64::max);
            default_mask = (0..w * h).map(|i| lum(reference, i) > 1e-3 * max).collect();
            &default_mask
        }
    };
    let cloud: Vec<usize> = (0..w * h).filter(|&i| mask[i]).collect();
    let mref = cloud.iter().map(|&i| lum(reference, i)).sum::<f64>() / cloud.len().max(1) as f64;
    // Invert the sRGB transfer function so write_png's curve gives back the display value.
    let linear = |v: f64| {
        let v = v.clamp(0.0, 1.0);
        if v <= 0.04045 {
            v / 12.92
        } else {
            ((v + 0.055) / 1.055).powf(2.4)
        }
    };
    let mut out = Image::new(w, h);
    for (i, px) in out.pixels.iter_mut().enumerate() {
        let t = lum(test, i);
        let t = if t.is_finite() { t } else { f64::INFINITY };
        let rel = (t - lum(reference, i)) / lum(reference, i).max(0.05 * mref).max(1e-30);
        let t = (rel / range).clamp(-1.0, 1.0);
        let (white, red, blue) = ([1.0, 1.0, 1.0], [0.80, 0.05, 0.05], [0.05, 0.20, 0.85]);
        let target = if t >= 0.0 { red } else { blue };
        let a = t.abs();
        let dim = if mask[i] { 1.0 } else { 0.35 };
        let mut c = [0.0f32; 3];
        for k in 0..3 {
            c[k] = linear(dim * (white[k] + a * (target[k] - white[k]))) as f32;
        }
        *px = c;
    }
    out
}

/// The three-panel comparison image of `shared/refs/compare.py`: reference | test |
/// [`diff_false_colour`]. The first two panels are linear radiance times `exposure` (write with
/// exposure 1 and the sRGB curve of [`Image::write_png`]). Panels are separated by 2 white
/// columns.
pub fn diff_panels(
    test: &Image,
    reference: &Image,
    mask: Option<&[bool]>,
    range: f64,
    exposure: f64,
) -> Image {
    let (w, h) = (reference.width, reference.height);
    let diff = diff_false_colour(test, reference, mask, range);
    let mut out = Image::new(3 * w + 4, h);
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let o = y * out.width;
            out.pixels[o + x] = reference.pixels[i].map(|c| (c as f64 * exposure) as f32);
            out.pixels[o + w + 2 + x] = test.pixels[i].map(|c| (c as f64 * exposure) as f32);
            out.pixels[o + 2 * w + 4 + x] = diff.pixels[i];
        }
        for k in [w, w + 1, 2 * w + 2, 2 * w + 3] {
            out.pixels[y * out.width + k] = [1.0; 3];
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn metrics_of_scaled_image() {
        let mut r = Image::new(8, 8);
        for (i, p) in r.pixels.iter_mut().enumerate() {
            *p = [1.0 + i as f32, 1.0 + i as f32, 1.0 + i as f32];
        }
        let mut t = r.clone();
        t.pixels
            .iter_mut()
            .for_each(|p| p.iter_mut().for_each(|c| *c *= 1.1));
        let m = compare(&t, &r, None);
        assert_eq!(m.cloud_pixels, 64);
        assert!((m.mean_lum_ratio - 1.1).abs() < 1e-6);
        assert!((m.rel_rmse_cloud_4x4 - 0.1 * rms_over_mean(&r)).abs() < 1e-3);
        t.pixels[0][0] = f32::NAN;
        assert_eq!(compare(&t, &r, None).nonfinite, 1);
        // Diff panels: equal images give a white third panel; a brighter test is red.
        let p = diff_panels(&r, &r, None, 0.2, 1.0);
        assert_eq!((p.width, p.height), (28, 8));
        assert!(
            p.pixels[2 * 8 + 4..3 * 8 + 4]
                .iter()
                .all(|c| c.iter().all(|v| (v - 1.0).abs() < 1e-6))
        );
        let mut bright = r.clone();
        bright
            .pixels
            .iter_mut()
            .for_each(|p| p.iter_mut().for_each(|c| *c *= 1.5));
        let p = diff_panels(&bright, &r, None, 0.2, 1.0);
        let c = p.pixels[2 * 8 + 4];
        assert!(c[0] > 0.5 && c[2] < 0.1, "{c:?}");
    }

    fn rms_over_mean(r: &Image) -> f64 {
        let (bt, _, _) = block_means(
            &r.pixels.iter().map(|p| p[0] as f64).collect::<Vec<_>>(),
            8,
            8,
        );
        let rms = (bt.iter().map(|v| v * v).sum::<f64>() / bt.len() as f64).sqrt();
        rms / (bt.iter().sum::<f64>() / bt.len() as f64)
    }
}
