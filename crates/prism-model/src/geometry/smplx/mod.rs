//! The SMPL-X branch (paper Sec. 3.2, Stage II, upper branch): from the source tokens of
//! `T_mid` to SMPL-X parameters, a posed body in the world, its position map in the target
//! view and the triplane features `F_smpl` of that map.
//!
//! 1. Adapter: per source token `a_i = GELU(W_a LN(x_i) + b_a)` (width `h`), pooled by one
//!    learned attention query `q`: `a = sum_i softmax_i(a_i . q / sqrt(h)) a_i`.
//! 2. Regressor: `r = W_2 GELU(W_1 a + b_1) + b_2` with 353 outputs: betas (10), 55 joint
//!    rotations as 6D vectors (330, see [`rotation`]), expression (10) and the
//!    weak-perspective camera `pi = (s, tx, ty)` (`s = softplus(.)`, see [`placement`]).
//!    `b_2` starts at the mean body: zero betas and expression, identity rotations, `s` of a body
//!    `body_height` tall at `depth_prior` metres, the anchor at the image centre.
//! 3. The Burn body model ([`BodyLayer`]) poses the mesh from the rotation matrices (no
//!    gradient), the placement of [`placement`] puts it in the world through the source
//!    camera (as tensor ops), and the mesh rasterizer finds the visible face and barycentrics at
//!    every target pixel ([`prism_render::mesh::rasterize_maps`]), all on the model's device.
//! 4. Position map: the canonical rest-pose positions `v_shaped = T + S [beta; psi]` (shape and
//!    expression blend shapes, no pose; differentiable in beta and psi), normalised to the cube
//!    `[-1, 1]^3` by the template's bounding box, interpolated with the barycentrics.
//! 5. `F_smpl = triplane(position map) * mask` ([`prism_render::triplane`], `C` channels), zero
//!    off the body.
//!
//! `L_smplx` compares the regressed parameters with a body fit ([`SmplxBranch::targets`]):
//! betas, expression and `pi` directly, the pose as rotation matrices (`body.json`'s axis-angle
//! through Rodrigues' formula): `|R - R*|_F^2` is smooth everywhere, unlike a difference of
//! axis-angle vectors (which jumps at angles of pi and is not unique).

pub(crate) mod body_model;
pub(crate) mod placement;
pub(crate) mod rotation;

use std::sync::Arc;

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::activation::{softmax, softplus};
use burn::tensor::{Device, Distribution, Tensor, TensorData};
use glam::{Mat3, Vec3};
use prism_body::joints::{NUM_BETAS, NUM_EXPRESSION, NUM_JOINTS};
use prism_body::rodrigues;
use prism_body::{BodyLayer, BodyModel};
use prism_core::Camera;
use prism_data::batch::BodyTensors;
use prism_kernels::{gelu, linear};
use prism_render::mesh::{FragmentMaps, rasterize_maps};
use prism_render::triplane::sample_triplane;

use crate::geometry::points::inverse_softplus;
use crate::views::Views;
#[cfg(test)]
use placement::scale_for_height;
use rotation::{IDENTITY_6D, rotation_6d_to_matrix};

/// Outputs of the regressor: betas, 6D rotations, expression, camera.
pub(crate) const SMPLX_OUTPUTS: usize = NUM_BETAS + 6 * NUM_JOINTS + NUM_EXPRESSION + 3;
/// Shape and expression coefficients of the rest shape.
const COEFFS: usize = NUM_BETAS + NUM_EXPRESSION;
/// The bounding box of the template is enlarged by this factor before it is mapped to the
/// triplane's cube, so that shapes a little larger than the template stay inside.
const BOX_MARGIN: f32 = 1.1;

