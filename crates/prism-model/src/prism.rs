//! The cascade (paper Sec. 3.2): tokenizer -> stage I -> geometry branches and injection ->
//! stage III -> NVS decoder and 3DGS head.

use burn::module::Module;
use burn::tensor::{Device, Tensor};
use prism_data::PrismBatch;

use crate::config::PrismConfig;
use crate::error::ModelError;
use crate::geometry::injection::{Injection, InjectionConfig};
use crate::geometry::points::dpt::dpt_taps;
use crate::geometry::points::{PointBranch, PointBranchConfig, PointOutput};
use crate::geometry::smplx::body_model::load_body_model;
use crate::geometry::smplx::{SmplxBranch, SmplxBranchConfig, SmplxOutput};
use crate::heads::gaussian::{GaussianHead, GaussianHeadConfig, GaussianOutput, SourcePixels};
use crate::heads::nvs::{NvsHead, NvsHeadConfig};
use crate::stages::attention::AttentionKind;
use crate::stages::block::{PrismBlock, PrismBlockConfig};
use crate::stages::{HiddenStates, StageOne, StageThree};
use crate::tokenizer::{Tokenizer, TokenizerConfig};
use crate::views::Views;

impl PrismConfig {
    /// Builds the model with fresh weights: every projection `N(0, init_std)`, the blocks'
    /// output projections `N(0, init_std / sqrt(2 (M + N)))`, norms' gains 1; the geometry
    /// parts the config enables, with the injection's zero convolutions at zero.
    ///
    /// # Panics
    /// If the config is invalid or its body model cannot be loaded; [`PrismConfig::try_init`]
    /// returns these as errors.
    pub fn init(&self, device: &Device) -> Prism {
        self.try_init(device)
            .unwrap_or_else(|err| panic!("cannot build the model: {err}"))
    }

    /// [`PrismConfig::init`], with an invalid config or an unreadable body model as an error.
    ///
    /// # Errors
    /// [`ModelError::Invalid`] (see [`PrismConfig::validate`]) or [`ModelError::Body`].
    pub fn try_init(&self, device: &Device) -> Result<Prism, ModelError> {
        self.validate()?;
        let kinds = self.attention_kinds()?;
        let block = |kind: AttentionKind| {
            PrismBlockConfig::new(self.width, self.heads)
                .with_mlp_ratio(self.mlp_ratio)
                .with_init_std(self.init_std)
                .with_num_blocks(self.num_blocks())
                .with_attention(kind)
                .with_feature_map(self.linear_feature_map)
                .with_linear_eps(self.linear_eps)
                .with_norm_eps(self.norm_eps)
                .init(device)
        };
        let (one, three) = kinds.split_at(self.stage_one_blocks);
        let smplx_branch = if self.smplx_branch {
            let body = load_body_model(&self.body_model)?;
            Some(
                SmplxBranchConfig::new(
                    self.width,
                    self.smplx_width,
                    self.triplane_resolution,
                    self.triplane_channels,
                    self.body_height,
                    self.depth_prior,
                )
                .with_init_std(self.init_std)
                .with_norm_eps(self.norm_eps)
                .init(&body, device),
            )
        } else {
            None
        };
        let point_branch = self.point_branch.then(|| {
            PointBranchConfig::new(
                self.width,
                dpt_taps(self.stage_one_blocks),
                self.patch_size,
                self.point_width,
                self.point_features,
                self.depth_prior,
            )
            .with_anchor_height(self.anchor_height)
            .with_init_std(self.init_std)
            .with_colours(self.point_colours)
            .init(device)
        });
        Ok(Prism {
            tokenizer: TokenizerConfig::new(self.width, self.patch_size)
                .with_init_std(self.init_std)
                .with_norm_eps(self.norm_eps)
                .init(device),
            stage_one: StageOne {
                blocks: one.iter().map(|&k| block(k)).collect(),
            },
            injection: InjectionConfig::new(self.width, self.patch_size)
                .with_smpl_channels(self.smplx_branch.then_some(self.triplane_channels))
                .with_pts_channels(point_branch.as_ref().map(PointBranch::feature_channels))
                .with_gate_init(self.gate_init)
                .init(device),
            smplx_branch,
            point_branch,
            stage_three: StageThree {
                blocks: three.iter().map(|&k| block(k)).collect(),
            },
            nvs_head: NvsHeadConfig::new(self.width, self.patch_size)
                .with_init_std(self.init_std)
                .with_norm_eps(self.norm_eps)
                .with_output(self.nvs_output)
                .with_sees_render(self.nvs_sees_render)
                .with_upsample(self.head_upsample)
                .init(device),
            gs_head: self.gs_head.then(|| {
                GaussianHeadConfig::new(self.width, self.patch_size, self.depth_prior)
                    .with_init_std(self.init_std)
                    .with_norm_eps(self.norm_eps)
                    .with_colour(self.gs_colour)
                    .with_depth(self.gs_depth)
                    .with_scale(self.gs_scale)
                    .with_keying(self.gs_keying)
                    .with_rim_depth(self.gs_rim_depth)
                    .with_upsample(self.head_upsample)
                    .init(device)
            }),
        })
    }
}

