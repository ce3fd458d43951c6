//! Body proportions of one procedural model: the average adult and its seeded jitter. A leaf
//! of the procedural modules: the head, the skeleton and the parts are all built from it.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Body proportions of one procedural model (metres). [`Proportions::from_seed`] jitters the
/// average adult by a few percent.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Proportions {
    pub hip_height: f32,
    pub hip_half_width: f32,
    pub shoulder_height: f32,
    pub shoulder_half_width: f32,
    pub upper_arm: f32,
    pub forearm: f32,
    pub palm: f32,
    pub finger_scale: f32,
    pub head_scale: f32,
    pub head_centre_y: f32,
    pub neck_y: f32,
    pub knee_height: f32,
    pub ankle_height: f32,
    pub foot_length: f32,
    pub limb_girth: f32,
    pub torso_girth: f32,
    pub nose: f32,
    pub eye_spacing: f32,
}

impl Proportions {
    /// The average adult of the model (about 1.76 m to the top of the head).
    pub fn average() -> Self {
        Self {
            hip_height: 0.90,
            hip_half_width: 0.088,
            shoulder_height: 1.425,
            shoulder_half_width: 0.185,
            upper_arm: 0.265,
            forearm: 0.245,
            palm: 0.088,
            finger_scale: 1.0,
            head_scale: 1.0,
            head_centre_y: 1.655,
            neck_y: 1.50,
            knee_height: 0.50,
            ankle_height: 0.085,
            foot_length: 0.25,
            limb_girth: 1.0,
            torso_girth: 1.0,
            nose: 1.0,
            eye_spacing: 1.0,
        }
    }

    /// The average adult jittered by a few percent, deterministically from `seed`.
    pub fn from_seed(seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_b0d1);
        let mut j = |x: f32, rel: f32| x * (1.0 + rng.random_range(-rel..=rel));
        let a = Self::average();
        let legs = j(1.0, 0.03);
        Self {
            hip_height: a.hip_height * legs,
            hip_half_width: j(a.hip_half_width, 0.04),
            shoulder_height: a.shoulder_height + a.hip_height * (legs - 1.0),
            shoulder_half_width: j(a.shoulder_half_width, 0.04),
            upper_arm: j(a.upper_arm, 0.03),
            forearm: j(a.forearm, 0.03),
            palm: j(a.palm, 0.03),
            finger_scale: j(1.0, 0.04),
            head_scale: j(1.0, 0.03),
            head_centre_y: a.head_centre_y + a.hip_height * (legs - 1.0),
            neck_y: a.neck_y + a.hip_height * (legs - 1.0),
            knee_height: a.knee_height * legs,
            ankle_height: a.ankle_height,
            foot_length: j(a.foot_length, 0.03),
            limb_girth: j(1.0, 0.05),
            torso_girth: j(1.0, 0.05),
            nose: j(1.0, 0.15),
            eye_spacing: j(1.0, 0.05),
        }
    }

    /// The vertical offset of everything above the hips relative to the average body.
    pub fn upper_shift(&self) -> f32 {
        self.shoulder_height - Self::average().shoulder_height
    }
}
