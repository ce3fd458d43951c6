//! The settings of a synthetic dataset (`prism data synth`, the configs' `[data]` section).
//! A synthesised dataset records them as its `dataset.json` generator, so that a rerun into the
//! same folder continues only the same dataset; the training configs name the dataset a run
//! uses by default with them.

use serde::{Deserialize, Serialize};

/// Settings of a synthetic dataset; they are recorded in `dataset.json` so that a rerun into
/// the same folder continues only the same dataset.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SynthOptions {
    /// Number of subjects.
    pub subjects: usize,
    /// Image width and height in pixels.
    pub resolution: u32,
    /// Seed of the whole dataset (people, poses, placements, views).
    pub seed: u64,
    /// Fraction of the subjects held out for testing (the last ones).
    pub test_fraction: f32,
    /// Background colour, components in [0, 1].
    pub background: [f32; 3],
    /// Supersampling factor of the renderer (s x s samples per pixel).
    pub supersample: u32,
}

impl Default for SynthOptions {
    fn default() -> Self {
        Self {
            subjects: 16,
            resolution: 256,
            seed: 0,
            test_fraction: 0.125,
            background: [1.0; 3],
            supersample: 3,
        }
    }
}
