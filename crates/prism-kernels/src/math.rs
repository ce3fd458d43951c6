//! Scalar math written so that the compiler vectorises the loops it is inlined into: no
//! branches, no calls into libm. The polynomials are written with `mul_add`, which the
//! kernels' AVX2 and AVX-512 variants compile to fused multiply-adds (half the instructions
//! of a multiply and an add, which Rust never fuses on its own); code built without FMA gets
//! the same values from a call. `exp` and `erf` are accurate to a few ulp / 5e-7 absolute,
//! which is what f32 training needs; the kernels' tests compare against libm through the
//! unfused Burn ops.

/// `log2(e)`.
const LOG2_E: f32 = std::f32::consts::LOG2_E;
/// `ln 2` split in a part exact in f32 and the rest (Cody-Waite range reduction).
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;

/// Lanes of the hand-split reductions: wide enough for AVX-512, so the compiler can keep one
/// vector accumulator (f32 sums are not reassociated automatically).
pub const LANES: usize = 16;

/// `e^x` for `x` in about [-87, 88] (clamped there: the result stays a normal f32).
///
/// `x = n ln 2 + r` with `|r| <= ln 2 / 2`, `e^r` from a degree-7 polynomial, `2^n` from the
/// exponent bits.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    let x = x.clamp(-87.0, 88.0);
    let n = x.mul_add(LOG2_E, 0.5).floor();
    let r = n.mul_add(-LN2_LO, n.mul_add(-LN2_HI, x));
    let mut p = 1.987_569_1e-4_f32;
    for c in [
        1.398_199_9e-3,
        8.333_452e-3,
        4.166_579_6e-2,
        1.666_666_5e-1,
        0.5,
    ] {
        p = p.mul_add(r, c);
    }
    let e_r = (p * r).mul_add(r, r) + 1.0;
    // `2^n` from the exponent bits. `n + 127` lies in [1, 254]; added to 2^23, it is the low
    // bits of the sum's mantissa. This stays in vector registers, where `n as i32` would not:
    // Rust's saturating float-to-int cast is compiled lane by lane (a scalar convert, compare
    // and select for each of the 16 lanes), which took a third of the attention's time on an
    // Intel Xeon (BENCHMARKS, issue 43).
    let biased = (n + (127.0 + 8_388_608.0)).to_bits() & 0xff;
    let two_n = f32::from_bits(biased << 23);
    e_r * two_n
}

/// The error function, `|error| < 5e-7` in f32 arithmetic (Abramowitz and Stegun 7.1.26).
#[inline(always)]
pub fn erf(x: f32) -> f32 {
    let a = x.abs();
    let t = 1.0 / a.mul_add(0.327_591_1, 1.0);
    let mut p = 1.061_405_4_f32;
    for c in [-1.453_152_1, 1.421_413_7, -0.284_496_74, 0.254_829_6] {
        p = p.mul_add(t, c);
    }
    let y = (-p * t).mul_add(exp(-a * a), 1.0);
    y.copysign(x)
}

/// `1 / sqrt(2)`.
const FRAC_1_SQRT_2: f32 = std::f32::consts::FRAC_1_SQRT_2;
/// `1 / sqrt(2 pi)`.
const FRAC_1_SQRT_2PI: f32 = 0.398_942_3;

/// `GELU(x) = x Phi(x) = x (1 + erf(x / sqrt 2)) / 2` (the exact GELU, as Burn's).
#[inline(always)]
pub fn gelu(x: f32) -> f32 {
    0.5 * x * (1.0 + erf(x * FRAC_1_SQRT_2))
}

/// `d GELU / dx = Phi(x) + x phi(x)`.
#[inline(always)]
pub fn gelu_derivative(x: f32) -> f32 {
    let cdf = 0.5 * (1.0 + erf(x * FRAC_1_SQRT_2));
    let pdf = FRAC_1_SQRT_2PI * exp(-0.5 * x * x);
    cdf + x * pdf
}

