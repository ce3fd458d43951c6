//! The distillation schedule (paper Sec. 3.4): the `[distill]` section and
//! [`progressive_schedule`], which says which blocks are Linear at a training step.

use std::fmt;

use burn::config::Config;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};

use crate::attention::AttentionKind;
use crate::error::ModelError;

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
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
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

/// The `[distill]` section: progressive linear-attention stitching (paper Sec. 3.4 and the
/// supplement's training details).
#[derive(Config, Debug)]
pub struct DistillConfig {
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
        self.layers.resolve(num_blocks).map(|_| ())
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
