//! AdamW's update on host slices: one pass over the parameter, its gradient and both moments,
//! split over threads.
//!
//! Burn's AdamW writes each of its dozen element-wise steps as a new tensor, one thread each:
//! about 15 passes over memory a parameter. This is the same arithmetic in one pass, with the
//! same f32 operations in the same order (no fused multiply-adds), so its values are Burn's bit
//! for bit.

use multiversion::multiversion;
use rayon::prelude::*;

/// Elements per parallel task; a parameter under one chunk runs on the calling thread.
const CHUNK: usize = 1 << 15;

/// The scalars of one AdamW step, as Burn's `AdamW` computes them (its `AdamWConfig` without
/// AMSGrad or cautious weight decay).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AdamWStep {
    /// The learning rate of this step.
    pub lr: f64,
    /// First-moment decay.
    pub beta_1: f32,
    /// Second-moment decay.
    pub beta_2: f32,
    /// Added to the second moment's square root.
    pub epsilon: f32,
    /// Decoupled weight decay, as a fraction of the learning rate.
    pub weight_decay: f32,
    /// The step's count, from 1 for a parameter's first update (its moments are zero then).
    pub time: usize,
}

/// The per-element constants of a step, in f32 as Burn's ops apply them.
#[derive(Clone, Copy)]
struct Constants {
    beta_1: f32,
    beta_2: f32,
    factor_1: f32,
    factor_2: f32,
    correction_1: f32,
    correction_2: f32,
    epsilon: f32,
    keep: f32,
    lr: f32,
    first: bool,
}

impl AdamWStep {
    fn constants(self) -> Constants {
        let time = self.time as i32;
        Constants {
            beta_1: self.beta_1,
            beta_2: self.beta_2,
            factor_1: 1.0 - self.beta_1,
            factor_2: 1.0 - self.beta_2,
            correction_1: 1.0 - self.beta_1.powi(time),
            correction_2: 1.0 - self.beta_2.powi(time),
            epsilon: self.epsilon,
            keep: (1.0 - self.lr * self.weight_decay as f64) as f32,
            lr: self.lr as f32,
            first: self.time == 1,
        }
    }
}

/// One AdamW step in place: `moment_1` and `moment_2` (zeros, or ignored, at `step.time == 1`)
/// are updated with `grad`, then `param` moves by the bias-corrected ratio and decays.
pub fn step(
    param: &mut [f32],
    moment_1: &mut [f32],
    moment_2: &mut [f32],
    grad: &[f32],
    step: AdamWStep,
) {
    let n = param.len();
    assert!(
        moment_1.len() == n && moment_2.len() == n && grad.len() == n,
        "adamw: parameter, moments and gradient sizes differ"
    );
    assert!(step.time >= 1, "adamw: steps count from 1");
    let c = step.constants();
    if n <= CHUNK {
        return step_chunk(param, moment_1, moment_2, grad, c);
    }
    param
        .par_chunks_mut(CHUNK)
        .zip(moment_1.par_chunks_mut(CHUNK))
        .zip(moment_2.par_chunks_mut(CHUNK))
        .zip(grad.par_chunks(CHUNK))
        .for_each(|(((p, m), v), g)| step_chunk(p, m, v, g, c));
}

#[multiversion(targets("x86_64+avx512f+avx512vl+avx512dq", "x86_64+avx2+fma"))]
fn step_chunk(param: &mut [f32], m: &mut [f32], v: &mut [f32], grad: &[f32], c: Constants) {
    let elements = param.iter_mut().zip(m.iter_mut()).zip(v.iter_mut());
    for (((p, m), v), &g) in elements.zip(grad) {
        // Burn's order: the moments' decayed old values plus the scaled new terms.
        let (new_1, new_2) = (g * c.factor_1, (g * g) * c.factor_2);
        let (m1, v1) = if c.first {
            (new_1, new_2)
        } else {
            (*m * c.beta_1 + new_1, *v * c.beta_2 + new_2)
        };
        let delta = (m1 / c.correction_1) / ((v1 / c.correction_2).sqrt() + c.epsilon);
        *p = *p * c.keep - delta * c.lr;
        *m = m1;
        *v = v1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Burn's AdamW arithmetic, written out op by op on one element.
    fn reference(p: f32, m: f32, v: f32, g: f32, s: AdamWStep) -> (f32, f32, f32) {
        let (f1, f2) = (1.0 - s.beta_1, 1.0 - s.beta_2);
        let (m1, v1) = if s.time == 1 {
            (g * f1, g * g * f2)
        } else {
            (m * s.beta_1 + g * f1, v * s.beta_2 + g * g * f2)
        };
        let t = s.time as i32;
        let mc = m1 / (1.0 - s.beta_1.powi(t));
        let vc = v1 / (1.0 - s.beta_2.powi(t));
        let delta = mc / (vc.sqrt() + s.epsilon);
        let decayed = p * (1.0 - s.lr * s.weight_decay as f64) as f32;
        (decayed - delta * s.lr as f32, m1, v1)
    }

    #[test]
    fn matches_the_op_by_op_arithmetic_on_every_chunk() {
        // More than two chunks, so the threaded path runs, with a partial last chunk.
        let n = 2 * CHUNK + 77;
        let value = |i: usize, k: f32| ((i as f32 * 0.37 + k).sin() * 1.7).powi(3);
        let grad: Vec<f32> = (0..n).map(|i| value(i, 0.1)).collect();
        for time in [1, 2, 57] {
            let s = AdamWStep {
                lr: 3e-4,
                beta_1: 0.9,
                beta_2: 0.95,
                epsilon: 1e-8,
                weight_decay: 0.05,
                time,
            };
            let mut p: Vec<f32> = (0..n).map(|i| value(i, 1.0)).collect();
            let mut m: Vec<f32> = (0..n).map(|i| value(i, 2.0) * 0.1).collect();
            let mut v: Vec<f32> = (0..n).map(|i| value(i, 3.0).abs() * 0.01).collect();
            let expected: Vec<_> = (0..n)
                .map(|i| reference(p[i], m[i], v[i], grad[i], s))
                .collect();
            step(&mut p, &mut m, &mut v, &grad, s);
            for (i, &(ep, em, ev)) in expected.iter().enumerate() {
                assert_eq!(
                    (p[i].to_bits(), m[i].to_bits(), v[i].to_bits()),
                    (ep.to_bits(), em.to_bits(), ev.to_bits()),
                    "element {i} at step {time}"
                );
            }
        }
    }

    #[test]
    fn first_step_moves_each_weight_by_about_the_learning_rate() {
        // Adam's first update is lr * g / |g| (bias-corrected), plus the weight decay.
        let s = AdamWStep {
            lr: 1e-2,
            beta_1: 0.9,
            beta_2: 0.999,
            epsilon: 1e-8,
            weight_decay: 0.0,
            time: 1,
        };
        let mut p = vec![1.0, -2.0, 0.5];
        let (mut m, mut v) = (vec![7.0; 3], vec![7.0; 3]);
        step(&mut p, &mut m, &mut v, &[0.3, -4.0, 0.0], s);
        let expected = [1.0 - 1e-2, -2.0 + 1e-2, 0.5];
        for (got, want) in p.iter().zip(expected) {
            assert!((got - want).abs() < 1e-6, "{got} against {want}");
        }
        assert_eq!(m, [0.3, -4.0, 0.0].map(|g: f32| g * (1.0 - 0.9f32)));
    }
}
