//! The distillation schedule (paper Sec. 3.4): the `[distill]` section and
//! [`progressive_schedule`], which says which blocks are Linear at a training step.

use std::fmt;

use burn::config::Config;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};

use crate::error::ModelError;
use crate::stages::attention::AttentionKind;

/// The layers whose hidden states enter `L_distill`, as written in a config file: a count
/// (that many uniformly spaced blocks, see [`DistillLayers::resolve`]) or an explicit list of
/// global block indices.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DistillLayers {
    /// `k` uniformly spaced blocks, the last block always among them.
    Count(usize),
    /// Explicit global block indices (`0..M+N`).
    List(Vec<usize>),
}

impl DistillLayers {
    /// The block indices for a network of `num_blocks` blocks, ascending.
    ///
    /// A count `k` gives `round((i + 1) L / k) - 1` for `i = 0..k` (with `L = num_blocks`):
    /// uniformly spaced and ending at the last block, e.g. `5, 11, 17, 23, 29, 35` for
    /// `k = 6, L = 36` (the last block of every group of 6).
    ///
    /// # Errors
    /// When the count is 0 or larger than `num_blocks`, or a listed index is out of range or
    /// repeated.
    pub fn resolve(&self, num_blocks: usize) -> Result<Vec<usize>, ModelError> {
        match self {
            Self::Count(k) if *k == 0 || *k > num_blocks => Err(ModelError::invalid(
                "distill.layers",
                format!("count {k} is not in 1..={num_blocks}"),
            )),
            Self::Count(k) => Ok((0..*k)
                .map(|i| ((i + 1) * num_blocks + k / 2) / k - 1)
                .collect()),
            Self::List(layers) => {
                let mut sorted = layers.clone();
                sorted.sort_unstable();
                sorted.dedup();
                if sorted.len() != layers.len() {
                    return Err(ModelError::invalid(
                        "distill.layers",
                        "a block index is listed twice",
                    ));
                }
                if let Some(bad) = sorted.iter().find(|&&i| i >= num_blocks) {
                    return Err(ModelError::invalid(
                        "distill.layers",
                        format!("block {bad} does not exist (the model has {num_blocks} blocks)"),
                    ));
                }
                if sorted.is_empty() {
                    return Err(ModelError::invalid("distill.layers", "empty list"));
                }
                Ok(sorted)
            }
        }
    }
}

impl Serialize for DistillLayers {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        match self {
            Self::Count(k) => serializer.serialize_u64(*k as u64),
            Self::List(layers) => layers.serialize(serializer),
        }
    }
}

impl<'de> Deserialize<'de> for DistillLayers {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct LayersVisitor;
        impl<'de> Visitor<'de> for LayersVisitor {
            type Value = DistillLayers;
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str("a count of layers or a list of block indices")
            }
            fn visit_u64<E: de::Error>(self, v: u64) -> Result<Self::Value, E> {
                Ok(DistillLayers::Count(v as usize))
            }
            fn visit_i64<E: de::Error>(self, v: i64) -> Result<Self::Value, E> {
                usize::try_from(v)
                    .map(DistillLayers::Count)
                    .map_err(|_| E::custom(format!("{v} is not a count of layers")))
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut layers = Vec::new();
                while let Some(layer) = seq.next_element::<usize>()? {
                    layers.push(layer);
                }
                Ok(DistillLayers::List(layers))
            }
        }
        deserializer.deserialize_any(LayersVisitor)
    }
}

/// Which student `prism distill-student` trains: the paper's method or one of its ablations
/// (paper Sec. 4.4, "Ablation Study"). Written in `[distill]` as `mode = "progressive"`, ...
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DistillMode {
    /// The paper's progressive stitching: from `start`, one more block of every group switches
    /// to Linear every `interval` steps (see [`progressive_schedule`]).
    #[default]
    Progressive,
    /// The "no progressive schedule" ablation: every switchable block (all but the last of each
    /// group) is Linear from step 0 (`start` and `interval` are not used).
    AllAtOnce,
    /// The "fully linear attention" ablation: every block, the last of each group too, is
    /// Linear from step 0, trained without a schedule.
    FullyLinear,
    /// The "teacher" row: no block ever switches; the copy of the teacher is trained on the
    /// same objective and budget as the student.
    Teacher,
}

