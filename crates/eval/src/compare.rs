//! `nimbus compare scene.toml --methods …`: reference, budget sweeps, metrics, report files.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use nimbus_scene::Scene;

use crate::method::{GpuSlot, Method, Run, RunSettings, sweep};
use crate::metrics::{evaluate, ref_stats};
use crate::reference::{Reference, ReferenceSettings, reference};
use crate::report::{RefInfo, Report, write};

/// What to compare.
#[derive(Debug, Clone)]
pub struct CompareOptions {
    pub methods: Vec<Method>,
    /// Budgets per method (methods not listed use [`Method::default_budgets`]).
    pub budgets: BTreeMap<Method, Vec<u32>>,
    pub run: RunSettings,
    pub reference: ReferenceSettings,
}

impl CompareOptions {
    pub fn budgets_of(&self, m: Method) -> Vec<u32> {
        self.budgets
            .get(&m)
            .cloned()
            .unwrap_or_else(|| m.default_budgets())
    }

    /// The reference seed: an independent stream from the runs' (sharing the seed would
    /// correlate the path tracer's first samples with the reference's).
    pub fn reference_seed(run_seed: u64) -> u64 {
        run_seed ^ 0x9e37_79b9_7f4a_7c15
    }
}

/// Everything one comparison produced.
pub struct Comparison {
    pub report: Report,
    pub reference: Reference,
    pub runs: Vec<Run>,
    pub files: Vec<PathBuf>,
}

/// An error unless `scene`'s image holds a 4×4 block at least half in the cloud (camera optical
/// depth τ ≥ 0.1, the reference's mask): the errors over 4×4 blocks, the bias and the
/// speed-ups are taken over those, and without one they were NaN and a bias of 0 "within the
/// floor". Checked before the reference renders (the optical depths take milliseconds).
pub fn check_cloud_blocks(scene: &Scene, name: &str) -> Result<()> {
    let (w, h) = (scene.camera.width, scene.camera.height);
    let mask = nimbus_scene::tau::cloud_mask(&nimbus_scene::tau::optical_depth_image(scene));
    if crate::blocks::cloud_blocks(&mask, w, h).is_empty() {
        bail!(
            "{name}: at {w}x{h} the cloud covers no 4×4 block at least half ({} cloud pixels), \
             and the errors over 4×4 blocks, the bias and the speed-ups are taken over those: \
             render it larger (the camera's width and height, or --size) or nearer",
            mask.iter().filter(|&&m| m).count()
        );
    }
    Ok(())
}

/// Renders the reference and every method's sweep on `scene`, writes the report into `out`.
pub fn compare_scene(
    scene: &Scene,
    name: &str,
    opts: &CompareOptions,
    out: &Path,
    gpu: &mut GpuSlot,
    log: &mut dyn FnMut(String),
) -> Result<Comparison> {
    check_cloud_blocks(scene, name)?;
    let reference = reference(scene, &opts.reference, gpu, log)?;
    let rs = ref_stats(&reference);
    let mut runs = Vec::new();
    for &m in &opts.methods {
        let budgets = opts.budgets_of(m);
        let mut each = |r: &Run| {
            log(format!(
                "{name}: {} {} {} in {:.3} s",
                r.method,
                r.budget,
                r.method.budget_unit(),
                r.time_s
            ))
        };
        runs.extend(sweep(scene, m, &budgets, &opts.run, gpu, &mut each)?);
    }
    let rows = evaluate(name, &runs, &reference);
    let report = Report {
        scene: name.to_string(),
        width: scene.camera.width,
        height: scene.camera.height,
        reference: RefInfo::new(&reference, rs),
        rows,
    };
    let files = write(out, &report, &reference.image, &runs, log)?;
    Ok(Comparison {
        report,
        reference,
        runs,
        files,
    })
}
