//! Procedural people: a body model posed and dressed, as a vertex-coloured mesh.
//!
//! [`generate`] draws, from a seed, a body shape and expression, a standing pose within joint
//! limits (facing the camera, as in a frontal telepresence photo), a skin tone, a hair style
//! and colour, a face (eyes, brows, lips), and an outfit (shirts, t-shirts, sweaters, jackets,
//! trousers, jeans, shorts, skirts, dresses, shoes; solid, striped, checked, plaid, dotted,
//! denim and knitted fabrics). The posed body mesh is refined (smooth subdivision) so that
//! silhouettes and patterns stay clean at 512 px; clothes stand off the skin, hair is a cap on
//! the scalp plus extra geometry for long styles, skirts are a separate shell; extra geometry
//! is skinned with the body's joint transforms. Lighting is baked into the colours.
//!
//! The person stands on `y = 0` facing +Z in the body model's frame (the model's own scale);
//! [`Person::body`] reproduces its body with scale 1 and a vertical translation that puts the
//! shoes on the floor. The dataset writer composes the viewing protocol's placement on top
//! ([`BodyParams::placed`] with `Placement::transform(person.height)`).

mod face;
mod geometry;
mod hair;
mod landmarks;
mod noise;
mod outfit;
mod palette;
mod pose;
mod refine;
mod shading;
mod skirt;

pub use pose::{PoseLimits, pose_limits, sample_pose, within_limits};

use glam::Vec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::mesh::Mesh;
use geometry::{Material, Piece, RadialProfile, vertex_normals};
use landmarks::{Landmarks, Region, dominant};
use prism_body::joints::{NUM_BETAS, NUM_EXPRESSION, joint};
use prism_body::{BodyModel, BodyParams, PosedBody};
use refine::Refinable;

/// A generated person.
#[derive(Clone, Debug)]
pub struct Person {
    /// The dressed, coloured mesh in the subject's frame: standing on `y = 0`, facing +Z.
    pub mesh: Mesh,
    /// The body parameters of the mesh's body in the same frame (scale 1).
    pub body: BodyParams,
    /// Height of the mesh (top of the hair), metres in the body model's units.
    pub height: f32,
}

impl Person {
    /// The person placed in the world by the viewing protocol: scaled to `placement.height`
    /// and translated (`Placement::transform(self.height)`), with the body parameters composed
    /// accordingly (`scale`, `transl` of `body.json`).
    pub fn placed(&self, placement: &prism_core::Placement) -> Person {
        let m = placement.transform(self.height);
        let mut mesh = self.mesh.clone();
        for p in &mut mesh.positions {
            *p = m.transform_point3(*p);
        }
        Person {
            mesh,
            body: self.body.placed(m),
            height: placement.height,
        }
    }
}

/// Options of the people generator.
#[derive(Clone, Debug, PartialEq)]
pub struct PeopleConfig {
    /// Subdivision levels of the body mesh (each multiplies its triangles by 4). 2 keeps
    /// silhouettes and patterns smooth at 512 px; 1 is enough for 256 px.
    pub subdivisions: u32,
}

impl Default for PeopleConfig {
    fn default() -> Self {
        Self { subdivisions: 2 }
    }
}

impl PeopleConfig {
    /// Options suited to renders of `resolution` pixels: one subdivision up to 256 px, two
    /// above.
    pub fn for_resolution(resolution: u32) -> Self {
        Self {
            subdivisions: if resolution <= 256 { 1 } else { 2 },
        }
    }
}

/// The identity part of a person: everything except the pose.
struct Look {
    feminine: bool,
    betas: [f32; NUM_BETAS],
    expression: [f32; NUM_EXPRESSION],
    face: face::Face,
    hair: hair::Hair,
    outfit: outfit::Outfit,
    light: Vec3,
}

fn normal(rng: &mut ChaCha8Rng) -> f32 {
    // Irwin-Hall approximation of a standard normal.
    (0..6).map(|_| rng.random_range(0.0f32..1.0)).sum::<f32>() - 3.0
}

