//! The training config file: `[model]` and `[distill]` (prism-model), `[losses]`
//! (prism-losses), and this crate's `[train]` and `[data]` sections.
//!
//! Every field of every section is written in the file: a missing field is an error naming it
//! and its section, so a config file fully describes a run.

use std::path::{Path, PathBuf};

use burn::config::Config;
use prism_data::SynthOptions;
use prism_losses::LossWeights;
use prism_model::{DistillConfig, PrismConfig, describe_toml_error};
use serde::{Deserialize, Serialize};

use crate::error::{Result, TrainError};

/// The optimisation settings: the `[train]` section.
///
/// The schedule (see [`crate::WarmupCosine`]): both learning rates rise linearly from 0 over
/// `warmup_steps`, then follow a cosine from their peak down to `min_lr` at step `steps`.
#[derive(Config, Debug, PartialEq)]
pub struct TrainConfig {
    /// Optimizer steps of the run (`--steps` overrides it).
    pub steps: usize,
    /// Samples per step (each sample is one subject's source view with `targets_per_sample`
    /// target views, so a step sees `batch_size * targets_per_sample` (source, target) pairs).
    pub batch_size: usize,
    /// Target views per sample, drawn from views 1..=104.
    pub targets_per_sample: usize,
    /// Peak learning rate of the backbone (tokenizer and transformer blocks; paper: 1e-5 for a
    /// pretrained LVSM backbone).
    pub lr_backbone: f64,
    /// Peak learning rate of the heads ([`crate::HEAD_MODULES`]: the newly added modules;
    /// paper: 2e-4).
    pub lr_heads: f64,
    /// AdamW's decoupled weight decay (paper: 1e-5).
    pub weight_decay: f64,
    /// Steps of linear warm-up from 0 to the peak learning rates (0: none).
    pub warmup_steps: usize,
    /// The learning rate both schedules anneal to (paper: 1e-6).
    pub min_lr: f64,
    /// Largest global L2 norm of the gradient: the norm over every parameter's gradient
    /// together (backbone and heads, after summing over devices); a larger gradient is scaled
    /// down to this norm before the optimizer step. 0 disables clipping.
    pub grad_clip_norm: f64,
    /// Steps in a row with a non-finite loss or gradient that are skipped before the run stops
    /// with an error (each one is logged and counted; a finite step resets the count).
    pub max_non_finite_steps: usize,
    /// Steps between checkpoints (one is always written at the end).
    pub checkpoint_every: usize,
    /// Checkpoints kept in the run folder (older ones are removed; at least 1).
    pub keep_checkpoints: usize,
    /// Steps between validations on the held-out subjects (one also runs before the first step
    /// and at the end); 0: only those two.
    pub validate_every: usize,
    /// Target views per held-out subject in a validation, evenly spread over views 1..=100.
    pub validation_views: usize,
    /// Seed of the model's initialisation and of the data order (the data of step `s` is a pure
    /// function of the seed and `s`).
    pub seed: u64,
    /// Threads that load and decode samples ahead of the training step (0: load on the
    /// training thread).
    pub data_workers: usize,
}

/// A training config file: every section a training run reads.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainingConfig {
    /// The `[model]` section.
    pub model: PrismConfig,
    /// The `[distill]` section.
    pub distill: DistillConfig,
    /// The `[losses]` section: the objective's weights.
    pub losses: LossWeights,
    /// The `[train]` section.
    pub train: TrainConfig,
    /// The `[data]` section: the synthetic dataset the commands train on when no `--data` is
    /// given (synthesised once into the cache folder by `prism_synth::ensure_synthetic_dataset`).
    pub data: SynthOptions,
}

/// The sections this crate parses itself (the model's are parsed by prism-model).
#[derive(Deserialize)]
struct OwnSections {
    losses: LossWeights,
    train: TrainConfig,
    data: SynthOptions,
}

/// The text of the config file at `path`.
fn read_config(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).map_err(|cause| TrainError::ReadConfig {
        path: path.to_path_buf(),
        cause,
    })
}

/// The first setting of `text` (as `section.field`, or a whole `section`) that `config`, parsed
/// from it, does not have: serde passes over fields it does not know, so a setting this version
/// lacks (one from another version, or a misspelt extra line) would otherwise be dropped
/// without a word.
fn unknown_key(text: &str, config: &TrainingConfig) -> Option<String> {
    let written: toml::Table = text.parse().ok()?;
    let known = toml::Table::try_from(config).expect("a training config serialises");
    for (section, value) in &written {
        let Some(known_section) = known.get(section) else {
            return Some(section.clone());
        };
        if let (toml::Value::Table(fields), toml::Value::Table(known_fields)) =
            (value, known_section)
            && let Some(field) = fields.keys().find(|f| !known_fields.contains_key(*f))
        {
            return Some(format!("{section}.{field}"));
        }
    }
    None
}