/// Configuration of a [`SmplxBranch`].
#[derive(Config, Debug)]
pub(crate) struct SmplxBranchConfig {
    /// Token width `d`.
    pub width: usize,
    /// Width `h` of the adapter and the regressor.
    pub hidden: usize,
    /// Side `R` of each triplane plane.
    pub triplane_resolution: usize,
    /// Channels `C` of the triplane (and of `F_smpl`).
    pub triplane_channels: usize,
    /// World height (metres) the placement gives the posed body (see [`placement`]).
    pub body_height: f64,
    /// Distance (metres) of the subject from the source camera at initialisation.
    pub depth_prior: f64,
    /// Standard deviation of the normal initialisation of the linear layers.
    #[config(default = 0.02)]
    pub init_std: f64,
    /// Standard deviation of the triplane's normal initialisation.
    #[config(default = 0.1)]
    pub triplane_std: f64,
    /// `eps` of the adapter's LayerNorm.
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

impl SmplxBranchConfig {
    /// Builds the branch around `body` (its template fixes the triplane's bounding box and the
    /// initial camera scale).
    pub(crate) fn init(&self, body: &BodyModel, device: &Device) -> SmplxBranch {
        let normal = |std: f64| Initializer::Normal { mean: 0.0, std };
        let linear = |i: usize, o: usize, std: f64| {
            LinearConfig::new(i, o)
                .with_initializer(normal(std))
                .init(device)
        };
        // Template bounding box -> cube [-1, 1]^3.
        let template = body.v_template();
        let (lo, hi) = template.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), v| (lo.min(*v), hi.max(*v)),
        );
        let centre = 0.5 * (lo + hi);
        let half = (0.5 * (hi - lo) * BOX_MARGIN).max(Vec3::splat(1e-3));
        let template_height = (hi.y - lo.y).max(1e-3);
        // Initial s: a body of `body_height` at `depth_prior` (sigma / Z).
        let s0 = (self.body_height as f32 / template_height) / self.depth_prior as f32;
        let mut mean = vec![0.0f32; SMPLX_OUTPUTS];
        for j in 0..NUM_JOINTS {
            mean[NUM_BETAS + 6 * j..NUM_BETAS + 6 * (j + 1)].copy_from_slice(&IDENTITY_6D);
        }
        mean[SMPLX_OUTPUTS - 3] = inverse_softplus(s0);
        let mut regressor_out = linear(self.hidden, SMPLX_OUTPUTS, 0.1 * self.init_std);
        regressor_out.bias = Some(Param::from_tensor(Tensor::from_data(
            TensorData::new(mean, [SMPLX_OUTPUTS]),
            device,
        )));

        // Rest shape: template [1, V*3] and shape + expression directions [20, V*3].
        let v = body.num_vertices();
        let flat_template: Vec<f32> = template.iter().flat_map(|p| p.to_array()).collect();
        let shapedirs = body.shapedirs();
        let stride = shapedirs.len() / (v * 3);
        let mut dirs = vec![0.0f32; COEFFS * v * 3];
        for i in 0..v * 3 {
            for k in 0..COEFFS {
                dirs[k * v * 3 + i] = shapedirs[i * stride + k];
            }
        }
        let r = self.triplane_resolution;
        SmplxBranch {
            adapter_norm: LayerNormConfig::new(self.width)
                .with_epsilon(self.norm_eps)
                .init(device),
            adapter: linear(self.width, self.hidden, self.init_std),
            pool_query: Param::from_tensor(Tensor::random(
                [self.hidden, 1],
                Distribution::Normal(0.0, self.init_std),
                device,
            )),
            regressor_hidden: linear(self.hidden, self.hidden, self.init_std),
            regressor_out,
            triplane: Param::from_tensor(Tensor::random(
                [3, self.triplane_channels, r, r],
                Distribution::Normal(0.0, self.triplane_std),
                device,
            )),
            body: BodyLayer::new(body, device),
            rest_template: Tensor::from_data(TensorData::new(flat_template, [1, v * 3]), device),
            rest_dirs: Tensor::from_data(TensorData::new(dirs, [COEFFS, v * 3]), device),
            faces: Arc::from(body.faces()),
            box_centre: centre.to_array(),
            box_half: half.to_array(),
            body_height: self.body_height as f32,
        }
    }
}

/// The SMPL-X branch (see the module docs).
#[derive(Module, Debug)]
pub struct SmplxBranch {
    /// LayerNorm of the adapter.
    pub adapter_norm: LayerNorm,
    /// The adapter's projection `d -> h`.
    pub adapter: Linear,
    /// The pooling query `[h, 1]`.
    pub pool_query: Param<Tensor<2>>,
    /// The regressor's hidden layer `h -> h`.
    pub regressor_hidden: Linear,
    /// The regressor's output layer `h -> 353`, bias at the mean body.
    pub regressor_out: Linear,
    /// The triplane `[3, C, R, R]` (planes `xy`, `xz`, `yz`).
    pub triplane: Param<Tensor<4>>,
    /// The body model (constant tensors).
    pub body: BodyLayer,
    /// Rest template `[1, V*3]`.
    rest_template: Tensor<2>,
    /// Shape and expression directions `[20, V*3]`.
    rest_dirs: Tensor<2>,
    #[module(skip)]
    faces: Arc<[[u32; 3]]>,
    #[module(skip)]
    box_centre: [f32; 3],
    #[module(skip)]
    box_half: [f32; 3],
    #[module(skip)]
    body_height: f32,
}

