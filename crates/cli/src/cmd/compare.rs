//! `nimbus compare`: a scene's methods against a cached reference (over `nimbus_eval`), or
//! one EXR against another; the error metrics that `render --reference` prints as well.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use nimbus_eval::GpuSlot;
use nimbus_scene::compare;

use crate::eval::{EvalArgs, log, preflight};
use crate::flags;

#[derive(clap::Args)]
pub(crate) struct CompareArgs {
    /// A scene (.toml), or a test EXR followed by a reference EXR.
    #[arg(required = true, num_args = 1..=2)]
    inputs: Vec<PathBuf>,
    /// Scene mode: report folder.
    #[arg(long, short, default_value = "report")]
    out: PathBuf,
    #[command(flatten)]
    eval: EvalArgs,
    /// Optical-depth mask (.npy, cloud = τ ≥ 0.1); default: `<reference>_tau.npy` if present.
    #[arg(long)]
    mask: Option<PathBuf>,
    /// Write the panels reference | test | relative difference (false colour) as PNG.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Full scale of the difference panel (0.2 = ±20 %), in (0, 1e6].
    #[arg(long, default_value_t = 0.2, value_parser = flags::f64_above(0.0, 1e6))]
    range: f64,
}

pub(crate) fn run(a: CompareArgs) -> Result<()> {
    let CompareArgs {
        inputs,
        out,
        eval,
        mask,
        png,
        range,
    } = a;
    if inputs[0].extension().is_some_and(|e| e == "toml") {
        if inputs.len() > 1 {
            bail!("compare with a scene takes one input, got {}", inputs.len());
        }
        return compare_scene(&inputs[0], &eval, &out);
    }
    let [test, reference] = inputs.as_slice() else {
        bail!("compare needs a scene (.toml), or a test EXR and a reference EXR");
    };
    let (test, reference) = (test.clone(), reference.clone());
    print_metrics(
        &test,
        &reference,
        read_reference(&reference)?,
        mask.clone(),
        None,
    )?;
    if let Some(out) = png {
        let t = nimbus_scene::Image::read_exr(&test)?;
        let r = nimbus_scene::Image::read_exr(&reference)?;
        let m = match mask_for(&reference, mask) {
            Some(p) => Some(compare::tau_mask(&p, r.width, r.height)?),
            None => None,
        };
        // The reference's auto exposure (99th-percentile luminance → 0.9) for both panels.
        let e = r.auto_exposure();
        compare::diff_panels(&t, &r, m.as_deref(), range, e).write_png(&out, 1.0)?;
        say!(
            "diff panels (reference | test | (test−ref)/ref, ±{range}) -> {}",
            out.display()
        );
    }
    Ok(())
}

/// `nimbus compare scene.toml --methods … --out DIR`.
fn compare_scene(scene: &Path, args: &EvalArgs, out: &Path) -> Result<()> {
    let s = nimbus_scene::Scene::load(scene)?;
    let opts = args.options(s.render.seed, s.sky.is_some())?;
    let name = scene
        .file_stem()
        .unwrap_or_default()
        .to_string_lossy()
        .into_owned();
    preflight(&opts, out, |m| {
        Ok(vec![nimbus_render::rpnn_model_path(
            opts.run.model.as_deref(),
            m,
            &s.phase_desc,
            s.sky.is_some(),
        )])
    })?;
    let mut gpu = GpuSlot::default();
    let c = nimbus_eval::compare_scene(&s, &name, &opts, out, &mut gpu, &mut log)?;
    say!(
        "{}",
        nimbus_eval::report::markdown_table(&c.report.rows, false)
    );
    for f in &c.files {
        say!("wrote {}", f.display());
    }
    Ok(())
}

/// The cloud mask to use: the given one, else `<reference>_tau.npy` when it exists.
fn mask_for(reference: &Path, mask: Option<PathBuf>) -> Option<PathBuf> {
    let auto = PathBuf::from(format!(
        "{}_tau.npy",
        reference.with_extension("").display()
    ));
    mask.or_else(|| auto.exists().then_some(auto))
}

/// A reference image: an EXR whose pixels are finite and ≥ 0.
pub(crate) fn read_reference(reference: &Path) -> Result<nimbus_scene::Image> {
    let r = nimbus_scene::Image::read_exr(reference)?;
    // A radiance reference has no negative or non-finite pixel: one would be dropped from the
    // metrics without a word (the cloud mask skips pixels of non-positive luminance).
    let bad: Vec<usize> = (0..r.pixels.len())
        .filter(|&i| r.pixels[i].iter().any(|c| !(c.is_finite() && *c >= 0.0)))
        .collect();
    if let Some(&i) = bad.first() {
        bail!(
            "{}: {} of {} pixels are negative or not finite (the first at x = {}, y = {}: {:?}); \
             a radiance reference has none",
            reference.display(),
            bad.len(),
            r.pixels.len(),
            i % r.width,
            i / r.width,
            r.pixels[i]
        );
    }
    Ok(r)
}

/// The error metrics of the EXR `test` against `r`, the reference read from `reference`, over
/// the cloud pixels: the mask file given, else `<reference>_tau.npy`, else `scene_mask` (the
/// scene's camera optical depth), else the reference's bright pixels.
pub(crate) fn print_metrics(
    test: &Path,
    reference: &Path,
    r: nimbus_scene::Image,
    mask: Option<PathBuf>,
    scene_mask: Option<Vec<bool>>,
) -> Result<()> {
    let t = nimbus_scene::Image::read_exr(test)?;
    if (t.width, t.height) != (r.width, r.height) {
        bail!(
            "{} is {}x{} but {} is {}x{}",
            test.display(),
            t.width,
            t.height,
            reference.display(),
            r.width,
            r.height
        );
    }
    let mask_path = mask_for(reference, mask);
    let m = match &mask_path {
        Some(p) => Some(compare::tau_mask(p, r.width, r.height)?),
        None => scene_mask.filter(|m| m.len() == r.width * r.height),
    };
    let res = compare::compare(&t, &r, m.as_deref());
    if res.cloud_pixels == 0 || !res.mean_lum_ratio.is_finite() && res.nonfinite == 0 {
        bail!(
            "{}: the reference has no cloud pixels with positive luminance{}; relative metrics are undefined",
            reference.display(),
            if mask_path.is_some() {
                " inside the mask"
            } else {
                ""
            }
        );
    }
    say!("cloud pixels        {}", res.cloud_pixels);
    say!("rmse_rgb            {:.6}", res.rmse_rgb);
    say!("rel_rmse_cloud      {:.4}", res.rel_rmse_cloud);
    say!("rel_rmse_cloud_4x4  {:.4}", res.rel_rmse_cloud_4x4);
    say!("mean_lum_ratio      {:.5}", res.mean_lum_ratio);
    if res.nonfinite > 0 {
        say!("non-finite values   {}", res.nonfinite);
    }
    Ok(())
}
