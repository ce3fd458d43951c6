//! Assembling the procedural body from closed parts: torso, neck, head and eyes, arms with
//! palms and fingers, legs with feet; each vertex with its skinning weights.
//!
//! Parts overlap at the joints (ball-shaped ends centred on the joint), so that rotations about
//! a joint keep the junction closed without stitching the parts together.

use glam::Vec3;

use super::head::{EYE_RADIUS, Head, uv_sphere};
use super::proportions::Proportions;
use super::skeleton::{finger_layout, rest_joints};
use super::tube::{Section, Tube, TubeVertex};
use crate::joints::{Finger, NUM_JOINTS, joint};

/// Which part of the body a vertex belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Part {
    Torso,
    Neck,
    Head,
    Eye { left: bool },
    Arm { left: bool },
    Palm { left: bool },
    Finger { left: bool, finger: Finger },
    Leg { left: bool },
    Foot { left: bool },
}

/// A vertex of the assembled body.
#[derive(Clone, Debug)]
pub(crate) struct PartVertex {
    pub position: Vec3,
    /// Sparse skinning weights `(joint, weight)`, summing to 1.
    pub weights: Vec<(usize, f32)>,
    pub part: Part,
    /// Unit direction from the part's axis (or centre) to the vertex.
    pub radial: Vec3,
}

/// The assembled rest body.
pub(crate) struct Assembly {
    pub vertices: Vec<PartVertex>,
    pub faces: Vec<[u32; 3]>,
    pub joints: [Vec3; NUM_JOINTS],
    pub proportions: Proportions,
    pub head: Head,
}

/// `0` below `e0`, `1` above `e1`, smooth in between (also for `e0 > e1`).
pub(crate) fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Weights along a chain of joints `(joint, s_start)` sorted by `s_start`: joint `k` owns
/// `[s_k, s_{k+1})`, with smooth transitions of half-width `h[k]` around each `s_k` (`k >= 1`).
/// The weights sum to 1.
pub(crate) fn chain_weights(s: f32, chain: &[(usize, f32)], h: &[f32]) -> Vec<(usize, f32)> {
    let step = |k: usize| -> f32 {
        if k == 0 {
            1.0
        } else if k >= chain.len() {
            0.0
        } else {
            smoothstep(chain[k].1 - h[k], chain[k].1 + h[k], s)
        }
    };
    (0..chain.len())
        .map(|k| (chain[k].0, step(k) - step(k + 1)))
        .filter(|(_, w)| *w > 1e-6)
        .collect()
}

/// Moves a fraction `f` of all weights onto `joint`.
fn mix(weights: &mut Vec<(usize, f32)>, joint: usize, f: f32) {
    if f <= 1e-6 {
        return;
    }
    for (_, w) in weights.iter_mut() {
        *w *= 1.0 - f;
    }
    match weights.iter_mut().find(|(j, _)| *j == joint) {
        Some((_, w)) => *w += f,
        None => weights.push((joint, f)),
    }
    weights.retain(|(_, w)| *w > 1e-6);
}

impl Assembly {
    fn add_tube(
        &mut self,
        tube: &Tube,
        part: Part,
        weights: impl Fn(&TubeVertex) -> Vec<(usize, f32)>,
    ) {
        let (verts, tris) = tube.build();
        let base = self.vertices.len() as u32;
        for v in &verts {
            self.vertices.push(PartVertex {
                position: v.position,
                weights: weights(v),
                part,
                radial: v.radial,
            });
        }
        self.faces.extend(tris.iter().map(|t| t.map(|i| i + base)));
    }

    fn add_mesh(
        &mut self,
        (positions, tris): (Vec<Vec3>, Vec<[u32; 3]>),
        part: Part,
        centre: Vec3,
        weights: impl Fn(Vec3) -> Vec<(usize, f32)>,
    ) {
        let base = self.vertices.len() as u32;
        for p in positions {
            self.vertices.push(PartVertex {
                position: p,
                weights: weights(p),
                part,
                radial: (p - centre).normalize_or(Vec3::Y),
            });
        }
        self.faces.extend(tris.iter().map(|t| t.map(|i| i + base)));
    }

    /// Builds the whole rest body for the given proportions.
    pub fn build(p: &Proportions) -> Self {
        let joints = rest_joints(p);
        let head = Head::new(p);
        let mut a = Self {
            vertices: Vec::new(),
            faces: Vec::new(),
            joints,
            proportions: p.clone(),
            head: head.clone(),
        };
        a.torso();
        a.neck();
        a.head_and_eyes();
        for left in [true, false] {
            a.arm(left);
            a.palm(left);
            for finger in Finger::ALL {
                a.finger(left, finger);
            }
            a.leg(left);
            a.foot(left);
        }
        a
    }