/// What the SMPL-X branch predicts for a batch of `B` pairs.
#[derive(Clone, Debug)]
pub struct SmplxOutput {
    /// Shape `beta`, `[B, 10]`.
    pub betas: Tensor<2>,
    /// Joint rotations (relative to the parent, SMPL-X order) `[B, 55, 3, 3]`.
    pub rotations: Tensor<4>,
    /// Expression `psi`, `[B, 10]`.
    pub expression: Tensor<2>,
    /// Weak-perspective camera `pi = (s, tx, ty)` in the source view, `[B, 3]`.
    pub camera: Tensor<2>,
    /// The canonical rest-pose position (in the triplane's cube) seen at each target pixel,
    /// `[B, 3, H, W]`, zero off the body.
    pub position_map: Tensor<4>,
    /// Target pixels where the posed body is visible, `[B, 1, H, W]` (no gradient).
    pub mask: Tensor<4>,
    /// `F_smpl`, `[B, C, H, W]`: the triplane features of the position map, zero off the body.
    pub features: Tensor<4>,
    /// The posed body's vertices in the world, `[B, V, 3]` (no gradient).
    pub world_vertices: Tensor<3>,
}

impl SmplxOutput {
    /// The pose as flattened rotation matrices `[B, 495]` (what `L_smplx` compares).
    pub fn flat_rotations(&self) -> Tensor<2> {
        let [b, ..] = self.rotations.dims();
        self.rotations.clone().reshape([b, NUM_JOINTS * 9])
    }
}

/// The body fits of a batch in the form the SMPL-X branch predicts, for `L_smplx`.
#[derive(Clone, Debug)]
pub struct SmplxTargets {
    /// `[B, 10]`.
    pub betas: Tensor<2>,
    /// Rodrigues of `body.json`'s axis-angle pose, `[B, 55, 3, 3]`.
    pub rotations: Tensor<4>,
    /// `[B, 10]`.
    pub expression: Tensor<2>,
    /// The weak-perspective camera of the fit in the source view (`placement::weak_perspective`),
    /// `[B, 3]`.
    pub camera: Tensor<2>,
    /// `[B]`: 1 where the pair's subject has a fit, 0 where not (the other rows are zeros).
    pub present: Tensor<1>,
}

impl SmplxTargets {
    /// The pose as flattened rotation matrices `[B, 495]`.
    pub fn flat_rotations(&self) -> Tensor<2> {
        let [b, ..] = self.rotations.dims();
        self.rotations.clone().reshape([b, NUM_JOINTS * 9])
    }
}

/// The source cameras' camera-to-world rotations `[B, 3, 3]` (row-major) and centres
/// `[B, 1, 3]`, uploaded to `device`.
fn camera_frames(cameras: &[Camera], device: &Device) -> (Tensor<3>, Tensor<3>) {
    let b = cameras.len();
    let mut rotation = Vec::with_capacity(9 * b);
    let mut centre = Vec::with_capacity(3 * b);
    for camera in cameras {
        let r = Mat3::from_mat4(camera.c2w);
        for row in 0..3 {
            rotation.extend([r.x_axis[row], r.y_axis[row], r.z_axis[row]]);
        }
        centre.extend(camera.center().to_array());
    }
    (
        Tensor::from_data(TensorData::new(rotation, [b, 3, 3]), device),
        Tensor::from_data(TensorData::new(centre, [b, 1, 3]), device),
    )
}

