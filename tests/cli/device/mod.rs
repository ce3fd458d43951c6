//! The wgpu backend's kernels on the machine's adapter (Mesa's lavapipe in CI) against
//! reference paths (the whole model against flex is `tests/wgpu_backend.rs`). Named to sort
//! early: these tests are long on a software adapter, and the test harness starts tests in
//! name order.

mod flash_attention;