impl DistillMode {
    /// The name written in config files (`progressive`, `all_at_once`, `fully_linear`,
    /// `teacher`).
    pub fn name(self) -> &'static str {
        match self {
            Self::Progressive => "progressive",
            Self::AllAtOnce => "all_at_once",
            Self::FullyLinear => "fully_linear",
            Self::Teacher => "teacher",
        }
    }

    /// Every mode, in the order above.
    pub const ALL: [DistillMode; 4] = [
        Self::Progressive,
        Self::AllAtOnce,
        Self::FullyLinear,
        Self::Teacher,
    ];
}

impl fmt::Display for DistillMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for DistillMode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let wanted = s.to_ascii_lowercase().replace('-', "_");
        Self::ALL
            .into_iter()
            .find(|m| m.name() == wanted)
            .ok_or_else(|| {
                format!(
                    "unknown distillation mode `{s}` (expected progressive, all_at_once, \
                     fully_linear or teacher)"
                )
            })
    }
}

/// The `[distill]` section: the student job (`prism distill-student`) and its progressive
/// linear-attention stitching (paper Sec. 3.4 and the supplement's "Student Distillation").
///
/// The run length, batch and learning rate of the student live here rather than in `[train]`
/// (which describes the teacher's pretraining): the student trains `steps` steps of
/// `batch_size` samples at the fixed learning rate `lr`; the rest of `[train]` (weight decay,
/// clipping, checkpoints, validation, seed) applies to both jobs.
#[derive(Config, Debug)]
pub struct DistillConfig {
    /// Which student: `progressive` (the paper), or the ablations `all_at_once`,
    /// `fully_linear`, `teacher` (see [`DistillMode`]).
    #[config(default = "DistillMode::Progressive")]
    pub mode: DistillMode,
    /// `G`, the consecutive blocks that form a group; the last block of each group always stays
    /// Full (paper: 6).
    #[config(default = 6)]
    pub group_size: usize,
    /// Training step of the first switch (paper: 5000).
    #[config(default = 5000)]
    pub start: usize,
    /// Steps between two switches (paper: 5000); 0 switches every switchable block at
    /// `start` (the "no progressive schedule" ablation with `start = 0`).
    #[config(default = 5000)]
    pub interval: usize,
    /// Blocks whose hidden states enter `L_distill`: a count of uniformly spaced blocks or a
    /// list of block indices.
    #[config(default = "DistillLayers::Count(6)")]
    pub layers: DistillLayers,
    /// Optimizer steps of the distillation (paper supplement: 40000; `--steps` overrides).
    #[config(default = 40000)]
    pub steps: usize,
    /// Samples per distillation step, each with `train.targets_per_sample` target views
    /// (paper: a batch of 4 pairs on one GPU, i.e. 1 sample of 4 targets).
    #[config(default = 1)]
    pub batch_size: usize,
    /// The fixed learning rate of the whole student, backbone and heads alike, without warm-up
    /// or annealing (paper supplement: 1e-6).
    #[config(default = 1e-6)]
    pub lr: f64,
}

impl DistillConfig {
    /// Checks the section for a network of `num_blocks` blocks.
    ///
    /// # Errors
    /// [`ModelError::Invalid`] naming the offending field.
    pub fn validate(&self, num_blocks: usize) -> Result<(), ModelError> {
        if self.group_size == 0 {
            return Err(ModelError::invalid(
                "distill.group_size",
                "must be at least 1",
            ));
        }
        if self.steps == 0 {
            return Err(ModelError::invalid("distill.steps", "must be at least 1"));
        }
        if self.batch_size == 0 {
            return Err(ModelError::invalid(
                "distill.batch_size",
                "must be at least 1",
            ));
        }
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return Err(ModelError::invalid(
                "distill.lr",
                format!("{} is not a positive number", self.lr),
            ));
        }
        self.layers.resolve(num_blocks).map(|_| ())
    }

    /// The student's attention kind of every block at distillation `step` (0-based: the kinds
    /// step `step` trains with), as [`DistillConfig::mode`] says: [`progressive_schedule`]
    /// for `progressive`; for `all_at_once` the schedule's final kinds from step 0; every block
    /// Linear for `fully_linear`; every block Full for `teacher`. A pure function of the step,
    /// so a resumed distillation switches exactly where an uninterrupted one does.
    pub fn kinds_at(&self, step: usize, num_blocks: usize) -> Vec<AttentionKind> {
        match self.mode {
            DistillMode::Progressive => progressive_schedule(step, self, num_blocks),
            DistillMode::AllAtOnce => {
                let at_once = self.clone().with_start(0).with_interval(0);
                progressive_schedule(0, &at_once, num_blocks)
            }
            DistillMode::FullyLinear => vec![AttentionKind::Linear; num_blocks],
            DistillMode::Teacher => vec![AttentionKind::Full; num_blocks],
        }
    }

    /// The kinds of the distilled student: those of its last step, `steps - 1` (what its final
    /// checkpoint records and what inference runs).
    pub fn final_kinds(&self, num_blocks: usize) -> Vec<AttentionKind> {
        self.kinds_at(self.steps.saturating_sub(1), num_blocks)
    }

    /// The first step at which the schedule has switched every block it will switch (0 for
    /// the modes without a schedule): `start + (G - 2) interval` for `progressive`.
    pub fn last_switch(&self) -> usize {
        match self.mode {
            DistillMode::Progressive if self.group_size >= 2 => {
                self.start + (self.group_size - 2) * self.interval
            }
            _ => 0,
        }
    }

    /// The blocks whose hidden states enter `L_distill` (see [`DistillLayers::resolve`]).
    ///
    /// # Errors
    /// As [`DistillLayers::resolve`].
    pub fn layer_indices(&self, num_blocks: usize) -> Result<Vec<usize>, ModelError> {
        self.layers.resolve(num_blocks)
    }

    /// How many blocks of each full group are Linear at `step`: 0 before `start`, then one
    /// more every `interval` steps, at most `group_size - 1`.
    pub fn linear_per_group(&self, step: usize) -> usize {
        let most = self.group_size.saturating_sub(1);
        if step < self.start {
            return 0;
        }
        match (step - self.start).checked_div(self.interval) {
            Some(switches) => (1 + switches).min(most),
            // interval 0: everything switches at `start`.
            None => most,
        }
    }
}

