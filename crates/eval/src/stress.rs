//! `nimbus stress`: stiff and extreme inputs for every estimator.
//!
//! The matrix varies one factor at a time around a small base scene (a 16×12×16 generated
//! cumulus, σ_t scale 30, albedo 1, HG g = 0.857, side sun with a 0.27° disc, constant sky,
//! 24×16 pixels), plus combinations of extremes:
//! - phase asymmetry g ∈ {−0.999, −0.5, 0, 10⁻⁶, 0.5, 0.857, 0.95, 0.999};
//! - density scale ∈ {10⁻⁴, 1, 10², 10⁴, 10⁵} × the base;
//! - albedo ∈ {0, 0.5, 0.99, 1};
//! - sun at the zenith, grazing (elevation 0.1°), exactly opposite the view (behind the camera)
//!   and exactly along it (the camera looks into the sun disc);
//! - grids: empty, a single non-zero voxel, 1×1×1, 512×4×4;
//! - invalid voxels (NaN, +∞, negative) that must be rejected with an error naming the file
//!   and the voxel.
//!
//! Each (case, method) runs in a child process under a time limit, so a hang or an abort is
//! reported instead of stopping the matrix. The child is the same executable, started with no
//! arguments and the environment variable [`CHILD_ENV`] set to
//! `nimbus-stress-child/1␉METHOD␉SCENE` ([`CHILD_PROTOCOL`], tab-separated); an executable that
//! calls [`serve_child_if_requested`] first thing in `main` answers with one line of JSON
//! ([`ChildReport`]) on stdout. The protocol belongs to this library, not to a command line. A valid case passes when
//! the method renders (or refuses with a clear error), every pixel is finite, and no pixel is
//! brighter than the brightest radiance present without the medium — per channel the larger of
//! the sky radiance and the sun disc's radiance E / Ω_sun. With albedo ≤ 1, scattering averages
//! incident radiance with a normalised phase function and attenuation only removes light, so no
//! exact or per-sample-bounded estimate can exceed it (the path tracer's MIS-weighted samples
//! are each bounded by it).

use std::fmt::Write as _;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use glam::DVec3;
use nimbus_scene::{DensityGrid, Scene, io};
use serde::{Deserialize, Serialize};

use crate::method::{GpuSlot, Method, RunSettings, sweep};

/// The grid of a case.
#[derive(Debug, Clone)]
enum GridSpec {
    Generated,
    /// Written to `<id>.vol` (valid) or `<id>.npy` (raw values, possibly invalid).
    File {
        res: [usize; 3],
        data: Vec<f32>,
        bounds: (DVec3, DVec3),
    },
}

/// One case of the matrix.
#[derive(Debug, Clone)]
pub struct Case {
    pub id: String,
    pub axis: &'static str,
    pub value: String,
    /// The scene must be refused when loaded, with a message naming the file and this field.
    pub expect_reject: bool,
    reject_field: &'static str,
    g: f64,
    density: f64,
    albedo: f64,
    sun: DVec3,
    /// Sun irradiance per channel is this × [1, 0.95, 0.87].
    irradiance: f64,
    /// Camera origin and target.
    camera: (DVec3, DVec3),
    grid: GridSpec,
}

const BASE_DENSITY: f64 = 30.0;
const CAMERA: DVec3 = DVec3::new(0.0, 0.2, 3.2);

fn base(id: &str, axis: &'static str, value: String) -> Case {
    Case {
        id: id.to_string(),
        axis,
        value,
        expect_reject: false,
        reject_field: "voxel[",
        g: 0.857,
        density: BASE_DENSITY,
        albedo: 1.0,
        sun: DVec3::new(1.0, 0.5, 0.3).normalize(),
        irradiance: 3.0,
        camera: (CAMERA, DVec3::ZERO),
        grid: GridSpec::Generated,
    }
}

