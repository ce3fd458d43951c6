//! Which parameters are "heads" and which are "backbone": the two learning rates of the paper
//! (supplement: 1e-5 for the pretrained LVSM backbone, 2e-4 for the newly added heads).
//!
//! The split is by module path. A parameter is a head parameter when its path starts with one
//! of [`HEAD_MODULES`] (a field of [`prism_model::Prism`]); everything else (tokenizer and
//! transformer blocks) is backbone. The parts the paper adds to the LVSM backbone (the heads,
//! the geometry branches and the injection's zero-convs and gates) are all "heads", and so are
//! the transformer blocks a converted pretrained model adds to LVSM's (`new_blocks` of the
//! checkpoint it was started from).

use burn::module::ParamGroup;
use burn::optim::lr_scheduler::module_lr_scheduler::ModuleLrScheduler;

use crate::schedule::WarmupCosine;
use crate::step::TRAINEE_FIELD;

/// The fields of [`prism_model::Prism`] whose parameters train with `lr_heads`: the NVS and
/// 3DGS heads, the SMPL-X and point branches and the injection.
pub const HEAD_MODULES: &[&str] = &[
    "nvs_head",
    "gs_head",
    "smplx_branch",
    "point_branch",
    "injection",
];

/// The regular expression of head parameter paths (paths as Burn's module visitors and
/// optimizer see them from the [`crate::Trainee`], e.g. `prism.nvs_head.linear.weight`).
pub fn heads_pattern() -> String {
    heads_pattern_with(&[], 0)
}

/// [`heads_pattern`] plus the newly initialised transformer blocks `new_blocks` (global
/// indices; `stage_one` = `M` blocks are stage I's) of a model made from a pretrained backbone
/// (see [`crate::CheckpointState::new_blocks`]).
pub fn heads_pattern_with(new_blocks: &[usize], stage_one: usize) -> String {
    let mut parts: Vec<String> = HEAD_MODULES.iter().map(|m| m.to_string()).collect();
    for &b in new_blocks {
        parts.push(if b < stage_one {
            format!(r"stage_one\.blocks\.{b}")
        } else {
            format!(r"stage_three\.blocks\.{}", b - stage_one)
        });
    }
    format!(r"^{TRAINEE_FIELD}\.({})\.", parts.join("|"))
}

/// The head parameters as a Burn [`ParamGroup`].
pub fn heads_group() -> ParamGroup {
    heads_group_with(&[], 0)
}

/// The head parameters and those of the new blocks (see [`heads_pattern_with`]).
pub fn heads_group_with(new_blocks: &[usize], stage_one: usize) -> ParamGroup {
    ParamGroup::from_regex(heads_pattern_with(new_blocks, stage_one))
        .expect("the heads pattern is a valid regex")
}

/// Whether the parameter at `path` is a head parameter.
pub fn is_head(path: &str) -> bool {
    HEAD_MODULES.iter().any(|m| {
        path.strip_prefix(TRAINEE_FIELD)
            .and_then(|p| p.strip_prefix('.'))
            .and_then(|p| p.strip_prefix(m))
            .is_some_and(|rest| rest.starts_with('.'))
    })
}

/// The per-group learning-rate scheduler: `backbone` for every parameter, `heads` for the
/// [`heads_group`] (Burn's [`ModuleLrScheduler`]: the last matching group wins).
pub fn learning_rates(backbone: WarmupCosine, heads: WarmupCosine) -> ModuleLrScheduler {
    learning_rates_with(backbone, heads, &[], 0)
}

