//! The path tracer's progress bar on stderr (indicatif, with the `progress` feature); without
//! the feature — a build for a page or a library that reports progress itself — a bar that
//! shows nothing.

/// A bar over `len` tiles.
pub(crate) struct Bar {
    #[cfg(feature = "progress")]
    bar: indicatif::ProgressBar,
}

impl Bar {
    /// Shown on stderr when `show` (and the feature is on), else hidden.
    pub(crate) fn new(len: u64, show: bool) -> Self {
        #[cfg(feature = "progress")]
        {
            use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
            let bar = if show {
                ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr())
            } else {
                ProgressBar::hidden()
            };
            bar.set_style(
                ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:40}] {pos}/{len} tiles, eta {eta}",
                )
                .expect("a valid template")
                .progress_chars("=> "),
            );
            Self { bar }
        }
        #[cfg(not(feature = "progress"))]
        {
            let _ = (len, show);
            Self {}
        }
    }

    pub(crate) fn inc(&self) {
        #[cfg(feature = "progress")]
        self.bar.inc(1);
    }

    pub(crate) fn finish(&self) {
        #[cfg(feature = "progress")]
        self.bar.finish_and_clear();
    }
}