impl Look {
    fn random(rng: &mut ChaCha8Rng) -> Self {
        let feminine = rng.random_bool(0.5);
        let mut betas = [0.0f32; NUM_BETAS];
        for b in &mut betas {
            *b = (0.8 * normal(rng)).clamp(-2.0, 2.0);
        }
        let s = if feminine { 1.0 } else { -1.0 };
        betas[0] = (betas[0] - 0.5 * s).clamp(-2.0, 2.0); // stature
        betas[4] = (betas[4] * 0.6 - 0.8 * s).clamp(-2.0, 2.0); // shoulders
        betas[5] = (betas[5] * 0.6 + 0.6 * s).clamp(-2.0, 2.0); // hips
        betas[7] = if feminine {
            rng.random_range(0.5..2.0)
        } else {
            rng.random_range(-0.5..0.3)
        };
        betas[8] = betas[8].abs() * if rng.random_bool(0.4) { 1.0 } else { 0.3 };
        let mut expression = [0.0f32; NUM_EXPRESSION];
        for e in &mut expression {
            *e = (0.35 * normal(rng)).clamp(-1.0, 1.0);
        }
        expression[0] = rng.random_range(-0.2..1.5); // mostly smiling
        let skin = palette::skin(rng);
        let hair = hair::Hair::random(rng, feminine);
        let face = face::Face::random(rng, skin, hair.color, feminine);
        let outfit = outfit::Outfit::random(rng, feminine);
        let light = Vec3::new(rng.random_range(-0.7..0.7), rng.random_range(0.5..1.2), 1.0);
        Self {
            feminine,
            betas,
            expression,
            face,
            hair,
            outfit,
            light,
        }
    }
}

/// A person drawn from `seed` on `model`, with the default options.
pub fn generate(model: &BodyModel, seed: u64) -> Person {
    generate_with(model, seed, &PeopleConfig::default())
}

