//! Tests of the people generator.

use super::*;

fn model() -> &'static BodyModel {
    static MODEL: std::sync::OnceLock<BodyModel> = std::sync::OnceLock::new();
    MODEL.get_or_init(|| BodyModel::procedural(0))
}

fn quick(seed: u64) -> Person {
    generate_with(model(), seed, &PeopleConfig { subdivisions: 1 })
}

#[test]
fn deterministic_per_seed_and_different_across_seeds() {
    let a = quick(11);
    let b = quick(11);
    let c = quick(12);
    assert_eq!(a.mesh, b.mesh);
    assert_eq!(a.body, b.body);
    assert_eq!(a.height, b.height);
    assert_ne!(a.body, c.body);
    assert_ne!(a.mesh.colors, c.mesh.colors);
}

#[test]
fn people_stand_on_the_floor_with_a_plausible_height_and_a_valid_mesh() {
    for seed in 0..6 {
        let p = quick(seed);
        let (lo, hi) = p.mesh.bounds().unwrap();
        assert!(lo.y.abs() < 1e-6, "seed {seed}: lowest point {}", lo.y);
        assert!((hi.y - p.height).abs() < 1e-6);
        assert!(
            (1.5..2.1).contains(&p.height),
            "seed {seed}: height {}",
            p.height
        );
        // Facing +Z: the mesh is roughly centred and not much deeper than wide.
        assert!(lo.x < -0.1 && hi.x > 0.1 && (hi.z - lo.z) < 1.0);
        let n = p.mesh.positions.len() as u32;
        assert!(p.mesh.triangles.iter().flatten().all(|&i| i < n));
        assert!(p.mesh.positions.iter().all(|v| v.is_finite()));
        assert!(
            p.mesh
                .colors
                .iter()
                .flatten()
                .all(|c| (0.0..=1.0).contains(c))
        );
        // Smooth enough for 512 px: tens of thousands of triangles.
        assert!(p.mesh.triangles.len() > 40_000);
    }
}

#[test]
fn body_parameters_reproduce_the_body_inside_the_clothes() {
    for seed in 0..4 {
        let p = quick(seed);
        assert_eq!(p.body.scale, 1.0);
        assert_eq!(p.body.model, model().name());
        assert_eq!((p.body.transl[0], p.body.transl[2]), (0.0, 0.0));
        p.body.validate().unwrap();
        let posed = model().pose(&p.body);
        let (lo, hi) = p.mesh.bounds().unwrap();
        let body_lo = posed
            .vertices
            .iter()
            .map(|v| v.y)
            .fold(f32::INFINITY, f32::min);
        // The soles lift the feet slightly; the body sits inside the person's bounds.
        assert!(
            (0.0..0.03).contains(&body_lo),
            "seed {seed}: feet at {body_lo}"
        );
        for v in &posed.vertices {
            assert!(v.cmpge(lo - Vec3::splat(0.01)).all() && v.cmple(hi + Vec3::splat(0.01)).all());
        }
    }
}

#[test]
fn sampled_poses_respect_the_joint_limits() {
    let limits = pose_limits();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for i in 0..300 {
        let pose = sample_pose(&mut rng, i % 3 == 0);
        assert!(within_limits(&pose, &limits), "sample {i}");
        // Standing and facing the camera: little global rotation.
        assert!(pose[0].iter().all(|x| x.abs() <= 0.3));
    }
    for seed in 0..3 {
        assert!(within_limits(&quick(seed).body.pose, &limits));
    }
    // Limits are mirror images across the body.
    let l = limits[joint::LEFT_SHOULDER];
    let r = limits[joint::RIGHT_SHOULDER];
    assert_eq!((r[1].0, r[1].1), (-l[1].1, -l[1].0));
    assert_eq!(r[0], l[0]);
}

