//! `nimbus bench-suite`: the analogue of Kallweit 2017 Table 1 (§6) — held-out generated
//! clouds (the test split of `nimbus datagen --clouds gen:40`, never seen in training) under
//! front, side and back light, with the sun alone and with sun and sky; every method against
//! the path-traced reference; bias of converged images and speed-ups in `docs/results.md`.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use nimbus_rpnn::data::dataset::{build_volume, generated_set};
use nimbus_scene::{Scene, io};

use crate::compare::{CompareOptions, compare_scene};
use crate::method::{GpuSlot, Method};
use crate::metrics::Row;
use crate::plot::{Series, error_vs_time};

/// Light placements relative to the camera (which looks along −z from +z, 20° above).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lighting {
    /// Sun behind the camera.
    Front,
    /// Sun from the right.
    Side,
    /// Sun behind the cloud.
    Back,
}

impl Lighting {
    pub const ALL: [Lighting; 3] = [Lighting::Front, Lighting::Side, Lighting::Back];

    pub fn name(self) -> &'static str {
        match self {
            Lighting::Front => "front",
            Lighting::Side => "side",
            Lighting::Back => "back",
        }
    }

    /// Direction towards the sun (elevation ≈ 26°).
    pub fn sun_dir(self) -> [f64; 3] {
        match self {
            Lighting::Front => [0.25, 0.5, 1.0],
            Lighting::Side => [1.0, 0.5, 0.0],
            Lighting::Back => [-0.25, 0.5, -1.0],
        }
    }

    pub fn parse(s: &str) -> Result<Self> {
        Lighting::ALL
            .into_iter()
            .find(|l| l.name() == s.trim())
            .with_context(|| format!("unknown lighting `{s}` (expected front, side or back)"))
    }
}

/// The sky of a suite condition.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SkyCondition {
    /// The sun alone.
    Sun,
    /// The sun and a constant sky.
    SunSky,
    /// The sun and an environment map: a clear sky of `nimbus_rpnn::sky::SkyModel` (gradient,
    /// glow about the sun, a ground below the horizon) as a lat-long EXR.
    SunEnv,
}

impl SkyCondition {
    pub const ALL: [SkyCondition; 3] = [
        SkyCondition::Sun,
        SkyCondition::SunSky,
        SkyCondition::SunEnv,
    ];

    /// The condition's name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            SkyCondition::Sun => "sun",
            SkyCondition::SunSky => "sun+sky",
            SkyCondition::SunEnv => "sun+env",
        }
    }

    /// The scene names' suffix.
    fn suffix(self) -> &'static str {
        match self {
            SkyCondition::Sun => "sun",
            SkyCondition::SunSky => "sunsky",
            SkyCondition::SunEnv => "sunenv",
        }
    }

    pub fn parse(s: &str) -> Result<Self> {
        SkyCondition::ALL
            .into_iter()
            .find(|c| c.name() == s.trim())
            .with_context(|| {
                format!("--skies: unknown condition `{s}` (expected sun, sun+sky or sun+env)")
            })
    }
}

/// The environment map of the `sun+env` condition for `lighting`: its sun at the suite's sun
/// direction, written once into `dir`; returns its path.
pub fn env_map(lighting: Lighting, dir: &Path) -> Result<PathBuf> {
    let d = glam::DVec3::from_array(lighting.sun_dir()).normalize();
    let model = nimbus_rpnn::sky::SkyModel {
        sun_elevation_deg: d.y.asin().to_degrees(),
        sun_azimuth_deg: d.x.atan2(d.z).to_degrees(),
        turbidity: 3.0,
        zenith: glam::DVec3::new(0.08, 0.16, 0.36),
        ground: glam::DVec3::new(0.06, 0.055, 0.05),
    };
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join(format!("sky_{}.exr", lighting.name()));
    model.latlong(256, 128).write_exr(&path, None)?;
    path.canonicalize()
        .with_context(|| format!("cannot resolve {}", path.display()))
}

