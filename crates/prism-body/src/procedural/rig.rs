//! The rig of the procedural body: the joint regressor (rows are convex combinations of the
//! vertices around each joint, reproducing the rest joints exactly, so that the joints follow
//! shape changes) and the pose correctives.

use glam::{DMat3, DVec3, Vec3};

use super::parts::{Assembly, Part};
use crate::joints::{Finger, JOINT_NAMES, NUM_JOINTS, NUM_POSE_FEATURES, joint};

/// The vertices a joint is regressed from, with a radius of influence.
fn candidates(a: &Assembly, j: usize) -> (Vec<usize>, f32) {
    let jp = a.joints[j];
    let left = |k: usize| JOINT_NAMES[k].starts_with("left_");
    let pick = |radius: f32, keep: &dyn Fn(Part) -> bool| -> (Vec<usize>, f32) {
        let ids = a
            .vertices
            .iter()
            .enumerate()
            .filter(|(_, v)| keep(v.part) && (v.position - jp).length() < radius)
            .map(|(i, _)| i)
            .collect();
        (ids, radius)
    };
    match j {
        joint::PELVIS => pick(0.17, &|p| p == Part::Torso),
        joint::SPINE1 | joint::SPINE2 | joint::SPINE3 => pick(0.2, &|p| p == Part::Torso),
        joint::LEFT_HIP | joint::RIGHT_HIP => pick(0.11, &|p| p == Part::Leg { left: left(j) }),
        joint::LEFT_KNEE | joint::RIGHT_KNEE => pick(0.07, &|p| p == Part::Leg { left: left(j) }),
        joint::LEFT_ANKLE | joint::RIGHT_ANKLE => pick(0.06, &|p| {
            p == Part::Leg { left: left(j) } || p == Part::Foot { left: left(j) }
        }),
        joint::LEFT_FOOT | joint::RIGHT_FOOT => pick(0.07, &|p| p == Part::Foot { left: left(j) }),
        joint::NECK => pick(0.07, &|p| p == Part::Neck),
        joint::LEFT_COLLAR | joint::RIGHT_COLLAR => pick(0.09, &|p| p == Part::Torso),
        joint::HEAD => pick(0.08, &|p| p == Part::Neck || p == Part::Head),
        joint::JAW => pick(0.09, &|p| p == Part::Head),
        joint::LEFT_EYE => pick(0.03, &|p| p == Part::Eye { left: true }),
        joint::RIGHT_EYE => pick(0.03, &|p| p == Part::Eye { left: false }),
        joint::LEFT_SHOULDER | joint::RIGHT_SHOULDER => {
            pick(0.08, &|p| p == Part::Arm { left: left(j) })
        }
        joint::LEFT_ELBOW | joint::RIGHT_ELBOW => pick(0.06, &|p| p == Part::Arm { left: left(j) }),
        joint::LEFT_WRIST | joint::RIGHT_WRIST => pick(0.045, &|p| {
            p == Part::Arm { left: left(j) } || p == Part::Palm { left: left(j) }
        }),
        _ => {
            let l = left(j);
            let start = if l {
                joint::LEFT_HAND_START
            } else {
                joint::RIGHT_HAND_START
            };
            let finger = Finger::ALL[(j - start) / 3];
            let first = (j - start).is_multiple_of(3);
            let r = if finger == Finger::Thumb {
                0.026
            } else {
                0.016
            };
            pick(r, &|p| {
                p == Part::Finger { left: l, finger } || (first && p == Part::Palm { left: l })
            })
        }
    }
}

