//! `nimbus view`: scene and options for the interactive viewer.

use std::path::{Path, PathBuf};

use anyhow::Result;
use nimbus_render::NetBackend;
use nimbus_scene::Scene;

use super::animate::density_sequence;
use crate::args::{PmArgs, one_of};
use crate::flags;

/// Arguments of `nimbus view`.
#[derive(clap::Args)]
pub(crate) struct ViewArgs {
    /// Scene TOML (default: the demo cumulus at 960×600).
    scene: Option<PathBuf>,
    /// Run without a window for --frames frames (default: the ring size m, i.e. converged).
    #[arg(long)]
    headless: bool,
    /// Stop after this many frames, at least 1 (windowed: close the window).
    #[arg(long, value_parser = flags::int_in(1u32, u32::MAX))]
    frames: Option<u32>,
    /// Timed actions, one `FRAME ACTION [ARGS]` per line (see `nimbus_viewer::script`).
    #[arg(long)]
    script: Option<PathBuf>,
    /// Save the last frame here when the viewer stops (`.exr`: linear; else PNG).
    #[arg(long)]
    screenshot: Option<PathBuf>,
    /// Image size WIDTHxHEIGHT, each side 1..=32768 (default: the scene camera's).
    #[arg(long, value_parser = flags::image_size(1, nimbus_scene::camera::MAX_IMAGE_SIDE))]
    size: Option<(usize, usize)>,
    /// Estimator at start: pm, pm-march, pt, rpnn or rpnn-dirs.
    #[arg(long, default_value = "pm")]
    method: String,
    /// RPNN model for RPNN mode (default: the shipped model for the scene: models/rpnn-hg.onnx,
    /// with a sky models/rpnn-hg-sky.onnx).
    #[arg(long)]
    model: Option<PathBuf>,
    /// RPNN mode: where the network runs, as `render --backend` (with wgpu the whole sample runs
    /// on the GPU where the scene allows it).
    #[arg(long, default_value = "auto", value_parser = one_of(NetBackend::ALL, NetBackend::name))]
    backend: NetBackend,
    /// Start with the sun moving.
    #[arg(long)]
    play_sun: bool,
    /// Sun angular speed about +y while playing, degrees per second (|v| ≤ 36000; headless, at
    /// most a whole turn per frame of --dt).
    #[arg(long, default_value_t = 10.0, allow_negative_numbers = true,
          value_parser = flags::f64_in(-flags::MAX_SUN_SPEED, flags::MAX_SUN_SPEED))]
    sun_speed: f64,
    /// Folder of volume files, one per frame (same resolution as the scene's volume).
    #[arg(long)]
    density_seq: Option<PathBuf>,
    /// Morph the scene's generated cloud into the next seed and back over N ≥ 1 frames.
    #[arg(long, value_parser = flags::int_in(1u32, u32::MAX))]
    evolve: Option<u32>,
    /// Density-animation frames per second, in (0, 1000] (the animation starts playing when
    /// given).
    #[arg(long, default_value_t = 10.0, value_parser = flags::f64_above(0.0, flags::MAX_FPS))]
    density_fps: f64,
    /// Ray march every frame instead of re-projecting the impostor (Elek §4.4).
    #[arg(long)]
    no_impostors: bool,
    /// Headless: simulated seconds per frame, in (0, 3600].
    #[arg(long, default_value_t = 1.0 / 30.0, value_parser = flags::f64_above(0.0, flags::MAX_DT))]
    dt: f64,
    /// Print every frame's status line (stages, photons, impostor criteria).
    #[arg(long)]
    log: bool,
    /// PNG exposure, a finite number > 0 (default: the first frame's auto exposure).
    #[arg(long, value_parser = crate::args::positive_finite)]
    exposure: Option<f64>,
    #[command(flatten)]
    pm: PmArgs,
    #[command(flatten)]
    gather: crate::args::GatherArgs,
}

impl ViewArgs {
    /// The ranges that depend on two flags: headless, the sun turns --sun-speed × --dt degrees
    /// per frame (the window's frame time is its own, at most 0.25 s).
    pub(crate) fn check_flag_combinations(&self) -> Result<(), String> {
        if self.headless {
            flags::check_turn_per_frame(self.sun_speed, self.dt, "--sun-speed × --dt")?;
        }
        Ok(())
    }
}

