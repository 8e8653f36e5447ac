//! Animation: a moving sun and/or an evolving density field, rendered frame by frame with the
//! temporally-coherent ring (Elek 2012 §3.2: only n_g beams per frame).
//!
//! Simulated time advances by 1/fps per frame (not wall-clock time), so animations are
//! reproducible. The sun turns about the world up axis (+y) at `sun_speed_deg_s`. Work a frame
//! does not need is left out: once the ring is full and neither the sun nor the density changed,
//! no beams are traced and J is not recomputed.
//!
//! Density sequences share one global majorant (the maximum over the whole sequence), because
//! each deposit in the ring carries the weight 1/σ̄ of the frame that traced it.

use std::path::{Path, PathBuf};

use glam::{DQuat, DVec3};
use nimbus_scene::{DensityGrid, Scene, generate};

use crate::mapper::{PhotonMapper, PmError};

/// Where the density of each frame comes from.
#[derive(Debug, Clone)]
pub enum DensitySequence {
    /// The scene's density, unchanged.
    Static,
    /// A folder of volume files (sorted by name), one per frame, looping.
    Files(Vec<PathBuf>),
    /// A procedural cloud morphing from seed s to seed s+1 over `period_frames` frames (and back).
    Morph {
        a: DensityGrid,
        b: DensityGrid,
        period_frames: u32,
    },
}

impl DensitySequence {
    /// All volume files of a folder (.vol, .npy, .vdb), sorted; an error if none.
    pub fn from_dir(dir: &Path) -> Result<Self, PmError> {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(|e| PmError::Unsupported(format!("{}: {e}", dir.display())))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                matches!(
                    p.extension().and_then(|e| e.to_str()),
                    Some("vol") | Some("npy") | Some("vdb")
                )
            })
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(PmError::Unsupported(format!(
                "{}: no .vol/.npy/.vdb files",
                dir.display()
            )));
        }
        Ok(Self::Files(files))
    }

    /// A procedural morph between two seeds of the scene's generator kind.
    pub fn morph(
        kind: nimbus_scene::CloudKind,
        seed: u64,
        res: [usize; 3],
        period_frames: u32,
    ) -> Result<Self, PmError> {
        let g =
            |s| generate::generate(kind, s, res).map_err(|e| PmError::Unsupported(e.to_string()));
        Ok(Self::Morph {
            a: g(seed)?,
            b: g(seed + 1)?,
            period_frames: period_frames.max(1),
        })
    }

    /// Density of frame `f`; `None` when it does not change.
    pub fn frame(&self, f: u32) -> Result<Option<Vec<f32>>, PmError> {
        match self {
            DensitySequence::Static => Ok(None),
            DensitySequence::Files(files) => {
                let p = &files[f as usize % files.len()];
                let g = nimbus_scene::io::read_grid(p)
                    .map_err(|e| PmError::Unsupported(e.to_string()))?;
                Ok(Some(g.grid.dense().map_err(PmError::Memory)?.into_owned()))
            }
            DensitySequence::Morph {
                a,
                b,
                period_frames,
            } => {
                let phase = (f % (2 * period_frames)) as f32 / *period_frames as f32;
                let t = if phase <= 1.0 { phase } else { 2.0 - phase };
                let t = t * t * (3.0 - 2.0 * t);
                let (a, b) = (
                    a.dense().map_err(PmError::Memory)?,
                    b.dense().map_err(PmError::Memory)?,
                );
                Ok(Some(
                    a.iter()
                        .zip(b.iter())
                        .map(|(x, y)| x + (y - x) * t)
                        .collect(),
                ))
            }
        }
    }

    /// Largest value over the whole sequence and its resolution check.
    pub fn max_value(&self, res: [usize; 3]) -> Result<f32, PmError> {
        match self {
            DensitySequence::Static => Ok(0.0),
            DensitySequence::Files(files) => {
                let mut m = 0.0f32;
                for p in files {
                    let g = nimbus_scene::io::read_grid(p)
                        .map_err(|e| PmError::Unsupported(e.to_string()))?;
                    if g.grid.res() != res {
                        return Err(PmError::Unsupported(format!(
                            "{}: resolution {:?} differs from the scene's {:?}; a density sequence must keep one resolution",
                            p.display(),
                            g.grid.res(),
                            res
                        )));
                    }
                    m = m.max(g.grid.stats().max);
                }
                Ok(m)
            }
            DensitySequence::Morph { a, b, .. } => Ok(a.stats().max.max(b.stats().max)),
        }
    }
}

