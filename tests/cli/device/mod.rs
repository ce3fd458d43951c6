//! The wgpu backend on the machine's adapter (Mesa's lavapipe in CI): the whole model against
//! flex ([`backend`]), prism's flash-attention kernels against the reference path, and
//! `prism tune attention` ([`tune`]). Named to sort early: these tests are long on a software
//! adapter, and the test harness starts tests in name order (the memory test, which holds the
//! device alone, last).

mod backend;
mod flash_attention;
mod tune;
