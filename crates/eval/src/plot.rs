//! Log–log error-against-time plots (plotters), as PNG and SVG.
//!
//! Text needs a TrueType font: `NIMBUS_FONT`, else DejaVu Sans or Liberation Sans from the
//! usual system folders (Debian: `fonts-dejavu-core`). Without one, [`error_vs_time`] fails
//! with a message saying so, and the reports are written without the plot.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use anyhow::{Result, anyhow, bail};
use plotters::coord::Shift;
use plotters::prelude::*;

/// One curve: a label, (time in s, error) points and, when known, the method's bias (drawn
/// as a dashed line of the curve's colour: the error its curve cannot fall below).
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub bias: Option<f64>,
}

const COLOURS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(148, 103, 189),
    RGBColor(255, 127, 14),
    RGBColor(140, 86, 75),
];

fn font_candidates() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::env::var_os("NIMBUS_FONT")
        .map(PathBuf::from)
        .into_iter()
        .collect();
    for p in [
        "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
        "/usr/share/fonts/TTF/DejaVuSans.ttf",
        "/usr/share/fonts/dejavu/DejaVuSans.ttf",
        "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
        "/Library/Fonts/Arial.ttf",
        "C:\\Windows\\Fonts\\arial.ttf",
    ] {
        v.push(PathBuf::from(p));
    }
    v
}

/// Registers the first readable font as "sans-serif" (once per process).
fn ensure_font() -> Result<()> {
    static FONT: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    FONT.get_or_init(|| {
        for p in font_candidates() {
            if let Ok(bytes) = nimbus_scene::fsio::read(&p) {
                // plotters keeps fonts for the life of the process: leak one copy.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return Ok(p);
                }
            }
        }
        Err(
            "no TrueType font found for the plot labels (install fonts-dejavu-core, or set \
             NIMBUS_FONT to a .ttf file)"
                .into(),
        )
    })
    .as_ref()
    .map(|_| ())
    .map_err(|e| anyhow!("{e}"))
}

/// Writes `<stem>.png` and `<stem>.svg`: error (log) against time (log), one curve per series,
/// and a dashed horizontal line at `floor` (the reference's own noise) when given.
pub fn error_vs_time(
    stem: &Path,
    title: &str,
    y_label: &str,
    series: &[Series],
    floor: Option<f64>,
) -> Result<(PathBuf, PathBuf)> {
    ensure_font()?;
    let pts: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|&(x, y)| x > 0.0 && y > 0.0 && x.is_finite() && y.is_finite())
        .collect();
    if pts.is_empty() {
        bail!("nothing to plot: no run has a positive time and error");
    }
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for &(x, y) in &pts {
        x0 = x0.min(x);
        x1 = x1.max(x);
        y0 = y0.min(y);
        y1 = y1.max(y);
    }
    let lines = series.iter().filter_map(|s| s.bias).chain(floor);
    for f in lines.filter(|f| *f > 0.0 && f.is_finite()) {
        y0 = y0.min(f);
        y1 = y1.max(f);
    }
    let range = (x0 / 1.5, x1 * 1.5, y0 / 1.5, y1 * 1.5);
    let png = stem.with_extension("png");
    let svg = stem.with_extension("svg");
    // Each written whole or not at all (a temporary beside it, same extension, renamed).
    fn failed(p: &Path) -> impl Fn(anyhow::Error) -> nimbus_scene::Error + '_ {
        move |e| nimbus_scene::Error::parse(p, format!("{e:#}"))
    }
    nimbus_scene::fsio::write_atomically(&png, |tmp| {
        draw(
            BitMapBackend::new(tmp, (800, 560)).into_drawing_area(),
            title,
            y_label,
            series,
            floor,
            range,
        )
        .map_err(failed(&png))
    })?;
    nimbus_scene::fsio::write_atomically(&svg, |tmp| {
        draw(
            SVGBackend::new(tmp, (800, 560)).into_drawing_area(),
            title,
            y_label,
            series,
            floor,
            range,
        )
        .map_err(failed(&svg))
    })?;
    Ok((png, svg))
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    y_label: &str,
    series: &[Series],
    floor: Option<f64>,
    (x0, x1, y0, y1): (f64, f64, f64, f64),
) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow!("plot: {e:?}");
    root.fill(&WHITE).map_err(e)?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(70)
        .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc("render time (s)")
        .y_desc(y_label)
        .x_label_formatter(&|v| format!("{v:.3}"))
        .y_label_formatter(&|v| format!("{v:.3}"))
        .draw()
        .map_err(e)?;
    for (k, s) in series.iter().enumerate() {
        let c = COLOURS[k % COLOURS.len()];
        let mut p: Vec<(f64, f64)> = s
            .points
            .iter()
            .copied()
            .filter(|&(x, y)| x > 0.0 && y > 0.0 && x.is_finite() && y.is_finite())
            .collect();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        chart
            .draw_series(LineSeries::new(p.clone(), c.stroke_width(2)))
            .map_err(e)?
            .label(s.label.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart
            .draw_series(p.iter().map(|&(x, y)| Circle::new((x, y), 4, c.filled())))
            .map_err(e)?;
        if let Some(b) = s.bias.filter(|b| *b > 0.0 && b.is_finite()) {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(x0, b), (x1, b)],
                    3,
                    5,
                    c.stroke_width(1),
                ))
                .map_err(e)?;
        }
    }
    if let Some(f) = floor.filter(|f| *f > 0.0 && f.is_finite()) {
        let grey = RGBColor(120, 120, 120);
        chart
            .draw_series(DashedLineSeries::new(
                vec![(x0, f), (x1, f)],
                6,
                4,
                grey.stroke_width(1),
            ))
            .map_err(e)?
            .label("reference noise (dashed colour: each method's bias)")
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}
