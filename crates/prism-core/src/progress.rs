//! The progress bars of the long jobs (training, dataset synthesis, evaluation, inference).
//!
//! On a terminal a bar redraws in place. On a pipe or a log file (stderr not a terminal) a bar
//! would print nothing at all, so there it becomes plain lines instead: the same template
//! without its bar, one line at most every [`PLAIN_LINE_SECONDS`] seconds while the job ticks
//! (`PRISM_PROGRESS_SECONDS` overrides the interval).

use std::io::{self, IsTerminal, Write};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle, TermLike};

/// Seconds between two plain progress lines on a pipe or a log file.
pub const PLAIN_LINE_SECONDS: f64 = 15.0;

/// The variable that overrides [`PLAIN_LINE_SECONDS`] (seconds, `0` for a line on every tick).
pub const PLAIN_LINE_SECONDS_VAR: &str = "PRISM_PROGRESS_SECONDS";

/// A bar of `len` steps drawn on stderr with `template` (indicatif's template syntax), or a
/// hidden one when `show` is false (tests, `--quiet`), so callers tick it either way. When
/// stderr is not a terminal the bar prints plain lines ([`PlainLines`]) instead.
pub fn progress_bar(show: bool, len: u64, template: &str) -> ProgressBar {
    let (target, template) = if !show {
        (ProgressDrawTarget::hidden(), template.to_string())
    } else if io::stderr().is_terminal() {
        (ProgressDrawTarget::stderr(), template.to_string())
    } else {
        let lines = PlainLines::new(plain_line_interval());
        (
            ProgressDrawTarget::term_like(Box::new(lines)),
            without_bar(template),
        )
    };
    ProgressBar::with_draw_target(Some(len), target)
        .with_style(ProgressStyle::with_template(&template).expect("valid progress template"))
}

/// The interval between plain lines: [`PLAIN_LINE_SECONDS_VAR`] when it holds a number of
/// seconds, else [`PLAIN_LINE_SECONDS`].
fn plain_line_interval() -> Duration {
    let seconds = std::env::var(PLAIN_LINE_SECONDS_VAR)
        .ok()
        .and_then(|s| s.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s >= 0.0)
        .unwrap_or(PLAIN_LINE_SECONDS);
    Duration::from_secs_f64(seconds)
}

/// `template` without its bar and spinner placeholders (`{bar}`, `{bar:30}`, `{wide_bar}`,
/// `{spinner}`, with the brackets around them), which mean nothing on a line of plain text.
pub fn without_bar(template: &str) -> String {
    let mut out = String::with_capacity(template.len());
    let mut rest = template;
    while let Some(open) = rest.find('{') {
        let Some(close) = rest[open..].find('}') else {
            break;
        };
        let key = &rest[open + 1..open + close];
        let name = key.split(':').next().unwrap_or("");
        let mut head = &rest[..open];
        let mut tail = &rest[open + close + 1..];
        if matches!(name, "bar" | "wide_bar" | "spinner") {
            if head.ends_with('[') && tail.starts_with(']') {
                head = &head[..head.len() - 1];
                tail = &tail[1..];
            }
            out.push_str(head);
            tail = tail.strip_prefix(' ').unwrap_or(tail);
        } else {
            out.push_str(&rest[..open + close + 1]);
        }
        rest = tail;
    }
    out.push_str(rest);
    out.trim().to_string()
}

/// A draw target for a pipe or a log file: each drawn frame of a bar is one line of text on
/// stderr, at most one every `interval` (the first at once), with none of a terminal's cursor
/// moves.
#[derive(Debug)]
pub struct PlainLines {
    interval: Duration,
    last: Mutex<Option<Instant>>,
}

impl PlainLines {
    /// Lines at most every `interval`.
    pub fn new(interval: Duration) -> Self {
        Self {
            interval,
            last: Mutex::new(None),
        }
    }

    /// Whether a line may be written now (and, if so, counts it as written).
    fn due(&self) -> bool {
        let mut last = self.last.lock().unwrap_or_else(|e| e.into_inner());
        let now = Instant::now();
        if last.is_some_and(|t| now.duration_since(t) < self.interval) {
            return false;
        }
        *last = Some(now);
        true
    }
}

impl TermLike for PlainLines {
    fn width(&self) -> u16 {
        // Wide enough that indicatif never wraps or cuts a line.
        1000
    }

    fn move_cursor_up(&self, _: usize) -> io::Result<()> {
        Ok(())
    }

    fn move_cursor_down(&self, _: usize) -> io::Result<()> {
        Ok(())
    }

    fn move_cursor_right(&self, _: usize) -> io::Result<()> {
        Ok(())
    }

    fn move_cursor_left(&self, _: usize) -> io::Result<()> {
        Ok(())
    }

    fn write_line(&self, s: &str) -> io::Result<()> {
        self.write_str(s)
    }

    fn write_str(&self, s: &str) -> io::Result<()> {
        let line = s.trim();
        if line.is_empty() || !self.due() {
            return Ok(());
        }
        writeln!(io::stderr().lock(), "{line}")
    }

    fn clear_line(&self) -> io::Result<()> {
        Ok(())
    }

    fn flush(&self) -> io::Result<()> {
        io::stderr().flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plain_templates_lose_their_bars_and_keep_the_rest() {
        assert_eq!(
            without_bar("{prefix} {bar:30} {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}"),
            "{prefix} {pos}/{len} [{elapsed_precise} < {eta_precise}] {msg}"
        );
        assert_eq!(
            without_bar("evaluating [{bar:30}] {pos}/{len} views {msg} (ETA {eta})"),
            "evaluating {pos}/{len} views {msg} (ETA {eta})"
        );
        assert_eq!(
            without_bar("{spinner} synth [{wide_bar}] {pos}/{len}"),
            "synth {pos}/{len}"
        );
    }

    #[test]
    fn plain_lines_are_rate_limited() {
        let lines = PlainLines::new(Duration::from_secs(3600));
        assert!(lines.due(), "the first line is written at once");
        assert!(!lines.due(), "the next waits for the interval");
        let every = PlainLines::new(Duration::ZERO);
        assert!(every.due() && every.due());
    }
}