/// `text` with every loss weight that is 0 in the paper's objective and absent from its
/// `[losses]` section written in as 0; `text` itself when nothing is absent or it does not
/// parse (then [`TrainingConfig::parse`] reports it, with its line).
fn with_absent_terms_off(text: &str) -> String {
    let Ok(mut doc) = text.parse::<toml::Table>() else {
        return text.to_string();
    };
    let Some(toml::Value::Table(losses)) = doc.get_mut("losses") else {
        return text.to_string();
    };
    let paper = toml::Table::try_from(LossWeights::new()).expect("loss weights serialise");
    let mut added = false;
    for (name, value) in paper {
        if value.as_float() == Some(0.0) && !losses.contains_key(&name) {
            losses.insert(name, value);
            added = true;
        }
    }
    if added {
        toml::to_string(&doc).expect("a parsed config serialises")
    } else {
        text.to_string()
    }
}

impl TrainingConfig {
    /// Parses a config text and checks every section; `origin` (usually the file's path) names
    /// the text in errors.
    ///
    /// # Errors
    /// [`TrainError::ParseConfig`] for bad TOML, a missing / mistyped field (with its line and
    /// section) or a setting this version does not have, [`TrainError::Model`] for an invalid
    /// `[model]` / `[distill]`, [`TrainError::InvalidConfig`] for an invalid value of the other
    /// sections.
    pub fn parse(text: &str, origin: &Path) -> Result<Self> {
        let config = Self::parse_known(text, origin)?;
        match unknown_key(text, &config) {
            Some(key) => Err(TrainError::ParseConfig {
                path: origin.to_path_buf(),
                message: format!(
                    "unknown setting `{key}`: this version has no such field (misspelt, or \
                     from another version?)"
                ),
            }),
            None => Ok(config),
        }
    }

    /// [`TrainingConfig::parse`] without the check for unknown settings: what a stored config
    /// may hold from a version that had more.
    fn parse_known(text: &str, origin: &Path) -> Result<Self> {
        let model = prism_model::parse_config(text, origin)?;
        let own: OwnSections = toml::from_str(text).map_err(|err| TrainError::ParseConfig {
            path: origin.to_path_buf(),
            message: describe_toml_error(text, &err),
        })?;
        let config = Self {
            model: model.model,
            distill: model.distill,
            losses: own.losses,
            train: own.train,
            data: own.data,
        };
        config
            .validate()
            .map_err(|(field, message)| TrainError::InvalidConfig {
                path: origin.to_path_buf(),
                field,
                message,
            })?;
        Ok(config)
    }

    /// Reads and checks a config file (see [`TrainingConfig::parse`]).
    ///
    /// # Errors
    /// [`TrainError::ReadConfig`] when the file cannot be read, otherwise as
    /// [`TrainingConfig::parse`].
    pub fn load(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse(&read_config(path)?, path)
    }

    /// Reads the config that a run folder or checkpoint stored (see [`TrainingConfig::load`]).
    /// A run written before one of the loss terms beyond the paper existed lacks that term's
    /// weight: the term was not in its objective, so its weight reads as 0 (the paper config's
    /// value for every such term). Every other missing field is an error, as in a config file;
    /// a setting this version does not know is passed over.
    ///
    /// # Errors
    /// As [`TrainingConfig::load`].
    pub fn load_stored(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref();
        Self::parse_known(&with_absent_terms_off(&read_config(path)?), path)
    }

