//! Random plausible standing poses within joint limits, for a subject facing the camera as in
//! a frontal telepresence photo.
//!
//! Limits are boxes on the axis-angle components (radians) of each joint's rotation relative to
//! its parent, in SMPL-X's convention (rest frames aligned with the world: x right-to-left
//! across the body, y up, z forward). They are written for the left side; the right side is
//! their mirror image (`(x, y, z) -> (x, -y, -z)`).

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use prism_body::joints::{Finger, NUM_JOINTS, joint};

/// Per joint and axis, the `(min, max)` of the axis-angle component.
pub type PoseLimits = [[(f32, f32); 3]; NUM_JOINTS];

/// The limits of left-side (and centre) joints; `None` for right-side joints (mirrored).
fn left_limits(j: usize) -> Option<[(f32, f32); 3]> {
    let sym = |a: f32| (-a, a);
    let l = |x: (f32, f32), y: (f32, f32), z: (f32, f32)| Some([x, y, z]);
    match j {
        joint::PELVIS => l(sym(0.1), sym(0.3), sym(0.06)),
        joint::SPINE1 | joint::SPINE2 | joint::SPINE3 => l((-0.12, 0.2), sym(0.15), sym(0.1)),
        joint::NECK => l((-0.2, 0.3), sym(0.3), sym(0.15)),
        joint::HEAD => l((-0.25, 0.3), sym(0.4), sym(0.2)),
        joint::JAW => l((0.0, 0.3), sym(0.05), sym(0.05)),
        joint::LEFT_EYE | joint::RIGHT_EYE => l(sym(0.2), sym(0.3), (0.0, 0.0)),
        joint::LEFT_HIP => l((-0.5, 0.3), sym(0.25), (-0.05, 0.35)),
        joint::LEFT_KNEE => l((0.0, 0.7), sym(0.05), sym(0.05)),
        joint::LEFT_ANKLE => l((-0.3, 0.35), sym(0.2), sym(0.15)),
        joint::LEFT_FOOT => l((-0.2, 0.3), sym(0.05), sym(0.05)),
        joint::LEFT_COLLAR => l(sym(0.1), (-0.15, 0.1), (-0.15, 0.2)),
        joint::LEFT_SHOULDER => l(sym(0.8), (-1.0, 0.35), (-1.4, 0.5)),
        joint::LEFT_ELBOW => l(sym(0.3), (-2.2, 0.0), sym(0.1)),
        joint::LEFT_WRIST => l(sym(0.6), sym(0.4), sym(0.5)),
        j if (joint::LEFT_HAND_START..joint::RIGHT_HAND_START).contains(&j) => {
            let finger = Finger::ALL[(j - joint::LEFT_HAND_START) / 3];
            let segment = (j - joint::LEFT_HAND_START) % 3;
            match (finger, segment) {
                (Finger::Thumb, 0) => l((-0.3, 0.5), sym(0.5), (-0.5, 0.3)),
                (Finger::Thumb, _) => l(sym(0.2), (-0.6, 0.2), (-0.6, 0.2)),
                (_, 0) => l(sym(0.1), sym(0.15), (-1.3, 0.1)),
                _ => l(sym(0.05), sym(0.05), (-1.5, 0.0)),
            }
        }
        _ => None,
    }
}

/// The mirror image of a left joint on the right side (`None` for centre joints).
fn mirror_of(j: usize) -> Option<usize> {
    match j {
        joint::RIGHT_HIP => Some(joint::LEFT_HIP),
        joint::RIGHT_KNEE => Some(joint::LEFT_KNEE),
        joint::RIGHT_ANKLE => Some(joint::LEFT_ANKLE),
        joint::RIGHT_FOOT => Some(joint::LEFT_FOOT),
        joint::RIGHT_COLLAR => Some(joint::LEFT_COLLAR),
        joint::RIGHT_SHOULDER => Some(joint::LEFT_SHOULDER),
        joint::RIGHT_ELBOW => Some(joint::LEFT_ELBOW),
        joint::RIGHT_WRIST => Some(joint::LEFT_WRIST),
        j if (joint::RIGHT_HAND_START..NUM_JOINTS).contains(&j) => {
            Some(j - joint::RIGHT_HAND_START + joint::LEFT_HAND_START)
        }
        _ => None,
    }
}