/// A person drawn from `seed` on `model`.
pub fn generate_with(model: &BodyModel, seed: u64, config: &PeopleConfig) -> Person {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let look = Look::random(&mut rng);
    let skirt = look.outfit.skirt();
    let pose = sample_pose(&mut rng, skirt);
    let _ = look.feminine;
    let mut body = BodyParams::rest(model.name());
    body.betas = look.betas;
    body.expression = look.expression;
    body.pose = pose;

    let posed = model.lbs(&body.betas, &body.pose, &body.expression);
    let lm = Landmarks::new(model, &posed);

    // The body surface, refined, coloured and dressed.
    let normals = vertex_normals(&posed.vertices, model.faces());
    let (region, jaw): (Vec<Region>, Vec<f32>) = (0..model.num_vertices())
        .map(|v| {
            let w = model.vertex_weights(v);
            (Region::of_joint(dominant(w).0), w[joint::JAW])
        })
        .unzip();
    let mut surface = Refinable {
        positions: posed.vertices.clone(),
        normals,
        rest: posed.shaped.clone(),
        region,
        jaw,
        triangles: model.faces().to_vec(),
    };
    for _ in 0..config.subdivisions {
        surface = surface.subdivide();
    }
    let mut positions = Vec::with_capacity(surface.positions.len());
    let mut colors = Vec::with_capacity(surface.positions.len());
    for i in 0..surface.positions.len() {
        let p = surface.rest[i];
        let (color, offset) = match surface.region[i] {
            Region::Head => match look.hair.scalp(&lm, p) {
                Some((c, t)) => (c, t),
                None => (look.face.head(&lm, p, surface.jaw[i]), 0.0),
            },
            Region::Eye { left } => {
                let centre = lm.joints[if left {
                    joint::LEFT_EYE
                } else {
                    joint::RIGHT_EYE
                }];
                (look.face.eye(p, centre), 0.0)
            }
            Region::Hand { .. } => (look.face.skin_at(p), 0.0),
            region => match outfit::clothe(&look.outfit, &lm, region, p) {
                Some(c) => (c.color, c.offset),
                None => (look.face.skin_at(p), 0.0),
            },
        };
        positions.push(surface.positions[i] + surface.normals[i] * offset);
        colors.push(color);
    }
    let mut mesh = Mesh::with_vertex_colors(positions, surface.triangles, colors);

    // Extra geometry in the shaped rest frame, skinned like the body.
    let mut pieces = Piece::default();
    let upper = RadialProfile::from_mesh(
        &posed.shaped,
        &part_triangles(model, &posed, |region, p| match region {
            Region::Head | Region::Neck | Region::Torso => true,
            Region::Arm { left } => lm.arm_t(p, left) < 0.1,
            _ => false,
        }),
        Vec3::new(0.0, 0.0, lm.head_centre.z),
        lm.neck_base_y - 0.45,
        lm.top_y,
        0.01,
        48,
    )
    .convex();
    pieces.append(look.hair.pieces(&lm, &upper));
    if skirt {
        let lower = RadialProfile::from_mesh(
            &posed.shaped,
            &part_triangles(model, &posed, |region, _| {
                matches!(region, Region::Torso | Region::Leg { .. })
            }),
            Vec3::new(0.0, 0.0, lm.joints[joint::PELVIS].z),
            0.0,
            lm.waist_y + 0.05,
            0.01,
            48,
        )
        .convex();
        let flare = rng.random_range(0.12..0.35);
        pieces.append(skirt::skirt(&look.outfit, &lm, &lower, flare));
    }
    let skinned: Vec<Vec3> = pieces
        .positions
        .iter()
        .zip(&pieces.weights)
        .map(|(p, w)| posed.skin_point(*p, w))
        .collect();
    let mut extra = Refinable {
        normals: vertex_normals(&skinned, &pieces.triangles),
        positions: skinned,
        jaw: vec![0.0; pieces.positions.len()],
        rest: pieces.positions,
        region: pieces.material,
        triangles: pieces.triangles,
    };
    // Extra geometry is built finer than the body: one level less.
    for _ in 1..config.subdivisions {
        extra = extra.subdivide();
    }
    let extra_colors = extra
        .rest
        .iter()
        .zip(&extra.region)
        .map(|(p, m)| match m {
            Material::Hair => look.hair.strand_color(&lm, *p),
            Material::Skirt { hem } => {
                let q = *p - lm.joints[joint::PELVIS];
                let c = look
                    .outfit
                    .bottom
                    .fabric
                    .color(q.x.atan2(q.z) * 0.18, p.y, *p);
                if p.y - hem < 0.012 {
                    palette::scale(c, 0.9)
                } else {
                    c
                }
            }
        })
        .collect();
    mesh.append(&Mesh::with_vertex_colors(
        extra.positions,
        extra.triangles,
        extra_colors,
    ));

    shading::bake(
        &mesh.positions,
        &mesh.triangles,
        &mut mesh.colors,
        look.light,
    );

    // Stand on the floor.
    let (lo, hi) = mesh.bounds().expect("a person has vertices");
    for p in &mut mesh.positions {
        p.y -= lo.y;
    }
    body.transl = [0.0, -lo.y, 0.0];
    Person {
        mesh,
        body,
        height: hi.y - lo.y,
    }
}

/// The triangles of the body whose three vertices lie in regions that `keep` accepts (given
/// the region and the shaped rest position).
fn part_triangles(
    model: &BodyModel,
    posed: &PosedBody,
    keep: impl Fn(Region, Vec3) -> bool,
) -> Vec<[u32; 3]> {
    let accepted: Vec<bool> = (0..model.num_vertices())
        .map(|v| {
            keep(
                Region::of_joint(dominant(model.vertex_weights(v)).0),
                posed.shaped[v],
            )
        })
        .collect();
    model
        .faces()
        .iter()
        .filter(|t| t.iter().all(|&i| accepted[i as usize]))
        .copied()
        .collect()
}

#[cfg(test)]
mod tests;