/// The full matrix.
pub fn cases() -> Vec<Case> {
    let mut v = Vec::new();
    for g in [-0.999, -0.5, 0.0, 1e-6, 0.5, 0.857, 0.95, 0.999] {
        let mut c = base(&format!("g_{g}"), "g", format!("{g}"));
        c.g = g;
        v.push(c);
    }
    for s in [1e-4, 1.0, 1e2, 1e4, 1e5] {
        let mut c = base(&format!("density_{s:e}"), "density ×", format!("{s:e}"));
        c.density = BASE_DENSITY * s;
        v.push(c);
    }
    for a in [0.0, 0.5, 0.99, 1.0] {
        let mut c = base(&format!("albedo_{a}"), "albedo", format!("{a}"));
        c.albedo = a;
        v.push(c);
    }
    let view = (-CAMERA).normalize();
    let e = 0.1f64.to_radians();
    for (name, dir) in [
        ("zenith", DVec3::Y),
        ("grazing", DVec3::new(e.cos(), e.sin(), 0.0)),
        ("opposite", -view),
        ("along_view", view),
    ] {
        let mut c = base(&format!("sun_{name}"), "sun", name.to_string());
        c.sun = dir;
        v.push(c);
    }
    let cube = (DVec3::splat(-0.5), DVec3::splat(0.5));
    let file = |res: [usize; 3], data: Vec<f32>, bounds| GridSpec::File { res, data, bounds };
    let mut single = vec![0.0f32; 16 * 16 * 16];
    single[(8 * 16 + 8) * 16 + 8] = 1.0;
    let long: Vec<f32> = (0..512 * 4 * 4)
        .map(|i| {
            let x = (i % 512) as f32;
            0.5 + 0.5 * (x * 0.05).sin()
        })
        .collect();
    let thin = 2.0 / 512.0 * 2.0;
    for (name, g) in [
        ("empty", file([16, 16, 16], vec![0.0; 4096], cube)),
        ("single_voxel", file([16, 16, 16], single, cube)),
        ("1x1x1", file([1, 1, 1], vec![1.0], cube)),
        (
            "512x4x4",
            file(
                [512, 4, 4],
                long,
                (DVec3::new(-1.0, -thin, -thin), DVec3::new(1.0, thin, thin)),
            ),
        ),
    ] {
        let mut c = base(&format!("grid_{name}"), "grid", name.to_string());
        c.grid = g;
        v.push(c);
    }
    for (name, bad) in [
        ("nan", f32::NAN),
        ("inf", f32::INFINITY),
        ("negative", -1.0),
    ] {
        let mut data = vec![0.5f32; 8 * 8 * 8];
        data[3 * 64 + 2 * 8 + 1] = bad;
        let mut c = base(&format!("voxel_{name}"), "invalid voxel", name.to_string());
        c.grid = file([8, 8, 8], data, cube);
        c.expect_reject = true;
        v.push(c);
    }
    // Values whose derived quantities leave the floating-point range: σ̄ so large that a
    // free-flight step is below one ulp of t (the walk must end, not stall), a camera whose
    // forward vector overflows, a sun whose radiance overflows the f32 image.
    let mut c = base("density_1e20", "extreme value", "density × 1e20".into());
    c.density = BASE_DENSITY * 1e20;
    v.push(c);
    let mut c = base(
        "camera_overflow",
        "extreme value",
        "origin 1e308, target −1e308".into(),
    );
    c.camera = (DVec3::new(1e308, 0.0, 0.0), DVec3::new(-1e308, 0.0, 0.0));
    c.expect_reject = true;
    c.reject_field = "camera.";
    v.push(c);
    let mut c = base("sun_1e308", "extreme value", "sun irradiance 1e308".into());
    c.irradiance = 1e308;
    c.expect_reject = true;
    c.reject_field = "sun.irradiance";
    v.push(c);
    // Combined extremes.
    for (id, g, s, a) in [
        ("combo_g0.999_density1e5", 0.999, 1e5, 1.0),
        ("combo_g-0.999_albedo0.99_density1e4", -0.999, 1e4, 0.99),
    ] {
        let mut c = base(
            id,
            "combined",
            format!("g {g}, density × {s:e}, albedo {a}"),
        );
        c.g = g;
        c.density = BASE_DENSITY * s;
        c.albedo = a;
        v.push(c);
    }
    v
}

/// The cases the test suite runs: one stiff case per axis (density × 10⁴ rather than 10⁵,
/// which takes the CPU path tracer about a minute on two cores).
pub fn subset() -> Vec<Case> {
    let want = [
        "g_0.999",
        "density_1e4",
        "albedo_0",
        "sun_along_view",
        "grid_empty",
        "grid_512x4x4",
        "voxel_nan",
        "density_1e20",
        "camera_overflow",
        "sun_1e308",
    ];
    cases()
        .into_iter()
        .filter(|c| want.contains(&c.id.as_str()))
        .collect()
}