/// `nimbus view`.
pub(crate) fn run(args: ViewArgs) -> Result<()> {
    let ViewArgs {
        scene,
        headless,
        frames,
        script,
        screenshot,
        size,
        method,
        model,
        backend,
        play_sun,
        sun_speed,
        density_seq,
        evolve,
        density_fps,
        no_impostors,
        dt,
        log,
        exposure,
        pm: pm_args,
        gather,
    } = args;
    use nimbus_viewer::{Script, ViewMode, ViewerOptions};
    let (mut s, source) = match &scene {
        Some(p) => {
            let s = Scene::load(p)?;
            let text = nimbus_scene::fsio::read_to_string(p)?;
            let dir = p.parent().map(|d| d.to_path_buf()).unwrap_or_default();
            let dir = std::fs::canonicalize(if dir.as_os_str().is_empty() {
                Path::new(".")
            } else {
                &dir
            })
            .unwrap_or(dir);
            (s, Some((text, dir)))
        }
        None => {
            let text = nimbus_viewer::DEFAULT_SCENE;
            let label = Path::new("scenes/demo-cumulus.toml");
            let mut s = Scene::from_toml_str(text, Path::new("."), label)?;
            let (w, h) = nimbus_viewer::DEFAULT_SIZE;
            s.camera = s.camera.with_size(w, h)?;
            (s, Some((text.to_string(), std::env::current_dir()?)))
        }
    };
    if let Some((w, h)) = size {
        s.camera = s
            .camera
            .with_size(w, h)
            .map_err(|e| anyhow::anyhow!("--size: {e}"))?;
    }
    let method = ViewMode::parse(&method).map_err(|e| anyhow::anyhow!("--method: {e}"))?;
    // The viewer's estimators but the CPU path tracer compute in f32 (its switch to pm or RPNN
    // needs the same).
    nimbus_render::check_f32_scale(&s, nimbus_render::Method::Pm)?;
    let density = density_sequence(&s, density_seq, evolve)?;
    let animated = !matches!(density, nimbus_photon::animate::DensitySequence::Static);
    let script = match &script {
        Some(p) => Script::load(p)?,
        None => Script::default(),
    };
    let opts = ViewerOptions {
        // The sun-transmittance rebuild is amortised over frames (chosen from the volume).
        pm: nimbus_photon::PmSettings {
            sun_chunks: 0,
            ..pm_args.settings(s.render.seed as u32)?
        },
        gather: gather.settings(pm_args.ring, pm_args.beams),
        half_res: pm_args.half_res,
        impostors: (!no_impostors).then(Default::default),
        density,
        sun_speed_deg_s: sun_speed,
        density_fps,
        play_sun,
        play_density: animated,
        method,
        exposure,
        rpnn_model: model,
        rpnn_backend: backend,
    };
    // Asked for on the command line, RPNN without a usable model is an error here (the key's
    // switch in a running viewer only leaves a note and keeps the method).
    if method.method().is_rpnn() {
        // The model the estimator will load.
        let path = nimbus_render::rpnn_model_path(
            opts.rpnn_model.as_deref(),
            method.method(),
            &s.phase_desc,
            s.sky.is_some(),
        );
        nimbus_rpnn::model::Rpnn::load(&path)
            .map_err(|e| anyhow::anyhow!("--method {}: {e}", method.method().name()))?;
    }
    if headless {
        let frames = frames.unwrap_or(match method {
            ViewMode::Pm => pm_args
                .ring
                .unwrap_or(nimbus_photon::mapper::DEFAULT_GATHER_RING),
            _ => pm_args.ring.unwrap_or(100),
        });
        let gpu = nimbus_gpu::Gpu::new()?;
        let h = nimbus_viewer::headless::HeadlessOptions {
            frames,
            dt,
            script,
            screenshot: screenshot.clone(),
        };
        let report = nimbus_viewer::headless::run(&gpu, s, source, opts, &h, |line| {
            if log {
                say!("{line}");
            }
        })?;
        say!(
            "nimbus view --headless on {}: {} frames, {:.1} ms per frame{}",
            gpu.describe(),
            report.frames,
            report.mean_frame_ms,
            screenshot
                .map(|p| format!(", wrote {}", p.display()))
                .unwrap_or_default()
        );
        return Ok(());
    }
    nimbus_viewer::window::run(
        s,
        source,
        opts,
        nimbus_viewer::window::WindowOptions {
            script,
            frames,
            screenshot,
            log,
        },
    )?;
    Ok(())
}