/// What one forward pass of [`Prism`] returns.
#[derive(Debug, Clone)]
pub struct PrismOutput {
    /// The synthesised target view `I_t`, `[B, 3, H, W]` in (0, 1).
    pub image: Tensor<4>,
    /// The hidden states (block outputs, `[B, T, d]`) of the blocks asked for, in the order
    /// asked for; empty when none was asked for.
    pub hidden: Vec<Tensor<3>>,
    /// `T_out`, the output tokens of stage III, `[B, T_s + T_t, d]`, source tokens first.
    pub t_out: Tensor<3>,
    /// `T_s`, the number of source tokens at the front of the sequence.
    pub source_tokens: usize,
    /// The SMPL-X branch's prediction (parameters, position map, `F_smpl`), when enabled.
    pub smplx: Option<SmplxOutput>,
    /// The point branch's prediction (points, confidence, `F_pts`), when enabled.
    pub points: Option<PointOutput>,
    /// The 3DGS head's Gaussians and `I_gs`, when enabled.
    pub gaussians: Option<GaussianOutput>,
}

impl PrismOutput {
    /// The source tokens of `T_out`, `[B, T_s, d]` (what the 3DGS head reads).
    pub fn source_t_out(&self) -> Tensor<3> {
        self.t_out.clone().narrow(1, 0, self.source_tokens)
    }

    /// The target tokens of `T_out`, `[B, T_t, d]` (what the NVS head reads).
    pub fn target_t_out(&self) -> Tensor<3> {
        let total = self.t_out.dims()[1];
        self.t_out
            .clone()
            .narrow(1, self.source_tokens, total - self.source_tokens)
    }
}

/// The PrismMirror network: `T_in = Tokenizer(I_s, P_s, P_t)`, `T_mid = StageOne(T_in)`,
/// the geometry branches on `T_mid` (and stage-I taps), `T'_mid = Injection(T_mid, T_in,
/// F_smpl, F_pts)`, `T_out = StageThree(T'_mid)`, `I_t = NvsHead(target tokens of T_out)` and
/// `I_gs = GaussianHead(source tokens of T_out)`.
#[derive(Module, Debug)]
pub struct Prism {
    /// Patches and rays to `T_in`.
    pub tokenizer: Tokenizer,
    /// The `M` encoder blocks.
    pub stage_one: StageOne,
    /// Zero convolutions and gates between the stages.
    pub injection: Injection,
    /// The SMPL-X branch, when enabled.
    pub smplx_branch: Option<SmplxBranch>,
    /// The point branch, when enabled.
    pub point_branch: Option<PointBranch>,
    /// The `N` decoder blocks.
    pub stage_three: StageThree,
    /// The NVS decoder.
    pub nvs_head: NvsHead,
    /// The 3DGS head, when enabled. `I_gs` is a training signal (and a PLY export): for
    /// timing or serving the NVS output alone, set this to `None` and the forward pass skips it.
    pub gs_head: Option<GaussianHead>,
}

impl Prism {
    /// `M + N`.
    pub fn num_blocks(&self) -> usize {
        self.stage_one.blocks.len() + self.stage_three.blocks.len()
    }

    /// All blocks in global order (stage I then stage III).
    pub fn blocks(&self) -> impl Iterator<Item = &PrismBlock> {
        self.stage_one
            .blocks
            .iter()
            .chain(self.stage_three.blocks.iter())
    }

    pub(crate) fn blocks_mut(&mut self) -> impl Iterator<Item = &mut PrismBlock> {
        self.stage_one
            .blocks
            .iter_mut()
            .chain(self.stage_three.blocks.iter_mut())
    }

    /// The attention kind of every block, in global order.
    pub fn attention_kinds(&self) -> Vec<AttentionKind> {
        self.blocks().map(PrismBlock::attention_kind).collect()
    }

    /// Sets the attention kind of every block in place (weights untouched), e.g. from
    /// [`crate::progressive_schedule`].
    ///
    /// # Panics
    /// If `kinds` does not have one entry per block.
    pub fn set_attention_kinds(&mut self, kinds: &[AttentionKind]) {
        assert_eq!(
            kinds.len(),
            self.num_blocks(),
            "set_attention_kinds: {} kinds for {} blocks",
            kinds.len(),
            self.num_blocks()
        );
        for (block, &kind) in self.blocks_mut().zip(kinds) {
            block.set_attention(kind);
        }
    }

    /// The model for inference: without the 3DGS head, a training signal that the forward
    /// pass then skips, unless the NVS decoder corrects its render (`nvs_output =
    /// "residual"`), in which case it is part of the prediction and stays.
    pub fn without_training_heads(mut self) -> Self {
        if self.nvs_head.output() != crate::heads::nvs::NvsOutput::Residual {
            self.gs_head = None;
        }
        self
    }

    /// Whether a geometry part (SMPL-X branch, point branch or 3DGS head) is built: then the
    /// forward pass needs the cameras ([`Prism::forward_views`]).
    pub fn has_geometry(&self) -> bool {
        self.smplx_branch.is_some() || self.point_branch.is_some() || self.gs_head.is_some()
    }

