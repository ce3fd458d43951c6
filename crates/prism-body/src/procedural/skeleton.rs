//! The rest skeleton of the procedural body: T-pose, Y-up, facing +Z, feet on `y = 0`, the
//! subject's left on +X, with joint positions in SMPL-X order.

use glam::Vec3;

use super::head::Head;
use super::proportions::Proportions;
use crate::joints::{Finger, NUM_JOINTS, joint};

/// Per-finger layout in the left hand (mirrored for the right): knuckle offset from the wrist
/// (along the arm, down, forward), segment lengths and radius.
#[derive(Clone, Copy, Debug)]
pub(crate) struct FingerLayout {
    pub knuckle: Vec3,
    pub direction: Vec3,
    pub lengths: [f32; 3],
    pub radius: f32,
}

/// The finger layout of the left hand in its rest frame (+X along the arm, palm down,
/// thumb towards +Z), relative to the wrist joint.
pub(crate) fn finger_layout(p: &Proportions, finger: Finger) -> FingerLayout {
    let s = p.finger_scale;
    let palm = p.palm;
    let (knuckle, dir, lengths, radius) = match finger {
        Finger::Index => (
            Vec3::new(palm, -0.004, 0.026),
            Vec3::new(1.0, 0.0, 0.04),
            [0.042, 0.025, 0.022],
            0.0088,
        ),
        Finger::Middle => (
            Vec3::new(palm + 0.004, -0.004, 0.007),
            Vec3::X,
            [0.046, 0.029, 0.024],
            0.0091,
        ),
        Finger::Ring => (
            Vec3::new(palm - 0.002, -0.004, -0.012),
            Vec3::new(1.0, 0.0, -0.04),
            [0.043, 0.027, 0.023],
            0.0085,
        ),
        Finger::Pinky => (
            Vec3::new(palm - 0.012, -0.005, -0.029),
            Vec3::new(1.0, 0.0, -0.1),
            [0.034, 0.020, 0.020],
            0.0075,
        ),
        Finger::Thumb => (
            Vec3::new(0.022, -0.012, 0.022),
            Vec3::new(0.62, -0.25, 0.74),
            [0.038, 0.033, 0.028],
            0.0105,
        ),
    };
    FingerLayout {
        knuckle: knuckle * Vec3::new(1.0, 1.0, s),
        direction: dir.normalize(),
        lengths: lengths.map(|l| l * s),
        radius: radius * s,
    }
}

/// Rest positions of the 55 joints (before the joint regressor snaps them onto the mesh; the
/// regressor is solved to reproduce exactly these).
pub(crate) fn rest_joints(p: &Proportions) -> [Vec3; NUM_JOINTS] {
    let mut j = [Vec3::ZERO; NUM_JOINTS];
    let up = p.upper_shift();
    j[joint::PELVIS] = Vec3::new(0.0, p.hip_height + 0.05, 0.0);
    j[joint::SPINE1] = Vec3::new(0.0, 1.06 + up * 0.3, -0.012);
    j[joint::SPINE2] = Vec3::new(0.0, 1.19 + up * 0.6, -0.015);
    j[joint::SPINE3] = Vec3::new(0.0, 1.32 + up, -0.012);
    j[joint::NECK] = Vec3::new(0.0, p.neck_y, -0.025);
    j[joint::HEAD] = Vec3::new(0.0, p.head_centre_y - 0.05 * p.head_scale, -0.012);
    j[joint::JAW] = Vec3::new(0.0, p.head_centre_y - 0.035 * p.head_scale, 0.0);
    let eye = Head::new(p).eye_centre();
    j[joint::LEFT_EYE] = eye;
    j[joint::RIGHT_EYE] = eye * Vec3::new(-1.0, 1.0, 1.0);
    for (side, sign) in [(0usize, 1.0f32), (1, -1.0)] {
        let m = Vec3::new(sign, 1.0, 1.0);
        let hip = Vec3::new(p.hip_half_width, p.hip_height, 0.0);
        let knee = Vec3::new(p.hip_half_width + 0.006, p.knee_height, 0.012);
        let ankle = Vec3::new(p.hip_half_width + 0.01, p.ankle_height, -0.03);
        let foot = Vec3::new(p.hip_half_width + 0.02, 0.025, -0.03 + 0.58 * p.foot_length);
        let collar = Vec3::new(0.075, p.shoulder_height + 0.005, -0.012);
        let shoulder = Vec3::new(p.shoulder_half_width, p.shoulder_height, -0.02);
        let elbow = shoulder + Vec3::new(p.upper_arm, 0.0, 0.0);
        let wrist = elbow + Vec3::new(p.forearm, 0.0, 0.0);
        j[joint::LEFT_HIP + side] = hip * m;
        j[joint::LEFT_KNEE + side] = knee * m;
        j[joint::LEFT_ANKLE + side] = ankle * m;
        j[joint::LEFT_FOOT + side] = foot * m;
        j[joint::LEFT_COLLAR + side] = collar * m;
        j[joint::LEFT_SHOULDER + side] = shoulder * m;
        j[joint::LEFT_ELBOW + side] = elbow * m;
        j[joint::LEFT_WRIST + side] = wrist * m;
        for finger in Finger::ALL {
            let f = finger_layout(p, finger);
            let mut at = wrist + f.knuckle;
            for seg in 0..3 {
                j[finger.joint(side == 0, seg)] = at * m;
                at += f.direction * f.lengths[seg];
            }
        }
    }
    j
}
