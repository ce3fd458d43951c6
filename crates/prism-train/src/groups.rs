//! Which parameters are "heads" and which are "backbone": the two learning rates of the paper
//! (supplement: 1e-5 for the pretrained LVSM backbone, 2e-4 for the newly added heads).
//!
//! The split is by module path. A parameter is a head parameter when its path starts with one
//! of [`HEAD_MODULES`] (a field of [`prism_model::Prism`]); everything else (tokenizer and
//! transformer blocks) is backbone. Later parts of the model register their modules by adding
//! their field names to [`HEAD_MODULES`] (the 3DGS head, the SMPL-X and point branches and the
//! injection's zero-convs and gates).

use burn::module::ParamGroup;
use burn::optim::lr_scheduler::module_lr_scheduler::ModuleLrScheduler;

use crate::schedule::WarmupCosine;
use crate::step::TRAINEE_FIELD;

/// The fields of [`prism_model::Prism`] whose parameters train with `lr_heads`: the NVS head
/// now; the 3DGS head and the geometry branches when they exist.
pub const HEAD_MODULES: &[&str] = &["nvs_head"];

/// The regular expression of head parameter paths (paths as Burn's module visitors and
/// optimizer see them from the [`crate::Trainee`], e.g. `prism.nvs_head.linear.weight`).
pub fn heads_pattern() -> String {
    format!(r"^{TRAINEE_FIELD}\.({})\.", HEAD_MODULES.join("|"))
}

/// The head parameters as a Burn [`ParamGroup`].
pub fn heads_group() -> ParamGroup {
    ParamGroup::from_regex(heads_pattern()).expect("the heads pattern is a valid regex")
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
    ModuleLrScheduler::new(backbone).with_group(heads_group(), heads)
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
        let group = heads_group();
        let id = burn::module::ParamId::new();
        assert!(group.matches(&id, Some("prism.nvs_head.linear.weight")));
        assert!(!group.matches(&id, Some("prism.stage_three.blocks.3.mlp.fc_in.weight")));
    }
}