    /// The injection point between stage I and stage III (paper Stage II, Eq. 4):
    /// `T'_mid = T_mid + g_smpl F_smpl + g_pts F_pts + g_res T_in` (see [`Injection`]).
    pub fn inject(
        &self,
        t_mid: Tensor<3>,
        t_in: &Tensor<3>,
        f_smpl: Option<Tensor<4>>,
        f_pts: Option<Tensor<4>>,
    ) -> Tensor<3> {
        self.injection.forward(t_mid, t_in, f_smpl, f_pts)
    }

    /// The forward pass of a model without geometry parts (the backbone and the NVS decoder):
    /// see [`Prism::forward_views`], which this calls without views.
    ///
    /// # Panics
    /// If the model has a geometry part (they need the cameras: call
    /// [`Prism::forward_views`]), on mismatched shapes or a hidden layer index `>= M + N`.
    pub fn forward(
        &self,
        source_image: Tensor<4>,
        source_rays: Tensor<4>,
        target_rays: Tensor<4>,
        hidden_layers: &[usize],
    ) -> PrismOutput {
        prism_kernels::warm(&source_image.device(), || {
            self.forward_impl(source_image, source_rays, target_rays, None, hidden_layers)
        })
    }

    /// The forward pass on a batch of (source, target) pairs.
    ///
    /// - `source_image`: `[B, 3, H, W]` in [0, 1];
    /// - `source_rays`, `target_rays`: Plücker rays `[B, 6, H, W]`;
    /// - `views`: the cameras of the pairs and the background (what the geometry parts need);
    /// - `hidden_layers`: global block indices (`0..M+N`) whose outputs to return in
    ///   [`PrismOutput::hidden`] (empty for none).
    ///
    /// `H` and `W` must be multiples of the patch size; any such size works (there is no
    /// positional embedding).
    ///
    /// # Panics
    /// On mismatched shapes, views for another batch size, or a hidden layer index
    /// `>= M + N`.
    pub fn forward_views(
        &self,
        source_image: Tensor<4>,
        source_rays: Tensor<4>,
        target_rays: Tensor<4>,
        views: &Views,
        hidden_layers: &[usize],
    ) -> PrismOutput {
        prism_kernels::warm(&source_image.device(), || {
            self.forward_impl(
                source_image,
                source_rays,
                target_rays,
                Some(views),
                hidden_layers,
            )
        })
    }

    /// [`Prism::forward_views`] on a dataset batch: its source images and rays, target rays and
    /// cameras, with the dataset's `background`.
    pub fn forward_batch(
        &self,
        batch: &PrismBatch,
        background: [f32; 3],
        hidden_layers: &[usize],
    ) -> PrismOutput {
        self.forward_views(
            batch.source_image.clone(),
            batch.source_rays.clone(),
            batch.target_rays.clone(),
            &Views::of_batch(batch, background),
            hidden_layers,
        )
    }

    /// The hidden states (block outputs, `[B, T, d]`) of `hidden_layers`, as
    /// [`Prism::forward_views`] returns them for the same inputs, without the heads: stage III's
    /// blocks after the last layer asked for, the 3DGS head and its render, and the NVS decoder
    /// are not run (stage I and the geometry branches always are). What a frozen distillation
    /// teacher gives its student.
    ///
    /// # Panics
    /// As [`Prism::forward_views`].
    pub fn hidden_states(
        &self,
        source_image: Tensor<4>,
        source_rays: Tensor<4>,
        target_rays: Tensor<4>,
        views: &Views,
        hidden_layers: &[usize],
    ) -> Vec<Tensor<3>> {
        let device = source_image.device();
        let inputs = TrunkInputs {
            source_image,
            source_rays,
            target_rays,
            views: Some(views),
        };
        let blocks = hidden_layers.iter().max().map_or(0, |&l| l + 1);
        prism_kernels::warm(&device, || {
            self.trunk(&inputs, hidden_layers, blocks).hidden
        })
    }

    fn forward_impl(
        &self,
        source_image: Tensor<4>,
        source_rays: Tensor<4>,
        target_rays: Tensor<4>,
        views: Option<&Views>,
        hidden_layers: &[usize],
    ) -> PrismOutput {
        let inputs = TrunkInputs {
            source_image,
            source_rays,
            target_rays,
            views,
        };
        let Trunk {
            t_out,
            hidden,
            source_tokens,
            smplx,
            points,
        } = self.trunk(&inputs, hidden_layers, self.num_blocks());
        let [_, _, height, width] = inputs.target_rays.dims();
        let total = t_out.dims()[1];
        let target = t_out
            .clone()
            .narrow(1, source_tokens, total - source_tokens);
        let gaussians = self.gs_head.as_ref().map(|head| {
            let source = SourcePixels {
                image: &inputs.source_image,
                rays: &inputs.source_rays,
                distance: points.as_ref().map(|p| p.distance.clone()),
            };
            head.forward(
                t_out.clone().narrow(1, 0, source_tokens),
                source,
                inputs.views.expect("checked by the trunk"),
                height,
                width,
            )
        });
        let image = self.nvs_head.forward(
            target,
            height,
            width,
            gaussians.as_ref().map(|g| g.image.clone()),
        );
        PrismOutput {
            image,
            hidden,
            t_out,
            source_tokens,
            smplx,
            points,
            gaussians,
        }
    }