/// Writes the case's scene (and grid file) into `dir`; returns the scene path.
pub fn write_case(c: &Case, dir: &Path) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let volume = match &c.grid {
        GridSpec::Generated => {
            "generator = { kind = \"cumulus\", seed = 3, resolution = [16, 12, 16] }".to_string()
        }
        GridSpec::File { res, data, bounds } => {
            let valid = !c.expect_reject;
            let path = dir.join(format!("{}.{}", c.id, if valid { "vol" } else { "npy" }));
            if valid {
                let grid = DensityGrid::new(*res, data.clone())
                    .map_err(|e| anyhow::anyhow!("case {}: {e}", c.id))?;
                io::write_grid(&path, &grid, *bounds)?;
            } else {
                io::npy::write_array(&path, &[res[2], res[1], res[0]], data)?;
            }
            format!(
                "file = {:?}",
                path.file_name()
                    .expect("named above")
                    .to_string_lossy()
                    .as_ref()
            )
        }
    };
    let phase = if c.g == 0.0 {
        "{ kind = \"isotropic\" }".to_string()
    } else {
        format!("{{ kind = \"hg\", g = {} }}", c.g)
    };
    let s = c.sun;
    let text = format!(
        "# nimbus stress case `{}` ({} = {})\n[volume]\n{volume}\ndensity_scale = {:e}\nalbedo = {}\nphase = {phase}\n\n\
         [sun]\ndirection = [{}, {}, {}]\nirradiance = [{:e}, {:e}, {:e}]\nangular_radius_deg = 0.27\n\n\
         [sky]\nradiance = [0.12, 0.2, 0.38]\n\n\
         [camera]\norigin = [{:e}, {:e}, {:e}]\ntarget = [{:e}, {:e}, {:e}]\nvfov_deg = 32.0\nwidth = 24\nheight = 16\n\n\
         [render]\nspp = 4\nseed = 1\n",
        c.id,
        c.axis,
        c.value,
        c.density,
        c.albedo,
        s.x,
        s.y,
        s.z,
        c.irradiance,
        c.irradiance * 0.95,
        c.irradiance * 0.87,
        c.camera.0.x,
        c.camera.0.y,
        c.camera.0.z,
        c.camera.1.x,
        c.camera.1.y,
        c.camera.1.z,
    );
    let p = dir.join(format!("{}.toml", c.id));
    nimbus_scene::fsio::write_bytes(&p, text.as_bytes())?;
    Ok(p)
}

/// Environment variable that turns an executable into a stress child (module docs).
pub const CHILD_ENV: &str = "NIMBUS_STRESS_CHILD";
/// Name and version of the child protocol; a child refuses any other version.
pub const CHILD_PROTOCOL: &str = "nimbus-stress-child/1";

/// The request a parent encodes in [`CHILD_ENV`].
pub fn child_request(method: Method, scene: &Path) -> String {
    format!("{CHILD_PROTOCOL}\t{}\t{}", method.name(), scene.display())
}

/// Parses a [`child_request`].
pub fn parse_child_request(req: &str) -> Result<(Method, PathBuf), String> {
    let mut parts = req.splitn(3, '\t');
    let (proto, method, scene) = (parts.next(), parts.next(), parts.next());
    match (proto, method, scene) {
        (Some(p), Some(m), Some(s)) if p == CHILD_PROTOCOL && !s.is_empty() => {
            Ok((m.parse()?, PathBuf::from(s)))
        }
        (Some(p), _, _) if p != CHILD_PROTOCOL => Err(format!(
            "{CHILD_ENV}: protocol `{p}`, this executable speaks `{CHILD_PROTOCOL}`"
        )),
        _ => Err(format!(
            "{CHILD_ENV}: expected `{CHILD_PROTOCOL}<TAB>METHOD<TAB>SCENE`, got `{req}`"
        )),
    }
}

/// If this process was started as a stress child ([`CHILD_ENV`] set), runs the requested
/// case, prints its [`ChildReport`] as one line of JSON and returns the exit code; `None`
/// for an ordinary start.
pub fn serve_child_if_requested() -> Option<i32> {
    let req = std::env::var(CHILD_ENV).ok()?;
    match parse_child_request(&req) {
        Ok((method, scene)) => {
            let r = run_child(&scene, method);
            match serde_json::to_string(&r) {
                Ok(line) => {
                    use std::io::Write;
                    let _ = writeln!(std::io::stdout(), "{line}");
                    Some(0)
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    Some(1)
                }
            }
        }
        Err(e) => {
            eprintln!("error: {e}");
            Some(2)
        }
    }
}

