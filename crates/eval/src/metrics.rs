//! From runs and a reference to the numbers of a report (Kallweit 2017 §6).
//!
//! Over the cloud pixels (reference luminance > 10⁻³ × its maximum, the mask of
//! `nimbus_trace::compare`), with luminance = mean of R, G, B:
//! - `rel_rmse`: RMSE / mean reference luminance; `rel_rmse_4x4` the same on 4×4 block means;
//!   `mean_ratio`: mean test / mean reference luminance;
//! - `mse`: mean squared luminance error; `noise`: mean variance of the run's pixel means;
//! - `ttuv` = time × mean pixel variance ("time to unit variance", §6) for Monte Carlo runs;
//!   `speedup_ttuv` = TTUV of the baseline path tracer / TTUV of the run (the paper's speed-up);
//! - `speedup_error`: how much longer the baseline path tracer needs to reach the run's error.
//!   An unbiased path tracer's MSE falls as C/t, so it reaches the run's MSE after C/MSE
//!   seconds; C = median over its runs of time × (MSE − reference variance);
//! - `bias` (converged runs: the largest budget of each method): the RMSE that remains after
//!   the estimated noise of run and reference is taken out, √max(0, MSE − noise − noise_ref),
//!   relative to the mean reference luminance (Table 1 reports this RMSE on converged images).
//!   The photon map has no per-pixel variance; its `bias` keeps its own residual noise and is an
//!   upper bound.

use nimbus_trace::compare::compare;
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
    pub mean_ratio: f64,
    pub mse: f64,
    pub noise: Option<f64>,
    pub ttuv: Option<f64>,
    pub speedup_ttuv: Option<f64>,
    pub speedup_error: Option<f64>,
    pub bias: Option<f64>,
    pub nonfinite: usize,
}

/// Reference statistics over the cloud pixels.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct RefStats {
    pub cloud_pixels: usize,
    pub mean_lum: f64,
    /// Mean variance of the reference's pixel means.
    pub noise: f64,
    /// √noise / mean: the relative error floor the reference itself sets.
    pub rel_noise: f64,
}