    fn torso(&mut self) {
        let p = &self.proportions;
        let j = self.joints;
        let dy = p.hip_height - 0.90;
        let g = p.torso_girth;
        // (y, front, back, half-width, exponent, z offset) at the average proportions.
        let keys: [(f32, f32, f32, f32, f32, f32); 12] = [
            (0.80, 0.060, 0.070, 0.115, 2.2, -0.010),
            (0.86, 0.085, 0.105, 0.160, 2.3, -0.010),
            (0.95, 0.090, 0.100, 0.168, 2.4, -0.005),
            (1.05, 0.092, 0.082, 0.150, 2.3, 0.000),
            (1.12, 0.088, 0.078, 0.140, 2.3, 0.000),
            (1.22, 0.095, 0.082, 0.150, 2.3, 0.000),
            (1.32, 0.105, 0.088, 0.165, 2.4, -0.005),
            (1.40, 0.092, 0.090, 0.185, 2.7, -0.010),
            (1.445, 0.075, 0.082, 0.185, 2.8, -0.015),
            (1.47, 0.062, 0.070, 0.150, 2.5, -0.018),
            (1.495, 0.050, 0.058, 0.090, 2.2, -0.022),
            (1.515, 0.045, 0.050, 0.058, 2.0, -0.025),
        ];
        let sw = p.shoulder_half_width / 0.185;
        let hw = p.hip_half_width / 0.088;
        let sections = keys
            .iter()
            .map(|&(y, f, b, w, n, z)| {
                // Widths follow the shoulders above the waist and the hips below it.
                let k = smoothstep(1.05, 1.35, y);
                let wscale = hw + (sw - hw) * k;
                Section {
                    s: y + dy,
                    e1_pos: f * g,
                    e1_neg: b * g,
                    e2_pos: w * g.sqrt() * wscale,
                    e2_neg: w * g.sqrt() * wscale,
                    exponent: n,
                    offset: [z, 0.0],
                }
            })
            .collect();
        let tube = Tube {
            origin: Vec3::ZERO,
            axis: Vec3::Y,
            e1: Vec3::Z,
            sections,
            rings: 28,
            segments: 32,
            start_cap: 0.035,
            end_cap: 0.012,
            cap_rings: [3, 3],
        };
        let chain = [
            (joint::PELVIS, f32::NEG_INFINITY),
            (joint::SPINE1, j[joint::SPINE1].y - 0.01),
            (joint::SPINE2, j[joint::SPINE2].y),
            (joint::SPINE3, j[joint::SPINE3].y),
        ];
        let hip_y = p.hip_height;
        let sh_y = p.shoulder_height;
        let neck_y = p.neck_y;
        let sh_x = p.shoulder_half_width;
        self.add_tube(&tube, Part::Torso, |v| {
            let pos = v.position;
            let mut w = chain_weights(v.s, &chain, &[0.0, 0.05, 0.05, 0.05]);
            let side = pos.x >= 0.0;
            let ax = pos.x.abs();
            let pick = |l: usize, r: usize| if side { l } else { r };
            // Collar bones carry the upper lateral chest and the shoulder tops.
            let collar = smoothstep(0.05, 0.14, ax)
                * smoothstep(j[joint::SPINE3].y + 0.02, sh_y - 0.02, pos.y);
            mix(
                &mut w,
                pick(joint::LEFT_COLLAR, joint::RIGHT_COLLAR),
                collar,
            );
            // The outer shoulder follows the arm a little.
            let shoulder = 0.35
                * smoothstep(sh_x - 0.04, sh_x, ax)
                * smoothstep(sh_y - 0.07, sh_y - 0.01, pos.y);
            mix(
                &mut w,
                pick(joint::LEFT_SHOULDER, joint::RIGHT_SHOULDER),
                shoulder,
            );
            // The neck base follows the neck.
            mix(
                &mut w,
                joint::NECK,
                0.5 * smoothstep(neck_y - 0.04, neck_y + 0.005, pos.y)
                    * (1.0 - smoothstep(0.04, 0.09, ax)),
            );
            // Buttocks and groin follow the thighs.
            let hip = 0.5
                * smoothstep(0.02, 0.11, ax)
                * (1.0 - smoothstep(hip_y - 0.03, hip_y + 0.07, pos.y));
            mix(&mut w, pick(joint::LEFT_HIP, joint::RIGHT_HIP), hip);
            w
        });
    }