    /// The tokens through stage I, the geometry branches and the injection, and the first
    /// `blocks - M` blocks of stage III (`blocks` counts from the first block of stage I), with
    /// the hidden states of `hidden_layers` (all below `blocks`).
    fn trunk(&self, inputs: &TrunkInputs<'_>, hidden_layers: &[usize], blocks: usize) -> Trunk {
        let num_blocks = self.num_blocks();
        if let Some(bad) = hidden_layers.iter().find(|&&i| i >= num_blocks) {
            panic!("hidden layer {bad} requested from a model of {num_blocks} blocks");
        }
        let TrunkInputs {
            source_image,
            source_rays,
            target_rays,
            views,
        } = inputs;
        let views = match views {
            Some(views) => {
                views.check(source_image.dims()[0]);
                Some(*views)
            }
            None if self.has_geometry() => panic!(
                "this model has geometry parts (SMPL-X branch, point branch or 3DGS head) that \
                 need the cameras: call Prism::forward_views"
            ),
            None => None,
        };
        let [_, _, height, width] = target_rays.dims();
        let p = self.tokenizer.patch_size();
        let [_, _, source_height, source_width] = source_image.dims();
        let grid = (source_height / p, source_width / p);
        let source_tokens = grid.0 * grid.1;

        // Stage I, with the point branch's taps.
        let taps = self
            .point_branch
            .as_ref()
            .map(|branch| branch.taps().to_vec())
            .unwrap_or_default();
        let wanted: Vec<usize> = hidden_layers.iter().chain(&taps).copied().collect();
        let mut hidden = HiddenStates::new(&wanted);
        let t_in = self.tokenizer.forward(
            source_image.clone(),
            source_rays.clone(),
            target_rays.clone(),
        );
        let t_mid = self.stage_one.forward(t_in.clone(), &mut hidden);
        let tapped: Vec<Tensor<3>> = taps
            .iter()
            .map(|&i| hidden.state(i).expect("stage-I taps are recorded"))
            .collect();

        // Stage II: the geometry branches and the injection.
        let source_of = |t: &Tensor<3>| t.clone().narrow(1, 0, source_tokens);
        let smplx = self.smplx_branch.as_ref().map(|branch| {
            branch.forward(
                source_of(&t_mid),
                views.expect("checked"),
                height,
                width,
                (source_height, source_width),
            )
        });
        let points = self.point_branch.as_ref().map(|branch| {
            let taps: Vec<Tensor<3>> = tapped.iter().map(source_of).collect();
            branch.forward(
                &taps,
                source_image,
                source_rays,
                views.expect("checked"),
                grid,
                height,
                width,
            )
        });
        let t_mid = self.inject(
            t_mid,
            &t_in,
            smplx.as_ref().map(|s| s.features.clone()),
            points.as_ref().map(|p| p.features.clone()),
        );

        // Stage III, as far as asked.
        let first = self.stage_one.blocks.len();
        let t_out =
            self.stage_three
                .forward(t_mid, first, blocks.saturating_sub(first), &mut hidden);
        let mut hidden = hidden.into_vec();
        hidden.truncate(hidden_layers.len());
        Trunk {
            t_out,
            hidden,
            source_tokens,
            smplx,
            points,
        }
    }
}

/// What [`Prism::trunk`] reads.
struct TrunkInputs<'a> {
    source_image: Tensor<4>,
    source_rays: Tensor<4>,
    target_rays: Tensor<4>,
    views: Option<&'a Views>,
}

/// What [`Prism::trunk`] gives the heads.
struct Trunk {
    /// The output of the last block run.
    t_out: Tensor<3>,
    hidden: Vec<Tensor<3>>,
    source_tokens: usize,
    smplx: Option<SmplxOutput>,
    points: Option<PointOutput>,
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::load_config;
    use crate::test_util::{inputs, max_abs_diff, ndarray, parameters, tiny_with, values};
    use crate::tools::info::ParameterCounts;
    use burn::module::{ModuleVisitor, Param};
    use burn::tensor::Distribution;
    use burn::tensor::Gradients;
    use std::path::Path;

    /// A shipped config's model with the paper's output parameterisation (what these tests
    /// check); the shipped geometric outputs have their own test.
    fn config(name: &str) -> PrismConfig {
        shipped(name).paper_outputs()
    }

    fn shipped(name: &str) -> PrismConfig {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../configs/{name}.toml"));
        load_config(path).unwrap().model
    }

