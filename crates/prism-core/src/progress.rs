//! The progress bars of the long jobs (training, dataset synthesis, evaluation, inference).

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar of `len` steps drawn on stderr with `template` (indicatif's template syntax), or a
/// hidden one when `show` is false (tests, `--quiet`), so callers tick it either way.
pub fn progress_bar(show: bool, len: u64, template: &str) -> ProgressBar {
    let target = if show {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::hidden()
    };
    ProgressBar::with_draw_target(Some(len), target)
        .with_style(ProgressStyle::with_template(template).expect("valid progress template"))
}