/// Suite settings.
#[derive(Debug, Clone)]
pub struct SuiteOptions {
    /// Held-out clouds (1 ..= 8, the test split of the 40-cloud training set).
    pub clouds: usize,
    pub lightings: Vec<Lighting>,
    /// The sky conditions, each run once.
    pub skies: Vec<SkyCondition>,
    pub width: usize,
    pub height: usize,
    pub compare: CompareOptions,
    /// Where the held-out clouds (`.vol`) and the generated scene files go (not the report:
    /// the scenes name the clouds by absolute path).
    pub work_dir: PathBuf,
}

/// One scene of the suite.
pub struct SuiteScene {
    pub name: String,
    pub cloud: String,
    pub lighting: Lighting,
    pub sky: SkyCondition,
    pub toml: String,
}

/// A held-out cloud written to disk.
pub struct HeldOut {
    pub name: String,
    pub path: PathBuf,
    /// σ_t per unit grid value (the training set's value for this cloud).
    pub density_scale: f64,
}

/// The held-out clouds written as `.vol` files into `dir`.
pub fn held_out_clouds(n: usize, dir: &Path) -> Result<Vec<HeldOut>> {
    if !(1..=8).contains(&n) {
        bail!("--clouds must lie in 1..=8 (the held-out clouds of the 40-cloud set), got {n}");
    }
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut out = Vec::new();
    for spec in generated_set(40, 0)
        .into_iter()
        .filter(|c| c.split == "test")
        .take(n)
    {
        let vol = build_volume(&spec)?;
        let path = dir.join(format!("{}.vol", spec.name));
        let (lo, hi) = (vol.aabb().min, vol.aabb().max);
        io::write_grid(&path, vol.grid(), (lo, hi))?;
        // Scene files resolve relative paths from their own folder: store an absolute one.
        let path = path
            .canonicalize()
            .with_context(|| format!("cannot resolve {}", path.display()))?;
        out.push(HeldOut {
            name: spec.name.clone(),
            path,
            density_scale: vol.density_scale(),
        });
    }
    Ok(out)
}

/// The scene description of one suite case; `env` is the environment map of `sun+env`.
#[allow(clippy::too_many_arguments)]
pub fn scene_toml(
    vol: &Path,
    density_scale: f64,
    lighting: Lighting,
    sky: SkyCondition,
    env: Option<&Path>,
    w: usize,
    h: usize,
    seed: u64,
) -> Result<String> {
    let d = lighting.sun_dir();
    let sky = match (sky, env) {
        (SkyCondition::Sun, _) => String::new(),
        (SkyCondition::SunSky, _) => "[sky]\nradiance = [0.12, 0.2, 0.38]\n".to_string(),
        (SkyCondition::SunEnv, Some(e)) => {
            format!("[sky]\nenvmap = {:?}\n", e.display().to_string())
        }
        (SkyCondition::SunEnv, None) => bail!("the sun+env condition needs its environment map"),
    };
    Ok(format!(
        "[volume]\nfile = {:?}\ndensity_scale = {density_scale}\nalbedo = 1.0\nphase = {{ kind = \"hg\", g = 0.857 }}\n\n\
         [sun]\ndirection = [{}, {}, {}]\nirradiance = [3.0, 2.85, 2.6]\nangular_radius_deg = 0.27\n\n{sky}\n\
         [camera]\norigin = [0.0, 1.25, 3.45]\ntarget = [0.0, 0.0, 0.0]\nvfov_deg = 38.0\nwidth = {w}\nheight = {h}\n\n\
         [render]\nspp = 16\nseed = {seed}\n",
        vol.display().to_string(),
        d[0],
        d[1],
        d[2]
    ))
}