/// What the animation does each frame.
#[derive(Debug, Clone)]
pub struct AnimateOptions {
    pub frames: u32,
    /// Sun angular speed about +y, degrees per simulated second.
    pub sun_speed_deg_s: f64,
    /// Simulated frames per second.
    pub fps: f64,
    pub density: DensitySequence,
    /// Reuse the last image while the impostor criteria allow (Elek §4.4).
    pub impostors: Option<crate::impostor::ImpostorCriteria>,
    /// Ray march at half resolution and upscale.
    pub half_res: bool,
}

/// Timings and work of one animation frame.
#[derive(Debug, Clone, Default)]
pub struct FrameReport {
    pub frame: u32,
    pub sun_azimuth_deg: f64,
    pub traced: bool,
    pub upsampled: bool,
    /// Why the image was ray marched (`None`: the impostor was reused).
    pub refresh: Option<crate::impostor::Refresh>,
    /// GPU milliseconds per stage (empty without timestamp support).
    pub stages: Vec<(&'static str, f64)>,
    pub wall_ms: f64,
}

/// Runs an animation, calling `sink` with each frame's image and report.
pub fn animate(
    pm: &mut PhotonMapper,
    scene: &Scene,
    opts: &AnimateOptions,
    mut sink: impl FnMut(&nimbus_scene::Image, &FrameReport) -> Result<(), PmError>,
) -> Result<(), PmError> {
    let sun0 = scene.sun.as_ref().map(|s| s.dir);
    let seq_max = opts.density.max_value(scene.volume.grid().res())?;
    if seq_max > 0.0 {
        pm.set_majorant_value(seq_max);
    }
    let mut j_valid = false;
    let mut impostor = opts.impostors.map(crate::impostor::ImpostorState::new);
    let mut last_image: Option<nimbus_scene::Image> = None;
    let mut prev_density: Option<Vec<f32>> = None;
    for f in 0..opts.frames {
        let t0 = nimbus_scene::clock::Instant::now();
        let angle = opts.sun_speed_deg_s * f as f64 / opts.fps;
        let mut changed = false;
        if let Some(d0) = sun0
            && opts.sun_speed_deg_s != 0.0
        {
            pm.set_sun_dir(DQuat::from_axis_angle(DVec3::Y, angle.to_radians()) * d0);
            changed = true;
        }
        if let Some(d) = opts.density.frame(f)? {
            if let (Some(state), Some(prev)) = (impostor.as_mut(), prev_density.as_ref()) {
                let diff: f64 = d.iter().zip(prev).map(|(a, b)| (a - b).abs() as f64).sum();
                let base: f64 = prev.iter().map(|v| *v as f64).sum::<f64>().max(1e-30);
                state.density_changed(diff / base);
            }
            pm.set_density(&d)?;
            prev_density = Some(d);
            changed = true;
        }
        pm.last_times.clear();
        let trace = changed || !pm.ring_full();
        if trace {
            pm.trace_frame(None);
            if let Some(s) = impostor.as_mut() {
                s.traced();
            }
        }
        let mut stages = std::mem::take(&mut pm.last_times);
        let upsample = trace || !j_valid;
        if upsample {
            pm.upsample();
            j_valid = true;
        }
        let refresh = match impostor.as_mut() {
            Some(s) => s.check(scene.camera.origin, pm.cloud_center(), pm.settings.ring),
            None => Some(crate::impostor::Refresh::First),
        };
        let img = match (&refresh, &last_image) {
            (None, Some(img)) => img.clone(),
            _ if opts.half_res => pm.raymarch_half(&scene.camera)?,
            _ => pm.raymarch(&scene.camera)?,
        };
        if trace {
            // The image was just read back (a sync): the 4-byte flag costs nothing more.
            pm.check_overflow()?;
        }
        last_image = Some(img.clone());
        stages.extend(std::mem::take(&mut pm.last_times));
        let report = FrameReport {
            frame: f,
            sun_azimuth_deg: angle,
            traced: trace,
            upsampled: upsample,
            refresh: if impostor.is_some() {
                refresh
            } else {
                Some(crate::impostor::Refresh::First)
            },
            stages,
            wall_ms: t0.elapsed().as_secs_f64() * 1e3,
        };
        sink(&img, &report)?;
    }
    Ok(())
}

/// Header of the animation's `timings.csv` (one [`csv_row`] per frame).
pub const CSV_HEADER: &str = "frame,sun_azimuth_deg,traced,upsampled,impostor,tracing_ms,update_ms,upsampling_ms,raymarching_ms,sun_transmittance_ms,gpu_total_ms,wall_ms\n";

/// One frame's line of `timings.csv`: GPU milliseconds per stage (stages summed by name
/// prefix; upsampling includes the cell pass and the unit conversion) and wall time.
pub fn csv_row(r: &FrameReport) -> String {
    let ms = |n: &str| {
        r.stages
            .iter()
            .filter(|(s, _)| s.starts_with(n))
            .map(|(_, v)| v)
            .sum::<f64>()
    };
    let (t, u, up, rm, st) = (
        ms("tracing"),
        ms("update"),
        ms("upsampl") + ms("conversion"),
        ms("ray"),
        ms("sun transmittance"),
    );
    format!(
        "{},{:.4},{},{},{},{t:.4},{u:.4},{up:.4},{rm:.4},{st:.4},{:.4},{:.3}\n",
        r.frame,
        r.sun_azimuth_deg,
        r.traced as u8,
        r.upsampled as u8,
        r.refresh.map_or("reuse", |x| x.name()),
        t + u + up + rm + st,
        r.wall_ms
    )
}

/// Runs an animation into folder `out`: numbered PNG frames `frame_00000.png` … at one
/// exposure (`exposure`, or the first frame's automatic one) and `timings.csv`, each file
/// written whole or not at all. Returns the CSV's path.
pub fn animate_to_dir(
    pm: &mut PhotonMapper,
    scene: &Scene,
    opts: &AnimateOptions,
    out: &std::path::Path,
    exposure: Option<f64>,
) -> Result<std::path::PathBuf, PmError> {
    let io_err = |e: nimbus_scene::Error| PmError::Unsupported(e.to_string());
    std::fs::create_dir_all(out)
        .map_err(|e| PmError::Unsupported(format!("cannot create {}: {e}", out.display())))?;
    let mut csv = String::from(CSV_HEADER);
    let mut fixed_exposure = exposure;
    animate(pm, scene, opts, |img, r| {
        let e = *fixed_exposure.get_or_insert_with(|| img.auto_exposure());
        img.write_png(out.join(format!("frame_{:05}.png", r.frame)), e)
            .map_err(io_err)?;
        csv += &csv_row(r);
        Ok(())
    })?;
    let csv_path = out.join("timings.csv");
    nimbus_scene::fsio::write_bytes(&csv_path, csv.as_bytes()).map_err(io_err)?;
    Ok(csv_path)
}

#[cfg(test)]
mod csv_tests {
    use super::*;

    /// Stages are summed by prefix into the CSV's columns, and the total is their sum.
    #[test]
    fn csv_row_sums_stages_by_name() {
        let r = FrameReport {
            frame: 3,
            sun_azimuth_deg: 1.5,
            traced: true,
            upsampled: false,
            refresh: None,
            stages: vec![
                ("tracing", 1.0),
                ("update", 0.25),
                ("upsampling cells", 2.0),
                ("upsampling", 3.0),
                ("conversion", 0.5),
                ("ray marching", 4.0),
                ("sun transmittance", 0.125),
            ],
            wall_ms: 20.0,
        };
        assert_eq!(
            csv_row(&r),
            "3,1.5000,1,0,reuse,1.0000,0.2500,5.5000,4.0000,0.1250,10.8750,20.000\n"
        );
        assert_eq!(
            CSV_HEADER.split(',').count(),
            csv_row(&r).split(',').count()
        );
    }
}