    #[test]
    fn the_shipped_geometric_output_starts_as_the_source_moved_by_the_point_depths() {
        let device = ndarray().autodiff();
        device.seed(9);
        let geometric = shipped("tiny");
        assert_eq!(geometric.nvs_output, crate::heads::nvs::NvsOutput::Residual);
        let model = geometric.init(&device);
        let x = inputs(2, 64, 64, &device);
        let out = forward(&model, &x, &[]);
        let gaussians = out
            .gaussians
            .clone()
            .expect("the 3DGS head is part of the output");
        // I_t = clamp(I_gs + 0) = I_gs at initialisation.
        assert_eq!(values(&out.image), values(&gaussians.image));
        // The Gaussians sit at the point branch's depths and carry the source's colours.
        let points = out.points.clone().unwrap();
        let rows = |t: Tensor<4>| values(&t.reshape([2, 3, 64 * 64]).swap_dims(1, 2));
        let means = values(&gaussians.gaussians.means);
        assert!(max_abs_diff(&means, &rows(points.points.clone())) < 1e-4);
        let colours = values(&gaussians.gaussians.features);
        assert!(max_abs_diff(&colours, &rows(x.0[0].clone())) < 1e-6);
        // Serving keeps the 3DGS head: the NVS output needs it.
        assert!(model.clone().without_training_heads().gs_head.is_some());
        assert!(
            config("tiny")
                .init(&device)
                .without_training_heads()
                .gs_head
                .is_none()
        );
        // The image loss reaches the backbone, the point branch and both heads.
        let grads = out.image.sub_scalar(0.5).powi_scalar(2).mean().backward();
        let nonzero = |t: Tensor<2>| values(&t.grad(&grads).unwrap()).iter().any(|&g| g != 0.0);
        assert!(nonzero(model.nvs_head.linear.weight.val()));
        assert!(nonzero(model.gs_head.as_ref().unwrap().linear.weight.val()));
        assert!(nonzero(
            model
                .point_branch
                .as_ref()
                .unwrap()
                .dpt
                .head_out
                .weight
                .val()
        ));
    }

    fn forward(model: &Prism, x: &([Tensor<4>; 3], Views), hidden: &[usize]) -> PrismOutput {
        let ([image, source, target], views) = x;
        model.forward_views(image.clone(), source.clone(), target.clone(), views, hidden)
    }

    #[test]
    fn output_shapes_and_hidden_states_only_when_asked() {
        let device = ndarray();
        let config = config("tiny");
        device.seed(1);
        let model = config.init(&device);
        // Not square and not the config's resolution: there is no positional embedding.
        let x = inputs(2, 32, 48, &device);
        let out = forward(&model, &x, &[]);
        assert_eq!(out.image.dims(), [2, 3, 32, 48]);
        assert_eq!(out.t_out.dims(), [2, 2 * 4 * 6, 64]);
        assert_eq!(out.source_tokens, 24);
        assert_eq!(out.source_t_out().dims(), [2, 24, 64]);
        assert_eq!(out.target_t_out().dims(), [2, 24, 64]);
        assert!(out.hidden.is_empty());
        let image = values(&out.image);
        assert!(image.iter().all(|&v| v > 0.0 && v < 1.0), "sigmoid output");

        // The geometry parts' outputs.
        let smplx = out.smplx.as_ref().expect("SMPL-X branch");
        assert_eq!(smplx.betas.dims(), [2, 10]);
        assert_eq!(smplx.rotations.dims(), [2, 55, 3, 3]);
        assert_eq!(smplx.expression.dims(), [2, 10]);
        assert_eq!(smplx.camera.dims(), [2, 3]);
        assert_eq!(smplx.features.dims(), [2, 32, 32, 48]);
        assert_eq!(smplx.position_map.dims(), [2, 3, 32, 48]);
        let points = out.points.as_ref().expect("point branch");
        assert_eq!(points.points.dims(), [2, 3, 32, 48]);
        assert_eq!(points.confidence.dims(), [2, 1, 32, 48]);
        assert_eq!(points.features.dims(), [2, 8 + 2, 32, 48]);
        assert!(values(&points.confidence).iter().all(|&c| c > 1.0));
        let gs = out.gaussians.as_ref().expect("3DGS head");
        assert_eq!(gs.image.dims(), [2, 3, 32, 48]);
        assert_eq!(gs.gaussians.means.dims(), [2, 32 * 48, 3]);

        let asked = [5, 1, 5];
        let with_hidden = forward(&model, &x, &asked);
        assert_eq!(with_hidden.hidden.len(), 3);
        for state in &with_hidden.hidden {
            assert_eq!(state.dims(), [2, 48, 64]);
        }
        // Block M + N - 1 is the last one: its output is T_out.
        assert_eq!(values(&with_hidden.hidden[0]), values(&with_hidden.t_out));
        assert_eq!(values(&with_hidden.hidden[2]), values(&with_hidden.t_out));
        // Block 1 (the last of stage I) gives T_mid, which the stage-III blocks then change.
        assert!(max_abs_diff(&values(&with_hidden.hidden[1]), &values(&with_hidden.t_out)) > 1e-3);
        // Asking for hidden states does not change the result.
        assert_eq!(values(&with_hidden.image), image);
    }

    #[test]
    #[should_panic(expected = "hidden layer 6")]
    fn a_hidden_layer_beyond_the_network_is_refused() {
        let device = ndarray();
        let model = config("tiny").init(&device);
        forward(&model, &inputs(1, 16, 16, &device), &[6]);
    }

    #[test]
    #[should_panic(expected = "forward_views")]
    fn geometry_needs_the_cameras() {
        let device = ndarray();
        let model = config("tiny").init(&device);
        let ([a, b, c], _) = inputs(1, 16, 16, &device);
        model.forward(a, b, c, &[]);
    }

