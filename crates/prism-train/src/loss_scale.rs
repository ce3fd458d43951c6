//! Dynamic loss scaling for training with the blocks in f16 ([`prism_model::Precision`]).
//!
//! f16 keeps 5 exponent bits: a gradient below about 6e-8 flushes to zero in the blocks'
//! backward pass, and one above 65504 overflows. The step multiplies the loss by a scale `S`
//! before the backward pass, which lifts the small gradients into f16's range, and divides
//! the gradients by `S` before clipping and AdamW. `S` is a power of two, so both products are
//! exact in f32. A non-finite gradient means `S` was too large: the step is skipped and `S`
//! halved. After `growth_interval` finite steps in a row `S` doubles, to find the largest
//! scale that does not overflow. bf16 has f32's exponent range and needs none of this.

use serde::{Deserialize, Serialize};

/// The scale of a run's first step: 2^16, as PyTorch's `GradScaler`.
pub const INITIAL_LOSS_SCALE: f64 = 65536.0;
/// Finite steps in a row after which the scale doubles: 2000, as PyTorch's `GradScaler`.
pub const LOSS_SCALE_GROWTH_INTERVAL: usize = 2000;
/// The smallest scale. Below 1 the scale would shrink gradients: a gradient that is not finite
/// at scale 1 is a non-finite step for the run's guard (`train.max_non_finite_steps`), not an
/// overflow the scale can absorb.
pub const MIN_LOSS_SCALE: f64 = 1.0;

/// The settings of dynamic loss scaling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossScaleConfig {
    /// The scale of the first step (a power of two).
    pub initial: f64,
    /// Finite steps in a row after which the scale doubles (at least 1).
    pub growth_interval: usize,
}

impl Default for LossScaleConfig {
    fn default() -> Self {
        Self {
            initial: INITIAL_LOSS_SCALE,
            growth_interval: LOSS_SCALE_GROWTH_INTERVAL,
        }
    }
}

/// Where the scaling stands: what a checkpoint saves (`state.json`'s `loss_scale`) so that a
/// resumed run continues with the same scale.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct LossScaleState {
    /// The scale of the next step.
    pub scale: f64,
    /// Finite steps in a row since the scale last changed.
    pub finite_steps: usize,
    /// Finite steps in a row after which the scale doubles.
    pub growth_interval: usize,
}

/// What [`LossScaler::update`] did to the scale.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ScaleChange {
    /// Unchanged.
    Kept,
    /// Doubled after `growth_interval` finite steps in a row.
    Doubled,
    /// Halved after a non-finite gradient: the step is to be skipped.
    Halved,
    /// A non-finite gradient at the smallest scale: left to the non-finite guard.
    AtMinimum,
}

/// Dynamic loss scaling: the scale of each step, updated from whether its gradient was finite.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LossScaler {
    state: LossScaleState,
}

impl LossScaler {
    /// A scaler starting at `config.initial`.
    ///
    /// # Panics
    /// If `config.initial` is not a positive power of two or `growth_interval` is 0 (the
    /// gradients would not be unscaled exactly, or the scale would double at every step).
    pub fn new(config: LossScaleConfig) -> Self {
        Self::restored(LossScaleState {
            scale: config.initial,
            finite_steps: 0,
            growth_interval: config.growth_interval,
        })
    }

    /// A scaler continuing from a checkpoint's `state`.
    ///
    /// # Panics
    /// As [`LossScaler::new`].
    pub fn restored(state: LossScaleState) -> Self {
        assert!(
            is_power_of_two(state.scale),
            "the loss scale {} is not a power of two",
            state.scale
        );
        assert!(
            state.growth_interval > 0,
            "the loss scale's growth interval must be at least 1"
        );
        Self { state }
    }

    /// The factor of the next step's loss.
    pub fn scale(&self) -> f64 {
        self.state.scale
    }

    /// Where the scaling stands (for checkpoints).
    pub fn state(&self) -> LossScaleState {
        self.state
    }

    /// Updates the scale after a step whose unscaled gradient was `finite` or not: halves it
    /// after a non-finite gradient (above [`MIN_LOSS_SCALE`]), doubles it after
    /// `growth_interval` finite steps in a row.
    pub fn update(&mut self, finite: bool) -> ScaleChange {
        let state = &mut self.state;
        if !finite {
            state.finite_steps = 0;
            if state.scale <= MIN_LOSS_SCALE {
                return ScaleChange::AtMinimum;
            }
            state.scale /= 2.0;
            return ScaleChange::Halved;
        }
        state.finite_steps += 1;
        if state.finite_steps < state.growth_interval {
            return ScaleChange::Kept;
        }
        state.finite_steps = 0;
        state.scale *= 2.0;
        ScaleChange::Doubled
    }
}

/// Whether `x` is a power of two (a normal positive float whose mantissa bits are all 0).
fn is_power_of_two(x: f64) -> bool {
    x.is_normal() && x > 0.0 && x.to_bits() & ((1u64 << 52) - 1) == 0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scale_halves_on_overflow_doubles_after_the_interval_and_stops_at_one() {
        let mut s = LossScaler::new(LossScaleConfig {
            initial: 8.0,
            growth_interval: 3,
        });
        assert_eq!(s.update(false), ScaleChange::Halved);
        assert_eq!(s.scale(), 4.0);
        assert_eq!(s.update(true), ScaleChange::Kept);
        assert_eq!(s.update(true), ScaleChange::Kept);
        // An overflow restarts the count of finite steps.
        assert_eq!(s.update(false), ScaleChange::Halved);
        assert_eq!((s.scale(), s.state().finite_steps), (2.0, 0));
        for _ in 0..2 {
            assert_eq!(s.update(true), ScaleChange::Kept);
        }
        assert_eq!(s.update(true), ScaleChange::Doubled);
        assert_eq!((s.scale(), s.state().finite_steps), (4.0, 0));
        for _ in 0..2 {
            s.update(false);
        }
        assert_eq!(s.scale(), MIN_LOSS_SCALE);
        assert_eq!(s.update(false), ScaleChange::AtMinimum);
        assert_eq!(s.scale(), MIN_LOSS_SCALE);
        assert_eq!(LossScaler::restored(s.state()), s);
        assert!(is_power_of_two(0.5) && is_power_of_two(65536.0) && !is_power_of_two(3.0));
    }

    #[test]
    #[should_panic(expected = "not a power of two")]
    fn a_scale_that_is_not_a_power_of_two_is_refused() {
        LossScaler::new(LossScaleConfig {
            initial: 1000.0,
            growth_interval: 10,
        });
    }
}
