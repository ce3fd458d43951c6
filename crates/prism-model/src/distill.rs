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
            0
        } else if self.interval == 0 {
            most
        } else {
            (1 + (step - self.start) / self.interval).min(most)
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
