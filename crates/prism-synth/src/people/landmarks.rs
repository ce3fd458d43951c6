//! Where things are on a body model in its shaped rest pose, found from its joints and skinning
//! weights only, so that people can be dressed on any model with SMPL-X's layout (procedural or
//! the real SMPL-X).

use glam::Vec3;

use prism_body::joints::{NUM_JOINTS, joint};
use prism_body::{BodyModel, PosedBody};

/// The body region of a vertex, from the joint that dominates its skinning weights.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Region {
    Head,
    Eye { left: bool },
    Neck,
    Torso,
    Arm { left: bool },
    Hand { left: bool },
    Leg { left: bool },
    Foot { left: bool },
}

impl Region {
    /// The region of a vertex whose largest skinning weight is on joint `j`.
    pub fn of_joint(j: usize) -> Region {
        match j {
            joint::HEAD | joint::JAW => Region::Head,
            joint::LEFT_EYE => Region::Eye { left: true },
            joint::RIGHT_EYE => Region::Eye { left: false },
            joint::NECK => Region::Neck,
            joint::LEFT_SHOULDER | joint::LEFT_ELBOW => Region::Arm { left: true },
            joint::RIGHT_SHOULDER | joint::RIGHT_ELBOW => Region::Arm { left: false },
            joint::LEFT_WRIST => Region::Hand { left: true },
            joint::RIGHT_WRIST => Region::Hand { left: false },
            joint::LEFT_HIP | joint::LEFT_KNEE => Region::Leg { left: true },
            joint::RIGHT_HIP | joint::RIGHT_KNEE => Region::Leg { left: false },
            joint::LEFT_ANKLE | joint::LEFT_FOOT => Region::Foot { left: true },
            joint::RIGHT_ANKLE | joint::RIGHT_FOOT => Region::Foot { left: false },
            j if (joint::LEFT_HAND_START..joint::RIGHT_HAND_START).contains(&j) => {
                Region::Hand { left: true }
            }
            j if (joint::RIGHT_HAND_START..NUM_JOINTS).contains(&j) => Region::Hand { left: false },
            _ => Region::Torso,
        }
    }
}

/// Landmarks of the shaped rest body (metres, the model's frame).
#[derive(Clone, Debug)]
pub(crate) struct Landmarks {
    pub joints: Vec<Vec3>,
    /// Midpoint of the eyes and the distance between them.
    pub eye_mid: Vec3,
    pub eye_distance: f32,
    /// Centre of the skull (centroid of the head-region vertices).
    pub head_centre: Vec3,
    /// Height of the lip line (where the jaw's weights take over at the front of the face).
    pub mouth_y: f32,
    /// Height of the natural waist (trouser line).
    pub waist_y: f32,
    /// Height of the base of the neck (neckline of a crew neck).
    pub neck_base_y: f32,
    /// Height of the top of the head.
    pub top_y: f32,
    /// Height of the hip joints.
    pub hip_y: f32,
}

impl Landmarks {
    pub fn new(model: &BodyModel, posed: &PosedBody) -> Self {
        let j = posed.rest_joints.clone();
        let rest = &posed.shaped;
        let eye_mid = (j[joint::LEFT_EYE] + j[joint::RIGHT_EYE]) / 2.0;
        let eye_distance = (j[joint::LEFT_EYE] - j[joint::RIGHT_EYE])
            .length()
            .max(0.03);
        let mut head_sum = Vec3::ZERO;
        let mut head_n = 0.0;
        let mut top_y = f32::NEG_INFINITY;
        let mut mouth_y = eye_mid.y - 1.2 * eye_distance;
        let mut best = f32::NEG_INFINITY;
        for (v, p) in rest.iter().enumerate() {
            let w = model.vertex_weights(v);
            let (dom, _) = dominant(w);
            if Region::of_joint(dom) == Region::Head {
                head_sum += *p;
                head_n += 1.0;
                top_y = top_y.max(p.y);
                // Highest jaw-carried vertex near the centre line, in front: the lower lip.
                if w[joint::JAW] > 0.5
                    && p.x.abs() < 0.3 * eye_distance
                    && p.z > eye_mid.z - 0.02
                    && p.y > best
                {
                    best = p.y;
                    mouth_y = p.y;
                }
            }
        }
        let head_centre = if head_n > 0.0 {
            head_sum / head_n
        } else {
            j[joint::HEAD]
        };
        let waist_y = j[joint::SPINE1].y + 0.25 * (j[joint::SPINE2].y - j[joint::SPINE1].y);
        let neck_base_y = j[joint::NECK].y - 0.01;
        Self {
            eye_mid,
            eye_distance,
            head_centre,
            mouth_y,
            waist_y,
            neck_base_y,
            top_y,
            hip_y: (j[joint::LEFT_HIP].y + j[joint::RIGHT_HIP].y) / 2.0,
            joints: j,
        }
    }

    /// Position of `p` along the arm from the shoulder (0) to the wrist (1).
    pub fn arm_t(&self, p: Vec3, left: bool) -> f32 {
        let (s, w) = if left {
            (joint::LEFT_SHOULDER, joint::LEFT_WRIST)
        } else {
            (joint::RIGHT_SHOULDER, joint::RIGHT_WRIST)
        };
        segment_t(p, self.joints[s], self.joints[w])
    }

    /// Position of `p` along the leg from the hip (0) to the ankle (1).
    pub fn leg_t(&self, p: Vec3, left: bool) -> f32 {
        let (h, a) = if left {
            (joint::LEFT_HIP, joint::LEFT_ANKLE)
        } else {
            (joint::RIGHT_HIP, joint::RIGHT_ANKLE)
        };
        segment_t(p, self.joints[h], self.joints[a])
    }
}

fn segment_t(p: Vec3, a: Vec3, b: Vec3) -> f32 {
    let d = b - a;
    (p - a).dot(d) / d.length_squared()
}

/// The joint with the largest weight and that weight.
pub(crate) fn dominant(weights: &[f32]) -> (usize, f32) {
    weights
        .iter()
        .copied()
        .enumerate()
        .fold(
            (0, f32::NEG_INFINITY),
            |a, (j, w)| if w > a.1 { (j, w) } else { a },
        )
}