    /// The config as TOML text (what a run folder and its checkpoints store).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a training config serialises to TOML")
    }

    /// Checks `[losses]`, `[train]` and `[data]`; returns the offending field and why.
    fn validate(&self) -> std::result::Result<(), (String, String)> {
        let fail = |field: &str, message: String| Err((field.to_string(), message));
        let l = &self.losses;
        for (field, value) in [
            ("losses.nvs", l.nvs),
            ("losses.gs", l.gs),
            ("losses.pts", l.pts),
            ("losses.smplx", l.smplx),
            ("losses.distill", l.distill),
            ("losses.lpips", l.lpips),
            ("losses.confidence_alpha", l.confidence_alpha),
            ("losses.gs_opacity", l.gs_opacity),
            ("losses.nvs_holes", l.nvs_holes),
            ("losses.gs_centres", l.gs_centres),
            ("losses.gs_spread", l.gs_spread),
            ("losses.laplacian", l.laplacian),
            ("losses.gs_laplacian", l.laplacian_in_gs()),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return fail(field, format!("{value} is not a non-negative number"));
            }
        }
        let t = &self.train;
        let positive = [
            ("train.steps", t.steps),
            ("train.batch_size", t.batch_size),
            ("train.checkpoint_every", t.checkpoint_every),
            ("train.keep_checkpoints", t.keep_checkpoints),
            ("train.validation_views", t.validation_views),
            ("train.max_non_finite_steps", t.max_non_finite_steps),
        ];
        for (field, value) in positive {
            if value == 0 {
                return fail(field, "must be at least 1".into());
            }
        }
        if !(1..=104).contains(&t.targets_per_sample) {
            return fail(
                "train.targets_per_sample",
                format!("{} is not in 1..=104", t.targets_per_sample),
            );
        }
        if t.validation_views > 100 {
            return fail(
                "train.validation_views",
                format!(
                    "{} is more than the 100 evaluation views",
                    t.validation_views
                ),
            );
        }
        for (field, value) in [
            ("train.lr_backbone", t.lr_backbone),
            ("train.lr_heads", t.lr_heads),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return fail(field, format!("{value} is not a positive number"));
            }
            if value < t.min_lr {
                return fail(field, format!("{value} is below train.min_lr {}", t.min_lr));
            }
        }
        for (field, value) in [
            ("train.weight_decay", t.weight_decay),
            ("train.min_lr", t.min_lr),
            ("train.grad_clip_norm", t.grad_clip_norm),
        ] {
            if !(value.is_finite() && value >= 0.0) {
                return fail(field, format!("{value} is not a non-negative number"));
            }
        }
        let d = &self.data;
        if d.subjects < 2 {
            return fail(
                "data.subjects",
                "at least 2 are needed (one is held out for validation)".into(),
            );
        }
        if d.resolution < 8 {
            return fail("data.resolution", format!("{} is below 8 px", d.resolution));
        }
        if !(d.test_fraction > 0.0 && d.test_fraction < 1.0) {
            return fail(
                "data.test_fraction",
                format!("{} is not in (0, 1)", d.test_fraction),
            );
        }
        if d.supersample == 0 {
            return fail("data.supersample", "must be at least 1".into());
        }
        if d.background.iter().any(|c| !(0.0..=1.0).contains(c)) {
            return fail(
                "data.background",
                format!("{:?} has a component outside [0, 1]", d.background),
            );
        }
        Ok(())
    }
}

/// The name of a config file without folder and extension (`configs/small.toml` -> `small`),
/// used in default run folder names.
pub fn config_name(path: &Path) -> String {
    path.file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "config".into())
}

