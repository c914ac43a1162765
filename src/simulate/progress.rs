//! The rendering progress bar on a terminal, when the library is built
//! with the `progress` feature (on by default); without it, or when
//! stderr is not a terminal, nothing is shown.

/// Frames rendered out of the sequence's total.
pub(crate) struct RenderProgress {
    #[cfg(feature = "progress")]
    bar: indicatif::ProgressBar,
}

impl RenderProgress {
    /// A bar over `frames` frames, shown only if `show` and stderr is a
    /// terminal.
    pub(crate) fn new(frames: usize, show: bool) -> Self {
        #[cfg(feature = "progress")]
        {
            use std::io::IsTerminal;
            let bar = if show && std::io::stderr().is_terminal() {
                indicatif::ProgressBar::new(frames as u64).with_style(
                    indicatif::ProgressStyle::with_template(
                        "{msg} {bar:40} {pos}/{len} frames, {per_sec}, eta {eta}",
                    )
                    .expect("template is valid"),
                )
            } else {
                indicatif::ProgressBar::hidden()
            };
            bar.set_message("rendering");
            RenderProgress { bar }
        }
        #[cfg(not(feature = "progress"))]
        {
            let _ = (frames, show);
            RenderProgress {}
        }
    }

    /// One more frame done.
    pub(crate) fn frame_done(&self) {
        #[cfg(feature = "progress")]
        self.bar.inc(1);
    }

    /// Removes the bar from the terminal.
    pub(crate) fn finish(&self) {
        #[cfg(feature = "progress")]
        self.bar.finish_and_clear();
    }
}