#[test]
fn wardrobes_and_hair_styles_vary() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut tops = std::collections::HashSet::new();
    let mut bottoms = std::collections::HashSet::new();
    let mut patterns = std::collections::HashSet::new();
    let mut hair = std::collections::HashSet::new();
    let mut jackets = 0;
    for i in 0..400 {
        let o = outfit::Outfit::random(&mut rng, i % 2 == 0);
        tops.insert(format!("{:?}", o.top.kind));
        bottoms.insert(format!("{:?}", o.bottom.kind));
        patterns.insert(std::mem::discriminant(&o.top.fabric.pattern));
        jackets += o.jacket.is_some() as usize;
        hair.insert(format!(
            "{:?}",
            hair::Hair::random(&mut rng, i % 2 == 0).style
        ));
    }
    assert_eq!(tops.len(), 5, "{tops:?}");
    assert_eq!(bottoms.len(), 4, "{bottoms:?}");
    assert!(patterns.len() >= 7);
    assert!(jackets > 20);
    assert_eq!(hair.len(), 8, "{hair:?}");
}

#[test]
fn extra_geometry_is_closed_and_outward() {
    let m = model();
    let posed = m.lbs(&[0.0; 10], &[[0.0; 3]; 55], &[0.0; 10]);
    let lm = Landmarks::new(m, &posed);
    let upper = RadialProfile::from_mesh(
        &posed.shaped,
        &part_triangles(m, &posed, |r, _| {
            matches!(r, Region::Head | Region::Neck | Region::Torso)
        }),
        Vec3::new(0.0, 0.0, lm.head_centre.z),
        lm.neck_base_y - 0.45,
        lm.top_y,
        0.01,
        48,
    )
    .convex();
    let lower = RadialProfile::from_mesh(
        &posed.shaped,
        &part_triangles(m, &posed, |r, _| {
            matches!(r, Region::Torso | Region::Leg { .. })
        }),
        Vec3::new(0.0, 0.0, lm.joints[joint::PELVIS].z),
        0.0,
        lm.waist_y + 0.05,
        0.01,
        48,
    )
    .convex();
    let volume = |p: &Piece| -> f32 {
        p.triangles
            .iter()
            .map(|f| {
                let [a, b, c] = f.map(|i| p.positions[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for style in [
        hair::HairStyle::Long,
        hair::HairStyle::Bob,
        hair::HairStyle::Ponytail,
        hair::HairStyle::Bun,
    ] {
        let mut h = hair::Hair::random(&mut rng, true);
        h.style = style;
        let piece = h.pieces(&lm, &upper);
        assert!(volume(&piece) > 1e-5, "{style:?}: {}", volume(&piece));
        assert!(
            piece
                .weights
                .iter()
                .all(|w| (w.iter().map(|x| x.1).sum::<f32>() - 1.0).abs() < 1e-5)
        );
    }
    let mut o = outfit::Outfit::random(&mut rng, true);
    o.bottom.kind = outfit::BottomKind::Skirt;
    let piece = skirt::skirt(&o, &lm, &lower, 0.2);
    assert!(volume(&piece) > 1e-4);
    // The skirt clears the legs: every point lies outside the body's convex profile.
    for p in &piece.positions {
        let q = *p - lower.axis;
        let a = q.x.atan2(q.z);
        if p.y < lm.hip_y - 0.05 {
            assert!(
                glam::Vec2::new(q.x, q.z).length() > lower.at(p.y, a) - 0.007,
                "{p}"
            );
        }
    }
}

#[test]
fn placement_moves_mesh_and_body_together() {
    let p = quick(5);
    let placement = prism_core::Placement {
        height: 1.82,
        translation: [0.07, 0.0, -0.04],
    };
    let w = p.placed(&placement);
    let (lo, hi) = w.mesh.bounds().unwrap();
    assert!(lo.y.abs() < 1e-5 && (hi.y - 1.82).abs() < 1e-4);
    // The posed body of the composed parameters is the placed body.
    let a = model().pose(&p.body);
    let b = model().pose(&w.body);
    let m = placement.transform(p.height);
    for (x, y) in a.vertices.iter().zip(&b.vertices) {
        assert!((m.transform_point3(*x) - *y).length() < 1e-4);
    }
}
