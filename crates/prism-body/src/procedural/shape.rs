//! Shape and expression blend shapes of the procedural body, as displacement fields on the
//! rest body (per unit coefficient; coefficients of about +-2 give the extremes).
//!
//! Betas: 0 stature, 1 girth, 2 leg length, 3 arm length, 4 shoulder width, 5 hip width,
//! 6 torso length, 7 bust, 8 belly, 9 head size.
//! Expression: 0 smile, 1 lips apart, 2 brows raised, 3 brows furrowed, 4 pucker,
//! 5 mouth corners down, 6 cheeks puffed, 7 half smile (left), 8 squint, 9 chin forward.

use glam::Vec3;

use super::parts::{Assembly, Part, PartVertex, smoothstep};
use crate::joints::{NUM_BETAS, NUM_EXPRESSION, joint};

fn gauss(p: Vec3, centre: Vec3, sigma: f32) -> f32 {
    (-(p - centre).length_squared() / (2.0 * sigma * sigma)).exp()
}

/// The 10 shape directions of every vertex.
pub(crate) fn shape_directions(a: &Assembly) -> Vec<[Vec3; NUM_BETAS]> {
    let p = &a.proportions;
    let j = &a.joints;
    let hip_y = p.hip_height;
    let sh_x = p.shoulder_half_width;
    let sh_y = p.shoulder_height;
    let wr_x = j[joint::LEFT_WRIST].x;
    let dy = hip_y - 0.90;
    let neck_top = Vec3::new(0.0, p.head_centre_y - 0.09, 0.0);
    a.vertices
        .iter()
        .map(|v: &PartVertex| {
            let pos = v.position;
            let sx = pos.x.signum();
            let part = v.part;
            let is_arm = matches!(
                part,
                Part::Arm { .. } | Part::Palm { .. } | Part::Finger { .. }
            );
            let is_leg = matches!(part, Part::Leg { .. } | Part::Foot { .. });
            let above_torso = matches!(part, Part::Neck | Part::Head | Part::Eye { .. }) || is_arm;
            let mut d = [Vec3::ZERO; NUM_BETAS];
            // 0: stature, a uniform scale about the floor point under the body.
            d[0] = 0.04 * pos;
            // 1: girth, outwards from each part's axis.
            let girth = match part {
                Part::Torso => {
                    0.016
                        + 0.01
                            * smoothstep(0.0, 0.1, pos.z)
                            * (1.0 - smoothstep(1.2 + dy, 1.35 + dy, pos.y))
                }
                Part::Neck => 0.006,
                Part::Arm { .. } | Part::Leg { .. } => 0.009,
                Part::Palm { .. } | Part::Finger { .. } => 0.0015,
                Part::Foot { .. } => 0.002,
                Part::Head | Part::Eye { .. } => 0.0,
            };
            let radial = if part == Part::Torso {
                Vec3::new(v.radial.x, 0.0, v.radial.z).normalize_or_zero()
            } else {
                v.radial
            };
            d[1] = girth * radial;
            // 2: leg length, stretching everything below the hips.
            d[2] = Vec3::Y * 0.05 * (pos.y / hip_y).clamp(0.0, 1.0);
            // 3: arm length, stretching the arms and moving the hands out.
            if is_arm {
                d[3] =
                    Vec3::X * sx * 0.035 * ((pos.x.abs() - sh_x) / (wr_x - sh_x)).clamp(0.0, 1.0);
            }
            // 4: shoulder width.
            let f4 = if is_arm {
                1.0
            } else if part == Part::Torso {
                smoothstep(0.0, sh_x, pos.x.abs()) * smoothstep(1.22 + dy, 1.38 + dy, pos.y)
            } else {
                0.0
            };
            d[4] = Vec3::X * sx * 0.02 * f4;
            // 5: hip width.
            let f5 = if is_leg {
                1.0
            } else if part == Part::Torso {
                smoothstep(0.0, 0.17, pos.x.abs()) * (1.0 - smoothstep(1.0 + dy, 1.15 + dy, pos.y))
            } else {
                0.0
            };
            let leg_side = match part {
                Part::Leg { left } | Part::Foot { left } => {
                    if left {
                        1.0
                    } else {
                        -1.0
                    }
                }
                _ => sx,
            };
            d[5] = Vec3::X * leg_side * 0.018 * f5;
            // 6: torso length.
            let f6 = if above_torso {
                1.0
            } else if part == Part::Torso {
                smoothstep(hip_y + 0.05, sh_y - 0.08, pos.y)
            } else {
                0.0
            };
            d[6] = Vec3::Y * 0.04 * f6;
            if part == Part::Torso {
                // 7: bust.
                let bust: f32 = [-1.0f32, 1.0]
                    .iter()
                    .map(|s| gauss(pos, Vec3::new(0.085 * s, 1.30 + dy, 0.10), 0.05))
                    .sum();
                d[7] = Vec3::new(0.0, -0.15, 1.0) * 0.02 * bust * smoothstep(0.0, 0.05, pos.z);
                // 8: belly.
                let belly = gauss(pos, Vec3::new(0.0, 1.06 + dy, 0.09), 0.09);
                d[8] = (Vec3::Z * 0.03 + radial * 0.01) * belly;
            }
            // 9: head size.
            match part {
                Part::Head | Part::Eye { .. } => d[9] = 0.07 * (pos - neck_top),
                Part::Neck => {
                    d[9] =
                        0.07 * (pos - neck_top) * smoothstep(neck_top.y, neck_top.y + 0.05, pos.y);
                }
                _ => {}
            }
            d
        })
        .collect()
}