/// `sum_i f(a_i, b_i)` over two equally long rows, with [`LANES`] partial sums.
#[inline(always)]
pub fn sum_zip(a: &[f32], b: &[f32], f: impl Fn(f32, f32) -> f32) -> f32 {
    debug_assert_eq!(a.len(), b.len());
    let mut acc = [0.0f32; LANES];
    let (a_chunks, b_chunks) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f32 = a_chunks
        .remainder()
        .iter()
        .zip(b_chunks.remainder())
        .map(|(&x, &y)| f(x, y))
        .sum();
    for (ca, cb) in a_chunks.zip(b_chunks) {
        for i in 0..LANES {
            acc[i] += f(ca[i], cb[i]);
        }
    }
    acc.iter().sum::<f32>() + tail
}

/// `sum_i f(a_i)` over a row, with [`LANES`] partial sums.
#[inline(always)]
pub fn sum_map(a: &[f32], f: impl Fn(f32) -> f32) -> f32 {
    sum_zip(a, a, |x, _| f(x))
}

/// Each `a_i` replaced by `f(a_i)`, in one pass that also returns the new values' sum (with
/// [`LANES`] partial sums).
#[inline(always)]
pub fn map_sum(a: &mut [f32], f: impl Fn(f32) -> f32) -> f32 {
    let mut acc = [0.0f32; LANES];
    let mut chunks = a.chunks_exact_mut(LANES);
    for c in &mut chunks {
        for i in 0..LANES {
            c[i] = f(c[i]);
            acc[i] += c[i];
        }
    }
    let mut tail = 0.0;
    for x in chunks.into_remainder() {
        *x = f(*x);
        tail += *x;
    }
    acc.iter().sum::<f32>() + tail
}

/// The largest value of a row (`-inf` for an empty one).
#[inline(always)]
pub fn max(a: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; LANES];
    let chunks = a.chunks_exact(LANES);
    let tail = chunks
        .remainder()
        .iter()
        .fold(f32::NEG_INFINITY, |m, &x| m.max(x));
    for c in chunks {
        for i in 0..LANES {
            acc[i] = acc[i].max(c[i]);
        }
    }
    acc.iter().fold(tail, |m, &x| m.max(x))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_matches_libm_to_a_few_ulp() {
        let mut worst = 0.0f32;
        for i in -8700..=8800 {
            let x = i as f32 * 0.01;
            let (ours, exact) = (exp(x), x.exp());
            worst = worst.max(((ours - exact) / exact).abs());
        }
        assert!(worst < 4e-7, "relative error {worst}");
        assert_eq!(exp(0.0), 1.0);
    }

    #[test]
    fn erf_is_within_5e7_of_the_series() {
        // erf by its Taylor series in f64 (converges fast for |x| <= 3).
        let series = |x: f64| {
            let (mut term, mut sum) = (x, x);
            for n in 1..200 {
                term *= -x * x / n as f64;
                sum += term / (2 * n + 1) as f64;
            }
            sum * 2.0 / std::f64::consts::PI.sqrt()
        };
        for i in -300..=300 {
            let x = i as f64 * 0.01;
            let err = (erf(x as f32) as f64 - series(x)).abs();
            assert!(err < 5e-7, "erf({x}): error {err}");
        }
        assert_eq!(erf(10.0), 1.0);
        assert_eq!(erf(-10.0), -1.0);
    }

    #[test]
    fn gelu_derivative_matches_finite_differences() {
        for i in -60..=60 {
            let x = i as f64 * 0.1;
            let h = 1e-3;
            let g = |x: f64| gelu(x as f32) as f64;
            let numeric = (g(x + h) - g(x - h)) / (2.0 * h);
            let err = (gelu_derivative(x as f32) as f64 - numeric).abs();
            assert!(err < 2e-3, "x = {x}: {err}");
        }
    }

    #[test]
    fn reductions_cover_the_tail() {
        let a: Vec<f32> = (0..37).map(|i| i as f32 - 20.0).collect();
        assert_eq!(sum_map(&a, |x| x), a.iter().sum::<f32>());
        assert_eq!(max(&a), 16.0);
        let mut b = a.clone();
        assert_eq!(map_sum(&mut b, |x| 2.0 * x), 2.0 * a.iter().sum::<f32>());
        assert!(b.iter().zip(&a).all(|(b, a)| *b == 2.0 * a));
        assert_eq!(
            sum_zip(&a, &a, |x, y| x * y),
            a.iter().map(|x| x * x).sum::<f32>()
        );
    }
}
