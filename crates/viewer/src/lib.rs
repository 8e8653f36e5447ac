//! # nimbus-viewer
//!
//! `nimbus view`: the interactive side of Elek et al. 2012 — the sun moves, the cloud evolves,
//! the camera flies, and the temporally coherent photon map follows (only n_g beams traced per
//! frame, §4.1), with impostor caching (§4.4). [`Viewer`] holds the state and renders frames;
//! [`window`] shows them in a winit window through a wgpu surface, [`headless`] runs the same
//! loop without one (tests, benchmarks). Input of both is a stream of [`script::Action`]s.

pub mod headless;
pub mod script;
pub mod viewer;
pub mod window;

pub use script::{Action, Script, ViewMode};
pub use viewer::{FrameStats, Viewer, ViewerError, ViewerOptions};

/// The scene `nimbus view` opens without arguments: the demo cumulus, back-lit by a low sun.
pub const DEFAULT_SCENE: &str = include_str!("../../../scenes/demo-cumulus.toml");

/// Default window size for the default scene.
pub const DEFAULT_SIZE: (usize, usize) = (960, 600);

/// Applies the actions due at a frame around one [`Viewer::step`]: view, light and mode changes
/// before the frame is rendered, screenshots / scene saving / quitting after it, so that a
/// `screenshot` at frame f saves frame f.
pub fn run_frame<'a>(
    viewer: &mut Viewer<'_>,
    actions: impl IntoIterator<Item = &'a Action>,
    dt: f64,
) -> Result<(), ViewerError> {
    let (post, pre): (Vec<&Action>, Vec<&Action>) = actions.into_iter().partition(|a| {
        matches!(
            a,
            Action::Screenshot(_) | Action::SaveScene(_) | Action::Quit
        )
    });
    for a in pre {
        viewer.apply(a)?;
    }
    viewer.step(dt)?;
    for a in post {
        viewer.apply(a)?;
    }
    Ok(())
}