/// Convex weights over `points` whose weighted mean is `target`: the maximum-entropy tilt
/// `p_i ~ g_i exp(lambda . (x_i - target))` of Gaussian priors `g_i`, solved by Newton's method.
/// Returns `None` when `target` is not inside the points' convex hull.
fn convex_weights(points: &[DVec3], target: DVec3, radius: f64) -> Option<Vec<f64>> {
    let x: Vec<DVec3> = points.iter().map(|p| (*p - target) / radius).collect();
    let prior: Vec<f64> = x.iter().map(|d| -2.0 * d.length_squared()).collect();
    let eval = |lambda: DVec3| {
        let logits: Vec<f64> = x
            .iter()
            .zip(&prior)
            .map(|(d, g)| g + lambda.dot(*d))
            .collect();
        let max = logits.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let e: Vec<f64> = logits.iter().map(|l| (l - max).exp()).collect();
        let z: f64 = e.iter().sum();
        let objective = max + z.ln();
        let p: Vec<f64> = e.iter().map(|v| v / z).collect();
        (objective, p)
    };
    let mut lambda = DVec3::ZERO;
    for _ in 0..100 {
        let (f, p) = eval(lambda);
        let m: DVec3 = x.iter().zip(&p).map(|(d, w)| *d * *w).sum();
        if m.length() < 1e-12 {
            return Some(p);
        }
        let mut h = DMat3::ZERO;
        for (d, w) in x.iter().zip(&p) {
            h += DMat3::from_cols(*d * d.x, *d * d.y, *d * d.z) * *w;
        }
        h -= DMat3::from_cols(m * m.x, m * m.y, m * m.z);
        h += DMat3::IDENTITY * 1e-12;
        let step = h.inverse() * m;
        // Backtracking on the convex objective.
        let mut t = 1.0;
        while t > 1e-8 {
            let (g, _) = eval(lambda - step * t);
            if g <= f - 0.25 * t * m.dot(step) {
                break;
            }
            t *= 0.5;
        }
        lambda -= step * t;
    }
    let (_, p) = eval(lambda);
    let m: DVec3 = x.iter().zip(&p).map(|(d, w)| *d * *w).sum();
    (m.length() < 1e-9).then_some(p)
}

/// The joint regressor `[55, V]` row-major.
pub(crate) fn joint_regressor(a: &Assembly) -> Vec<f32> {
    let v = a.vertices.len();
    let mut out = vec![0.0f32; NUM_JOINTS * v];
    for j in 0..NUM_JOINTS {
        let (ids, radius) = candidates(a, j);
        assert!(
            ids.len() >= 8,
            "joint {j} has only {} regressor vertices",
            ids.len()
        );
        let points: Vec<DVec3> = ids
            .iter()
            .map(|&i| a.vertices[i].position.as_dvec3())
            .collect();
        let w = convex_weights(&points, a.joints[j].as_dvec3(), f64::from(radius)).unwrap_or_else(
            || {
                panic!(
                    "joint {j} lies outside its {} regressor vertices",
                    ids.len()
                )
            },
        );
        for (i, wi) in ids.iter().zip(w) {
            out[j * v + i] = wi as f32;
        }
    }
    out
}

/// Pose correctives `[V, 3, 486]`: joints bulge outwards as they bend, proportionally to
/// `1 - cos(theta) = -(tr(R) - 3) / 2`, compensating the volume linear blend skinning loses.
pub(crate) fn pose_correctives(a: &Assembly) -> Vec<f32> {
    let v = a.vertices.len();
    let mut out = vec![0.0f32; v * 3 * NUM_POSE_FEATURES];
    // (joint, the child the bone points to, bulge in metres at a right angle, axial falloff)
    let spots: [(usize, usize, f32, f32); 8] = [
        (joint::LEFT_ELBOW, joint::LEFT_WRIST, 0.008, 0.03),
        (joint::RIGHT_ELBOW, joint::RIGHT_WRIST, 0.008, 0.03),
        (joint::LEFT_KNEE, joint::LEFT_ANKLE, 0.010, 0.04),
        (joint::RIGHT_KNEE, joint::RIGHT_ANKLE, 0.010, 0.04),
        (joint::LEFT_HIP, joint::LEFT_KNEE, 0.008, 0.06),
        (joint::RIGHT_HIP, joint::RIGHT_KNEE, 0.008, 0.06),
        (joint::LEFT_SHOULDER, joint::LEFT_ELBOW, 0.006, 0.05),
        (joint::RIGHT_SHOULDER, joint::RIGHT_ELBOW, 0.006, 0.05),
    ];
    for (j, child, bulge, sigma) in spots {
        let centre: Vec3 = a.joints[j];
        let bone = (a.joints[child] - centre).normalize();
        for (i, vert) in a.vertices.iter().enumerate() {
            // Only the limb the joint bends (its weights involve the joint).
            if !vert.weights.iter().any(|(k, _)| *k == j) {
                continue;
            }
            let d = (vert.position - centre).dot(bone);
            let g = (-(d * d) / (2.0 * sigma * sigma)).exp();
            if g < 1e-4 {
                continue;
            }
            let offset = vert.radial * bulge * g;
            for axis in 0..3 {
                for diag in 0..3 {
                    let k = (j - 1) * 9 + diag * 4;
                    out[(i * 3 + axis) * NUM_POSE_FEATURES + k] += -0.5 * offset[axis];
                }
            }
        }
    }
    out
}
