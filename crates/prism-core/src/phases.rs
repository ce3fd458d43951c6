//! Wall time per phase of a job (dataset, data loading, training steps, validation,
//! checkpoints, evaluation, LPIPS): the one stopwatch of prism's phase timings.
//!
//! A phase is timed by wrapping its call in [`timed`], which adds the call's wall time to the
//! totals of the calling thread; a job reads [`phase_totals`] before and after a part of its
//! work and takes the difference ([`PhaseTimes::since`]). The totals are per thread, so two
//! jobs on two threads (two tests) never mix their times: the training loop, validation and
//! evaluation run on the thread that called them, and work they hand to rayon's pool (batches
//! scored at once, with their LPIPS) is timed with [`recorded`] and [`credit`]ed back to it.
//!
//! On GPU backends kernels run asynchronously: a phase's wall time covers its device work only
//! up to its last read of values to the host (a synchronisation). Every phase below ends with
//! such a read (the loss values of the log, the scores, the checkpoint's weights), so each
//! phase's time includes its own kernels; what a phase queues after its last read (the
//! optimizer's update after the step's last loss read) is counted in the next phase that reads.

use std::cell::Cell;
use std::time::Instant;

/// A phase of a training or evaluation job.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Phase {
    /// Synthesising the dataset, or finding it in the cache.
    Dataset,
    /// The training loop waiting for the prefetcher's next batch (host only: the worker threads
    /// load ahead, so this is the time loading did not hide).
    DataWait,
    /// Training steps: batching and upload, forward, loss, backward, clipping (the gradient
    /// norm's read) and the optimizer's update; ends with the read of the step's loss values.
    Steps,
    /// Validation during training: the held-out views' scores (LPIPS included), the sample
    /// grid and the training curves.
    Validation,
    /// Writing checkpoints (reads every weight and the optimizer's state to the host).
    Checkpoints,
    /// An evaluation: loading the checkpoint and LPIPS, forward passes on the test views,
    /// scores (LPIPS included), grids, the FPS timing, the report.
    Evaluation,
    /// LPIPS distances in scoring; nested inside [`Phase::Validation`] and
    /// [`Phase::Evaluation`] (not a separate part of the wall time). Starts after the scores
    /// read before it (PSNR, SSIM) have synchronised the prediction.
    Lpips,
}

impl Phase {
    /// Every phase, in the order a job goes through them.
    pub const ALL: [Phase; 7] = [
        Phase::Dataset,
        Phase::DataWait,
        Phase::Steps,
        Phase::Validation,
        Phase::Checkpoints,
        Phase::Evaluation,
        Phase::Lpips,
    ];

    /// Whether the phase runs inside another one (LPIPS inside validation and evaluation), so
    /// that it must not be added to the others.
    pub fn is_nested(self) -> bool {
        self == Phase::Lpips
    }

    fn index(self) -> usize {
        self as usize
    }
}

/// Seconds spent in each [`Phase`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PhaseTimes {
    seconds: [f64; Phase::ALL.len()],
}

impl PhaseTimes {
    /// Seconds spent in `phase`.
    pub fn get(&self, phase: Phase) -> f64 {
        self.seconds[phase.index()]
    }

    /// Adds `seconds` to `phase`.
    pub fn add(&mut self, phase: Phase, seconds: f64) {
        self.seconds[phase.index()] += seconds;
    }

    /// The times spent since the totals were `earlier` (each phase's difference).
    pub fn since(&self, earlier: &PhaseTimes) -> PhaseTimes {
        let mut out = *self;
        for (s, e) in out.seconds.iter_mut().zip(earlier.seconds) {
            *s -= e;
        }
        out
    }

    /// Every phase's seconds times `factor`.
    pub fn scaled(&self, factor: f64) -> PhaseTimes {
        let mut out = *self;
        out.seconds.iter_mut().for_each(|s| *s *= factor);
        out
    }

    /// The sum of the phases that are not nested in others: the wall time they cover.
    pub fn top_level_seconds(&self) -> f64 {
        Phase::ALL
            .iter()
            .filter(|p| !p.is_nested())
            .map(|&p| self.get(p))
            .sum()
    }
}

thread_local! {
    static TOTALS: Cell<PhaseTimes> = Cell::new(PhaseTimes::default());
}

/// Runs `f`, adding its wall time to `phase` in this thread's totals.
pub fn timed<T>(phase: Phase, f: impl FnOnce() -> T) -> T {
    let start = Instant::now();
    let out = f();
    let seconds = start.elapsed().as_secs_f64();
    TOTALS.with(|totals| {
        let mut now = totals.get();
        now.add(phase, seconds);
        totals.set(now);
    });
    out
}

/// This thread's totals since it started (take differences with [`PhaseTimes::since`]).
pub fn phase_totals() -> PhaseTimes {
    TOTALS.with(Cell::get)
}

/// Runs `f`, returning with its result the phase times it added, which are taken out of this
/// thread's totals again: for work that may run on another thread of rayon's pool (a batch
/// scored beside another), whose times the calling thread then [`credit`]s to itself.
pub fn recorded<T>(f: impl FnOnce() -> T) -> (T, PhaseTimes) {
    let before = phase_totals();
    let out = f();
    let times = phase_totals().since(&before);
    TOTALS.with(|totals| totals.set(before));
    (out, times)
}

/// Adds `times` (from [`recorded`]) to this thread's totals.
pub fn credit(times: &PhaseTimes) {
    TOTALS.with(|totals| {
        let mut now = totals.get();
        for phase in Phase::ALL {
            now.add(phase, times.get(phase));
        }
        totals.set(now);
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recorded_times_move_to_the_thread_that_credits_them() {
        // Each test runs on a thread of its own, whose totals start at zero.
        assert_eq!(phase_totals(), PhaseTimes::default());
        let (value, times) = std::thread::spawn(|| {
            recorded(|| {
                timed(Phase::Lpips, || {
                    std::thread::sleep(std::time::Duration::from_millis(20));
                    7
                })
            })
        })
        .join()
        .unwrap();
        assert_eq!(value, 7);
        assert!(times.get(Phase::Lpips) >= 0.02, "{times:?}");
        assert_eq!(phase_totals(), PhaseTimes::default());
        // Recorded on this thread, the times leave its totals until credited.
        let ((), again) = recorded(|| credit(&times));
        assert_eq!(again, times);
        assert_eq!(phase_totals(), PhaseTimes::default());
        credit(&times);
        assert_eq!(phase_totals(), times);
    }

    #[test]
    fn timed_phases_add_up_per_thread() {
        let before = phase_totals();
        let value = timed(Phase::Steps, || {
            std::thread::sleep(std::time::Duration::from_millis(20));
            timed(Phase::Lpips, || 7)
        });
        assert_eq!(value, 7);
        let spent = phase_totals().since(&before);
        assert!(spent.get(Phase::Steps) >= 0.02, "{spent:?}");
        assert!(spent.get(Phase::Lpips) <= spent.get(Phase::Steps));
        // The nested LPIPS is not counted twice.
        assert_eq!(spent.top_level_seconds(), spent.get(Phase::Steps));
        // Another thread has its own totals.
        let other = std::thread::spawn(|| phase_totals().get(Phase::Steps))
            .join()
            .unwrap();
        assert_eq!(other, 0.0);
    }
}
