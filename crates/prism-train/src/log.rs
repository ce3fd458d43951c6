//! `metrics.jsonl`: one JSON object per line, per training step, validation and baseline.
//!
//! - a step: `{"step", "loss", <every loss term by name>, "lr", "lr_heads", "grad_norm",
//!   "seconds"}` (`step` counts steps done, from 1), and `"loss_scale"` (the factor of the
//!   step's loss in its backward pass) when the run scales its loss (f16);
//! - a skipped step: `{"step", "skipped": true, "reason", "loss", "grad_norm", "lr", ...}`;
//! - a validation: `{"step", "val_psnr", "val_ssim", "val_lpips", "samples"}` (step 0 is the
//!   initial model);
//! - the baseline, once: `{"step": 0, "copy_source_psnr", "copy_source_ssim",
//!   "copy_source_lpips"}`.
//!
//! Non-finite numbers are written as `null`.

use std::fs::{self, File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use serde_json::Value;

use crate::error::{Result, TrainError};

/// File name of the log in a run folder.
pub const METRICS_FILE: &str = "metrics.jsonl";

/// The metrics log of a run, appended to line by line (each line is flushed, so a killed run
/// keeps every line it wrote).
pub struct MetricsLog {
    path: PathBuf,
    file: File,
}

impl MetricsLog {
    /// Opens `run/metrics.jsonl` for appending. With `keep_until = Some(step)` (a resumed run)
    /// the lines of later steps, written after the checkpoint the run resumes from, are removed
    /// first: the resumed run writes them again.
    ///
    /// # Errors
    /// I/O errors, naming the file.
    pub fn open(run: &Path, keep_until: Option<usize>) -> Result<Self> {
        let path = run.join(METRICS_FILE);
        if let Some(step) = keep_until.filter(|_| path.exists()) {
            let kept: Vec<String> = read_lines(&path)?
                .into_iter()
                .filter(|(value, _)| line_step(value).is_some_and(|s| s <= step))
                .map(|(_, line)| line)
                .collect();
            let mut text = kept.join("\n");
            if !text.is_empty() {
                text.push('\n');
            }
            prism_core::files::write_bytes(&path, text.as_bytes())
                .map_err(|e| TrainError::io(&path, e))?;
        }
        let file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(&path)
            .map_err(|e| TrainError::io(&path, e))?;
        Ok(Self { path, file })
    }

    /// Appends one object as a line.
    ///
    /// # Errors
    /// I/O errors, naming the file.
    pub fn write(&mut self, value: &Value) -> Result<()> {
        let mut line = serde_json::to_string(value).expect("JSON value serialises");
        line.push('\n');
        self.file
            .write_all(line.as_bytes())
            .and_then(|()| self.file.flush())
            .map_err(|e| TrainError::io(&self.path, e))
    }

    /// The log file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

fn line_step(value: &Value) -> Option<usize> {
    value.get("step")?.as_u64().map(|s| s as usize)
}

fn read_lines(path: &Path) -> Result<Vec<(Value, String)>> {
    let text = fs::read_to_string(path).map_err(|e| TrainError::io(path, e))?;
    Ok(text
        .lines()
        .filter(|l| !l.trim().is_empty())
        // A line cut short by a kill is dropped.
        .filter_map(|l| serde_json::from_str(l).ok().map(|v| (v, l.to_string())))
        .collect())
}

/// Every object of a metrics log, in order (a line cut short by a kill is skipped).
///
/// # Errors
/// When the file cannot be read.
pub fn read_metrics(path: &Path) -> Result<Vec<Value>> {
    Ok(read_lines(path)?.into_iter().map(|(v, _)| v).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn resuming_drops_the_lines_after_the_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let mut log = MetricsLog::open(dir.path(), None).unwrap();
        for step in 1..=5 {
            log.write(&json!({"step": step, "loss": 1.0 / step as f64}))
                .unwrap();
        }
        log.write(&json!({"step": 4, "val_psnr": f64::NAN}))
            .unwrap();
        drop(log);
        let mut log = MetricsLog::open(dir.path(), Some(3)).unwrap();
        log.write(&json!({"step": 4, "loss": 0.2})).unwrap();
        let lines = read_metrics(&dir.path().join(METRICS_FILE)).unwrap();
        let steps: Vec<u64> = lines.iter().map(|v| v["step"].as_u64().unwrap()).collect();
        assert_eq!(steps, vec![1, 2, 3, 4]);
        assert_eq!(lines[3]["loss"], json!(0.2));
    }
}