    #[test]
    fn switching_attention_keeps_parameters_bit_identical() {
        let device = ndarray();
        let mut model = tiny_with(false, false, false).init(&device);
        let before = parameters(&model);
        let x = inputs(1, 32, 32, &device);
        let full = values(&forward(&model, &x, &[]).image);
        use AttentionKind::{Full as F, Linear as L};
        let mixed = [L, L, F, L, F, F];
        model.set_attention_kinds(&mixed);
        assert_eq!(model.attention_kinds(), mixed.to_vec());
        let after = parameters(&model);
        assert_eq!(before.len(), after.len());
        for ((name, a), (_, b)) in before.iter().zip(&after) {
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(a), bits(b), "{name} changed");
        }
        // The switch changes what the model computes, and switching back restores it.
        let hybrid = values(&forward(&model, &x, &[]).image);
        assert!(max_abs_diff(&full, &hybrid) > 1e-6);
        model.set_attention_kinds(&[F; 6]);
        assert_eq!(values(&forward(&model, &x, &[]).image), full);
        // A model without geometry also runs without views.
        let ([a, b, c], _) = x;
        assert_eq!(values(&model.forward(a, b, c, &[]).image), full);
    }

    /// Every float parameter's gradient, by path.
    fn gradients(model: &Prism, grads: &Gradients) -> Vec<(String, Option<Vec<f32>>)> {
        struct Collect<'a> {
            grads: &'a Gradients,
            path: Vec<String>,
            out: Vec<(String, Option<Vec<f32>>)>,
        }
        impl ModuleVisitor for Collect<'_> {
            fn enter_module(&mut self, name: &str, _: &str) {
                self.path.push(name.to_string());
            }
            fn exit_module(&mut self, _: &str, _: &str) {
                self.path.pop();
            }
            fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
                let grad = param.val().grad(self.grads).map(|g| values(&g));
                self.out.push((self.path.join("."), grad));
            }
        }
        let mut collect = Collect {
            grads,
            path: Vec::new(),
            out: Vec::new(),
        };
        model.visit(&mut collect);
        collect.out
    }

    /// A stand-in objective touching every output: image MSE for I_t and I_gs, squared
    /// parameters of the SMPL-X branch, points and confidence, and a term on a hidden state.
    fn all_outputs_loss(out: &PrismOutput, target: &Tensor<4>) -> Tensor<1> {
        let mut loss = (out.image.clone() - target.clone()).powi_scalar(2).mean()
            + out.hidden[0].clone().powi_scalar(2).mean() * 1e-3;
        if let Some(s) = &out.smplx {
            loss = loss
                + s.betas.clone().powi_scalar(2).mean()
                + s.expression.clone().powi_scalar(2).mean()
                + s.rotations.clone().powi_scalar(2).mean()
                + s.camera.clone().powi_scalar(2).mean();
        }
        if let Some(p) = &out.points {
            loss = loss + p.points.clone().mean() + p.confidence.clone().mean();
        }
        if let Some(g) = &out.gaussians {
            loss = loss + (g.image.clone() - target.clone()).powi_scalar(2).mean();
        }
        loss
    }

    fn is_zero_at_init(name: &str) -> bool {
        // Behind the zero convolutions: the gates of the branches see a zero map, the triplane
        // a zero weight.
        name.starts_with("injection.gate_smpl")
            || name.starts_with("injection.gate_pts")
            || name.starts_with("smplx_branch.triplane")
    }

    #[test]
    fn every_parameter_gets_a_finite_gradient_nonzero_where_expected() {
        use AttentionKind::{Full as F, Linear as L};
        let device = ndarray().autodiff();
        for (kinds, geometry) in [([F; 6], false), ([L, F, L, L, F, F], true)] {
            device.seed(3);
            let mut model = tiny_with(geometry, geometry, geometry).init(&device);
            model.set_attention_kinds(&kinds);
            let x = inputs(2, 32, 32, &device);
            let target =
                Tensor::<4>::random([2, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
            let out = forward(&model, &x, &[2]);
            let grads = all_outputs_loss(&out, &target).backward();
            let all = gradients(&model, &grads);
            if !geometry {
                assert_eq!(
                    all.len(),
                    3 + 6 * 8 + 2 + 1,
                    "parameter tensors (with g_res)"
                );
            }
            for (name, grad) in all {
                let grad = grad.unwrap_or_else(|| panic!("{kinds:?}: {name} has no gradient"));
                assert!(
                    grad.iter().all(|g| g.is_finite()),
                    "{kinds:?}: {name} not finite"
                );
                let nonzero = grad.iter().any(|&g| g != 0.0);
                assert_eq!(nonzero, !is_zero_at_init(&name), "{kinds:?}: {name}");
            }
        }
    }

    #[test]
    fn initialisation_equals_the_plain_backbone_bit_for_bit() {
        let device = ndarray();
        device.seed(4);
        let model = config("tiny").init(&device);
        assert!(model.has_geometry());
        let x = inputs(2, 32, 32, &device);
        let out = forward(&model, &x, &[]);
        // The plain backbone: tokenizer, stage I straight into stage III, NVS decoder.
        let ([image, source, target], _) = x;
        let t_in = model.tokenizer.forward(image, source, target);
        let mut hidden = HiddenStates::new(&[]);
        let t_mid = model.stage_one.forward(t_in, &mut hidden);
        let t_out = model.stage_three.forward(t_mid, 2, usize::MAX, &mut hidden);
        let plain = model
            .nvs_head
            .forward(t_out.clone().narrow(1, 16, 16), 32, 32, None);
        let bits = |t: &Tensor<4>| values(t).iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&out.image), bits(&plain));
        assert_eq!(
            values(&out.t_out)
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>(),
            values(&t_out)
                .iter()
                .map(|v| v.to_bits())
                .collect::<Vec<_>>()
        );
        // The branches did run and produce nonzero features.
        let f = values(&out.smplx.as_ref().unwrap().features);
        assert!(f.iter().any(|&v| v != 0.0), "F_smpl is all zero");
        let f = values(&out.points.as_ref().unwrap().features);
        assert!(f.iter().any(|&v| v != 0.0), "F_pts is all zero");
    }

    /// Gives the zero convolutions random weights (as after some training).
    fn trained_injection(model: Prism, device: &Device) -> Prism {
        let mut model = model;
        let randomise = |conv: &mut Option<crate::geometry::injection::ZeroConv>| {
            if let Some(conv) = conv {
                let [i, o] = conv.linear.weight.dims();
                conv.linear.weight = Param::from_tensor(Tensor::random(
                    [i, o],
                    Distribution::Normal(0.0, 0.05),
                    device,
                ));
            }
        };
        randomise(&mut model.injection.smpl_conv);
        randomise(&mut model.injection.pts_conv);
        model
    }

    #[test]
    fn with_the_injection_open_gradients_reach_the_geometry_branches() {
        let device = ndarray().autodiff();
        device.seed(6);
        let model = trained_injection(config("tiny").init(&device), &device);
        let x = inputs(2, 32, 32, &device);
        let target = Tensor::<4>::random([2, 3, 32, 32], Distribution::Uniform(0.0, 1.0), &device);
        let out = forward(&model, &x, &[]);
        // The NVS image alone: every geometry gradient comes through the injection.
        let grads = (out.image - target).powi_scalar(2).mean().backward();
        let all = gradients(&model, &grads);
        let norm = |prefix: &str| -> f32 {
            all.iter()
                .filter(|(name, _)| name.starts_with(prefix))
                .map(|(name, g)| {
                    let g = g
                        .as_ref()
                        .unwrap_or_else(|| panic!("{name} has no gradient"));
                    g.iter().map(|v| v * v).sum::<f32>()
                })
                .sum::<f32>()
                .sqrt()
        };
        for part in [
            "smplx_branch.triplane",
            "smplx_branch.regressor_out",
            "smplx_branch.adapter",
            "point_branch.dpt.reassemble",
            "point_branch.dpt.head_out",
            "injection.gate_smpl",
            "injection.gate_pts",
            "injection.gate_res",
        ] {
            let n = norm(part);
            assert!(n > 0.0 && n.is_finite(), "{part}: gradient norm {n}");
        }
    }

    #[test]
    fn a_zero_gate_behind_a_zero_convolution_never_trains() {
        // Why gate_init is not 0: both gradients vanish exactly.
        let device = ndarray().autodiff();
        let mut config = tiny_with(true, false, false);
        config.gate_init = 0.0;
        let model = config.init(&device);
        let x = inputs(1, 32, 32, &device);
        let out = forward(&model, &x, &[]);
        let grads = out.image.mean().backward();
        let all = gradients(&model, &grads);
        let get = |name: &str| {
            all.iter()
                .find(|(n, _)| n.starts_with(name))
                .and_then(|(_, g)| g.clone())
                .unwrap_or_else(|| panic!("{name}"))
        };
        assert!(get("injection.gate_smpl").iter().all(|&g| g == 0.0));
        assert!(
            get("injection.smpl_conv.linear.weight")
                .iter()
                .all(|&g| g == 0.0)
        );
        // With gate_init = 1 (the shipped configs) the convolution learns at once.
        config.gate_init = 1.0;
        let model = config.init(&device);
        let out = forward(&model, &x, &[]);
        let grads = out.image.mean().backward();
        let all = gradients(&model, &grads);
        let conv = all
            .iter()
            .find(|(n, _)| n.starts_with("injection.smpl_conv.linear.weight"))
            .and_then(|(_, g)| g.clone())
            .unwrap();
        assert!(conv.iter().any(|&g| g != 0.0));
    }

    #[test]
    fn ablation_switches_remove_their_parts() {
        let device = ndarray();
        for (smplx, points, gs) in [
            (false, true, true),
            (true, false, false),
            (false, false, true),
        ] {
            let config = tiny_with(smplx, points, gs);
            let model = config.init(&device);
            assert_eq!(model.smplx_branch.is_some(), smplx);
            assert_eq!(model.injection.smpl_conv.is_some(), smplx);
            assert_eq!(model.injection.gate_smpl.is_some(), smplx);
            assert_eq!(model.point_branch.is_some(), points);
            assert_eq!(model.injection.pts_conv.is_some(), points);
            assert_eq!(model.gs_head.is_some(), gs);
            let out = forward(&model, &inputs(1, 16, 16, &device), &[]);
            assert_eq!(out.smplx.is_some(), smplx);
            assert_eq!(out.points.is_some(), points);
            assert_eq!(out.gaussians.is_some(), gs);
            assert_eq!(ParameterCounts::of(&config).total, model.num_params());
        }
    }

    #[test]
    fn ndarray_and_flex_give_the_same_forward() {
        use AttentionKind::{Full as F, Linear as L};
        let nd = ndarray();
        let flex = prism_core::BackendKind::Flex.device().unwrap();
        let mut model = config("tiny").init(&nd);
        model.set_attention_kinds(&[F, L, F, L, L, F]);
        let on_flex = model.clone().to_device(&flex);
        assert_eq!(on_flex.attention_kinds(), model.attention_kinds());
        let x = inputs(2, 32, 32, &nd);
        let x_flex = (x.0.clone().map(|t| t.to_device(&flex)), x.1.clone());
        let a = forward(&model, &x, &[1, 4]);
        let b = forward(&on_flex, &x_flex, &[1, 4]);
        let err = max_abs_diff(&values(&a.image), &values(&b.image));
        assert!(err < 1e-4, "image: max difference {err}");
        for (ha, hb) in a.hidden.iter().zip(&b.hidden) {
            let err = max_abs_diff(&values(ha), &values(hb));
            assert!(err < 1e-4, "hidden: max difference {err}");
        }
        let (ga, gb) = (a.gaussians.unwrap(), b.gaussians.unwrap());
        let err = max_abs_diff(&values(&ga.image), &values(&gb.image));
        assert!(err < 1e-3, "I_gs: max difference {err}");
        let (pa, pb) = (a.points.unwrap(), b.points.unwrap());
        let err = max_abs_diff(&values(&pa.points), &values(&pb.points));
        assert!(err < 1e-4, "points: max difference {err}");
    }

    #[test]
    fn analytic_parameter_counts_match_the_built_models() {
        let device = ndarray();
        let options = PrismConfig {
            point_colours: true,
            nvs_sees_render: true,
            head_upsample: 2,
            ..shipped("tiny")
        };
        let configs = [
            ("tiny", config("tiny")),
            ("small", config("small")),
            (
                "tiny with coloured points, a decoder seeing I_gs and smooth heads",
                options,
            ),
        ];
        for (name, config) in configs {
            let model = config.init(&device);
            let counts = ParameterCounts::of(&config);
            assert_eq!(counts.total, model.num_params(), "{name}");
            assert_eq!(counts.tokenizer, model.tokenizer.num_params(), "{name}");
            assert_eq!(counts.stage_one, model.stage_one.num_params(), "{name}");
            assert_eq!(counts.stage_three, model.stage_three.num_params(), "{name}");
            assert_eq!(counts.nvs_head, model.nvs_head.num_params(), "{name}");
            assert_eq!(counts.injection, model.injection.num_params(), "{name}");
            let part = |m: Option<usize>| m.unwrap_or(0);
            assert_eq!(
                counts.smplx_branch,
                part(model.smplx_branch.as_ref().map(Module::num_params)),
                "{name}"
            );
            assert_eq!(
                counts.point_branch,
                part(model.point_branch.as_ref().map(Module::num_params)),
                "{name}"
            );
            assert_eq!(
                counts.gs_head,
                part(model.gs_head.as_ref().map(Module::num_params)),
                "{name}"
            );
            assert_eq!(
                counts.triplane,
                model.smplx_branch.as_ref().unwrap().triplane.num_params(),
                "{name}"
            );
            let out = forward(&model, &inputs(1, 16, 16, &device), &[]);
            assert_eq!(out.image.dims(), [1, 3, 16, 16], "{name}");
            let gs = out.gaussians.expect("a 3DGS head");
            assert_eq!(gs.gaussians.means.dims(), [1, 256, 3], "{name}");
        }
    }

    #[test]
    fn initialisation_follows_the_config() {
        let device = ndarray();
        device.seed(5);
        let config = config("small");
        let model = config.init(&device);
        let std = |v: &[f32]| {
            let mean = v.iter().sum::<f32>() / v.len() as f32;
            (v.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / v.len() as f32).sqrt()
        };
        let block = &model.stage_three.blocks[0];
        let qkv = std(&values(&block.attention.qkv.weight.val()));
        let fc_out = std(&values(&block.mlp.fc_out.weight.val()));
        let out_std = 0.02 / (2.0f32 * 12.0).sqrt();
        assert!((qkv - 0.02).abs() < 0.02 * 0.05, "qkv std {qkv}");
        assert!(
            (fc_out - out_std).abs() < out_std * 0.05,
            "fc_out std {fc_out}"
        );
        let gamma = values(&block.attention_norm.gamma.val());
        assert!(gamma.iter().all(|&g| g == 1.0));
        assert!(block.attention_norm.beta.is_none(), "no biases");
        assert!(model.tokenizer.source.bias.is_none() && block.attention.qkv.bias.is_none());
        // The injection: zero convolutions, g_res 0, branch gates at gate_init.
        let conv = model.injection.smpl_conv.as_ref().unwrap();
        assert!(values(&conv.linear.weight.val()).iter().all(|&w| w == 0.0));
        assert!(
            values(&conv.linear.bias.as_ref().unwrap().val())
                .iter()
                .all(|&w| w == 0.0)
        );
        assert_eq!(values(&model.injection.gate_res.val()), vec![0.0]);
        assert_eq!(
            values(&model.injection.gate_pts.as_ref().unwrap().val()),
            vec![config.gate_init as f32]
        );
    }
}
