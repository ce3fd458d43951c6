//! The body model as Burn tensor operations: batched, differentiable linear blend skinning.
//!
//! The same computation as [`BodyModel::lbs`] (see `lbs.rs` for the equations), over a batch
//! `B`, differentiable with respect to betas, pose and expression. The kinematic chain runs one
//! tree level at a time (11 levels for SMPL-X) instead of one joint at a time, and skinning
//! blends the 55 joint transforms with one matmul, so that the layer is cheap enough to run per
//! training sample.

use burn::module::Module;
use burn::tensor::{Device, Int, Tensor, TensorData};

use super::joints::{NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS, NUM_POSE_FEATURES, depths};
use super::model::{BodyModel, NUM_SHAPE_COEFFS};
use super::rotation::SMALL_ANGLE_SQ;

/// One level of the kinematic tree: its joints, and for each the position of its parent in the
/// previous level.
#[derive(Clone, Debug)]
struct Level {
    joints: Vec<usize>,
    parents: Vec<usize>,
    parent_slots: Vec<usize>,
}

/// The joints of the tree grouped by depth, and the permutation back to joint order.
#[derive(Clone, Debug)]
pub struct KinematicLevels {
    levels: Vec<Level>,
    /// For each joint, its position in the concatenation of all levels.
    order: Vec<usize>,
}

impl KinematicLevels {
    fn new(parents: &[Option<usize>]) -> Self {
        let depth = depths(parents);
        let max = depth.iter().copied().max().unwrap_or(0);
        let mut levels: Vec<Level> = Vec::with_capacity(max + 1);
        let mut slot = vec![0usize; parents.len()];
        let mut order = vec![0usize; parents.len()];
        let mut offset = 0;
        for d in 0..=max {
            let joints: Vec<usize> = (0..parents.len()).filter(|&j| depth[j] == d).collect();
            for (k, &j) in joints.iter().enumerate() {
                slot[j] = k;
                order[j] = offset + k;
            }
            offset += joints.len();
            let parents_of: Vec<usize> = joints.iter().map(|&j| parents[j].unwrap_or(j)).collect();
            let parent_slots = parents_of.iter().map(|&p| slot[p]).collect();
            levels.push(Level {
                joints,
                parents: parents_of,
                parent_slots,
            });
        }
        Self { levels, order }
    }
}

/// The output of [`BodyLayer::forward`].
#[derive(Clone, Debug)]
pub struct BodyOutput {
    /// Posed vertices `[B, V, 3]`.
    pub vertices: Tensor<3>,
    /// Posed joints `[B, 55, 3]`.
    pub joints: Tensor<3>,
}

/// A body model on a device, ready for batched differentiable skinning.
///
/// Its tensors are constants (no trainable parameters); as a [`Module`] it can be a field of a
/// model and moves with it between devices.
#[derive(Module, Debug)]
pub struct BodyLayer {
    /// `[1, V*3]` template, flattened.
    v_template: Tensor<2>,
    /// `[20, V*3]` shape (10) and expression (10) directions.
    shapedirs: Tensor<2>,
    /// `[1, 55*3]` rest joints of the template.
    j_template: Tensor<2>,
    /// `[20, 55*3]` how the joints move with each coefficient (`J_regressor` applied to
    /// `shapedirs`).
    j_shapedirs: Tensor<2>,
    /// `[486, V*3]` pose-corrective directions.
    posedirs: Tensor<2>,
    /// `[1, 486]` the pose feature of the identity rotations (`I` repeated), subtracted from the
    /// flattened rotations.
    identity_feature: Tensor<2>,
    /// `[V, 55]` skinning weights.
    weights: Tensor<2>,
    /// `[F, 3]` triangles.
    faces: Tensor<2, Int>,
    #[module(skip)]
    levels: KinematicLevels,
    #[module(skip)]
    num_vertices: usize,
}