/// The attention kind of each of `num_blocks` blocks at training `step` (a pure function of
/// the step, so a resumed run gets the same schedule).
///
/// Blocks `0..num_blocks` are split into groups of `group_size` consecutive blocks. From
/// `start`, every `interval` steps one more block of every group switches to Linear, first
/// block first; the last block of each group (also of a shorter last group) always stays Full.
/// Paper scale (36 blocks, start 5000, interval 5000, groups of 6): 0, 6, 12, 18, 24, 30
/// Linear blocks after 0, 5k, 10k, 15k, 20k, 25k steps, and 30 from then on.
pub fn progressive_schedule(
    step: usize,
    config: &DistillConfig,
    num_blocks: usize,
) -> Vec<AttentionKind> {
    let group = config.group_size.max(1);
    let linear = config.linear_per_group(step);
    (0..num_blocks)
        .map(|block| {
            let position = block % group;
            let group_len = group.min(num_blocks - (block - position));
            if position < linear && position + 1 < group_len {
                AttentionKind::Linear
            } else {
                AttentionKind::Full
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn paper() -> DistillConfig {
        DistillConfig::new()
    }

    fn count_linear(kinds: &[AttentionKind]) -> usize {
        kinds
            .iter()
            .filter(|&&k| k == AttentionKind::Linear)
            .count()
    }

    #[test]
    fn paper_schedule_switches_one_block_per_group_every_interval() {
        let config = paper();
        for (step, want) in [
            (0, 0),
            (4999, 0),
            (5000, 6),
            (9999, 6),
            (10_000, 12),
            (15_000, 18),
            (20_000, 24),
            (25_000, 30),
            (30_000, 30),
            (35_000, 30),
            (1_000_000, 30),
        ] {
            let kinds = progressive_schedule(step, &config, 36);
            assert_eq!(kinds.len(), 36);
            assert_eq!(count_linear(&kinds), want, "step {step}");
            for group in kinds.chunks(6) {
                assert_eq!(
                    group[5],
                    AttentionKind::Full,
                    "step {step}: last of a group"
                );
                // First blocks first: the Linear ones are a prefix of the group.
                let n = count_linear(group);
                assert!(group[..n].iter().all(|&k| k == AttentionKind::Linear));
            }
        }
    }

    #[test]
    fn no_progressive_schedule_switches_everything_at_once() {
        let config = DistillConfig::new().with_start(0).with_interval(0);
        let kinds = progressive_schedule(0, &config, 36);
        assert_eq!(count_linear(&kinds), 30);
    }

    #[test]
    fn modes_give_the_ablations_kinds() {
        let letters = |config: &DistillConfig, step| {
            config
                .kinds_at(step, 8)
                .iter()
                .map(|k| k.letter())
                .collect::<String>()
        };
        // 8 blocks in groups of 3, first switch at step 10, then every 5 steps.
        let base = DistillConfig::new()
            .with_group_size(3)
            .with_start(10)
            .with_interval(5)
            .with_steps(30);
        let progressive = base.clone();
        assert_eq!(letters(&progressive, 0), "FFFFFFFF");
        assert_eq!(letters(&progressive, 10), "LFFLFFLF");
        assert_eq!(letters(&progressive, 15), "LLFLLFLF");
        assert_eq!(progressive.last_switch(), 15);
        let at_once = base.clone().with_mode(DistillMode::AllAtOnce);
        for step in [0, 9, 10, 1000] {
            assert_eq!(letters(&at_once, step), "LLFLLFLF", "step {step}");
        }
        assert_eq!(at_once.last_switch(), 0);
        let linear = base.clone().with_mode(DistillMode::FullyLinear);
        assert_eq!(letters(&linear, 0), "LLLLLLLL");
        let teacher = base.clone().with_mode(DistillMode::Teacher);
        assert_eq!(letters(&teacher, 1000), "FFFFFFFF");
        // The student's final kinds are those of its last step.
        assert_eq!(progressive.final_kinds(8), progressive.kinds_at(29, 8));
        assert_eq!(
            progressive.clone().with_steps(12).final_kinds(8),
            progressive.kinds_at(10, 8)
        );
        // Paper scale: the schedule is complete at 25k of the 40k steps.
        let paper = paper();
        assert_eq!(paper.last_switch(), 25_000);
        assert_eq!(count_linear(&paper.final_kinds(36)), 30);
    }

    #[test]
    fn modes_parse_from_their_names() {
        for mode in DistillMode::ALL {
            assert_eq!(mode.name().parse::<DistillMode>().unwrap(), mode);
            let toml = format!("mode = \"{mode}\"");
            #[derive(Deserialize)]
            struct M {
                mode: DistillMode,
            }
            assert_eq!(toml::from_str::<M>(&toml).unwrap().mode, mode);
        }
        assert_eq!(
            "Fully-Linear".parse::<DistillMode>().unwrap(),
            DistillMode::FullyLinear
        );
        let err = "linear".parse::<DistillMode>().unwrap_err();
        assert!(
            err.contains("`linear`") && err.contains("all_at_once"),
            "{err}"
        );
    }

    #[test]
    fn invalid_run_settings_are_named() {
        for (config, field) in [
            (paper().with_steps(0), "distill.steps"),
            (paper().with_batch_size(0), "distill.batch_size"),
            (paper().with_lr(0.0), "distill.lr"),
            (paper().with_lr(f64::NAN), "distill.lr"),
        ] {
            let err = config.validate(36).unwrap_err().to_string();
            assert!(err.contains(field), "{err}");
        }
        assert!(paper().validate(36).is_ok());
    }

    #[test]
    fn a_short_last_group_keeps_its_last_block_full() {
        // 8 blocks in groups of 3: [0 1 2] [3 4 5] [6 7].
        let config = DistillConfig::new()
            .with_group_size(3)
            .with_start(0)
            .with_interval(10);
        let letters = |step| {
            progressive_schedule(step, &config, 8)
                .iter()
                .map(|k| k.letter())
                .collect::<String>()
        };
        assert_eq!(letters(0), "LFFLFFLF");
        assert_eq!(letters(10), "LLFLLFLF");
        assert_eq!(letters(1000), "LLFLLFLF");
    }

    #[test]
    fn distill_layers_are_uniformly_spaced_or_listed() {
        assert_eq!(
            DistillLayers::Count(6).resolve(36).unwrap(),
            vec![5, 11, 17, 23, 29, 35]
        );
        assert_eq!(DistillLayers::Count(2).resolve(6).unwrap(), vec![2, 5]);
        assert_eq!(
            DistillLayers::Count(4).resolve(12).unwrap(),
            vec![2, 5, 8, 11]
        );
        assert_eq!(DistillLayers::Count(1).resolve(5).unwrap(), vec![4]);
        assert_eq!(
            DistillLayers::Count(5).resolve(5).unwrap(),
            vec![0, 1, 2, 3, 4]
        );
        assert_eq!(
            DistillLayers::List(vec![7, 1]).resolve(8).unwrap(),
            vec![1, 7]
        );
        for bad in [
            DistillLayers::Count(0),
            DistillLayers::Count(9),
            DistillLayers::List(vec![8]),
            DistillLayers::List(vec![1, 1]),
            DistillLayers::List(vec![]),
        ] {
            let err = bad.resolve(8).unwrap_err().to_string();
            assert!(err.contains("distill.layers"), "{err}");
        }
    }
}