/// The workspace's `configs/` folder (for tests and examples).
pub fn configs_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tiny_text() -> String {
        std::fs::read_to_string(configs_dir().join("tiny.toml")).unwrap()
    }

    fn parse(text: &str) -> Result<TrainingConfig> {
        TrainingConfig::parse(text, Path::new("test.toml"))
    }

    #[test]
    fn shipped_configs_load_with_every_section() {
        for name in ["tiny", "small", "paper"] {
            let config = TrainingConfig::load(configs_dir().join(format!("{name}.toml")))
                .unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(config.train.steps > 0, "{name}");
            assert!(config.data.subjects >= 2, "{name}");
            assert_eq!(config.model.resolution % config.model.patch_size, 0);
        }
        let paper = TrainingConfig::load(configs_dir().join("paper.toml")).unwrap();
        assert_eq!(paper.train.weight_decay, 1e-5);
        assert_eq!(paper.train.min_lr, 1e-6);
        assert_eq!(
            (paper.train.lr_backbone, paper.train.lr_heads),
            (1e-5, 2e-4)
        );
        assert_eq!(paper.losses, LossWeights::new());
    }

    #[test]
    fn a_stored_config_from_before_a_loss_term_reads_it_as_off() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("config.toml");
        // A run of the small config, stored before `L_spread` and `L_centres` existed.
        let small = std::fs::read_to_string(configs_dir().join("small.toml")).unwrap();
        let old: String = small
            .lines()
            .filter(|l| !l.starts_with("gs_spread") && !l.starts_with("gs_centres"))
            .map(|l| format!("{l}\n"))
            .collect();
        std::fs::write(&path, &old).unwrap();
        let stored = TrainingConfig::load_stored(&path).unwrap();
        let mut want = TrainingConfig::load(configs_dir().join("small.toml")).unwrap();
        want.losses.gs_spread = 0.0;
        assert_eq!(stored.to_toml(), want.to_toml());
        // A config file must still name every field, and a stored config every other one.
        let err = TrainingConfig::load(&path).unwrap_err().to_string();
        assert!(err.contains("missing field `gs_centres`"), "{err}");
        std::fs::write(&path, old.replace("warmup_steps", "warmup_stepz")).unwrap();
        let err = TrainingConfig::load_stored(&path).unwrap_err().to_string();
        assert!(err.contains("warmup_steps"), "{err}");
    }

    #[test]
    fn unknown_settings_are_refused_in_a_file_and_passed_over_in_a_stored_config() {
        let text = tiny_text();
        for (extra, key) in [
            ("[losses]\ngs_gradient = 10.0\n", "`losses.gs_gradient`"),
            ("[model]\nskip_blocks = 2\n", "`model.skip_blocks`"),
            ("[augment]\nflip = true\n", "`augment`"),
        ] {
            let section = &extra[..extra.find('\n').unwrap() + 1];
            let written = if text.contains(section) {
                text.replacen(section, extra, 1)
            } else {
                format!("{text}\n{extra}")
            };
            let err = parse(&written).unwrap_err().to_string();
            assert!(err.starts_with("test.toml") && err.contains(key), "{err}");
            let dir = tempfile::tempdir().unwrap();
            let path = dir.path().join("config.toml");
            std::fs::write(&path, &written).unwrap();
            let stored = TrainingConfig::load_stored(&path).unwrap();
            assert_eq!(stored.to_toml(), parse(&text).unwrap().to_toml());
        }
    }

    #[test]
    fn round_trips_through_toml() {
        let config = parse(&tiny_text()).unwrap();
        let again = parse(&config.to_toml()).unwrap();
        assert_eq!(again.to_toml(), config.to_toml());
        assert_eq!(again.train, config.train);
    }

    #[test]
    fn errors_name_the_file_section_and_field() {
        let text = tiny_text();
        let missing = text.replace("warmup_steps", "warmup_stepz");
        let err = parse(&missing).unwrap_err().to_string();
        assert!(
            err.starts_with("test.toml") && err.contains("warmup_steps") && err.contains("[train]"),
            "{err}"
        );
        let mistyped = text.replace("subjects = ", "subjects = \"x\" #");
        let err = parse(&mistyped).unwrap_err().to_string();
        assert!(err.contains("test.toml") && err.contains("line"), "{err}");
        // `[distill]` has a `batch_size` too: zero the one of `[train]` only.
        let (head, train) = text.split_at(text.find("[train]").unwrap());
        let zero = format!("{head}{}", regex_replace(train, "batch_size", "0"));
        let err = parse(&zero).unwrap_err().to_string();
        assert!(
            err.contains("test.toml") && err.contains("train.batch_size"),
            "{err}"
        );
        let bad_lr = regex_replace(&text, "lr_heads", "1e-9");
        let err = parse(&bad_lr).unwrap_err().to_string();
        assert!(
            err.contains("train.lr_heads") && err.contains("min_lr"),
            "{err}"
        );
        let bad_fraction = regex_replace(&text, "test_fraction", "1.5");
        let err = parse(&bad_fraction).unwrap_err().to_string();
        assert!(err.contains("data.test_fraction"), "{err}");
        let no_losses = text.replace("[losses]", "[lossez]");
        let err = parse(&no_losses).unwrap_err().to_string();
        assert!(err.contains("losses"), "{err}");
        // The model's own checks still apply.
        let bad_heads = regex_replace(&text, "heads", "5");
        let err = parse(&bad_heads).unwrap_err().to_string();
        assert!(err.contains("model.heads"), "{err}");
    }

    /// `text` with the value of `key = ...` replaced by `value`.
    fn regex_replace(text: &str, key: &str, value: &str) -> String {
        text.lines()
            .map(|line| {
                let trimmed = line.trim_start();
                if trimmed.starts_with(key) && trimmed[key.len()..].trim_start().starts_with('=') {
                    format!("{key} = {value}")
                } else {
                    line.to_string()
                }
            })
            .collect::<Vec<_>>()
            .join("\n")
    }
}
