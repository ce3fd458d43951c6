//! What the trainer does when a served device (`prism serve`) fails mid-run: it stops with
//! one error naming the device, instead of a panic, and leaves the last checkpoint for
//! `--resume`.
//!
//! A lost server shows up as a failed read wherever the trainer next needs one of its tensors:
//! in a device's worker (reported by [`crate::DataParallel`] with the device's name), or on
//! the trainer's own thread (the optimizer, clipping, validation, a checkpoint), where
//! [`guarded`] catches it and asks the servers which one is gone.

use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};

use prism_remote::{DeviceList, DeviceSpec, accepts_connections};

use crate::error::{Result, TrainError};

thread_local! {
    /// Whether this thread runs inside [`guarded`], which reports a panic itself.
    static GUARDING: Cell<bool> = const { Cell::new(false) };
}

/// Whether a panic on this thread is caught and reported by [`guarded`] (a panic hook need
/// not print it).
pub fn reports_panics() -> bool {
    GUARDING.get()
}

/// What a run whose served device failed can do next.
pub const RESUME_HINT: &str = "the last checkpoint is intact: restart the server (on WebSocket \
                               on a new port, or restart them all) and run again with --resume, \
                               or resume with fewer --devices";

/// The `--devices` entries of `list`, one per device: what errors call the devices.
pub fn device_names(list: &DeviceList) -> Vec<String> {
    list.specs().iter().map(ToString::to_string).collect()
}

/// Runs `work`; with served devices in `list`, a panic (a server that stopped answering) is
/// turned into a [`TrainError::Worker`] naming the servers that no longer accept
/// connections.
///
/// # Errors
/// `work`'s, and a lost server.
pub fn guarded<T>(list: &DeviceList, work: impl FnOnce() -> Result<T>) -> Result<T> {
    if !list.has_remote() {
        return work();
    }
    GUARDING.set(true);
    let outcome = catch_unwind(AssertUnwindSafe(work));
    GUARDING.set(false);
    outcome.unwrap_or_else(|payload| {
        let message = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("a panic")
            .lines()
            .next()
            .unwrap_or_default()
            .to_string();
        Err(TrainError::Worker(lost_server(list, &message)))
    })
}

/// The error of a step that failed with `message` on served devices.
fn lost_server(list: &DeviceList, message: &str) -> String {
    let remote: Vec<&DeviceSpec> = list.specs().iter().filter(|s| s.is_remote()).collect();
    let gone: Vec<String> = remote
        .iter()
        .filter(|spec| accepts_connections(spec) == Some(false))
        .map(ToString::to_string)
        .collect();
    let which = if gone.is_empty() {
        let all: Vec<String> = remote.iter().map(ToString::to_string).collect();
        format!(
            "one of the served devices stopped answering ({})",
            all.join(", ")
        )
    } else {
        format!("the server of {} stopped answering", gone.join(", "))
    };
    format!("{which}: {message}; {RESUME_HINT}")
}