/// The joint limits of the people generator.
pub fn pose_limits() -> PoseLimits {
    let mut out = [[(0.0f32, 0.0f32); 3]; NUM_JOINTS];
    for (j, limits) in out.iter_mut().enumerate() {
        *limits = match (left_limits(j), mirror_of(j)) {
            (Some(l), _) => l,
            (None, Some(m)) => {
                let l = left_limits(m).expect("mirrored joints have limits");
                [l[0], (-l[1].1, -l[1].0), (-l[2].1, -l[2].0)]
            }
            (None, None) => unreachable!("joint {j} has no limits"),
        };
    }
    out
}

/// Whether every component of `pose` lies within `limits`.
pub fn within_limits(pose: &[[f32; 3]; NUM_JOINTS], limits: &PoseLimits) -> bool {
    pose.iter().zip(limits).all(|(r, l)| {
        r.iter()
            .zip(l)
            .all(|(x, (lo, hi))| *x >= *lo - 1e-6 && *x <= *hi + 1e-6)
    })
}

/// How the arms are held.
#[derive(Clone, Copy, Debug, PartialEq)]
enum ArmStyle {
    Relaxed,
    Gesture,
    OnHip,
    Wave,
}

/// A random standing pose within [`pose_limits`]. `skirt` keeps the legs close together.
pub fn sample_pose(rng: &mut ChaCha8Rng, skirt: bool) -> [[f32; 3]; NUM_JOINTS] {
    let mut pose = [[0.0f32; 3]; NUM_JOINTS];
    let u = |rng: &mut ChaCha8Rng, a: f32, b: f32| rng.random_range(a..=b);

    // Facing the camera, with a little turn and sway.
    pose[joint::PELVIS] = [u(rng, -0.04, 0.04), u(rng, -0.2, 0.2), u(rng, -0.03, 0.03)];
    for j in [joint::SPINE1, joint::SPINE2, joint::SPINE3] {
        pose[j] = [
            u(rng, -0.05, 0.08),
            u(rng, -0.06, 0.06),
            u(rng, -0.04, 0.04),
        ];
    }
    // Head and gaze back towards the camera.
    let turn = -pose[joint::PELVIS][1];
    pose[joint::NECK] = [
        u(rng, -0.08, 0.12),
        0.4 * turn + u(rng, -0.1, 0.1),
        u(rng, -0.06, 0.06),
    ];
    pose[joint::HEAD] = [
        u(rng, -0.12, 0.15),
        0.4 * turn + u(rng, -0.15, 0.15),
        u(rng, -0.1, 0.1),
    ];
    pose[joint::JAW] = [
        if rng.random_bool(0.3) {
            u(rng, 0.02, 0.2)
        } else {
            0.0
        },
        0.0,
        0.0,
    ];
    let gaze = [u(rng, -0.1, 0.1), u(rng, -0.15, 0.15), 0.0];
    pose[joint::LEFT_EYE] = gaze;
    pose[joint::RIGHT_EYE] = gaze;

    // Legs: standing, the weight on one leg now and then.
    let spread = if skirt { 0.05 } else { 0.15 };
    for left in [true, false] {
        let (hip, knee, ankle, foot) = if left {
            (
                joint::LEFT_HIP,
                joint::LEFT_KNEE,
                joint::LEFT_ANKLE,
                joint::LEFT_FOOT,
            )
        } else {
            (
                joint::RIGHT_HIP,
                joint::RIGHT_KNEE,
                joint::RIGHT_ANKLE,
                joint::RIGHT_FOOT,
            )
        };
        let bend = if rng.random_bool(0.35) {
            u(rng, 0.05, if skirt { 0.25 } else { 0.4 })
        } else {
            u(rng, 0.0, 0.06)
        };
        let hip_r = [
            -0.5 * bend + u(rng, -0.05, 0.05),
            u(rng, -0.12, 0.12),
            u(rng, 0.0, spread),
        ];
        let knee_r = [bend, 0.0, 0.0];
        let ankle_r = [
            u(rng, -0.05, 0.05) - 0.5 * bend * 0.5,
            u(rng, -0.1, 0.1),
            u(rng, -0.05, 0.05),
        ];
        let foot_r = [u(rng, -0.05, 0.1), 0.0, 0.0];
        let m = |r: [f32; 3]| if left { r } else { [r[0], -r[1], -r[2]] };
        pose[hip] = m(hip_r);
        pose[knee] = m(knee_r);
        pose[ankle] = m(ankle_r);
        pose[foot] = m(foot_r);
    }

    // Arms.
    let styles = [
        ArmStyle::Relaxed,
        ArmStyle::Relaxed,
        ArmStyle::Relaxed,
        ArmStyle::Gesture,
        ArmStyle::Gesture,
        ArmStyle::OnHip,
        ArmStyle::Wave,
    ];
    let both = styles[rng.random_range(0..styles.len())];
    for left in [true, false] {
        let relax = (both == ArmStyle::Wave && !left)
            || (both == ArmStyle::Gesture && rng.random_bool(0.4));
        let style = if relax { ArmStyle::Relaxed } else { both };
        let (shoulder, elbow, wrist) = match style {
            ArmStyle::Relaxed => (
                [u(rng, -0.2, 0.2), u(rng, -0.25, 0.1), u(rng, -1.3, -1.1)],
                [0.0, u(rng, -0.5, -0.05), 0.0],
                [u(rng, -0.3, 0.3), u(rng, -0.2, 0.2), u(rng, -0.2, 0.2)],
            ),
            ArmStyle::Gesture => (
                [u(rng, -0.3, 0.1), u(rng, -0.7, -0.25), u(rng, -1.25, -0.9)],
                [u(rng, -0.2, 0.2), u(rng, -1.8, -0.9), 0.0],
                [u(rng, -0.5, 0.5), u(rng, -0.3, 0.3), u(rng, -0.3, 0.3)],
            ),
            ArmStyle::OnHip => (
                [u(rng, -0.2, 0.1), u(rng, 0.1, 0.3), u(rng, -1.0, -0.8)],
                [0.0, u(rng, -1.9, -1.6), 0.0],
                [u(rng, -0.2, 0.2), u(rng, -0.2, 0.2), u(rng, -0.3, 0.0)],
            ),
            ArmStyle::Wave => (
                [u(rng, -0.1, 0.2), u(rng, -0.4, -0.1), u(rng, 0.0, 0.4)],
                [u(rng, -0.1, 0.1), u(rng, -1.8, -1.2), 0.0],
                [u(rng, -0.3, 0.3), u(rng, -0.2, 0.2), u(rng, -0.3, 0.3)],
            ),
        };
        let collar = [0.0, u(rng, -0.05, 0.05), u(rng, -0.08, 0.08)];
        let m = |r: [f32; 3]| if left { r } else { [r[0], -r[1], -r[2]] };
        let side = if left { 0 } else { 1 };
        pose[joint::LEFT_COLLAR + side] = m(collar);
        pose[joint::LEFT_SHOULDER + side] = m(shoulder);
        pose[joint::LEFT_ELBOW + side] = m(elbow);
        pose[joint::LEFT_WRIST + side] = m(wrist);

        // Fingers: a relaxed curl shared by the hand, more for a fist now and then.
        let curl = if rng.random_bool(0.15) {
            u(rng, 0.9, 1.3)
        } else {
            u(rng, 0.1, 0.6)
        };
        for finger in Finger::ALL {
            for seg in 0..3 {
                let j = finger.joint(true, seg);
                let r = if finger == Finger::Thumb {
                    [
                        u(rng, -0.1, 0.2),
                        -0.3 * curl + u(rng, -0.1, 0.1),
                        -0.2 * curl,
                    ]
                } else {
                    let c = curl * [0.8, 1.0, 0.7][seg] + u(rng, -0.1, 0.1);
                    [0.0, if seg == 0 { u(rng, -0.1, 0.1) } else { 0.0 }, -c]
                };
                let target = if left {
                    j
                } else {
                    j - joint::LEFT_HAND_START + joint::RIGHT_HAND_START
                };
                pose[target] = m(r);
            }
        }
    }
    clamp_to_limits(&mut pose, &pose_limits());
    pose
}

/// Clamps every component into its limits.
pub fn clamp_to_limits(pose: &mut [[f32; 3]; NUM_JOINTS], limits: &PoseLimits) {
    for (r, l) in pose.iter_mut().zip(limits) {
        for (x, (lo, hi)) in r.iter_mut().zip(l) {
            *x = x.clamp(*lo, *hi);
        }
    }
}