impl BodyLayer {
    /// The layer of `model` on `device`.
    pub fn new(model: &BodyModel, device: &Device) -> Self {
        let v = model.num_vertices();
        let c = NUM_SHAPE_COEFFS;
        let f2 = |data: Vec<f32>, shape: [usize; 2]| {
            Tensor::<2>::from_data(TensorData::new(data, shape), device)
        };

        let template: Vec<f32> = model.v_template.iter().flat_map(|p| p.to_array()).collect();
        // shapedirs [V, 3, C] -> [C, V*3].
        let mut shapedirs = vec![0.0f32; c * v * 3];
        for (i, row) in model.shapedirs.chunks_exact(c).enumerate() {
            for (k, x) in row.iter().enumerate() {
                shapedirs[k * v * 3 + i] = *x;
            }
        }
        // posedirs [V, 3, 486] -> [486, V*3].
        let mut posedirs = vec![0.0f32; NUM_POSE_FEATURES * v * 3];
        for (i, row) in model.posedirs.chunks_exact(NUM_POSE_FEATURES).enumerate() {
            for (k, x) in row.iter().enumerate() {
                posedirs[k * v * 3 + i] = *x;
            }
        }
        // Joints of the template and their blend directions, through J_regressor (in f64 so
        // that the regressed joints match the f32 path's sums closely).
        let mut j_template = vec![0.0f32; NUM_JOINTS * 3];
        let mut j_shapedirs = vec![0.0f32; c * NUM_JOINTS * 3];
        for j in 0..NUM_JOINTS {
            let row = &model.j_regressor[j * v..(j + 1) * v];
            for d in 0..3 {
                let mut acc = 0.0f64;
                let mut dirs = vec![0.0f64; c];
                for (vi, w) in row.iter().enumerate().filter(|(_, w)| **w != 0.0) {
                    acc += f64::from(*w) * f64::from(model.v_template[vi][d]);
                    for (k, dk) in dirs.iter_mut().enumerate() {
                        *dk += f64::from(*w) * f64::from(model.shapedirs[(vi * 3 + d) * c + k]);
                    }
                }
                j_template[j * 3 + d] = acc as f32;
                for (k, dk) in dirs.iter().enumerate() {
                    j_shapedirs[k * NUM_JOINTS * 3 + j * 3 + d] = *dk as f32;
                }
            }
        }
        let identity: Vec<f32> = (0..NUM_JOINTS - 1)
            .flat_map(|_| [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
            .collect();
        let faces: Vec<i64> = model.faces.iter().flatten().map(|&i| i as i64).collect();
        Self {
            v_template: f2(template, [1, v * 3]),
            shapedirs: f2(shapedirs, [c, v * 3]),
            j_template: f2(j_template, [1, NUM_JOINTS * 3]),
            j_shapedirs: f2(j_shapedirs, [c, NUM_JOINTS * 3]),
            posedirs: f2(posedirs, [NUM_POSE_FEATURES, v * 3]),
            identity_feature: f2(identity, [1, NUM_POSE_FEATURES]),
            weights: f2(model.weights.clone(), [v, NUM_JOINTS]),
            faces: Tensor::<2, Int>::from_data(
                TensorData::new(faces, [model.faces.len(), 3]),
                device,
            ),
            levels: KinematicLevels::new(&model.parents),
            num_vertices: v,
        }
    }

    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.num_vertices
    }

    /// The triangles `[F, 3]` (for rasterizing the posed mesh).
    pub fn faces(&self) -> Tensor<2, Int> {
        self.faces.clone()
    }

    /// Batched SMPL-X skinning: `betas [B, 10]`, `pose [B, 55, 3]` (axis-angle, SMPL-X order),
    /// `expression [B, 10]` to posed vertices `[B, V, 3]` and joints `[B, 55, 3]` in the
    /// model's frame. Differentiable in all three inputs.
    pub fn forward(&self, betas: Tensor<2>, pose: Tensor<3>, expression: Tensor<2>) -> BodyOutput {
        let [b, _] = betas.dims();
        assert_eq!(betas.dims()[1], NUM_BETAS, "betas must be [B, 10]");
        assert_eq!(
            expression.dims(),
            [b, NUM_EXPRESSION],
            "expression must be [B, 10]"
        );
        assert_eq!(pose.dims(), [b, NUM_JOINTS, 3], "pose must be [B, 55, 3]");
        let rotations: Tensor<4> =
            rodrigues(pose.reshape([b * NUM_JOINTS, 3])).reshape([b, NUM_JOINTS, 3, 3]);
        self.forward_rotations(betas, rotations, expression)
    }

    /// The joints `[B, 55, 3]` of the shaped body in its rest pose, for `betas [B, 10]` and
    /// `expression [B, 10]`. The root joint is where [`BodyLayer::forward`] leaves it whatever
    /// the pose (its joints' row 0, to the bit), so this gives it without posing the vertices.
    pub fn rest_joints(&self, betas: Tensor<2>, expression: Tensor<2>) -> Tensor<3> {
        self.joints_of(Tensor::cat(vec![betas, expression], 1))
    }

    /// The rest joints for the blend coefficients `[betas, expression]` `[B, 20]`: the
    /// regressor is linear, so the joints of the shaped body are the template's joints plus the
    /// regressed directions.
    fn joints_of(&self, coeffs: Tensor<2>) -> Tensor<3> {
        let [b, _] = coeffs.dims();
        (coeffs.matmul(self.j_shapedirs.clone()) + self.j_template.clone())
            .reshape([b, NUM_JOINTS, 3])
    }

    /// [`BodyLayer::forward`] with the joints' rotations given as matrices `[B, 55, 3, 3]`
    /// (row-major) instead of axis-angle.
    pub fn forward_rotations(
        &self,
        betas: Tensor<2>,
        rotations: Tensor<4>,
        expression: Tensor<2>,
    ) -> BodyOutput {
        let [b, _] = betas.dims();
        let v = self.num_vertices;
        assert_eq!(
            rotations.dims(),
            [b, NUM_JOINTS, 3, 3],
            "rotations must be [B, 55, 3, 3]"
        );

        // Shape and expression blend shapes, and the rest joints.
        let coeffs = Tensor::cat(vec![betas, expression], 1);
        let v_shaped = coeffs.clone().matmul(self.shapedirs.clone()) + self.v_template.clone();
        let rest_joints = self.joints_of(coeffs);

        // Pose correctives.
        let feature = rotations
            .clone()
            .slice([0..b, 1..NUM_JOINTS])
            .reshape([b, NUM_POSE_FEATURES])
            - self.identity_feature.clone();
        let v_posed: Tensor<3> =
            (v_shaped + feature.matmul(self.posedirs.clone())).reshape([b, v, 3]);

        // Kinematic chain, one tree level at a time.
        let device = rotations.device();
        let index = |ids: &[usize]| {
            let ids: Vec<i64> = ids.iter().map(|&i| i as i64).collect();
            Tensor::<1, Int>::from_data(TensorData::new(ids.clone(), [ids.len()]), &device)
        };
        let mut level_r: Vec<Tensor<4>> = Vec::new();
        let mut level_t: Vec<Tensor<3>> = Vec::new();
        for (d, level) in self.levels.levels.iter().enumerate() {
            let ids = index(&level.joints);
            let r = rotations.clone().select(1, ids.clone());
            let j = rest_joints.clone().select(1, ids);
            if d == 0 {
                level_r.push(r);
                level_t.push(j);
                continue;
            }
            let local_t = j - rest_joints.clone().select(1, index(&level.parents));
            let slots = index(&level.parent_slots);
            let parent_r = level_r[d - 1].clone().select(1, slots.clone());
            let parent_t = level_t[d - 1].clone().select(1, slots);
            let t = parent_r
                .clone()
                .matmul(local_t.unsqueeze_dim::<4>(3))
                .squeeze_dim::<3>(3)
                + parent_t;
            level_r.push(parent_r.matmul(r));
            level_t.push(t);
        }
        let order = index(&self.levels.order);
        let world_r = Tensor::cat(level_r, 1).select(1, order.clone()); // [B, 55, 3, 3]
        let joints = Tensor::cat(level_t, 1).select(1, order); // [B, 55, 3]

        // Skinning: A_j = [G_R | G_t - G_R J], blended per vertex by the weights.
        let a_t = joints.clone()
            - world_r
                .clone()
                .matmul(rest_joints.unsqueeze_dim::<4>(3))
                .squeeze_dim::<3>(3);
        let a = Tensor::cat(vec![world_r.reshape([b, NUM_JOINTS, 9]), a_t], 2); // [B, 55, 12]
        let blended = self.weights.clone().unsqueeze_dim::<3>(0).matmul(a); // [B, V, 12]
        let m = blended
            .clone()
            .slice([0..b, 0..v, 0..9])
            .reshape([b, v, 3, 3]);
        let t = blended.slice([0..b, 0..v, 9..12]);
        let vertices = (m * v_posed.unsqueeze_dim::<4>(2))
            .sum_dim(3)
            .squeeze_dim::<3>(3)
            + t;
        BodyOutput { vertices, joints }
    }
}

/// Batched Rodrigues: axis-angle `[N, 3]` to rotation matrices `[N, 3, 3]`,
/// `R = cos(theta) I + A [r]_x + B r r^T` (see `rotation.rs`), with Taylor coefficients near
/// zero so that values and gradients stay finite there.
pub fn rodrigues(r: Tensor<2>) -> Tensor<3> {
    let [n, _] = r.dims();
    let x = r.clone().slice([0..n, 0..1]);
    let y = r.clone().slice([0..n, 1..2]);
    let z = r.clone().slice([0..n, 2..3]);
    let t2 = (r.clone() * r).sum_dim(1); // [N, 1]
    let small = t2.clone().lower_elem(SMALL_ANGLE_SQ);
    // Large-angle branch on a safe theta^2 (1 where the Taylor branch is used).
    let t2_safe = t2.clone().mask_fill(small.clone(), 1.0);
    let theta = t2_safe.clone().sqrt();
    let half = (theta.clone() * 0.5).sin();
    let a_large = theta.clone().sin() / theta;
    let b_large = half.clone() * half * 2.0 / t2_safe;
    let t4 = t2.clone() * t2.clone();
    let a_small = -t2.clone() / 6.0 + t4.clone() / 120.0 + 1.0;
    let b_small = -t2.clone() / 24.0 + t4 / 720.0 + 0.5;
    let a = a_large.mask_where(small.clone(), a_small);
    let b = b_large.mask_where(small, b_small);
    let c = -(b.clone() * t2) + 1.0;
    let bx = b.clone() * x.clone();
    let by = b.clone() * y.clone();
    let bz = b * z.clone();
    let (ax, ay, az) = (a.clone() * x.clone(), a.clone() * y.clone(), a * z.clone());
    Tensor::cat(
        vec![
            c.clone() + bx.clone() * x.clone(),
            -az.clone() + bx.clone() * y.clone(),
            ay.clone() + bx.clone() * z.clone(),
            az + bx * y.clone(),
            c.clone() + by.clone() * y.clone(),
            -ax.clone() + by * z.clone(),
            -ay + bz.clone() * x,
            ax + bz.clone() * y,
            c + bz * z,
        ],
        1,
    )
    .reshape([n, 3, 3])
}
