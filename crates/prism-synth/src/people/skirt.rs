//! Skirts (and the skirt of a dress): a thick A-line shell around hips and thighs, skinned to
//! the pelvis and, towards the hem, partly to the hips.

use super::geometry::{Material, Piece, RadialProfile, grid_triangles};
use super::landmarks::Landmarks;
use super::outfit::Outfit;
use prism_body::joint;

/// The skirt of `outfit` around `body` (torso and legs of the shaped rest body).
pub(crate) fn skirt(outfit: &Outfit, lm: &Landmarks, body: &RadialProfile, flare: f32) -> Piece {
    let j = &lm.joints;
    let ankle_y = 0.5 * (j[joint::LEFT_ANKLE].y + j[joint::RIGHT_ANKLE].y);
    let hip_y = lm.hip_y;
    let top = lm.waist_y + 0.01;
    let hem = hip_y + outfit.bottom.length * (ankle_y - hip_y);
    let rows = 30;
    let cols = 96;
    let thick = 0.006;
    let outer = |y: f32, a: f32| {
        let fit = body.at(y, a) + 0.007;
        let below = (hip_y - y).max(0.0);
        let cone = body.at(hip_y.min(top), a).max(body.at(hip_y, a)) + 0.012 + flare * below;
        if y > hip_y { fit } else { fit.max(cone) }
    };
    // The closed profile: into the body at the top, down the outside, round the hem, up the
    // inside and back into the body.
    let mut profile: Vec<(f32, f32, f32)> = Vec::new(); // (y, offset from the outer surface, which)
    profile.push((top + 0.006, -0.02, 0.0));
    for k in 0..rows {
        let y = top + (hem - top) * k as f32 / (rows - 1) as f32;
        profile.push((y, 0.0, 1.0));
    }
    profile.push((hem + 0.002, -0.5 * thick, 1.0));
    for k in (0..rows).rev() {
        let y = top + (hem - top) * k as f32 / (rows - 1) as f32;
        profile.push((y + 0.001, -thick, 1.0));
    }
    profile.push((top - 0.01, -0.02, 0.0));
    let mut positions = Vec::new();
    let mut weights = Vec::new();
    for (y, off, _) in &profile {
        for c in 0..cols {
            let a = std::f32::consts::TAU * c as f32 / cols as f32;
            let r = outer(*y, a) + off;
            let p = body.point(*y, a, r);
            positions.push(p);
            let legs = 0.6 * ((hip_y - y) / (hip_y - hem).max(0.05)).clamp(0.0, 1.0);
            let l = 0.5 + 0.5 * (2.0 * a.sin()).clamp(-1.0, 1.0);
            let mut w = vec![(joint::PELVIS, 1.0 - legs)];
            if legs > 0.0 {
                w.push((joint::LEFT_HIP, legs * l));
                w.push((joint::RIGHT_HIP, legs * (1.0 - l)));
            }
            weights.push(w);
        }
    }
    // Rows run down the outside; flip the grid's winding so that the outside faces out.
    let triangles = grid_triangles(profile.len(), cols, true, true)
        .into_iter()
        .map(|[a, b, c]| [a, c, b])
        .collect();
    let material = vec![Material::Skirt { hem }; positions.len()];
    Piece {
        positions,
        triangles,
        weights,
        material,
    }
}
