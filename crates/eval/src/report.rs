//! Report files: `report.csv`, `report.json`, `report.md`, the error-against-time plot
//! (`error_vs_time.png` / `.svg`) and the image strip (`strip.png`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use nimbus_scene::Image;
use serde::Serialize;

use crate::method::{Method, Run};
use crate::metrics::{RefStats, Row};
use crate::plot::{Series, error_vs_time};
use crate::reference::Reference;

/// Everything measured on one scene.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub scene: String,
    pub width: usize,
    pub height: usize,
    pub reference: RefInfo,
    pub rows: Vec<Row>,
}

/// The reference a report was measured against.
#[derive(Debug, Clone, Serialize)]
pub struct RefInfo {
    pub key: String,
    pub estimator: String,
    pub spp: u32,
    pub time_s: f64,
    pub cached: bool,
    pub stats: RefStats,
}

impl RefInfo {
    pub fn new(r: &Reference, stats: RefStats) -> Self {
        Self {
            key: r.key.clone(),
            estimator: r.estimator.clone(),
            spp: r.spp,
            time_s: r.time_s,
            cached: r.cached,
            stats,
        }
    }
}

fn opt(v: Option<f64>) -> String {
    v.map_or(String::new(), |x| format!("{x:.6e}"))
}

fn quote(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The CSV header and one line per row.
pub fn csv(rows: &[Row]) -> String {
    let mut s = String::from(
        "scene,method,budget,budget_unit,time_s,gpu_ms,setup_s,device,rmse,rel_rmse,rel_rmse_4x4,rel_rmse_all,mean_ratio,mse,mse_4x4,noise,noise_4x4,ttuv,speedup_error,speedup_ttuv,bias,bias_floor,nonfinite\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{:.6},{},{:.6},{},{:.6e},{:.6},{:.6},{:.6},{:.6},{:.6e},{:.6e},{},{},{},{},{},{},{},{}",
            quote(&r.scene),
            r.method,
            r.budget,
            r.budget_unit,
            r.time_s,
            opt(r.gpu_ms),
            r.setup_s,
            quote(&r.device),
            r.rmse,
            r.rel_rmse,
            r.rel_rmse_4x4,
            r.rel_rmse_all,
            r.mean_ratio,
            r.mse,
            r.mse_4x4,
            opt(r.noise),
            opt(r.noise_4x4),
            opt(r.ttuv),
            opt(r.speedup_error),
            opt(r.speedup_ttuv),
            opt(r.bias),
            opt(r.bias_floor),
            r.nonfinite
        );
    }
    s
}

/// A speed-up factor: `123×`, `4.5×`, `0.067×`, or `–`.
pub fn fmt_x(v: Option<f64>) -> String {
    match v {
        Some(x) if x >= 100.0 => format!("{x:.0}×"),
        Some(x) if x >= 1.0 => format!("{x:.1}×"),
        Some(x) => format!("{x:.3}×"),
        None => "–".into(),
    }
}

/// A bias with its floor: `0.123 (floor 0.010)`, marked `within the floor` when it is below
/// twice its floor (the noise that was removed cannot tell it from 0).
pub fn fmt_bias(r: &Row) -> String {
    match (r.bias, r.bias_floor) {
        (Some(b), Some(f)) if b < 2.0 * f => format!("{b:.3} (floor {f:.3}: within the floor)"),
        (Some(b), Some(f)) => format!("{b:.3} (floor {f:.3})"),
        (Some(b), None) => format!("{b:.3}"),
        _ => String::new(),
    }
}

/// A Markdown table of the rows (one scene or many).
pub fn markdown_table(rows: &[Row], with_scene: bool) -> String {
    let mut s = String::new();
    if with_scene {
        s += "| scene ";
    }
    s += "| method | budget | time (s) | RMSE | rel. RMSE | rel. RMSE 4×4 | rel. RMSE all pixels | mean ratio | speed-up (time to equal error) | speed-up (TTUV, variance only) | bias (4×4) |\n";
    if with_scene {
        s += "|---";
    }
    s += "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n";
    for r in rows {
        if with_scene {
            let _ = write!(s, "| {} ", r.scene);
        }
        let _ = writeln!(
            s,
            "| {} | {} {} | {:.3} | {:.3e} | {:.4} | {:.4} | {:.4} | {:.4} | {} | {} | {} |",
            r.method,
            r.budget,
            r.budget_unit,
            r.time_s,
            r.rmse,
            r.rel_rmse,
            r.rel_rmse_4x4,
            r.rel_rmse_all,
            r.mean_ratio,
            fmt_x(r.speedup_error),
            fmt_x(r.speedup_ttuv),
            fmt_bias(r)
        );
    }
    s
}

/// The plot's curves: relative RMSE over 4×4 cloud blocks against time, one per method, with
/// the method's bias.
pub fn series(rows: &[Row]) -> Vec<Series> {
    Method::ALL
        .into_iter()
        .filter(|m| rows.iter().any(|r| r.method == *m))
        .map(|m| Series {
            label: m.name().to_string(),
            points: rows
                .iter()
                .filter(|r| r.method == m)
                .map(|r| (r.time_s, r.rel_rmse_4x4))
                .collect(),
            bias: rows.iter().filter(|r| r.method == m).find_map(|r| r.bias),
        })
        .collect()
}