/// What a child reports.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ChildReport {
    /// `ok`, `rejected` (the scene did not load) or `error` (the method refused).
    pub status: String,
    pub msg: String,
    pub time_s: f64,
    pub nonfinite: usize,
    /// Largest pixel value / the no-medium bound of its channel.
    pub max_over_bound: f64,
    pub mean_lum: f64,
}

/// The no-medium upper bound per channel: max(sky, sun disc radiance).
pub fn radiance_bound(scene: &Scene) -> [f64; 3] {
    let sky = match &scene.sky {
        Some(nimbus_scene::Sky::Constant(c)) => [c.x, c.y, c.z],
        Some(nimbus_scene::Sky::Env(_)) => [f64::INFINITY; 3],
        None => [0.0; 3],
    };
    let disc = match &scene.sun {
        Some(s) if !s.is_delta() => {
            let r = s.angular_radius;
            let omega = (2.0 * std::f64::consts::PI * (1.0 - r.cos()))
                .min(std::f64::consts::PI * r.sin().powi(2));
            [s.irradiance.x, s.irradiance.y, s.irradiance.z].map(|e| e / omega)
        }
        Some(_) => [f64::INFINITY; 3],
        None => [0.0; 3],
    };
    [0, 1, 2].map(|k| sky[k].max(disc[k]))
}

/// Runs one method on one case scene in this process (the child side).
pub fn run_child(scene_path: &Path, method: Method) -> ChildReport {
    let t0 = Instant::now();
    let scene = match Scene::load(scene_path) {
        Ok(s) => s,
        Err(e) => {
            return ChildReport {
                status: "rejected".into(),
                msg: e.to_string(),
                time_s: t0.elapsed().as_secs_f64(),
                nonfinite: 0,
                max_over_bound: 0.0,
                mean_lum: 0.0,
            };
        }
    };
    let budget = match method {
        Method::Pm | Method::PmMarch | Method::PmElek2012 => 4,
        Method::Rpnn | Method::RpnnDirs => 1,
        _ => 4,
    };
    // Photon mapping: a ring of 4 generations × 1 024 beams for both the ray marcher and the
    // final gathering (their defaults, 16 × 8 192 and 8 × 65 536, only add run time here).
    let settings = RunSettings {
        pm_beams: 1024,
        pm_gather: nimbus_photon::GatherSettings {
            ring: 4,
            beams: 1024,
            ..Default::default()
        },
        rpnn_backend: nimbus_render::NetBackend::Auto,
        ..Default::default()
    };
    let mut gpu = GpuSlot::default();
    match sweep(&scene, method, &[budget], &settings, &mut gpu, &mut |_| {}) {
        Err(e) => ChildReport {
            status: "error".into(),
            msg: format!("{e:#}"),
            time_s: t0.elapsed().as_secs_f64(),
            nonfinite: 0,
            max_over_bound: 0.0,
            mean_lum: 0.0,
        },
        Ok(runs) => {
            let img = &runs[0].image;
            let bound = radiance_bound(&scene);
            let mut nonfinite = 0;
            let mut worst = 0.0f64;
            let mut sum = 0.0;
            for p in &img.pixels {
                for k in 0..3 {
                    let v = p[k] as f64;
                    if !v.is_finite() {
                        nonfinite += 1;
                    } else if v > 0.0 {
                        worst = worst.max(v / bound[k].max(f64::MIN_POSITIVE));
                    }
                }
                sum += (p[0] as f64 + p[1] as f64 + p[2] as f64) / 3.0;
            }
            ChildReport {
                status: "ok".into(),
                msg: String::new(),
                time_s: t0.elapsed().as_secs_f64(),
                nonfinite,
                max_over_bound: worst,
                mean_lum: sum / img.pixels.len() as f64,
            }
        }
    }
}

/// The verdict on one (case, method).
#[derive(Debug, Clone, Serialize)]
pub struct Outcome {
    pub case: String,
    pub axis: String,
    pub value: String,
    pub method: Method,
    pub pass: bool,
    /// `ok`, `rejected`, `refused`, `timeout`, `crash`, `non-finite`, `too bright`, …
    pub verdict: String,
    pub detail: String,
    pub time_s: f64,
    pub mean_lum: f64,
    pub max_over_bound: f64,
}