impl SmplxBranch {
    /// The triangles of the body mesh.
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.faces
    }

    /// The regressed parameters from the source tokens of `T_mid` `[B, T_s, d]`:
    /// `(betas, rotations, expression, camera)`.
    pub fn regress(
        &self,
        source_tokens: Tensor<3>,
    ) -> (Tensor<2>, Tensor<4>, Tensor<2>, Tensor<2>) {
        let [b, _, _] = source_tokens.dims();
        let a = gelu(linear(
            &self.adapter,
            self.adapter_norm.forward(source_tokens),
        ));
        let [_, _, h] = a.dims();
        let logits = a
            .clone()
            .matmul(self.pool_query.val().unsqueeze_dim::<3>(0))
            .div_scalar((h as f64).sqrt());
        let weights = softmax(logits, 1);
        let pooled = (a * weights).sum_dim(1).reshape([b, h]);
        let r = self
            .regressor_out
            .forward(gelu(self.regressor_hidden.forward(pooled)));
        let mut at = 0;
        let mut take = |n: usize| {
            let part = r.clone().narrow(1, at, n);
            at += n;
            part
        };
        let betas = take(NUM_BETAS);
        let rotations = rotation_6d_to_matrix(take(6 * NUM_JOINTS).reshape([b, NUM_JOINTS, 6]));
        let expression = take(NUM_EXPRESSION);
        let raw = take(3);
        let s = softplus(raw.clone().narrow(1, 0, 1), 1.0).add_scalar(1e-4);
        let camera = Tensor::cat(vec![s, raw.narrow(1, 1, 2)], 1);
        (betas, rotations, expression, camera)
    }

    /// The shaped rest-pose vertices `T + S [beta; psi]`, `[B, V, 3]` (differentiable).
    pub fn rest_vertices(&self, betas: Tensor<2>, expression: Tensor<2>) -> Tensor<3> {
        let [b, _] = betas.dims();
        let coeffs = Tensor::cat(vec![betas, expression], 1);
        let flat = coeffs.matmul(self.rest_dirs.clone()) + self.rest_template.clone();
        flat.reshape([b, self.body.num_vertices(), 3])
    }

    /// Poses the body (no gradient) and places it in the world through the source cameras
    /// (the `placement` module's formulas, as tensor ops on the model's device): `[B, V, 3]`.
    pub fn world_vertices(
        &self,
        betas: &Tensor<2>,
        rotations: &Tensor<4>,
        expression: &Tensor<2>,
        camera: &Tensor<2>,
        source_cameras: &[Camera],
    ) -> Tensor<3> {
        let [b, ..] = rotations.dims();
        let posed = self.body.forward_rotations(
            betas.clone().detach(),
            rotations.clone().detach(),
            expression.clone().detach(),
        );
        let vertices = posed.vertices.detach();
        let root = posed.joints.detach().narrow(1, 0, 1); // [B, 1, 3]
        // scale_for_height: the scale that makes the posed body `body_height` tall (1 where the
        // extent is not a positive number).
        let heights = vertices.clone().narrow(2, 1, 1);
        let extent = heights.clone().max_dim(1) - heights.min_dim(1); // [B, 1, 1]
        let usable = extent
            .clone()
            .greater_elem(0.0)
            .bool_and(extent.clone().is_finite());
        let scale = extent.recip().mul_scalar(self.body_height).mask_where(
            usable.bool_not(),
            Tensor::ones([b, 1, 1], &vertices.device()),
        );
        // place: Z = scale / s, anchor = C + R (Z tx, Z ty, Z).
        let pi = camera.clone().detach().reshape([b, 1, 3]);
        let z = scale.clone() / pi.clone().narrow(2, 0, 1);
        let local = Tensor::cat(
            vec![
                z.clone() * pi.clone().narrow(2, 1, 1),
                z.clone() * pi.narrow(2, 2, 1),
                z,
            ],
            2,
        );
        let (rotation, centre) = camera_frames(source_cameras, &vertices.device());
        let anchor = local.matmul(rotation.swap_dims(1, 2)) + centre;
        (vertices - root) * scale + anchor
    }

    /// The position map of world-placed bodies `[B, V, 3]` in the target cameras:
    /// `(fragments, canonical positions [B, 3, H, W] in the triplane's cube)`; differentiable in
    /// `betas` and `expression`.
    pub fn position_map(
        &self,
        world: Tensor<3>,
        betas: Tensor<2>,
        expression: Tensor<2>,
        target_cameras: &[Camera],
    ) -> (FragmentMaps, Tensor<4>) {
        let fragments = rasterize_maps(world, &self.faces, target_cameras)
            .expect("the body and the target cameras fit together");
        let device = betas.device();
        let constant =
            |v: [f32; 3]| Tensor::<3>::from_data(TensorData::new(v.to_vec(), [1, 1, 3]), &device);
        let inv_half = self.box_half.map(|h| 1.0 / h);
        let rest = (self.rest_vertices(betas, expression) - constant(self.box_centre))
            * constant(inv_half);
        let map = fragments.interpolate(rest, &self.faces);
        (fragments, map)
    }

    /// The whole branch (see the module docs) on the source tokens of `T_mid` `[B, T_s, d]`
    /// of source images of `source_size = (height, width)`, for target images of
    /// `height x width`.
    pub fn forward(
        &self,
        source_tokens: Tensor<3>,
        views: &Views,
        height: usize,
        width: usize,
        source_size: (usize, usize),
    ) -> SmplxOutput {
        let (betas, rotations, expression, camera) = self.regress(source_tokens);
        let sources = views.source_at(source_size.1, source_size.0);
        let world = self.world_vertices(&betas, &rotations, &expression, &camera, &sources);
        let targets = views.target_at(width, height);
        let (fragments, position_map) =
            self.position_map(world.clone(), betas.clone(), expression.clone(), &targets);
        let mask = fragments.mask();
        let features = sample_triplane(self.triplane.val(), position_map.clone())
            .expect("the triplane and the position map fit together")
            * mask.clone();
        SmplxOutput {
            betas,
            rotations,
            expression,
            camera,
            position_map,
            mask,
            features,
            world_vertices: world,
        }
    }

    /// The body fits of a batch (`PrismBatch::body_tensors`) as targets of the regressor, the
    /// camera through the source cameras (`placement::weak_perspective`, anchored at the fit's root
    /// joint). Rows without a fit are zeros with `present` 0.
    ///
    /// # Panics
    /// If the number of cameras is not the batch size.
    pub fn targets(&self, body: &BodyTensors, source_cameras: &[Camera]) -> SmplxTargets {
        let [b, _] = body.betas.dims();
        assert_eq!(source_cameras.len(), b, "one source camera per pair");
        let device = body.betas.device();
        let rotations = rodrigues(body.pose.clone().reshape([b * NUM_JOINTS, 3]))
            .reshape([b, NUM_JOINTS, 3, 3]);
        // weak_perspective as tensor ops: the anchor sigma J_0 + transl in the source camera.
        // The root joint does not move with the pose, so the body is not posed for it.
        let root = self
            .body
            .rest_joints(body.betas.clone(), body.expression.clone())
            .detach()
            .narrow(1, 0, 1); // [B, 1, 3]
        let scale = body.scale.clone().reshape([b, 1, 1]);
        let anchor = root * scale.clone() + body.transl.clone().reshape([b, 1, 3]);
        let (rotation, centre) = camera_frames(source_cameras, &device);
        // World to camera: R^T (p - C).
        let p = (anchor - centre).matmul(rotation);
        let depth = p.clone().narrow(2, 2, 1);
        let camera = Tensor::cat(
            vec![
                scale / depth.clone(),
                p.clone().narrow(2, 0, 1) / depth.clone(),
                p.narrow(2, 1, 1) / depth,
            ],
            2,
        )
        .reshape([b, 3]);
        // Rows without a fit are zeros (and their division by a zero depth must not leak).
        let present = body.present.clone().reshape([b, 1]);
        let camera = camera.mask_where(
            present.clone().equal_elem(0.0).expand([b, 3]),
            Tensor::zeros([b, 3], &device),
        );
        // Rows without a fit: zero rotations too (not Rodrigues' identity), so that every
        // field of a missing row is zero.
        let rows = body.present.clone().reshape([b, 1, 1, 1]);
        SmplxTargets {
            betas: body.betas.clone(),
            rotations: rotations * rows,
            expression: body.expression.clone(),
            camera,
            present: body.present.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::test_util::{ndarray, values};
    use prism_body::BodyParams;
    use prism_core::Intrinsics;

    /// A posed, placed body fit as `body.json` would hold it.
    fn fit() -> BodyParams {
        let mut p = BodyParams::rest("procedural:0");
        p.betas[0] = 0.7;
        p.betas[3] = -0.4;
        p.expression[1] = 0.5;
        p.pose[0] = [0.05, 0.2, -0.03];
        p.pose[16] = [0.0, 0.0, -1.2];
        p.pose[17] = [0.1, 0.0, 1.1];
        p.pose[4] = [0.5, 0.0, 0.0];
        p.scale = 0.97;
        p.transl = [0.06, 0.0, -0.04];
        p
    }

    fn tensors(p: &BodyParams, device: &Device) -> BodyTensors {
        let t2 = |v: Vec<f32>, n: usize| Tensor::<2>::from_data(TensorData::new(v, [1, n]), device);
        BodyTensors {
            betas: t2(p.betas.to_vec(), NUM_BETAS),
            pose: Tensor::from_data(
                TensorData::new(
                    p.pose.iter().flatten().copied().collect::<Vec<_>>(),
                    [1, NUM_JOINTS, 3],
                ),
                device,
            ),
            expression: t2(p.expression.to_vec(), NUM_EXPRESSION),
            scale: Tensor::from_data(TensorData::new(vec![p.scale], [1]), device),
            transl: t2(p.transl.to_vec(), 3),
            present: Tensor::from_data(TensorData::new(vec![1.0f32], [1]), device),
        }
    }

    #[test]
    fn the_fit_s_parameters_place_the_body_where_the_dataset_has_it() {
        let device = ndarray();
        let model = body_model::load_body_model("procedural:0").unwrap();
        let p = fit();
        let posed_world = model.pose(&p);
        // The placement's height rule with the height this fit has: the scale comes out exact.
        let posed_model = model.lbs(&p.betas, &p.pose, &p.expression);
        let height = scale_for_height(&posed_model.vertices, 1.0).recip() * p.scale;
        let branch = SmplxBranchConfig::new(64, 32, 8, 4, height as f64, 2.0).init(&model, &device);
        let camera = Camera::orbit(
            0.0,
            0.0,
            2.0,
            Vec3::new(0.0, 0.9, 0.0),
            Intrinsics::protocol_default(32, 32),
        );
        let targets = branch.targets(&tensors(&p, &device), &[camera]);
        let pi = values(&targets.camera);
        assert!((pi[0] - p.scale / 2.0).abs() < 0.1, "s = {}", pi[0]);
        let world = branch.world_vertices(
            &targets.betas,
            &targets.rotations,
            &targets.expression,
            &targets.camera,
            &[camera],
        );
        let world = values(&world);
        let err = world
            .chunks_exact(3)
            .zip(&posed_world.vertices)
            .map(|(a, b)| (Vec3::from_slice(a) - *b).length())
            .fold(0.0f32, f32::max);
        assert!(err < 1e-3, "placed body differs from the fit by {err} m");

        // The rest shape of the branch is the body model's shaped rest pose.
        let rest = values(&branch.rest_vertices(targets.betas.clone(), targets.expression.clone()));
        for (i, v) in posed_model.shaped.iter().enumerate() {
            let got = Vec3::from_slice(&rest[3 * i..3 * i + 3]);
            assert!((got - *v).length() < 1e-4, "vertex {i}: {got} vs {v}");
        }
    }

    #[test]
    fn the_regressor_starts_at_the_mean_body() {
        let device = ndarray();
        let model = body_model::load_body_model("procedural:0").unwrap();
        let branch = SmplxBranchConfig::new(16, 16, 8, 4, 1.77, 2.0).init(&model, &device);
        device.seed(2);
        let tokens = Tensor::<3>::random([2, 4, 16], Distribution::Normal(0.0, 1.0), &device);
        let (betas, rotations, expression, camera) = branch.regress(tokens);
        assert!(values(&betas).iter().all(|v| v.abs() < 0.05));
        assert!(values(&expression).iter().all(|v| v.abs() < 0.05));
        let r = values(&rotations);
        for m in r.chunks_exact(9) {
            for (k, v) in m.iter().enumerate() {
                let identity = if k % 4 == 0 { 1.0 } else { 0.0 };
                assert!((v - identity).abs() < 0.05, "{m:?}");
            }
        }
        // s of a body 1.77 m tall at 2 m: 1.77 / template height / 2.
        let height = {
            let (lo, hi) = model
                .v_template()
                .iter()
                .fold((f32::MAX, f32::MIN), |(l, h), v| (l.min(v.y), h.max(v.y)));
            hi - lo
        };
        let c = values(&camera);
        assert!((c[0] - 1.77 / height / 2.0).abs() < 0.02, "{c:?}");
        assert!(c[1].abs() < 0.05 && c[2].abs() < 0.05);
    }
}