fn lum(p: [f32; 3]) -> f64 {
    (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0
}

/// The cloud mask: reference luminance > 10⁻³ × max.
pub fn cloud_mask(reference: &Reference) -> Vec<bool> {
    let l: Vec<f64> = reference.image.pixels.iter().map(|&p| lum(p)).collect();
    let max = l.iter().cloned().fold(0.0, f64::max);
    l.iter().map(|&v| v > 1e-3 * max).collect()
}

pub fn ref_stats(reference: &Reference) -> RefStats {
    let mask = cloud_mask(reference);
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
    RefStats {
        cloud_pixels: idx.len(),
        mean_lum: mean,
        noise,
        rel_noise: noise.sqrt() / mean.max(f64::MIN_POSITIVE),
    }
}

/// The rows of one scene's runs (any order; speed-ups use `pt`, else `pt-gpu`, as baseline).
pub fn evaluate(scene: &str, runs: &[Run], reference: &Reference) -> Vec<Row> {
    let mask = cloud_mask(reference);
    let idx: Vec<usize> = (0..mask.len()).filter(|&i| mask[i]).collect();
    let n = idx.len().max(1) as f64;
    let rs = ref_stats(reference);
    let mut rows: Vec<Row> = runs
        .iter()
        .map(|r| {
            let m = compare(&r.image, &reference.image, Some(&mask));
            let mse = idx
                .iter()
                .map(|&i| {
                    let t = lum(r.image.pixels[i]);
                    let t = if t.is_finite() { t } else { 0.0 };
                    (t - lum(reference.image.pixels[i])).powi(2)
                })
                .sum::<f64>()
                / n;
            let noise = r
                .variance
                .as_ref()
                .map(|v| idx.iter().map(|&i| v[i] as f64).sum::<f64>() / n);
            Row {
                scene: scene.to_string(),
                method: r.method,
                budget: r.budget,
                budget_unit: r.method.budget_unit(),
                time_s: r.time_s,
                gpu_ms: r.gpu_ms,
                setup_s: r.setup_s,
                device: r.device.clone(),
                rmse: m.rmse_rgb,
                rel_rmse: m.rel_rmse_cloud,
                rel_rmse_4x4: m.rel_rmse_cloud_4x4,
                mean_ratio: m.mean_lum_ratio,
                mse,
                noise,
                ttuv: noise.map(|v| v * r.time_s),
                speedup_ttuv: None,
                speedup_error: None,
                bias: None,
                nonfinite: m.nonfinite,
            }
        })
        .collect();
    // Bias of converged runs: each method's largest budget.
    for method in Method::ALL {
        let Some(top) = rows
            .iter_mut()
            .filter(|r| r.method == method)
            .max_by_key(|r| r.budget)
        else {
            continue;
        };
        let b2 = top.mse - top.noise.unwrap_or(0.0) - rs.noise;
        top.bias = Some(b2.max(0.0).sqrt() / rs.mean_lum.max(f64::MIN_POSITIVE));
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
                .map(|r| r.time_s * (r.mse - rs.noise).max(0.0))
                .collect(),
        );
        for r in rows.iter_mut() {
            if let (Some(tb), Some(t)) = (ttuv_base, r.ttuv)
                && t > 0.0
            {
                r.speedup_ttuv = Some(tb / t);
            }
            let e = (r.mse - rs.noise).max(0.0) * r.time_s;
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

    fn img(v: f32) -> Image {
        let mut i = Image::new(8, 8);
        i.pixels.iter_mut().for_each(|p| *p = [v; 3]);
        i
    }

    fn reference(v: f32, var: f32) -> Reference {
        Reference {
            image: img(v),
            variance: vec![var; 64],
            key: String::new(),
            estimator: "pt".into(),
            spp: 1,
            time_s: 0.0,
            cached: false,
            path: None,
        }
    }

    fn run(method: Method, budget: u32, v: f32, var: Option<f32>, t: f64) -> Run {
        Run {
            method,
            budget,
            image: img(v),
            variance: var.map(|x| vec![x; 64]),
            time_s: t,
            gpu_ms: None,
            setup_s: 0.0,
            device: String::new(),
        }
    }

    #[test]
    fn bias_ttuv_and_speedups() {
        let r = reference(1.0, 1e-4);
        // Path tracer: unbiased, MSE = its noise + the reference's (images constant here, so
        // the noise terms are given, and MSE comes from a 0.02 offset: 4e-4).
        let runs = vec![
            run(Method::Pt, 1, 1.02, Some(3e-4), 1.0),
            run(Method::Pt, 4, 1.02, Some(3e-4), 1.0),
            // A method 10 % too bright, 10× cheaper in TTUV.
            run(Method::Rpnn, 1, 1.1, Some(3e-5), 1.0),
            run(Method::Pm, 8, 0.95, None, 0.5),
        ];
        let rows = evaluate("s", &runs, &r);
        let pt = &rows[1];
        assert!((pt.rel_rmse - 0.02).abs() < 1e-6);
        // Variances are f32: relative tolerances of 1e-5 cover their rounding (6e-8 each).
        assert!((pt.ttuv.unwrap() / 3e-4 - 1.0).abs() < 1e-5);
        // bias = √max(0, 4e-4 − 3e-4 − 1e-4) = 0 (up to f32 rounding of the offset).
        assert!(pt.bias.unwrap() < 2e-3, "{:?}", pt.bias);
        assert!(
            rows[0].bias.is_none(),
            "only the largest budget is converged"
        );
        let nn = &rows[2];
        assert!((nn.speedup_ttuv.unwrap() / 10.0 - 1.0).abs() < 1e-5);
        // bias = √(0.01 − 3e-5 − 1e-4) ≈ 0.09935.
        assert!((nn.bias.unwrap() - (0.01f64 - 3e-5 - 1e-4).sqrt()).abs() < 1e-5);
        // Baseline C = 1 s × (4e-4 − 1e-4); the network needs 1 s × (0.01 − 1e-4) → 0.0303×.
        let se = nn.speedup_error.unwrap();
        assert!((se - 3e-4 / (0.01 - 1e-4)).abs() < 1e-4, "{se}");
        let pm = &rows[3];
        assert!(pm.ttuv.is_none() && pm.noise.is_none());
        assert!((pm.bias.unwrap() - (0.0025f64 - 1e-4).sqrt()).abs() < 1e-5);
        assert!((pm.mean_ratio - 0.95).abs() < 1e-6);
    }

    #[test]
    fn median_ignores_non_finite() {
        assert_eq!(median(vec![3.0, f64::NAN, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(vec![]), None);
    }
}