    fn neck(&mut self) {
        let p = &self.proportions;
        let j = self.joints;
        let y0 = p.neck_y - 0.07;
        let y1 = p.head_centre_y - 0.02;
        let g = p.torso_girth.sqrt();
        let tube = Tube {
            origin: Vec3::new(0.0, 0.0, -0.018),
            axis: Vec3::Y,
            e1: Vec3::Z,
            sections: vec![
                Section {
                    s: y0,
                    ..Section::ellipse(y0, 0.056 * g, 0.064 * g)
                },
                Section::ellipse(p.neck_y, 0.05 * g, 0.056 * g),
                Section::ellipse(y1, 0.048 * g, 0.052 * g),
            ],
            rings: 6,
            segments: 16,
            start_cap: 0.02,
            end_cap: 0.03,
            cap_rings: [2, 2],
        };
        let chain = [
            (joint::SPINE3, f32::NEG_INFINITY),
            (joint::NECK, j[joint::NECK].y - 0.02),
            (joint::HEAD, j[joint::HEAD].y + 0.005),
        ];
        self.add_tube(&tube, Part::Neck, |v| {
            chain_weights(v.s, &chain, &[0.0, 0.03, 0.03])
        });
    }

    fn head_and_eyes(&mut self) {
        let head = self.head.clone();
        let j = self.joints;
        let c = head.centre;
        let mouth_y = head.mouth_y();
        self.add_mesh(head.mesh(26, 34), Part::Head, c, |pos| {
            let mut w = vec![(joint::HEAD, 1.0)];
            // The jaw carries the chin and lower lip: below the mouth line, in front of the
            // hinge, fading out towards the neck.
            let below = smoothstep(mouth_y - 0.001, mouth_y - 0.007, pos.y);
            let front = smoothstep(c.z - 0.05, c.z + 0.01, pos.z);
            let dir = (pos - c).normalize();
            let not_neck = 1.0 - smoothstep(-0.85, -0.97, -dir.y) * (1.0 - front);
            mix(&mut w, joint::JAW, below * front * not_neck);
            w
        });
        for left in [true, false] {
            let centre = j[if left {
                joint::LEFT_EYE
            } else {
                joint::RIGHT_EYE
            }];
            let jid = if left {
                joint::LEFT_EYE
            } else {
                joint::RIGHT_EYE
            };
            // Poles along +-Z so that the iris (around +Z) is a clean cap.
            let (pos, tris) = uv_sphere(6, 10, |d| centre + Vec3::new(d.x, -d.z, d.y) * EYE_RADIUS);
            self.add_mesh((pos, tris), Part::Eye { left }, centre, |_| {
                vec![(jid, 1.0)]
            });
        }
    }

    fn arm(&mut self, left: bool) {
        let p = &self.proportions;
        let side = if left { 0 } else { 1 };
        let sign = if left { 1.0 } else { -1.0 };
        let sh = self.joints[joint::LEFT_SHOULDER + side];
        let ua = p.upper_arm;
        let fa = p.forearm;
        let g = p.limb_girth;
        // (s, up, down, front, back)
        let keys = [
            (0.0, 0.052, 0.052, 0.052, 0.052),
            (0.06, 0.050, 0.047, 0.047, 0.046),
            (0.13, 0.046, 0.044, 0.045, 0.043),
            (ua - 0.04, 0.039, 0.037, 0.038, 0.037),
            (ua, 0.037, 0.035, 0.037, 0.038),
            (ua + 0.05, 0.040, 0.038, 0.041, 0.039),
            (ua + 0.11, 0.036, 0.034, 0.036, 0.034),
            (ua + fa - 0.035, 0.025, 0.022, 0.028, 0.027),
            (ua + fa + 0.005, 0.019, 0.018, 0.028, 0.027),
        ];
        let sections = keys
            .iter()
            .map(|&(s, up, down, front, back)| {
                let (e2p, e2n) = if left { (front, back) } else { (back, front) };
                Section {
                    s,
                    e1_pos: up * g,
                    e1_neg: down * g,
                    e2_pos: e2p * g,
                    e2_neg: e2n * g,
                    exponent: 2.0,
                    offset: [0.0, 0.0],
                }
            })
            .collect();
        let tube = Tube {
            origin: sh,
            axis: Vec3::X * sign,
            e1: Vec3::Y,
            sections,
            rings: 20,
            segments: 16,
            start_cap: 0.052 * g,
            end_cap: 0.018,
            cap_rings: [4, 2],
        };
        let chain = [
            (joint::LEFT_SHOULDER + side, f32::NEG_INFINITY),
            (joint::LEFT_ELBOW + side, ua),
            (joint::LEFT_WRIST + side, ua + fa),
        ];
        self.add_tube(&tube, Part::Arm { left }, |v| {
            chain_weights(v.s, &chain, &[0.0, 0.045, 0.02])
        });
    }

