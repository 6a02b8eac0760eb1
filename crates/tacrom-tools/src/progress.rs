//! Progress of the long commands on stderr: an `indicatif` bar, drawn only when stderr is a
//! terminal (so logs stay clean), and summary lines printed above it.

use std::borrow::Cow;

use indicatif::{ProgressBar, ProgressStyle};

/// A progress bar over a known number of steps, with summary lines.
#[derive(Clone, Debug)]
pub struct Progress {
    bar: ProgressBar,
    lines: bool,
}

impl Progress {
    /// A bar of `len` steps on stderr; with `enabled` false, neither bar nor lines.
    pub fn new(len: usize, enabled: bool) -> Self {
        let bar = if enabled {
            ProgressBar::new(len as u64)
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template("[{bar:30}] {pos:>4}/{len} {elapsed:>4} {wide_msg}")
                .expect("a valid progress template")
                .progress_chars("#>."),
        );
        Self {
            bar,
            lines: enabled,
        }
    }

    /// Says what is being done now.
    pub fn message(&self, what: impl Into<Cow<'static, str>>) {
        self.bar.set_message(what);
    }

    /// `n` steps are done.
    pub fn advance(&self, n: usize) {
        self.bar.inc(n as u64);
    }

    /// Prints a summary line on stderr, above the bar (also when stderr is not a terminal).
    pub fn line(&self, text: &str) {
        if self.lines {
            self.suspend(|| eprintln!("{text}"));
        }
    }

    /// Runs `f` with the bar cleared, for output of its own.
    pub fn suspend<R>(&self, f: impl FnOnce() -> R) -> R {
        self.bar.suspend(f)
    }

    /// Removes the bar.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