/// Runs the suite; per-scene reports go to `out/results/scenes/<name>/`, the summary to
/// `out/results.md` with `out/results/error_vs_time.{png,svg}`.
pub fn run(opts: &SuiteOptions, out: &Path, log: &mut dyn FnMut(String)) -> Result<Vec<Row>> {
    // The errors are taken over 4×4 blocks of cloud pixels: a side under 4 holds none.
    if opts.width < 4 || opts.height < 4 || opts.width > 4096 || opts.height > 4096 {
        bail!(
            "--size must lie in 4..=4096 per side (the errors are taken over 4×4 blocks), got {}x{}",
            opts.width,
            opts.height
        );
    }
    let work = out.join("results");
    let clouds = held_out_clouds(opts.clouds, &opts.work_dir.join("clouds"))?;
    let mut gpu = GpuSlot::default();
    let mut rows = Vec::new();
    let mut cases = Vec::new();
    for cloud in &clouds {
        for &l in &opts.lightings {
            for &sky in &opts.skies {
                let name = format!("{}_{}_{}", cloud.name, l.name(), sky.suffix());
                let env = match sky {
                    SkyCondition::SunEnv => Some(env_map(l, &opts.work_dir.join("skies"))?),
                    _ => None,
                };
                let text = scene_toml(
                    &cloud.path,
                    cloud.density_scale,
                    l,
                    sky,
                    env.as_deref(),
                    opts.width,
                    opts.height,
                    opts.compare.run.seed,
                )?;
                let toml_path = opts.work_dir.join("scenes").join(format!("{name}.toml"));
                std::fs::create_dir_all(toml_path.parent().expect("has a parent"))?;
                nimbus_scene::fsio::write_bytes(&toml_path, text.as_bytes())?;
                let scene = Scene::load(&toml_path)?;
                // An environment map is left to the methods that take one.
                let mut compare = opts.compare.clone();
                if sky == SkyCondition::SunEnv {
                    compare.methods.retain(|m| m.supports_env_map());
                }
                cases.push((name, scene, compare));
            }
        }
    }
    // Before any scene runs: each has blocks of cloud to measure, and (--ref-cached-only) its
    // reference.
    for (name, scene, _) in &cases {
        crate::compare::check_cloud_blocks(scene, name)?;
    }
    let scenes: Vec<&Scene> = cases.iter().map(|c| &c.1).collect();
    crate::reference::require_cached(&scenes, &opts.compare.reference, &mut gpu)?;
    for (name, scene, compare) in &cases {
        let c = compare_scene(
            scene,
            name,
            compare,
            &work.join("scenes").join(name),
            &mut gpu,
            log,
        )?;
        rows.extend(c.report.rows);
    }
    let md = results_markdown(opts, &rows, &clouds);
    let fig = error_vs_time(
        &work.join("error_vs_time"),
        "held-out clouds: median over scenes",
        "relative RMSE, 4x4 cloud blocks (median)",
        &median_series(&rows),
        None,
    );
    let mut md = md;
    match fig {
        Ok(_) => md += "\n![error against time](results/error_vs_time.png)\n",
        Err(e) => log(format!("plot skipped: {e:#}")),
    }
    let p = out.join("results.md");
    nimbus_scene::fsio::write_bytes(&p, md.as_bytes())?;
    log(format!("wrote {}", p.display()));
    Ok(rows)
}

fn condition(scene: &str) -> &'static str {
    SkyCondition::ALL
        .into_iter()
        .find(|c| scene.ends_with(&format!("_{}", c.suffix())))
        .map_or("sun", SkyCondition::name)
}

/// Per method and sky condition, the median time and median relative RMSE of each budget.
pub fn median_series(rows: &[Row]) -> Vec<Series> {
    let mut out = Vec::new();
    for m in Method::ALL {
        for cond in SkyCondition::ALL.map(SkyCondition::name) {
            let sel: Vec<&Row> = rows
                .iter()
                .filter(|r| r.method == m && condition(&r.scene) == cond)
                .collect();
            let mut budgets: Vec<u32> = sel.iter().map(|r| r.budget).collect();
            budgets.sort_unstable();
            budgets.dedup();
            let points: Vec<(f64, f64)> = budgets
                .iter()
                .map(|&b| {
                    let t: Vec<f64> = sel
                        .iter()
                        .filter(|r| r.budget == b)
                        .map(|r| r.time_s)
                        .collect();
                    let e: Vec<f64> = sel
                        .iter()
                        .filter(|r| r.budget == b)
                        .map(|r| r.rel_rmse_4x4)
                        .collect();
                    (med(t), med(e))
                })
                .collect();
            let biases: Vec<f64> = sel.iter().filter_map(|r| r.bias).collect();
            if !points.is_empty() {
                out.push(Series {
                    label: format!("{m} ({cond})"),
                    points,
                    bias: (!biases.is_empty()).then(|| med(biases)),
                });
            }
        }
    }
    out
}