    fn palm(&mut self, left: bool) {
        let p = &self.proportions;
        let side = if left { 0 } else { 1 };
        let sign = if left { 1.0 } else { -1.0 };
        let wrist = self.joints[joint::LEFT_WRIST + side];
        let len = p.palm;
        let fs = p.finger_scale;
        // (s, up (back of the hand), down (palm), half-width, exponent)
        let keys = [
            (0.0, 0.019, 0.017, 0.028, 2.2),
            (0.025, 0.017, 0.016, 0.038, 2.8),
            (len - 0.012, 0.014, 0.013, 0.044, 3.2),
            (len + 0.004, 0.012, 0.011, 0.043, 3.0),
        ];
        let sections = keys
            .iter()
            .map(|&(s, up, down, w, n)| Section {
                s,
                e1_pos: up * fs,
                e1_neg: down * fs,
                e2_pos: w * fs,
                e2_neg: w * fs,
                exponent: n,
                offset: [-0.004, 0.0],
            })
            .collect();
        let tube = Tube {
            origin: wrist,
            axis: Vec3::X * sign,
            e1: Vec3::Y,
            sections,
            rings: 8,
            segments: 14,
            start_cap: 0.01,
            end_cap: 0.012,
            cap_rings: [2, 2],
        };
        let joints = self.joints;
        let knuckles: Vec<(usize, f32)> =
            [Finger::Index, Finger::Middle, Finger::Ring, Finger::Pinky]
                .iter()
                .map(|f| (f.joint(left, 0), joints[f.joint(left, 0)].z))
                .collect();
        let thumb = Finger::Thumb.joint(left, 0);
        self.add_tube(&tube, Part::Palm { left }, |v| {
            let mut w = vec![(joint::LEFT_WRIST + side, 1.0)];
            let pos = v.position;
            let (f, _) = knuckles
                .iter()
                .min_by(|a, b| (a.1 - pos.z).abs().total_cmp(&(b.1 - pos.z).abs()))
                .copied()
                .unwrap();
            mix(&mut w, f, 0.5 * smoothstep(len - 0.03, len + 0.01, v.s));
            let thenar =
                smoothstep(0.005, 0.03, pos.z - wrist.z) * (1.0 - smoothstep(0.03, 0.07, v.s));
            mix(&mut w, thumb, 0.45 * thenar);
            w
        });
    }

    fn finger(&mut self, left: bool, finger: Finger) {
        let p = &self.proportions;
        let f = finger_layout(p, finger);
        let base = self.joints[finger.joint(left, 0)];
        let m = if left {
            Vec3::ONE
        } else {
            Vec3::new(-1.0, 1.0, 1.0)
        };
        let dir = f.direction * m;
        let [l1, l2, l3] = f.lengths;
        let r = f.radius;
        let end = l1 + l2 + l3 - 0.9 * r;
        let thumb = finger == Finger::Thumb;
        let r0 = if thumb { 1.45 * r } else { r };
        let flat = 0.9;
        let sections = [
            (0.0, r0),
            (l1 * 0.5, if thumb { 1.15 * r } else { r }),
            (l1, 0.95 * r),
            (l1 + l2, 0.88 * r),
            (end, 0.8 * r),
        ]
        .iter()
        .map(|&(s, rr)| Section::ellipse(s, rr * flat, rr))
        .collect();
        let e1 = (Vec3::Y - Vec3::Y.dot(dir) * dir).normalize();
        let tube = Tube {
            origin: base,
            axis: dir,
            e1,
            sections,
            rings: 8,
            segments: 8,
            start_cap: r0,
            end_cap: 0.9 * r,
            cap_rings: [2, 3],
        };
        let chain = [
            (finger.joint(left, 0), f32::NEG_INFINITY),
            (finger.joint(left, 1), l1),
            (finger.joint(left, 2), l1 + l2),
        ];
        let h = if thumb { 0.008 } else { 0.006 };
        self.add_tube(&tube, Part::Finger { left, finger }, |v| {
            chain_weights(v.s, &chain, &[0.0, h, h])
        });
    }

