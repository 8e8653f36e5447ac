//! The viewer's loop without a window: a fixed number of frames with a fixed simulated time step,
//! scripted input, and a final screenshot. Deterministic, so tests compare its images.

use std::path::PathBuf;

use nimbus_gpu::Gpu;
use nimbus_scene::Scene;

use crate::script::Script;
use crate::viewer::{SceneSource, Viewer, ViewerError, ViewerOptions};

/// What a headless run does.
#[derive(Debug, Clone)]
pub struct HeadlessOptions {
    /// Frames to render (a `quit` action ends earlier).
    pub frames: u32,
    /// Simulated seconds per frame (sun and density motion).
    pub dt: f64,
    pub script: Script,
    /// Saved after the last frame (`.exr` linear, else PNG).
    pub screenshot: Option<PathBuf>,
}

/// Summary of a run.
#[derive(Debug, Clone)]
pub struct HeadlessReport {
    pub frames: u32,
    pub mean_frame_ms: f64,
    /// The status line of every frame.
    pub lines: Vec<String>,
}

/// Runs the viewer headless; `log` receives each frame's status line.
pub fn run(
    gpu: &Gpu,
    scene: Scene,
    source: Option<SceneSource>,
    opts: ViewerOptions,
    h: &HeadlessOptions,
    mut log: impl FnMut(&str),
) -> Result<HeadlessReport, ViewerError> {
    let mut viewer = Viewer::new(gpu, scene, source, opts)?;
    let mut lines = Vec::new();
    let mut total_ms = 0.0;
    let mut frames = 0;
    for f in 0..h.frames {
        crate::run_frame(&mut viewer, h.script.due(f), h.dt)?;
        frames += 1;
        total_ms += viewer.stats().wall_ms;
        let line = format!("frame {f}: {}", viewer.status_line());
        log(&line);
        lines.push(line);
        if viewer.quit_requested() {
            break;
        }
    }
    if let Some(path) = &h.screenshot {
        viewer.screenshot(path)?;
    }
    Ok(HeadlessReport {
        frames,
        mean_frame_ms: total_ms / frames.max(1) as f64,
        lines,
    })
}
