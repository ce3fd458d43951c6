//! The core's clock under 512-bit and 256-bit FMA load: issue 43's "AVX-512 frequency
//! licences" hypothesis, measured without a cycle counter (virtual machines often have none).
//!
//!     rustc -O --edition 2021 scripts/peer/clock_probe.rs -o /tmp/clock_probe && /tmp/clock_probe
//!
//! Three readings, on one thread, for a few rounds:
//! - a dependent chain of integer adds, one cycle each, so adds per second are the clock;
//! - FMA throughput with 512-bit and with 256-bit vectors, twelve independent accumulators (more
//!   than latency times ports), as the clock it implies on a core with two FMA ports;
//! - the add chain again in 1 ms windows right after each FMA burst, where a core that lowers
//!   its clock for wide vectors (an AVX-512 licence) is still slow.
//!
//! A core without a licence penalty shows about the same clock in all of them, and 512-bit FMA
//! at about twice the 256-bit throughput. Needs an x86-64 CPU with AVX-512F.

use std::arch::x86_64::*;
use std::time::Instant;

/// Accumulators of the FMA loops: each FMA waits for its own accumulator's last one.
const CHAINS: usize = 12;

/// Adds per nanosecond (GHz) of a dependent chain of `n` integer adds.
fn chain_ghz(n: u64) -> f64 {
    let start = Instant::now();
    // SAFETY: register-only arithmetic and a loop; touches no memory.
    unsafe {
        std::arch::asm!(
            "2:", "add {x}, 1", "dec {n}", "jnz 2b",
            x = inout(reg) 0u64 => _, n = inout(reg) n => _,
            options(nomem, nostack),
        );
    }
    n as f64 / start.elapsed().as_secs_f64() / 1e9
}

/// `iters` rounds of [`CHAINS`] 512-bit FMAs; their sum, so that none is optimised away.
#[target_feature(enable = "avx512f,fma")]
unsafe fn fma_512(iters: u64) -> f32 {
    let mut acc = [_mm512_set1_ps(1.0); CHAINS];
    let (m, c) = (_mm512_set1_ps(0.999_999), _mm512_set1_ps(1e-7));
    for _ in 0..iters {
        for a in acc.iter_mut() {
            *a = _mm512_fmadd_ps(*a, m, c);
        }
    }
    acc.iter().map(|&a| _mm512_reduce_add_ps(a)).sum()
}

/// `iters` rounds of [`CHAINS`] 256-bit FMAs; their sum.
#[target_feature(enable = "avx2,fma")]
unsafe fn fma_256(iters: u64) -> f32 {
    let mut acc = [_mm256_set1_ps(1.0); CHAINS];
    let (m, c) = (_mm256_set1_ps(0.999_999), _mm256_set1_ps(1e-7));
    for _ in 0..iters {
        for a in acc.iter_mut() {
            *a = _mm256_fmadd_ps(*a, m, c);
        }
    }
    let mut lanes = [0.0f32; 8];
    acc.iter()
        .map(|&a| {
            _mm256_storeu_ps(lanes.as_mut_ptr(), a);
            lanes.iter().sum::<f32>()
        })
        .sum()
}

/// GFLOP/s of `run(iters)` on `lanes`-wide vectors, and the sum it returned.
fn gflops(iters: u64, lanes: u64, run: impl FnOnce(u64) -> f32) -> (f64, f32) {
    let start = Instant::now();
    let sum = run(iters);
    let flops = iters * CHAINS as u64 * lanes * 2;
    (flops as f64 / start.elapsed().as_secs_f64() / 1e9, sum)
}

/// Ten 1 ms readings of the add chain at `ghz`, rounded to 0.01 GHz.
fn windows(ghz: f64) -> Vec<f64> {
    let n = (ghz * 1e6) as u64;
    (0..10)
        .map(|_| (chain_ghz(n) * 100.0).round() / 100.0)
        .collect()
}

fn main() {
    assert!(
        is_x86_feature_detected!("avx512f") && is_x86_feature_detected!("fma"),
        "this probe needs AVX-512F and FMA"
    );
    let iters = 20_000_000;
    for round in 0..3 {
        let idle = chain_ghz(400_000_000);
        // SAFETY: the features were detected above.
        let (g512, s512) = gflops(iters, 16, |n| unsafe { fma_512(n) });
        let after_512 = windows(idle);
        let (g256, s256) = gflops(iters, 8, |n| unsafe { fma_256(n) });
        let after_256 = windows(idle);
        println!("round {round} (sums {s512} {s256})");
        println!("  add chain alone:            {idle:.2} GHz");
        println!(
            "  512-bit FMA: {g512:6.1} GFLOP/s = {:.2} GHz at 2 ports x 16 lanes; chain after, 1 ms windows: {after_512:?}",
            g512 / 64.0
        );
        println!(
            "  256-bit FMA: {g256:6.1} GFLOP/s = {:.2} GHz at 2 ports x 8 lanes;  chain after, 1 ms windows: {after_256:?}",
            g256 / 32.0
        );
        println!("  512-bit / 256-bit throughput: {:.2}x", g512 / g256);
    }
}
