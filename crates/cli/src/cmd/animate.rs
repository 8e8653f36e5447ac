//! `nimbus animate`: a photon-mapped animation to numbered PNG frames and per-frame timings.

use std::path::PathBuf;

use anyhow::{Result, bail};
use nimbus_photon::animate::{AnimateOptions, DensitySequence};
use nimbus_scene::{Scene, io};

use crate::args::{PmArgs, positive_finite};
use crate::flags;

#[derive(clap::Args)]
pub(crate) struct AnimateArgs {
    scene: PathBuf,
    /// Frames to render and write (at least 1).
    #[arg(long, default_value_t = 100, value_parser = clap::value_parser!(u32).range(1..))]
    frames: u32,
    /// Sun angular speed about +y, degrees per simulated second (|v| ≤ 36000; at most a
    /// whole turn per frame).
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true,
          value_parser = flags::f64_in(-flags::MAX_SUN_SPEED, flags::MAX_SUN_SPEED))]
    sun_speed: f64,
    /// Simulated frames per second, in (0, 1000] (the sun moves sun_speed / fps degrees per
    /// frame).
    #[arg(long, default_value_t = 30.0, value_parser = flags::f64_above(0.0, flags::MAX_FPS))]
    fps: f64,
    /// Folder of volume files, one per frame (same resolution as the scene's volume).
    #[arg(long)]
    density_seq: Option<PathBuf>,
    /// Morph the scene's generated cloud into the next seed and back over N ≥ 1 frames.
    #[arg(long, value_parser = flags::int_in(1u32, u32::MAX))]
    evolve: Option<u32>,
    /// Reuse the last image while Elek's four impostor criteria allow.
    #[arg(long)]
    impostors: bool,
    #[command(flatten)]
    pm: PmArgs,
    /// Output folder (frames frame_00000.png …, timings.csv).
    #[arg(long, short, default_value = "out/animation")]
    out: PathBuf,
    /// PNG exposure (default: fixed from the first frame's 99th-percentile luminance).
    #[arg(long, value_parser = positive_finite)]
    exposure: Option<f64>,
}

impl AnimateArgs {
    /// The range that depends on two flags: the sun turns --sun-speed / --fps degrees per
    /// frame.
    pub(crate) fn check_flag_combinations(&self) -> Result<(), String> {
        flags::check_turn_per_frame(self.sun_speed, 1.0 / self.fps, "--sun-speed / --fps")
    }
}

pub(crate) fn run(a: AnimateArgs) -> Result<()> {
    let AnimateArgs {
        scene,
        frames,
        sun_speed,
        fps,
        density_seq,
        evolve,
        impostors,
        pm: pm_args,
        out,
        exposure,
    } = a;
    let s = Scene::load(&scene)?;
    let density = density_sequence(&s, density_seq, evolve)?;
    // The folder is made and checked before any GPU work.
    io::check_writable(out.join("timings.csv"))?;
    let gpu = nimbus_gpu::Gpu::new()?;
    let settings = pm_args.settings(s.render.seed as u32)?;
    let mut pm = nimbus_photon::PhotonMapper::new(&gpu, &s, settings)?;
    let opts = AnimateOptions {
        frames,
        sun_speed_deg_s: sun_speed,
        fps,
        density,
        impostors: impostors.then(Default::default),
        half_res: pm_args.half_res,
    };
    nimbus_photon::animate::animate_to_dir(&mut pm, &s, &opts, &out, exposure)?;
    say!(
        "{} frames on {} -> {}",
        frames,
        gpu.describe(),
        out.display()
    );
    Ok(())
}

/// The density animation asked for by `--density-seq` / `--evolve` (`animate` and `view`).
pub(crate) fn density_sequence(
    s: &Scene,
    density_seq: Option<PathBuf>,
    evolve: Option<u32>,
) -> Result<DensitySequence> {
    Ok(match (density_seq, evolve) {
        (Some(_), Some(_)) => bail!("give --density-seq or --evolve, not both"),
        (Some(d), None) => DensitySequence::from_dir(&d)?,
        (None, Some(n)) => match &s.volume_source {
            nimbus_scene::VolumeSource::Generated { kind, seed } => {
                DensitySequence::morph(*kind, *seed, s.volume.grid().res(), n)?
            }
            _ => bail!("--evolve needs a scene whose volume uses `generator`"),
        },
        (None, None) => DensitySequence::Static,
    })
}