    fn leg(&mut self, left: bool) {
        let p = &self.proportions;
        let side = if left { 0 } else { 1 };
        let hip = self.joints[joint::LEFT_HIP + side];
        let knee = self.joints[joint::LEFT_KNEE + side];
        let ankle = self.joints[joint::LEFT_ANKLE + side];
        let axis = (ankle - hip).normalize();
        let len = (ankle - hip).length();
        let s_knee = (knee - hip).dot(axis);
        let g = p.limb_girth;
        // (fraction of the hip-knee or knee-ankle span, front, back, inner, outer)
        let thigh = [
            (0.0, 0.088, 0.088, 0.082, 0.088),
            (0.2, 0.086, 0.094, 0.078, 0.092),
            (0.5, 0.078, 0.078, 0.068, 0.080),
            (0.8, 0.063, 0.060, 0.056, 0.063),
            (1.0, 0.052, 0.050, 0.048, 0.052),
        ];
        let shin = [
            (0.18, 0.050, 0.062, 0.049, 0.052),
            (0.36, 0.047, 0.068, 0.049, 0.052),
            (0.70, 0.036, 0.040, 0.034, 0.036),
            (0.92, 0.031, 0.032, 0.029, 0.031),
            (1.0, 0.031, 0.031, 0.029, 0.031),
        ];
        let mk = |s: f32, f: f32, b: f32, inner: f32, outer: f32| {
            // e1 = +Z (front); e2 = axis x e1 points to -X: inner side for the left leg.
            let (e2p, e2n) = if left { (inner, outer) } else { (outer, inner) };
            Section {
                s,
                e1_pos: f * g,
                e1_neg: b * g,
                e2_pos: e2p * g,
                e2_neg: e2n * g,
                exponent: 2.0,
                offset: [0.0, 0.0],
            }
        };
        let mut sections: Vec<Section> = thigh
            .iter()
            .map(|&(t, f, b, i, o)| mk(t * s_knee, f, b, i, o))
            .collect();
        sections.extend(
            shin.iter()
                .map(|&(t, f, b, i, o)| mk(s_knee + t * (len - s_knee), f, b, i, o)),
        );
        let tube = Tube {
            origin: hip,
            axis,
            e1: Vec3::Z,
            sections,
            rings: 26,
            segments: 18,
            start_cap: 0.088 * g,
            end_cap: 0.03,
            cap_rings: [4, 2],
        };
        let chain = [
            (joint::LEFT_HIP + side, f32::NEG_INFINITY),
            (joint::LEFT_KNEE + side, s_knee),
            (joint::LEFT_ANKLE + side, len),
        ];
        self.add_tube(&tube, Part::Leg { left }, |v| {
            chain_weights(v.s, &chain, &[0.0, 0.05, 0.025])
        });
    }

    fn foot(&mut self, left: bool) {
        let p = &self.proportions;
        let side = if left { 0 } else { 1 };
        let ankle = self.joints[joint::LEFT_ANKLE + side];
        let ball = self.joints[joint::LEFT_FOOT + side];
        let len = p.foot_length;
        let y0 = 0.045;
        let heel = Vec3::new(
            ankle.x + if left { 0.004 } else { -0.004 },
            y0,
            ankle.z - 0.055,
        );
        // (s from the heel, top height, half-width)
        let keys = [
            (0.0, 0.080, 0.031),
            (0.055, 0.105, 0.034),
            (0.11, 0.082, 0.040),
            (0.165, 0.055, 0.045),
            ((ball.z - heel.z).min(len - 0.04), 0.042, 0.047),
            (len - 0.03, 0.030, 0.043),
        ];
        let sections = keys
            .iter()
            .map(|&(s, top, w)| Section {
                s,
                e1_pos: top / 2.0,
                e1_neg: top / 2.0,
                e2_pos: w,
                e2_neg: w,
                exponent: 2.6,
                offset: [top / 2.0 - y0, 0.0],
            })
            .collect();
        let tube = Tube {
            origin: heel,
            axis: Vec3::Z,
            e1: Vec3::Y,
            sections,
            rings: 12,
            segments: 14,
            start_cap: 0.028,
            end_cap: 0.028,
            cap_rings: [3, 3],
        };
        let chain = [
            (joint::LEFT_ANKLE + side, f32::NEG_INFINITY),
            (joint::LEFT_FOOT + side, ball.z - heel.z),
        ];
        self.add_tube(&tube, Part::Foot { left }, |v| {
            chain_weights(v.s, &chain, &[0.0, 0.03])
        });
    }
}