/// [`learning_rates`] with the new blocks of a model made from a pretrained backbone in the
/// heads' group (see [`heads_group_with`]).
pub fn learning_rates_with(
    backbone: WarmupCosine,
    heads: WarmupCosine,
    new_blocks: &[usize],
    stage_one: usize,
) -> ModuleLrScheduler {
    ModuleLrScheduler::new(backbone).with_group(heads_group_with(new_blocks, stage_one), heads)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn heads_are_matched_by_path_prefix() {
        assert!(is_head("prism.nvs_head.linear.weight"));
        assert!(is_head("prism.nvs_head.norm.gamma"));
        assert!(!is_head("prism.stage_one.blocks.0.attention.qkv.weight"));
        assert!(!is_head("prism.tokenizer.source.weight"));
        assert!(!is_head("prism.nvs_headx.w"));
        assert!(is_head("prism.injection.gate_res"));
        assert!(is_head("prism.point_branch.dpt.out.weight"));
        let group = heads_group();
        let id = burn::module::ParamId::new();
        assert!(group.matches(&id, Some("prism.nvs_head.linear.weight")));
        assert!(!group.matches(&id, Some("prism.stage_three.blocks.3.mlp.fc_in.weight")));
    }

    #[test]
    fn new_blocks_join_the_heads() {
        let group = heads_group_with(&[1, 4, 5], 2);
        let id = burn::module::ParamId::new();
        let matches = |path: &str| group.matches(&id, Some(path));
        assert!(matches("prism.stage_one.blocks.1.attention.qkv.weight"));
        assert!(matches("prism.stage_three.blocks.2.mlp.fc_out.weight"));
        assert!(matches("prism.stage_three.blocks.3.attention_norm.gamma"));
        assert!(matches("prism.nvs_head.linear.weight"));
        assert!(!matches("prism.stage_one.blocks.0.attention.qkv.weight"));
        assert!(!matches("prism.stage_three.blocks.1.mlp.fc_in.weight"));
        assert!(!matches("prism.stage_three.blocks.23.mlp.fc_in.weight"));
        assert!(!matches("prism.tokenizer.source.weight"));
    }

    /// The optimizer applies each group's rate: with a backbone rate of 0 only the heads move.
    #[test]
    fn the_optimizer_uses_the_heads_rate_for_head_parameters_only() {
        use crate::clip::parameter_values;
        use crate::step::Trainee;
        use burn::module::{Module, ModuleVisitor, Param};
        use burn::optim::{AdamWConfig, GradientsParams};
        use burn::tensor::{Distribution, Tensor};

        let path = crate::config::configs_dir().join("tiny.toml");
        // The backbone and the NVS head only: every parameter then gets a gradient.
        let config = prism_model::load_config(path)
            .unwrap()
            .model
            .with_smplx_branch(false)
            .with_point_branch(false)
            .with_gs_head(false)
            .with_gs_depth(prism_model::GsDepth::Head)
            .with_nvs_output(prism_model::NvsOutput::Direct);
        let device = prism_core::BackendKind::Ndarray
            .device()
            .unwrap()
            .autodiff();
        let trainee = Trainee {
            prism: config.init(&device),
            background: [1.0; 3],
        };
        let x = Tensor::<4>::random([1, 3, 16, 16], Distribution::Uniform(0.0, 1.0), &device);
        let rays = Tensor::<4>::random([1, 6, 16, 16], Distribution::Normal(0.0, 1.0), &device);
        let out = trainee.prism.forward(x, rays.clone(), rays, &[]);
        let grads = GradientsParams::from_grads(out.image.mean().backward(), &trainee);
        let mut scheduler = ModuleLrScheduler::new(0.0_f64).with_group(heads_group(), 1e-2);
        let mut optim = AdamWConfig::new().init();
        let before = parameter_values(&trainee);
        let after = parameter_values(&optim.step(scheduler.step(), trainee.clone(), grads));

        struct Paths(Vec<String>, Vec<String>);
        impl ModuleVisitor for Paths {
            fn enter_module(&mut self, name: &str, _: &str) {
                self.1.push(name.into());
            }
            fn exit_module(&mut self, _: &str, _: &str) {
                self.1.pop();
            }
            fn visit_float<const D: usize>(&mut self, _: &Param<Tensor<D>>) {
                self.0.push(self.1.join("."));
            }
        }
        let mut paths = Paths(Vec::new(), Vec::new());
        trainee.visit(&mut paths);
        let mut heads = 0;
        for ((path, a), b) in paths.0.iter().zip(&before).zip(&after) {
            let moved = a.iter().zip(b).any(|(x, y)| x != y);
            assert_eq!(moved, is_head(path), "{path}");
            heads += usize::from(is_head(path));
        }
        assert_eq!(
            heads, 3,
            "the NVS head's norm and linear layer, the injection's g_res"
        );
    }
}