/// reference | each method's largest budget (top row); each method's false-colour relative
/// difference, ±`range` (bottom row, under its image; white under the reference). Linear panels use the reference's
/// auto exposure. Written with `Image::write_png(path, 1.0)`.
pub fn strip(reference: &Image, best: &[&Run], range: f64) -> Image {
    let (w, h) = (reference.width, reference.height);
    let cols = 1 + best.len();
    let gap = 2;
    let mut out = Image::new(cols * w + (cols - 1) * gap, 2 * h + gap);
    out.pixels.iter_mut().for_each(|p| *p = [1.0; 3]);
    let e = reference.auto_exposure();
    let mut put = |img: &Image, col: usize, row: usize, scale: f64| {
        for y in 0..h {
            for x in 0..w {
                let o = (row * (h + gap) + y) * out.width + col * (w + gap) + x;
                out.pixels[o] = img.pixels[y * w + x].map(|c| {
                    let v = c as f64 * scale;
                    if v.is_finite() { v as f32 } else { 0.0 }
                });
            }
        }
    };
    put(reference, 0, 0, e);
    for (k, r) in best.iter().enumerate() {
        put(&r.image, k + 1, 0, e);
        let d = nimbus_scene::compare::diff_false_colour(&r.image, reference, None, range);
        put(&d, k + 1, 1, 1.0);
    }
    out
}

/// Writes all report files into `dir`; returns the paths written. A missing plot font is
/// reported through `log` and skips only the plot.
pub fn write(
    dir: &Path,
    report: &Report,
    reference: &Image,
    runs: &[Run],
    log: &mut dyn FnMut(String),
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut written = Vec::new();
    let mut put = |name: &str, text: String| -> Result<()> {
        let p = dir.join(name);
        nimbus_scene::fsio::write_bytes(&p, text.as_bytes())?;
        written.push(p);
        Ok(())
    };
    put("report.csv", csv(&report.rows))?;
    put("report.json", serde_json::to_string_pretty(report)?)?;
    put("report.md", markdown(report, runs))?;
    let floor = Some(report.reference.stats.rel_noise_4x4);
    match error_vs_time(
        &dir.join("error_vs_time"),
        &format!("{} ({}x{})", report.scene, report.width, report.height),
        "relative RMSE, 4x4 cloud blocks",
        &series(&report.rows),
        floor,
    ) {
        Ok((png, svg)) => {
            written.push(png);
            written.push(svg);
        }
        Err(e) => log(format!("plot skipped: {e:#}")),
    }
    let best: Vec<&Run> = Method::ALL
        .into_iter()
        .filter_map(|m| {
            runs.iter()
                .filter(|r| r.method == m)
                .max_by_key(|r| r.budget)
        })
        .collect();
    let p = dir.join("strip.png");
    strip(reference, &best, 0.2).write_png(&p, 1.0)?;
    written.push(p);
    Ok(written)
}

/// The Markdown summary of one scene.
pub fn markdown(report: &Report, runs: &[Run]) -> String {
    let r = &report.reference;
    let order: Vec<&str> = Method::ALL
        .into_iter()
        .filter(|m| runs.iter().any(|x| x.method == *m))
        .map(|m| m.name())
        .collect();
    let mut s = format!(
        "# {} — error against render time\n\n\
         {}×{} pixels; reference: {} at {} spp ({:.1} s{}), {} cloud pixels (camera optical \
         depth ≥ 0.1), {} full 4×4 cloud blocks; its own relative noise {:.2e} per pixel, \
         {:.2e} per 4×4 block{}.\n\n",
        report.scene,
        report.width,
        report.height,
        r.estimator,
        r.spp,
        r.time_s,
        if r.cached { ", cached" } else { "" },
        r.stats.cloud_pixels,
        r.stats.cloud_blocks,
        r.stats.rel_noise,
        r.stats.rel_noise_4x4,
        if r.stats.target_met {
            ""
        } else {
            " (the noise target was not met within the time cap)"
        }
    );
    s += &markdown_table(&report.rows, false);
    s += "\nAll errors over cloud pixels (camera optical depth ≥ 0.1) except \"all pixels\". Time: \
          from the first sample to the finished image (setup excluded, in `report.csv`). RMSE: of \
          luminance, absolute. Speed-up (time to equal error): the time the path tracer needs to \
          reach the method's 4×4 error against the reference / the method's time — the headline. \
          TTUV = time × mean pixel variance (Kallweit 2017 §6): a variance-only speed-up that \
          ignores bias. Bias: relative RMSE over 4×4 cloud blocks left after the run's and the \
          reference's noise (both from independent halves) are removed, for each method's \
          largest budget, with the noise removed as its floor (for `pm` an upper bound: its \
          noise is not estimated).\n\n";
    s += "![error against time](error_vs_time.png)\n\n";
    let _ = writeln!(
        s,
        "![strip](strip.png)\n\nStrip: reference | {} (largest budgets); below each, (method − \
         reference) / reference in false colour, ±20 % (red: brighter, blue: darker).",
        order.join(" | ")
    );
    s
}
