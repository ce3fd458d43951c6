//! Inputs and bit-for-bit comparisons for the kernels' unit tests.

/// Uniform values in [-1, 1) from a fixed linear congruential sequence.
pub(crate) fn values(n: usize, seed: u64) -> Vec<f32> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
        })
        .collect()
}

/// The values' bit patterns, for comparing results bit for bit (`-0.0` apart from `0.0`).
pub(crate) fn bits(values: &[f32]) -> Vec<u32> {
    values.iter().map(|v| v.to_bits()).collect()
}
