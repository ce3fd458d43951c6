//! The learning-rate schedule: linear warm-up, then cosine annealing to a minimum (paper
//! supplement: "Cosine Annealing ... with a minimum learning rate of 1e-6").

use std::f64::consts::PI;

use burn::optim::LearningRate;
use burn::optim::lr_scheduler::{LrScheduler, LrSchedulerRecord};

/// Record key of the scheduler's step counter.
const STEP_KEY: &str = "step";

/// Linear warm-up from 0 to `peak` over `warmup` steps, then a cosine from `peak` down to `min`
/// at the last step:
///
/// - step `s < warmup`: `lr = peak (s + 1) / warmup`;
/// - otherwise, with `t = (s - warmup) / (total - warmup - 1)` clamped to [0, 1]:
///   `lr = min + (peak - min) (1 + cos(pi t)) / 2`.
///
/// `s` counts optimizer steps from 0, so the first step after the warm-up runs at `peak` and
/// step `total - 1` at `min`. The learning rate is a pure function of the step ([`lr_at`]); the
/// scheduler's state is only the step counter, stored in its Burn record.
///
/// [`lr_at`]: WarmupCosine::lr_at
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WarmupCosine {
    /// The peak learning rate, reached at the end of the warm-up.
    pub peak: f64,
    /// The learning rate at the last step.
    pub min: f64,
    /// Warm-up steps (0: start at the peak).
    pub warmup: usize,
    /// Steps of the whole schedule.
    pub total: usize,
    /// The next step [`LrScheduler::step`] returns the learning rate of.
    pub step: usize,
}

impl WarmupCosine {
    /// A schedule at step 0.
    pub fn new(peak: f64, min: f64, warmup: usize, total: usize) -> Self {
        Self {
            peak,
            min,
            warmup,
            total,
            step: 0,
        }
    }

    /// The learning rate of step `s` (0-based).
    pub fn lr_at(&self, s: usize) -> f64 {
        if s < self.warmup {
            return self.peak * (s + 1) as f64 / self.warmup as f64;
        }
        let span = self.total.saturating_sub(self.warmup + 1).max(1);
        let t = ((s - self.warmup) as f64 / span as f64).clamp(0.0, 1.0);
        self.min + (self.peak - self.min) * 0.5 * (1.0 + (PI * t).cos())
    }
}

impl LrScheduler for WarmupCosine {
    fn step(&mut self) -> LearningRate {
        let lr = self.lr_at(self.step);
        self.step += 1;
        lr
    }

    fn to_record(&self) -> LrSchedulerRecord {
        LrSchedulerRecord::new().with_scalar(STEP_KEY, self.step as u64)
    }

    fn load_record(&mut self, record: LrSchedulerRecord) {
        if let Some(step) = record.scalar::<u64>(STEP_KEY) {
            self.step = step as usize;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn warm_up_then_cosine_to_the_minimum() {
        let s = WarmupCosine::new(1e-3, 1e-6, 4, 14);
        let lrs: Vec<f64> = (0..14).map(|i| s.lr_at(i)).collect();
        assert_eq!(&lrs[..4], &[2.5e-4, 5e-4, 7.5e-4, 1e-3]);
        assert_eq!(lrs[4], 1e-3);
        // Halfway through the cosine part (steps 4..=13, t = 0.5 at step 8.5): between 8 and 9.
        let mid = 1e-6 + (1e-3 - 1e-6) * 0.5;
        assert!(lrs[8] > mid && lrs[9] < mid);
        assert!((lrs[13] - 1e-6).abs() < 1e-18, "{}", lrs[13]);
        assert!(lrs[4..].windows(2).all(|w| w[1] < w[0]), "decreasing");
        // Past the end it stays at the minimum.
        assert!((s.lr_at(100) - 1e-6).abs() < 1e-18);
        // No warm-up: the first step is the peak.
        assert_eq!(WarmupCosine::new(0.1, 0.0, 0, 10).lr_at(0), 0.1);
    }

    #[test]
    fn stepping_matches_the_pure_function_and_resumes_from_its_record() {
        let mut a = WarmupCosine::new(2e-4, 1e-6, 3, 20);
        let first: Vec<f64> = (0..7).map(|_| a.step()).collect();
        assert_eq!(first, (0..7).map(|i| a.lr_at(i)).collect::<Vec<_>>());
        let record = a.to_record();
        let mut b = WarmupCosine::new(2e-4, 1e-6, 3, 20);
        b.load_record(record);
        for _ in 0..13 {
            assert_eq!(a.step(), b.step());
        }
    }
}
