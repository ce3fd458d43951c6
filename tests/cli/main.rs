//! The workspace's end-to-end tests: the built `prism` binary driven as a user drives it, and
//! the wgpu backend's kernels against reference paths on the machine's adapter.
//!
//! One test binary, one module per command or subsystem: `cargo test` runs test binaries one
//! after the other, so in one binary the long tests (a training run on the CPU, a kernel check
//! on a single-threaded software GPU) run side by side, and the stack is linked once. Run one
//! module with `cargo test --release --test cli -- learning_cli`.

mod browser;
mod common;
mod sockets;

mod ablate_cli;
mod bench_cli;
mod body_cli;
mod data_cli;
mod data_render_cli;
mod device;
mod distill_cli;
mod evaluate_cli;
mod learning_cli;
mod lvsm_cli;
mod metrics_cli;
mod quickstart_cli;
mod remote_cli;
mod splat_cli;
mod train_cli;
mod view_cli;