/// The 10 expression directions of every vertex (face only).
pub(crate) fn expression_directions(a: &Assembly) -> Vec<[Vec3; NUM_EXPRESSION]> {
    let h = &a.head;
    let k = h.scale;
    let lm = |x: f32, y: f32| h.front_point(x * k, y * k);
    let mouth = h.mouth_y() - h.centre.y;
    let corner = |s: f32| lm(0.024 * s, mouth / k);
    let upper_lip = lm(0.0, mouth / k + 0.007);
    let lower_lip = lm(0.0, mouth / k - 0.009);
    let brow_in = |s: f32| lm(0.014 * s, 0.045);
    let brow_out = |s: f32| lm(0.045 * s, 0.042);
    let cheek = |s: f32| lm(0.042 * s, -0.028);
    let under_eye = |s: f32| lm(0.032 * s, 0.006);
    let chin = lm(0.0, -0.085);
    a.vertices
        .iter()
        .map(|v| {
            let mut d = [Vec3::ZERO; NUM_EXPRESSION];
            if v.part != Part::Head {
                return d;
            }
            let p = v.position;
            let g = |c: Vec3, s: f32| gauss(p, c, s * k);
            for s in [-1.0f32, 1.0] {
                let smile = Vec3::new(0.004 * s, 0.005, -0.002) * g(corner(s), 0.012)
                    + Vec3::new(0.0, 0.003, 0.001) * g(cheek(s), 0.015);
                d[0] += smile;
                if s > 0.0 {
                    d[7] += smile;
                }
                d[2] += Vec3::new(0.0, 0.005, 0.0)
                    * (g(brow_in(s), 0.014) + g(brow_out(s), 0.014)).min(1.0);
                d[3] += Vec3::new(-0.002 * s, -0.004, 0.001) * g(brow_in(s), 0.01);
                d[4] += Vec3::new(-0.005 * s, 0.0, 0.0) * g(corner(s), 0.01);
                d[5] += Vec3::new(0.0, -0.005, 0.0) * g(corner(s), 0.012);
                d[6] += v.radial * 0.006 * g(cheek(s), 0.018);
                d[8] += Vec3::new(0.0, 0.002, 0.0) * g(under_eye(s), 0.01)
                    + Vec3::new(0.0, -0.002, 0.0) * g(brow_out(s), 0.014);
            }
            d[1] = Vec3::new(0.0, 0.002, 0.001) * g(upper_lip, 0.008)
                + Vec3::new(0.0, -0.004, 0.001) * g(lower_lip, 0.01);
            d[4] += Vec3::new(0.0, 0.0, 0.006) * g(lm(0.0, mouth / k), 0.012);
            d[9] = Vec3::new(0.0, 0.0, 0.006) * g(chin, 0.02);
            d
        })
        .collect()
}
