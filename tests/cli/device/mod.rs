//! The wgpu backend on the machine's adapter (Mesa's lavapipe in CI): its kernels and the
//! whole model against reference paths. Named to sort early: these tests are long on a software
//! adapter, and the test harness starts tests in name order.

mod flash_attention;
mod wgpu_backend;
