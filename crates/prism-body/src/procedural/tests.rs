//! Tests of the procedural body model.

use std::collections::HashMap;

use glam::Vec3;

use super::proportions::Proportions;
use super::skeleton::rest_joints;
use crate::joints::{NUM_JOINTS, joint};
use crate::{BodyModel, BodyParams};

fn model() -> &'static BodyModel {
    static MODEL: std::sync::OnceLock<BodyModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| BodyModel::procedural(0))
}

#[test]
fn has_the_smplx_tree_and_a_moderate_size() {
    let m = model();
    assert!(m.has_smplx_tree());
    assert_eq!(m.parents().len(), NUM_JOINTS);
    let v = m.num_vertices();
    assert!((2000..=6500).contains(&v), "{v} vertices");
}

#[test]
fn weights_are_convex_and_the_regressor_reproduces_the_skeleton() {
    let m = model();
    for v in 0..m.num_vertices() {
        let w = m.vertex_weights(v);
        assert!(w.iter().all(|&x| x >= 0.0));
        assert!((w.iter().sum::<f32>() - 1.0).abs() < 1e-5, "vertex {v}");
    }
    let n = m.num_vertices();
    for j in 0..NUM_JOINTS {
        let row = &m.j_regressor()[j * n..(j + 1) * n];
        assert!(row.iter().all(|&x| x >= 0.0));
        assert!((row.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        assert!(
            row.iter().filter(|&&x| x > 1e-4).count() >= 8,
            "joint {j} uses few vertices"
        );
    }
    let designed = rest_joints(&Proportions::from_seed(0));
    for (j, (a, b)) in m.rest_joints().iter().zip(designed).enumerate() {
        assert!((*a - b).length() < 1e-5, "joint {j}: {a} vs {b}");
    }
}

#[test]
fn rest_pose_stands_on_the_floor_facing_z_in_a_t_pose() {
    let m = model();
    let t = m.v_template();
    let min_y = t.iter().map(|p| p.y).fold(f32::INFINITY, f32::min);
    let max_y = t.iter().map(|p| p.y).fold(f32::NEG_INFINITY, f32::max);
    assert!(min_y.abs() < 0.003, "feet at {min_y}");
    assert!((1.65..1.85).contains(&max_y), "height {max_y}");
    let j = m.rest_joints();
    // Left on +X, arms horizontal, the face (nose) in front of the eyes.
    assert!(j[joint::LEFT_WRIST].x > 0.6 && j[joint::RIGHT_WRIST].x < -0.6);
    assert!((j[joint::LEFT_WRIST].y - j[joint::LEFT_SHOULDER].y).abs() < 1e-3);
    let nose =
        t.iter()
            .filter(|p| p.y > j[joint::HEAD].y)
            .fold(Vec3::splat(f32::NEG_INFINITY), |a, p| {
                if p.z > a.z { *p } else { a }
            });
    assert!(nose.z > j[joint::LEFT_EYE].z + 0.02 && nose.x.abs() < 0.01);
}

#[test]
fn the_surface_is_closed_and_outward() {
    let m = model();
    let mut edges: HashMap<(u32, u32), i32> = HashMap::new();
    for f in m.faces() {
        for k in 0..3 {
            // Directed edges: each must be matched by its reverse.
            *edges.entry((f[k], f[(k + 1) % 3])).or_insert(0) += 1;
        }
    }
    for (&(a, b), &c) in &edges {
        assert_eq!(c, 1, "edge {a}-{b} used {c} times");
        assert_eq!(edges.get(&(b, a)), Some(&1), "edge {a}-{b} has no twin");
    }
    let t = m.v_template();
    let volume: f32 = m
        .faces()
        .iter()
        .map(|f| t[f[0] as usize].dot(t[f[1] as usize].cross(t[f[2] as usize])) / 6.0)
        .sum();
    // A person of ~70 kg has ~0.07 m^3; overlapping parts count twice where they overlap.
    assert!((0.04..0.12).contains(&volume), "volume {volume}");
}

#[test]
fn shape_coefficients_change_height_limbs_and_girth_and_move_the_joints() {
    let m = model();
    let posed = |k: usize, b: f32| {
        let mut p = BodyParams::rest("procedural:0");
        p.betas[k] = b;
        m.pose(&p)
    };
    let height = |v: &[Vec3]| v.iter().map(|p| p.y).fold(f32::NEG_INFINITY, f32::max);
    let base = posed(0, 0.0);
    assert!(height(&posed(0, 1.0).vertices) > height(&base.vertices) + 0.05);
    let legs = posed(2, 1.0);
    assert!(legs.joints[joint::LEFT_HIP].y > base.joints[joint::LEFT_HIP].y + 0.04);
    assert!((legs.joints[joint::LEFT_ANKLE].y - base.joints[joint::LEFT_ANKLE].y).abs() < 0.01);
    let arms = posed(3, 1.0);
    assert!(arms.joints[joint::LEFT_WRIST].x > base.joints[joint::LEFT_WRIST].x + 0.025);
    assert!(arms.joints[joint::RIGHT_WRIST].x < base.joints[joint::RIGHT_WRIST].x - 0.025);
    // Girth: the waist ring grows.
    let waist = |v: &[Vec3]| {
        let y = base.joints[joint::SPINE1].y + 0.05;
        v.iter()
            .zip(m.v_template())
            .filter(|(_, t)| (t.y - y).abs() < 0.01 && t.x.abs() < 0.2)
            .map(|(p, _)| p.x.abs())
            .fold(0.0, f32::max)
    };
    assert!(waist(&posed(1, 2.0).vertices) > waist(&base.vertices) + 0.02);
}

#[test]
fn expressions_move_only_the_face() {
    let m = model();
    let mut p = BodyParams::rest("procedural:0");
    let base = m.pose(&p);
    p.expression[0] = 1.0;
    let smile = m.pose(&p);
    let head_y = base.joints[joint::HEAD].y;
    let mut moved = 0;
    for (a, b) in base.vertices.iter().zip(&smile.vertices) {
        if (*a - *b).length() > 1e-6 {
            assert!(a.y > head_y - 0.07 && a.z > 0.0, "{a} moved");
            moved += 1;
        }
    }
    assert!(moved > 20);
    // The mouth corners rise.
    let corner = base
        .vertices
        .iter()
        .zip(&smile.vertices)
        .map(|(a, b)| b.y - a.y)
        .fold(0.0, f32::max);
    assert!(corner > 0.003);
}

#[test]
fn bones_stay_rigid_and_correctives_bulge_a_bent_elbow() {
    let m = model();
    let mut p = BodyParams::rest("procedural:0");
    p.pose[joint::LEFT_ELBOW] = [0.0, -1.5, 0.0];
    p.pose[joint::LEFT_SHOULDER] = [0.0, 0.0, -1.2];
    let posed = m.pose(&p);
    let rest = m.rest_joints();
    let len = |a: Vec3, b: Vec3| (a - b).length();
    for (a, b) in [
        (joint::LEFT_SHOULDER, joint::LEFT_ELBOW),
        (joint::LEFT_ELBOW, joint::LEFT_WRIST),
    ] {
        assert!((len(posed.joints[a], posed.joints[b]) - len(rest[a], rest[b])).abs() < 1e-5);
    }
    // The arm hangs down, the forearm points forward.
    assert!(posed.joints[joint::LEFT_ELBOW].y < rest[joint::LEFT_SHOULDER].y - 0.2);
    assert!(posed.joints[joint::LEFT_WRIST].z > posed.joints[joint::LEFT_ELBOW].z + 0.2);
    // Pose correctives push vertices near the bent elbow outwards.
    let mut flat = m.clone().into_arrays();
    flat.posedirs.iter_mut().for_each(|x| *x = 0.0);
    let without = BodyModel::from_arrays(flat).unwrap().pose(&p);
    let e = posed.joints[joint::LEFT_ELBOW];
    let spread = |v: &[Vec3]| {
        v.iter()
            .map(|x| (*x - e).length())
            .filter(|d| *d < 0.06)
            .count()
    };
    let moved = posed
        .vertices
        .iter()
        .zip(&without.vertices)
        .filter(|(a, b)| (**a - **b).length() > 0.003)
        .count();
    assert!(moved > 10, "{moved}");
    assert!(spread(&posed.vertices) <= spread(&without.vertices));
}

#[test]
fn deterministic_per_seed_with_a_shared_topology() {
    let a = BodyModel::procedural(3);
    let b = BodyModel::procedural(3);
    let c = BodyModel::procedural(4);
    assert_eq!(a, b);
    assert_ne!(a.v_template(), c.v_template());
    assert_eq!(a.faces(), c.faces());
    assert_eq!(super::parse_model_name(&super::model_name(42)), Some(42));
    assert_eq!(super::parse_model_name("/data/SMPLX_NEUTRAL.npz"), None);
}