/// Runs `exe` as a stress child ([`CHILD_ENV`]) on `scene` with `method` under `limit` and
/// judges the result.
pub fn run_case(exe: &Path, case: &Case, scene: &Path, method: Method, limit: Duration) -> Outcome {
    let t0 = Instant::now();
    let mut out = Outcome {
        case: case.id.clone(),
        axis: case.axis.to_string(),
        value: case.value.clone(),
        method,
        pass: false,
        verdict: String::new(),
        detail: String::new(),
        time_s: 0.0,
        mean_lum: 0.0,
        max_over_bound: 0.0,
    };
    let child = Command::new(exe)
        .env(CHILD_ENV, child_request(method, scene))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn();
    let mut child = match child {
        Ok(c) => c,
        Err(e) => {
            out.verdict = "crash".into();
            out.detail = format!("cannot start {}: {e}", exe.display());
            return out;
        }
    };
    // Drain the pipes on threads so a chatty child cannot block on a full pipe.
    let mut so = child.stdout.take().expect("piped");
    let mut se = child.stderr.take().expect("piped");
    let h_out = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = so.read_to_string(&mut s);
        s
    });
    let h_err = std::thread::spawn(move || {
        let mut s = String::new();
        let _ = se.read_to_string(&mut s);
        s
    });
    let status = loop {
        match child.try_wait() {
            Ok(Some(st)) => break Some(st),
            Ok(None) if t0.elapsed() > limit => {
                let _ = child.kill();
                let _ = child.wait();
                break None;
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(20)),
            Err(_) => break None,
        }
    };
    out.time_s = t0.elapsed().as_secs_f64();
    let stdout = h_out.join().unwrap_or_default();
    let stderr = h_err.join().unwrap_or_default();
    let Some(status) = status else {
        out.verdict = "timeout".into();
        out.detail = format!("killed after {:.0} s", limit.as_secs_f64());
        return out;
    };
    let report: Option<ChildReport> = stdout
        .lines()
        .rev()
        .find_map(|l| serde_json::from_str(l).ok());
    let Some(r) = report.filter(|_| status.success()) else {
        out.verdict = "crash".into();
        out.detail = format!(
            "{status}: {}",
            stderr.lines().last().unwrap_or("no output").trim()
        );
        return out;
    };
    out.mean_lum = r.mean_lum;
    out.max_over_bound = r.max_over_bound;
    let file = scene.file_stem().unwrap_or_default().to_string_lossy();
    match (case.expect_reject, r.status.as_str()) {
        (true, "rejected") => {
            // The message must name the file and the offending field (voxel, camera, light).
            out.pass = r.msg.contains(file.as_ref()) && r.msg.contains(case.reject_field);
            out.verdict = "rejected".into();
            out.detail = r.msg;
        }
        (true, _) => {
            out.verdict = "accepted invalid input".into();
            out.detail = r.msg;
        }
        (false, "rejected") => {
            out.verdict = "rejected valid input".into();
            out.detail = r.msg;
        }
        (false, "error") => {
            // A clear refusal naming the limitation is acceptable behaviour.
            out.pass = !r.msg.is_empty();
            out.verdict = "refused".into();
            out.detail = r.msg;
        }
        _ if r.nonfinite > 0 => {
            out.verdict = "non-finite".into();
            out.detail = format!("{} non-finite values", r.nonfinite);
        }
        // 1e-3: f32 rounding of accumulated sums.
        _ if r.max_over_bound > 1.0 + 1e-3 => {
            out.verdict = "too bright".into();
            out.detail = format!("{:.3}× the no-medium bound", r.max_over_bound);
        }
        _ => {
            out.pass = true;
            out.verdict = "ok".into();
        }
    }
    out
}

/// Runs `cases` × `methods`, calling `each` per outcome.
pub fn run_matrix(
    exe: &Path,
    cases: &[Case],
    methods: &[Method],
    dir: &Path,
    limit: Duration,
    each: &mut dyn FnMut(&Outcome),
) -> Result<Vec<Outcome>> {
    let mut all = Vec::new();
    for c in cases {
        let scene = write_case(c, dir)?;
        let methods: &[Method] = if c.expect_reject {
            &[Method::Pt]
        } else {
            methods
        };
        for &m in methods {
            let o = run_case(exe, c, &scene, m, limit);
            each(&o);
            all.push(o);
        }
    }
    Ok(all)
}

