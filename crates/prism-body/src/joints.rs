//! The SMPL-X skeleton: 55 joints, their names and the kinematic tree.
//!
//! The order is SMPL-X's: global (pelvis), 21 body joints, jaw, left eye, right eye, 15 left-hand
//! joints, 15 right-hand joints. Each finger has three joints, from the knuckle outwards, in the
//! finger order index, middle, pinky, ring, thumb.

/// Number of joints of the SMPL-X skeleton.
pub const NUM_JOINTS: usize = 55;
/// Number of shape coefficients (betas) used by prism.
pub const NUM_BETAS: usize = 10;
/// Number of expression coefficients used by prism.
pub const NUM_EXPRESSION: usize = 10;
/// Length of the pose feature: `(R_j - I)` of joints 1..54, 9 entries each.
pub const NUM_POSE_FEATURES: usize = (NUM_JOINTS - 1) * 9;

/// Joint names in SMPL-X order.
pub const JOINT_NAMES: [&str; NUM_JOINTS] = [
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "jaw",
    "left_eye",
    "right_eye",
    "left_index1",
    "left_index2",
    "left_index3",
    "left_middle1",
    "left_middle2",
    "left_middle3",
    "left_pinky1",
    "left_pinky2",
    "left_pinky3",
    "left_ring1",
    "left_ring2",
    "left_ring3",
    "left_thumb1",
    "left_thumb2",
    "left_thumb3",
    "right_index1",
    "right_index2",
    "right_index3",
    "right_middle1",
    "right_middle2",
    "right_middle3",
    "right_pinky1",
    "right_pinky2",
    "right_pinky3",
    "right_ring1",
    "right_ring2",
    "right_ring3",
    "right_thumb1",
    "right_thumb2",
    "right_thumb3",
];

/// Parent of each joint in the SMPL-X kinematic tree (`-1` for the root), as in row 0 of
/// `kintree_table`.
pub const SMPLX_PARENTS: [i32; NUM_JOINTS] = [
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, // body
    15, 15, 15, // jaw, eyes
    20, 25, 26, 20, 28, 29, 20, 31, 32, 20, 34, 35, 20, 37, 38, // left hand
    21, 40, 41, 21, 43, 44, 21, 46, 47, 21, 49, 50, 21, 52, 53, // right hand
];

/// Index of a joint by name.
pub mod joint {
    /// Root joint (global orientation).
    pub const PELVIS: usize = 0;
    /// Left hip.
    pub const LEFT_HIP: usize = 1;
    /// Right hip.
    pub const RIGHT_HIP: usize = 2;
    /// Lower spine.
    pub const SPINE1: usize = 3;
    /// Left knee.
    pub const LEFT_KNEE: usize = 4;
    /// Right knee.
    pub const RIGHT_KNEE: usize = 5;
    /// Middle spine.
    pub const SPINE2: usize = 6;
    /// Left ankle.
    pub const LEFT_ANKLE: usize = 7;
    /// Right ankle.
    pub const RIGHT_ANKLE: usize = 8;
    /// Upper spine (chest).
    pub const SPINE3: usize = 9;
    /// Left foot (ball of the foot, toes).
    pub const LEFT_FOOT: usize = 10;
    /// Right foot.
    pub const RIGHT_FOOT: usize = 11;
    /// Neck.
    pub const NECK: usize = 12;
    /// Left collar bone.
    pub const LEFT_COLLAR: usize = 13;
    /// Right collar bone.
    pub const RIGHT_COLLAR: usize = 14;
    /// Head.
    pub const HEAD: usize = 15;
    /// Left shoulder.
    pub const LEFT_SHOULDER: usize = 16;
    /// Right shoulder.
    pub const RIGHT_SHOULDER: usize = 17;
    /// Left elbow.
    pub const LEFT_ELBOW: usize = 18;
    /// Right elbow.
    pub const RIGHT_ELBOW: usize = 19;
    /// Left wrist.
    pub const LEFT_WRIST: usize = 20;
    /// Right wrist.
    pub const RIGHT_WRIST: usize = 21;
    /// Jaw.
    pub const JAW: usize = 22;
    /// Left eyeball.
    pub const LEFT_EYE: usize = 23;
    /// Right eyeball.
    pub const RIGHT_EYE: usize = 24;
    /// First joint of the left hand (left_index1); the left hand is 25..40.
    pub const LEFT_HAND_START: usize = 25;
    /// First joint of the right hand (right_index1); the right hand is 40..55.
    pub const RIGHT_HAND_START: usize = 40;
}

/// The five fingers in SMPL-X's order inside a hand.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Finger {
    /// Index finger.
    Index,
    /// Middle finger.
    Middle,
    /// Little finger.
    Pinky,
    /// Ring finger.
    Ring,
    /// Thumb.
    Thumb,
}

impl Finger {
    /// The fingers in SMPL-X's order.
    pub const ALL: [Finger; 5] = [
        Finger::Index,
        Finger::Middle,
        Finger::Pinky,
        Finger::Ring,
        Finger::Thumb,
    ];

    /// The joint index of `segment` (0 = knuckle, 1, 2) of this finger on the left or right hand.
    pub fn joint(self, left: bool, segment: usize) -> usize {
        let base = if left {
            joint::LEFT_HAND_START
        } else {
            joint::RIGHT_HAND_START
        };
        base + 3 * (self as usize) + segment
    }
}

/// The depth of every joint in the SMPL-X tree (root 0), for processing the kinematic chain
/// level by level.
pub fn depths(parents: &[Option<usize>]) -> Vec<usize> {
    (0..parents.len())
        .map(|j| {
            let mut d = 0;
            let mut k = j;
            while let Some(p) = parents[k] {
                d += 1;
                k = p;
            }
            d
        })
        .collect()
}

/// The SMPL-X parents as `Option<usize>`.
pub fn smplx_parents() -> Vec<Option<usize>> {
    SMPLX_PARENTS
        .iter()
        .map(|&p| usize::try_from(p).ok())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parents_precede_children_and_names_match_the_finger_table() {
        for (j, &p) in SMPLX_PARENTS.iter().enumerate().skip(1) {
            assert!(p >= 0 && (p as usize) < j, "joint {j} parent {p}");
        }
        assert_eq!(JOINT_NAMES[Finger::Thumb.joint(true, 2)], "left_thumb3");
        assert_eq!(JOINT_NAMES[Finger::Ring.joint(false, 0)], "right_ring1");
        assert_eq!(
            SMPLX_PARENTS[Finger::Pinky.joint(true, 0)],
            joint::LEFT_WRIST as i32
        );
        let d = depths(&smplx_parents());
        assert_eq!(d[0], 0);
        assert_eq!(*d.iter().max().unwrap(), 10);
    }
}
