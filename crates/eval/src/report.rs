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
        "scene,method,budget,budget_unit,time_s,gpu_ms,setup_s,device,rmse,rel_rmse,rel_rmse_4x4,mean_ratio,mse,noise,ttuv,speedup_ttuv,speedup_error,bias,nonfinite\n",
    );
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{:.6},{},{:.6},{},{:.6e},{:.6},{:.6},{:.6},{:.6e},{},{},{},{},{},{}",
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
            r.mean_ratio,
            r.mse,
            opt(r.noise),
            opt(r.ttuv),
            opt(r.speedup_ttuv),
            opt(r.speedup_error),
            opt(r.bias),
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

fn fmt_e(v: Option<f64>) -> String {
    v.map_or("–".into(), |x| format!("{x:.2e}"))
}

/// A Markdown table of the rows (one scene or many).
pub fn markdown_table(rows: &[Row], with_scene: bool) -> String {
    let mut s = String::new();
    if with_scene {
        s += "| scene ";
    }
    s += "| method | budget | time (s) | rel. RMSE | rel. RMSE 4×4 | mean ratio | TTUV | speed-up (TTUV) | speed-up (error) | bias |\n";
    if with_scene {
        s += "|---";
    }
    s += "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for r in rows {
        if with_scene {
            let _ = write!(s, "| {} ", r.scene);
        }
        let _ = writeln!(
            s,
            "| {} | {} {} | {:.3} | {:.4} | {:.4} | {:.4} | {} | {} | {} | {} |",
            r.method,
            r.budget,
            r.budget_unit,
            r.time_s,
            r.rel_rmse,
            r.rel_rmse_4x4,
            r.mean_ratio,
            fmt_e(r.ttuv),
            fmt_x(r.speedup_ttuv),
            fmt_x(r.speedup_error),
            r.bias.map_or("".into(), |b| format!("{b:.4}"))
        );
    }
    s
}

/// The plot's curves: relative RMSE against time, one per method.
pub fn series(rows: &[Row]) -> Vec<Series> {
    Method::ALL
        .into_iter()
        .filter(|m| rows.iter().any(|r| r.method == *m))
        .map(|m| Series {
            label: m.name().to_string(),
            points: rows
                .iter()
                .filter(|r| r.method == m)
                .map(|r| (r.time_s, r.rel_rmse))
                .collect(),
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
        let d = nimbus_trace::compare::diff_false_colour(&r.image, reference, None, range);
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
        std::fs::write(&p, text).with_context(|| format!("cannot write {}", p.display()))?;
        written.push(p);
        Ok(())
    };
    put("report.csv", csv(&report.rows))?;
    put("report.json", serde_json::to_string_pretty(report)?)?;
    put("report.md", markdown(report, runs))?;
    let floor = Some(report.reference.stats.rel_noise);
    match error_vs_time(
        &dir.join("error_vs_time"),
        &format!("{} ({}x{})", report.scene, report.width, report.height),
        "relative RMSE over cloud pixels",
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
         {}×{} pixels; reference: {} at {} spp ({:.1} s{}), {} cloud pixels, its own relative \
         noise {:.2e}.\n\n",
        report.scene,
        report.width,
        report.height,
        r.estimator,
        r.spp,
        r.time_s,
        if r.cached { ", cached" } else { "" },
        r.stats.cloud_pixels,
        r.stats.rel_noise
    );
    s += &markdown_table(&report.rows, false);
    s += "\nTime: from the first sample to the finished image (setup excluded, in `report.csv`). \
          TTUV = time × mean pixel variance (Kallweit 2017 §6); speed-up (TTUV) = TTUV of the path \
          tracer / TTUV of the method; speed-up (error) = time the path tracer needs for the \
          method's error / the method's time; bias = RMSE left after the estimated noise of run \
          and reference is removed, relative to the mean reference luminance, for each method's \
          largest budget (for `pm` an upper bound: its noise is not estimated).\n\n";
    s += "![error against time](error_vs_time.png)\n\n";
    let _ = writeln!(
        s,
        "![strip](strip.png)\n\nStrip: reference | {} (largest budgets); below each, (method − \
         reference) / reference in false colour, ±20 % (red: brighter, blue: darker).",
        order.join(" | ")
    );
    s
}