/// Writes the Markdown page (see [`markdown`]) to `<out>/stability.md`, whole or not at all,
/// with this machine's cores and GPU adapter in its header; returns the path.
pub fn write_markdown(
    outcomes: &[Outcome],
    methods: &[Method],
    limit: Duration,
    out: &Path,
) -> Result<PathBuf> {
    let machine = format!(
        "{} cores{}",
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        match nimbus_gpu::Gpu::new() {
            Ok(g) => format!(", GPU: {}", g.describe()),
            Err(_) => String::new(),
        }
    );
    let md = markdown(outcomes, methods, limit, &machine);
    let p = out.join("stability.md");
    nimbus_scene::fsio::write_bytes(&p, md.as_bytes())?;
    Ok(p)
}

/// The Markdown page `docs/stability.md`.
pub fn markdown(
    outcomes: &[Outcome],
    methods: &[Method],
    limit: Duration,
    machine: &str,
) -> String {
    let mut s = String::from("# Stability on stiff and extreme inputs\n\n");
    let _ = writeln!(
        s,
        "Generated by `nimbus stress` ({machine}; time limit {:.0} s per case and method). Each \
         cell: the verdict and the wall time of a child process that loads the case's scene and \
         renders it (path tracers 4 spp, photon mapping a ring of 4 frames × 1024 beams, read by 4 spp of final gathering or one ray march, RPNN 1 spp). \
         Pass (✓): finite pixels, none brighter than max(sky, sun disc radiance) per channel \
         (`max/bound` is the largest ratio), no hang, no crash; invalid voxels must be rejected \
         with an error naming the file and the voxel. The scenes are in \
         `docs/stability/cases/`.\n",
        limit.as_secs_f64()
    );
    s += "| case | ";
    s += &methods
        .iter()
        .map(|m| m.name().to_string())
        .collect::<Vec<_>>()
        .join(" | ");
    s += " |\n|---|";
    s += &"---|".repeat(methods.len());
    s += "\n";
    let mut ids: Vec<&str> = outcomes.iter().map(|o| o.case.as_str()).collect();
    ids.dedup();
    for id in ids {
        let first = outcomes.iter().find(|o| o.case == id).expect("listed");
        let _ = write!(s, "| {} = {} |", first.axis, first.value);
        for m in methods {
            match outcomes.iter().find(|o| o.case == id && o.method == *m) {
                Some(o) => {
                    let mark = if o.pass { "✓" } else { "✗" };
                    let extra = if o.verdict == "ok" {
                        format!(" max/bound {:.1e}", o.max_over_bound)
                    } else {
                        String::new()
                    };
                    let _ = write!(s, " {mark} {} {:.1} s{extra} |", o.verdict, o.time_s);
                }
                None => s += " – |",
            }
        }
        s += "\n";
    }
    let fails: Vec<&Outcome> = outcomes.iter().filter(|o| !o.pass).collect();
    let notes: Vec<&Outcome> = outcomes
        .iter()
        .filter(|o| !o.detail.is_empty() && o.pass)
        .collect();
    let _ = writeln!(
        s,
        "\n{} of {} runs pass.\n",
        outcomes.len() - fails.len(),
        outcomes.len()
    );
    if !fails.is_empty() {
        s += "## Failures\n\n";
        for o in fails {
            let _ = writeln!(
                s,
                "- `{}` / {}: {} — {}",
                o.case, o.method, o.verdict, o.detail
            );
        }
        s += "\n";
    }
    if !notes.is_empty() {
        s += "## Messages\n\n";
        for o in notes {
            let _ = writeln!(s, "- `{}` / {}: {}", o.case, o.method, o.detail);
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A request round-trips; another version, a missing field or an unknown method is an
    /// error naming what was expected.
    #[test]
    fn child_protocol_round_trips_and_checks_its_version() {
        let scene = Path::new("/tmp/a dir/case.toml");
        let req = child_request(Method::PmElek2012, scene);
        assert_eq!(
            parse_child_request(&req).unwrap(),
            (Method::PmElek2012, scene.to_path_buf())
        );
        let e = parse_child_request("nimbus-stress-child/2\tpt\tx.toml").unwrap_err();
        assert!(e.contains("speaks `nimbus-stress-child/1`"), "{e}");
        let e = parse_child_request("nimbus-stress-child/1\tpt").unwrap_err();
        assert!(e.contains("expected"), "{e}");
        let e = parse_child_request("nimbus-stress-child/1\tfoo\tx.toml").unwrap_err();
        assert!(e.contains("unknown method"), "{e}");
    }
}