fn med(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    if v.is_empty() {
        f64::NAN
    } else {
        v[v.len() / 2]
    }
}

/// "a", "a and b", "a, b and c".
fn english_list<'a>(items: impl Iterator<Item = &'a str>) -> String {
    let v: Vec<&str> = items.collect();
    match v.split_last() {
        None => String::new(),
        Some((last, [])) => last.to_string(),
        Some((last, rest)) => format!("{} and {last}", rest.join(", ")),
    }
}

fn results_markdown(opts: &SuiteOptions, rows: &[Row], clouds: &[HeldOut]) -> String {
    let c = &opts.compare;
    let methods: Vec<Method> = c.methods.clone();
    // The speed-ups' baseline: the CPU path tracer, else the GPU one (`crate::metrics`).
    let base = [Method::Pt, Method::PtGpu]
        .into_iter()
        .find(|m| methods.contains(m))
        .unwrap_or(Method::Pt);
    let mut s = String::from("# Results: error, bias and speed-up on held-out clouds\n\n");
    let _ = writeln!(
        s,
        "The analogue of Kallweit et al. 2017, Table 1: {} held-out generated clouds ({}) — the \
         test split of the training set, never seen by the shipped network — under {} light, \
         {}; {}×{} pixels; reference: path tracer in rounds \
         of 2 × {} spp until its relative noise over 4×4 cloud blocks is ≤ {:.1} % (cap {:.0} s \
         per scene; the noise reached is in each scene's report). Every error is over the cloud \
         pixels (camera optical depth ≥ 0.1), never the sky. Regenerate with `nimbus \
         bench-suite` (see BENCHMARKS.md for the exact command).\n",
        clouds.len(),
        clouds
            .iter()
            .map(|c| c.name.as_str())
            .collect::<Vec<_>>()
            .join(", "),
        english_list(opts.lightings.iter().map(|l| l.name())),
        english_list(opts.skies.iter().map(|&sky| match sky {
            SkyCondition::Sun => "sun only",
            SkyCondition::SunSky => "sun + sky",
            SkyCondition::SunEnv => "sun + environment map (a clear sky with its ground)",
        })),
        opts.width,
        opts.height,
        c.reference.spp,
        100.0 * c.reference.target_rel_noise,
        c.reference.time_cap_s
    );
    if c.run.traced_bounces > 0 && methods.iter().any(|m| m.name().starts_with("rpnn")) {
        let _ = writeln!(
            s,
            "RPNN traces {} bounce(s) before it asks the network (`--traced-bounces`; beyond the \
             paper, which asks at the first collision).\n",
            c.run.traced_bounces
        );
    }
    if c.run.query_every > 1 && methods.iter().any(|m| m.name().starts_with("rpnn")) {
        let _ = writeln!(
            s,
            "RPNN asks the network in one sample of every {} per pixel and weights the answers \
             {} (`--query-every`; beyond the paper, which asks in every sample).\n",
            c.run.query_every, c.run.query_every
        );
    }
    if c.run.rpnn_backend == nimbus_render::NetBackend::OrtInt8
        && methods.iter().any(|m| m.name().starts_with("rpnn"))
    {
        s += "RPNN's network is the model's int8 copy in ONNX Runtime (`--backend ort-int8`; \
              beyond the paper, whose network is f32).\n\n";
    }
    // Summary: converged runs per method and condition.
    s += "## Summary (largest budget of each method, all clouds and sun placements)\n\n";
    s += "| method | condition | mean ratio median [min, max] | bias median [min, max] | bias floor median | within the floor | speed-up, time to equal error: median [min, max] | speed-up, TTUV (variance only): median |\n|---|---|---|---|---|---|---|---|\n";
    for m in &methods {
        for cond in SkyCondition::ALL.map(SkyCondition::name) {
            let top: Vec<&Row> = rows
                .iter()
                .filter(|r| r.method == *m && r.bias.is_some() && condition(&r.scene) == cond)
                .collect();
            if top.is_empty() {
                continue;
            }
            let stat = |v: Vec<f64>, f: &dyn Fn(f64) -> String| {
                let v: Vec<f64> = v.into_iter().filter(|x| x.is_finite()).collect();
                if v.is_empty() {
                    return "–".to_string();
                }
                let lo = v.iter().cloned().fold(f64::MAX, f64::min);
                let hi = v.iter().cloned().fold(f64::MIN, f64::max);
                format!("{} [{}, {}]", f(med(v)), f(lo), f(hi))
            };
            let speed: Vec<f64> = top.iter().filter_map(|r| r.speedup_error).collect();
            let ttuv: Vec<f64> = top.iter().filter_map(|r| r.speedup_ttuv).collect();
            let floors: Vec<f64> = top.iter().filter_map(|r| r.bias_floor).collect();
            let within = top
                .iter()
                .filter(|r| r.within_floor() == Some(true))
                .count();
            let _ = writeln!(
                s,
                "| {m} | {cond} | {} | {} | {} | {within} of {} | {} | {} |",
                stat(top.iter().map(|r| r.mean_ratio).collect(), &|x| format!(
                    "{x:.3}"
                )),
                stat(
                    top.iter().map(|r| r.bias.unwrap_or(f64::NAN)).collect(),
                    &|x| format!("{x:.3}")
                ),
                if floors.is_empty() {
                    "–".to_string()
                } else {
                    format!("{:.3}", med(floors))
                },
                top.len(),
                if *m == base {
                    "1× (baseline)".to_string()
                } else {
                    stat(speed, &|x| crate::report::fmt_x(Some(x)))
                },
                if *m == base || ttuv.is_empty() {
                    "–".to_string()
                } else {
                    crate::report::fmt_x(Some(med(ttuv)))
                }
            );
        }
    }
    s += "\n";
    // Table 1 analogue: bias (converged) and speed-up per cloud × lighting × condition.
    s += "## Bias of converged images and speed-up over path tracing\n\n";
    s += "| cloud | light | sky |";
    for m in methods.iter().filter(|m| **m != base) {
        let _ = write!(s, " bias {m} (floor) | speed-up {m} |");
    }
    let _ = write!(s, " bias {base} |\n|---|---|---|");
    for _ in methods.iter().filter(|m| **m != base) {
        s += "---:|---:|";
    }
    s += "---:|\n";
    let mut scenes: Vec<&str> = rows.iter().map(|r| r.scene.as_str()).collect();
    scenes.dedup();
    for sc in &scenes {
        let parts: Vec<&str> = sc.rsplitn(3, '_').collect();
        let (cloud, light) = (parts.get(2).copied().unwrap_or(sc), parts[1]);
        let _ = write!(s, "| {cloud} | {light} | {} |", condition(sc));
        let top = |m: Method| {
            rows.iter()
                .rfind(|r| r.scene == *sc && r.method == m && r.bias.is_some())
        };
        for m in methods.iter().filter(|m| **m != base) {
            match top(*m) {
                Some(r) => {
                    let _ = write!(
                        s,
                        " {} | {} |",
                        crate::report::fmt_bias(r),
                        crate::report::fmt_x(r.speedup_error)
                    );
                }
                None => s += " – | – |",
            }
        }
        match top(base) {
            Some(r) => {
                let _ = write!(s, " {} |", crate::report::fmt_bias(r));
            }
            None => s += " – |",
        }
        s += "\n";
    }
    s += "\nBias: relative RMSE over 4×4 cloud blocks (tiles at least half in the cloud, averaged \
          over their cloud pixels) of each method's largest budget after the \
          noise of run and reference (both estimated from independent halves) is removed; the \
          floor is the noise removed, and a bias below twice its floor cannot be told from 0 \
          (`pm` keeps its own noise: an upper bound). The path tracer's own bias checks the \
          procedure. Speed-up: the time the path tracer needs to reach the method's 4×4 error \
          against the reference divided by the method's time (below 1×: the path tracer is \
          faster at equal error on this machine); the TTUV ratio (Kallweit §6) in the summary \
          measures variance only and ignores bias.\n\n";
    s += "## All runs\n\n";
    s += &crate::report::markdown_table(rows, true);
    s
}
