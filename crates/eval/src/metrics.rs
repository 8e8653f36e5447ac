//! From runs and a reference to the numbers of a report (Kallweit 2017 §6).
//!
//! Over the **cloud pixels** — camera optical depth τ ≥ 0.1 ([`nimbus_scene::tau`]), a mask
//! from the geometry, not from brightness (with a sky every pixel is bright) — with luminance =
//! mean of R, G, B:
//! - `rmse`: RMSE of luminance (absolute, as Kallweit Table 1); `rel_rmse`: RMSE / mean
//!   reference luminance; `rel_rmse_4x4` the same on the means of 4×4 blocks lying fully in the
//!   cloud; `mean_ratio`: mean test / mean reference luminance; `rel_rmse_all`: relative RMSE
//!   over every pixel, sky included (for comparison with brightness-masked figures);
//! - blocks of the noise, bias and speed-up figures: 4×4 tiles at least half in the cloud,
//!   averaged over their cloud pixels ([`cloud_blocks`]); `rel_rmse_4x4` keeps the definition
//!   of `shared/refs/compare.py` (tiles fully in the cloud) so it compares with Mitsuba figures;
//! - `noise`, `noise_4x4`: the run's own noise variance per pixel and per block, from its two
//!   halves ((A − B)²/4, see [`crate::method`]);
//! - `ttuv` = time × mean pixel variance ("time to unit variance", §6): variance only;
//!   `speedup_ttuv` = TTUV of the baseline path tracer / TTUV of the run;
//! - `speedup_error` (the headline): how much longer the baseline path tracer needs to reach
//!   the run's error against the truth, on 4×4 blocks. An unbiased path tracer's block MSE
//!   against the truth falls as C/t, so it reaches a run's error e² = MSE₄ₓ₄ − (reference noise)
//!   after C/e² seconds; C = median over its runs of time × (MSE₄ₓ₄ − reference noise). A biased
//!   method's error never falls below its bias, so its speed-up shrinks at small errors;
//! - `bias` (converged runs: the largest budget of each method): the relative RMSE over 4×4
//!   cloud blocks left after the run's and the reference's noise are taken out,
//!   √max(0, MSE₄ₓ₄ − noise₄ₓ₄ − noise_ref₄ₓ₄) / mean; `bias_floor` = √(noise₄ₓ₄ +
//!   noise_ref₄ₓ₄) / mean, the noise that was removed: a bias below 2× its floor is reported as
//!   "within the floor". The ray-marched photon maps (`pm-march`, `pm-elek2012`: ring-frame
//!   budgets) have no noise estimate; their bias keeps their own residual noise and is an upper
//!   bound. `pm`'s halves each trace their own photon map (their seeds differ), so its noise
//!   holds the photon map's as well as the gather's.

use nimbus_scene::compare::compare;
use serde::Serialize;

use crate::method::{Method, Run};
use crate::reference::Reference;

/// One line of a report.
#[derive(Debug, Clone, Serialize)]
pub struct Row {
    pub scene: String,
    pub method: Method,
    pub budget: u32,
    pub budget_unit: &'static str,
    pub time_s: f64,
    pub gpu_ms: Option<f64>,
    pub setup_s: f64,
    pub device: String,
    pub rmse: f64,
    pub rel_rmse: f64,
    pub rel_rmse_4x4: f64,
    pub rel_rmse_all: f64,
    pub mean_ratio: f64,
    pub mse: f64,
    pub mse_4x4: f64,
    pub noise: Option<f64>,
    pub noise_4x4: Option<f64>,
    pub ttuv: Option<f64>,
    pub speedup_ttuv: Option<f64>,
    pub speedup_error: Option<f64>,
    pub bias: Option<f64>,
    pub bias_floor: Option<f64>,
    pub nonfinite: usize,
}

impl Row {
    /// Whether the bias is below twice the noise floor it was measured against.
    pub fn within_floor(&self) -> Option<bool> {
        Some(self.bias? < 2.0 * self.bias_floor?)
    }
}

/// Reference statistics over the cloud pixels.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct RefStats {
    pub cloud_pixels: usize,
    /// 4×4 blocks at least half in the cloud ([`cloud_blocks`]).
    pub cloud_blocks: usize,
    pub mean_lum: f64,
    /// Mean variance of the reference's pixel means (from its halves).
    pub noise: f64,
    /// √noise / mean: the per-pixel relative noise of the reference.
    pub rel_noise: f64,
    /// Mean variance of the reference's 4×4 block means (from its halves).
    pub noise_4x4: f64,
    /// √noise_4x4 / mean: the floor the reference sets for block errors and biases.
    pub rel_noise_4x4: f64,
    pub spp: u32,
    pub target_met: bool,
}

fn lum(p: [f32; 3]) -> f64 {
    (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0
}

/// The cloud mask: camera optical depth τ ≥ 0.1.
pub fn cloud_mask(reference: &Reference) -> Vec<bool> {
    nimbus_scene::tau::cloud_mask(&reference.tau)
}

pub use crate::blocks::{MIN_BLOCK_PIXELS, block_mean_square, cloud_blocks};

/// Mean over blocks of (block mean of `d`)² / 4: the variance of the block means of (A + B)/2
/// when `d` = A − B.
fn block_half_noise(d: &[f32], blocks: &[Vec<usize>]) -> f64 {
    block_mean_square(|i| d[i] as f64, blocks) / 4.0
}

pub fn ref_stats(reference: &Reference) -> RefStats {
    let (w, h) = (reference.image.width, reference.image.height);
    let mask = cloud_mask(reference);
    let blocks = cloud_blocks(&mask, w, h);
    let idx: Vec<usize> = (0..mask.len()).filter(|&i| mask[i]).collect();
    let n = idx.len().max(1) as f64;
    let mean = idx
        .iter()
        .map(|&i| lum(reference.image.pixels[i]))
        .sum::<f64>()
        / n;
    let noise = idx
        .iter()
        .map(|&i| reference.variance[i] as f64)
        .sum::<f64>()
        / n;
    let noise_4x4 = block_half_noise(&reference.half_diff, &blocks);
    let m = mean.max(f64::MIN_POSITIVE);
    RefStats {
        cloud_pixels: idx.len(),
        cloud_blocks: blocks.len(),
        mean_lum: mean,
        noise,
        rel_noise: noise.sqrt() / m,
        noise_4x4,
        rel_noise_4x4: noise_4x4.sqrt() / m,
        spp: reference.spp,
        target_met: reference.target_met,
    }
}

/// The rows of one scene's runs (any order; speed-ups use `pt`, else `pt-gpu`, as baseline).
pub fn evaluate(scene: &str, runs: &[Run], reference: &Reference) -> Vec<Row> {
    let (w, h) = (reference.image.width, reference.image.height);
    let mask = cloud_mask(reference);
    let blocks = cloud_blocks(&mask, w, h);
    let idx: Vec<usize> = (0..mask.len()).filter(|&i| mask[i]).collect();
    let n = idx.len().max(1) as f64;
    let rs = ref_stats(reference);
    let ref_lum: Vec<f64> = reference.image.pixels.iter().map(|&p| lum(p)).collect();
    let mean_all = ref_lum.iter().sum::<f64>() / ref_lum.len().max(1) as f64;
    let mut rows: Vec<Row> = runs
        .iter()
        .map(|r| {
            let m = compare(&r.image, &reference.image, Some(&mask));
            let t_lum: Vec<f64> = r
                .image
                .pixels
                .iter()
                .map(|&p| {
                    let t = lum(p);
                    if t.is_finite() { t } else { 0.0 }
                })
                .collect();
            let mse = idx
                .iter()
                .map(|&i| (t_lum[i] - ref_lum[i]).powi(2))
                .sum::<f64>()
                / n;
            let mse_all = t_lum
                .iter()
                .zip(&ref_lum)
                .map(|(t, r)| (t - r).powi(2))
                .sum::<f64>()
                / ref_lum.len().max(1) as f64;
            let mse_4x4 = block_mean_square(|i| t_lum[i] - ref_lum[i], &blocks);
            let noise = r
                .variance
                .as_ref()
                .map(|v| idx.iter().map(|&i| v[i] as f64).sum::<f64>() / n);
            let noise_4x4 = r.half_diff.as_ref().map(|d| block_half_noise(d, &blocks));
            Row {
                scene: scene.to_string(),
                method: r.method,
                budget: r.budget,
                budget_unit: r.method.budget_unit(),
                time_s: r.time_s,
                gpu_ms: r.gpu_ms,
                setup_s: r.setup_s,
                device: r.device.clone(),
                rmse: mse.sqrt(),
                rel_rmse: m.rel_rmse_cloud,
                rel_rmse_4x4: m.rel_rmse_cloud_4x4,
                rel_rmse_all: mse_all.sqrt() / mean_all.max(f64::MIN_POSITIVE),
                mean_ratio: m.mean_lum_ratio,
                mse,
                mse_4x4,
                noise,
                noise_4x4,
                ttuv: noise.map(|v| v * r.time_s),
                speedup_ttuv: None,
                speedup_error: None,
                bias: None,
                bias_floor: None,
                nonfinite: m.nonfinite,
            }
        })
        .collect();
    let mean = rs.mean_lum.max(f64::MIN_POSITIVE);
    // Bias of converged runs: each method's largest budget, on 4×4 blocks.
    for method in Method::ALL {
        let Some(top) = rows
            .iter_mut()
            .filter(|r| r.method == method)
            .max_by_key(|r| r.budget)
        else {
            continue;
        };
        let removed = top.noise_4x4.unwrap_or(0.0) + rs.noise_4x4;
        top.bias = Some((top.mse_4x4 - removed).max(0.0).sqrt() / mean);
        top.bias_floor = Some(removed.sqrt() / mean);
    }
    // Baseline: the CPU path tracer, else the GPU one.
    let base = [Method::Pt, Method::PtGpu]
        .into_iter()
        .find(|m| rows.iter().any(|r| r.method == *m));
    if let Some(base) = base {
        let b: Vec<&Row> = rows.iter().filter(|r| r.method == base).collect();
        let ttuv_base = median(b.iter().filter_map(|r| r.ttuv).collect());
        let c_base = median(
            b.iter()
                .map(|r| r.time_s * (r.mse_4x4 - rs.noise_4x4).max(0.0))
                .collect(),
        );
        for r in rows.iter_mut() {
            if let (Some(tb), Some(t)) = (ttuv_base, r.ttuv)
                && t > 0.0
            {
                r.speedup_ttuv = Some(tb / t);
            }
            let e = (r.mse_4x4 - rs.noise_4x4).max(0.0) * r.time_s;
            if let Some(c) = c_base
                && e > 0.0
                && c > 0.0
            {
                r.speedup_error = Some(c / e);
            }
        }
    }
    rows
}

fn median(mut v: Vec<f64>) -> Option<f64> {
    v.retain(|x| x.is_finite());
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let k = v.len();
    Some(if k % 2 == 1 {
        v[k / 2]
    } else {
        0.5 * (v[k / 2 - 1] + v[k / 2])
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nimbus_scene::Image;

    /// An 8×8 image: `cloud` in the top four rows (τ = 1: two full 4×4 cloud blocks), `sky` in
    /// the bottom four (τ = 0).
    fn img(cloud: f32, sky: f32) -> Image {
        let mut i = Image::new(8, 8);
        for (k, p) in i.pixels.iter_mut().enumerate() {
            *p = [if k < 32 { cloud } else { sky }; 3];
        }
        i
    }

    /// A half difference d everywhere: block and pixel noise d²/4.
    fn diff(noise: f64) -> Vec<f32> {
        vec![(4.0 * noise).sqrt() as f32; 64]
    }

    fn reference(v: f32, noise: f64) -> Reference {
        let d = diff(noise);
        Reference {
            image: img(v, 0.5),
            variance: d.iter().map(|x| x * x / 4.0).collect(),
            half_diff: d,
            tau: (0..64).map(|k| if k < 32 { 1.0 } else { 0.0 }).collect(),
            rel_noise_4x4: noise.sqrt(),
            target_met: true,
            key: String::new(),
            estimator: "pt".into(),
            spp: 2,
            time_s: 0.0,
            cached: false,
            path: None,
        }
    }

    fn run(method: Method, budget: u32, v: f32, noise: Option<f64>, t: f64) -> Run {
        let d = noise.map(diff);
        Run {
            method,
            budget,
            // The sky is far off in every run: the cloud metrics must not see it.
            image: img(v, 5.0),
            variance: d.as_ref().map(|d| d.iter().map(|x| x * x / 4.0).collect()),
            half_diff: d,
            time_s: t,
            gpu_ms: None,
            setup_s: 0.0,
            device: String::new(),
        }
    }

    #[test]
    fn geometric_mask_bias_floor_ttuv_and_time_to_equal_error() {
        let r = reference(1.0, 1e-4);
        let rs = ref_stats(&r);
        assert_eq!((rs.cloud_pixels, rs.cloud_blocks), (32, 2));
        // f32 half differences: relative tolerances of 1e-5 cover their rounding.
        assert!((rs.rel_noise_4x4 / 0.01 - 1.0).abs() < 1e-5);
        // Path tracer: unbiased; MSE₄ₓ₄ = 4e-4 from a 0.02 offset = its noise (3e-4) + the
        // reference's (1e-4).
        let runs = vec![
            run(Method::Pt, 2, 1.02, Some(3e-4), 1.0),
            run(Method::Pt, 8, 1.02, Some(3e-4), 1.0),
            // A method 10 % too bright, 10× cheaper in TTUV.
            run(Method::Rpnn, 2, 1.1, Some(3e-5), 1.0),
            run(Method::Pm, 8, 0.95, None, 0.5),
        ];
        let rows = evaluate("s", &runs, &r);
        let pt = &rows[1];
        assert!((pt.rel_rmse - 0.02).abs() < 1e-6 && (pt.rmse - 0.02).abs() < 1e-6);
        assert!((pt.mean_ratio - 1.02).abs() < 1e-6);
        // All pixels: (32 · 0.02² + 32 · 4.5²) / 64 over a mean of 0.75.
        let all = ((32.0 * 0.0004 + 32.0 * 20.25) / 64.0f64).sqrt() / 0.75;
        assert!(
            (pt.rel_rmse_all / all - 1.0).abs() < 1e-5,
            "{}",
            pt.rel_rmse_all
        );
        assert!((pt.ttuv.unwrap() / 3e-4 - 1.0).abs() < 1e-5);
        // bias = √max(0, 4e-4 − 3e-4 − 1e-4) = 0 (up to f32 rounding), floor √4e-4 = 0.02.
        assert!(pt.bias.unwrap() < 2e-3, "{:?}", pt.bias);
        assert!((pt.bias_floor.unwrap() - 0.02).abs() < 1e-6);
        assert_eq!(pt.within_floor(), Some(true));
        assert!(
            rows[0].bias.is_none(),
            "only the largest budget is converged"
        );
        let nn = &rows[2];
        assert!((nn.speedup_ttuv.unwrap() / 10.0 - 1.0).abs() < 1e-5);
        // bias = √(0.01 − 3e-5 − 1e-4) ≈ 0.09935, far above its floor √1.3e-4 ≈ 0.0114.
        assert!((nn.bias.unwrap() - (0.01f64 - 3e-5 - 1e-4).sqrt()).abs() < 1e-5);
        assert_eq!(nn.within_floor(), Some(false));
        // Baseline C = 1 s × (4e-4 − 1e-4); the network needs 1 s × (0.01 − 1e-4): the path
        // tracer reaches the network's error 33× sooner (speed-up 0.0303×).
        let se = nn.speedup_error.unwrap();
        assert!((se - 3e-4 / (0.01 - 1e-4)).abs() < 1e-4, "{se}");
        let pm = &rows[3];
        assert!(pm.ttuv.is_none() && pm.noise.is_none() && pm.noise_4x4.is_none());
        assert!((pm.bias.unwrap() - (0.0025f64 - 1e-4).sqrt()).abs() < 1e-5);
        assert!((pm.mean_ratio - 0.95).abs() < 1e-6);
    }

    /// Tiles count from half their pixels in the cloud, and their means are over those pixels:
    /// a difference of 1 on the cloud pixels (0 outside) gives block mean squares of 1.
    #[test]
    fn partial_tiles_count_from_half_in_the_cloud() {
        let (w, h) = (8, 4);
        // Left tile: 8 cloud pixels (its top two rows); right tile: 7.
        let mask: Vec<bool> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                if x < 4 {
                    y < 2
                } else {
                    y < 1 || (y == 1 && x < 7)
                }
            })
            .collect();
        let blocks = cloud_blocks(&mask, w, h);
        assert_eq!(blocks.len(), 1);
        assert_eq!(blocks[0].len(), MIN_BLOCK_PIXELS);
        let d: Vec<f64> = mask.iter().map(|&m| if m { 1.0 } else { 0.0 }).collect();
        assert_eq!(block_mean_square(|i| d[i], &blocks), 1.0);
        assert_eq!(block_mean_square(|i| d[i], &[]), 0.0);
    }

    #[test]
    fn median_ignores_non_finite() {
        assert_eq!(median(vec![3.0, f64::NAN, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(vec![]), None);
    }
}
