//! The model's configuration: the `[model]` section of a TOML config file, and the loader of
//! the `[model]` and `[distill]` sections.
//!
//! Every field of `[model]` and `[distill]` is written in the file (the file fully describes
//! the model; a missing field is an error naming it). Other sections (`[losses]`, `[train]`,
//! `[data]`, ...) are ignored here: they belong to other crates.

use std::fmt;
use std::path::Path;

use burn::config::Config;
use serde::de::{self, Deserializer, SeqAccess, Visitor};
use serde::{Deserialize, Serialize, Serializer};

use crate::attention::{AttentionKind, FeatureMap};
use crate::distill::DistillConfig;
use crate::error::ModelError;

/// The attention kind of every transformer block, as written in a config file.
///
/// In TOML either a string, `"full"` (every block Full), `"linear"` (every block Linear) or one
/// letter per block, `F` or `L` (spaces and `_` `|` are ignored, e.g. `"LLLLLF LLLLLF"`), or a
/// list with one `"full"` / `"linear"` per block.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum AttentionPattern {
    /// The same kind for every block.
    All(AttentionKind),
    /// One kind per block, in global block order (stage I then stage III).
    PerBlock(Vec<AttentionKind>),
}

impl AttentionPattern {
    /// The kinds of `num_blocks` blocks.
    ///
    /// # Errors
    /// When a per-block pattern does not have exactly `num_blocks` entries.
    pub fn resolve(&self, num_blocks: usize) -> Result<Vec<AttentionKind>, ModelError> {
        match self {
            Self::All(kind) => Ok(vec![*kind; num_blocks]),
            Self::PerBlock(kinds) if kinds.len() == num_blocks => Ok(kinds.clone()),
            Self::PerBlock(kinds) => Err(ModelError::invalid(
                "model.attention",
                format!(
                    "{} entries for {num_blocks} blocks (stage_one_blocks + stage_three_blocks)",
                    kinds.len()
                ),
            )),
        }
    }

    /// The compact text form: `full`, `linear` or one `F`/`L` letter per block.
    pub fn to_compact(&self) -> String {
        match self {
            Self::All(kind) => kind.name().to_string(),
            Self::PerBlock(kinds) => kinds.iter().map(|k| k.letter()).collect(),
        }
    }

    /// Parses the compact text form (see the type's documentation).
    ///
    /// # Errors
    /// On a character other than `F`, `L`, spaces, `_` and `|`, or an empty pattern.
    pub fn parse_compact(text: &str) -> Result<Self, String> {
        match text.trim().to_ascii_lowercase().as_str() {
            "full" => return Ok(Self::All(AttentionKind::Full)),
            "linear" => return Ok(Self::All(AttentionKind::Linear)),
            _ => {}
        }
        let mut kinds = Vec::new();
        for c in text.chars() {
            match c {
                'F' | 'f' => kinds.push(AttentionKind::Full),
                'L' | 'l' => kinds.push(AttentionKind::Linear),
                ' ' | '_' | '|' => {}
                other => {
                    return Err(format!(
                        "unexpected `{other}` in attention pattern `{text}` (expected \"full\", \
                         \"linear\" or one F/L letter per block)"
                    ));
                }
            }
        }
        if kinds.is_empty() {
            return Err("empty attention pattern".to_string());
        }
        Ok(Self::PerBlock(kinds))
    }
}

impl Serialize for AttentionPattern {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.serialize_str(&self.to_compact())
    }
}

impl<'de> Deserialize<'de> for AttentionPattern {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct PatternVisitor;
        impl<'de> Visitor<'de> for PatternVisitor {
            type Value = AttentionPattern;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str(
                    "\"full\", \"linear\", a pattern of F/L letters, or a list of \"full\" / \
                     \"linear\"",
                )
            }
            fn visit_str<E: de::Error>(self, v: &str) -> Result<Self::Value, E> {
                AttentionPattern::parse_compact(v).map_err(E::custom)
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut kinds = Vec::new();
                while let Some(kind) = seq.next_element::<AttentionKind>()? {
                    kinds.push(kind);
                }
                Ok(AttentionPattern::PerBlock(kinds))
            }
        }
        deserializer.deserialize_any(PatternVisitor)
    }
}

/// The model: the `[model]` section of a config file (paper Sec. 3.2). See
/// `configs/paper.toml` for the paper's values.
#[derive(Config, Debug)]
pub struct PrismConfig {
    /// Token width `d` (paper: 768).
    pub width: usize,
    /// Attention heads; `width` must be a multiple (paper: 12, head dim 64).
    pub heads: usize,
    /// Patch size `p` in pixels (paper: 8).
    pub patch_size: usize,
    /// `M`, the blocks of stage I before the injection point (paper: 12).
    pub stage_one_blocks: usize,
    /// `N`, the blocks of stage III after the injection point (paper: 24).
    pub stage_three_blocks: usize,
    /// Training and evaluation image size in pixels (square; paper: 512). The network itself
    /// has no positional embedding and runs at any multiple of `patch_size`.
    pub resolution: usize,
    /// MLP hidden width as a multiple of `width`.
    #[config(default = 4)]
    pub mlp_ratio: usize,
    /// Attention kind of every block (`"full"`, `"linear"`, an F/L pattern or a list).
    #[config(default = "AttentionPattern::All(AttentionKind::Full)")]
    pub attention: AttentionPattern,
    /// Feature map `phi` of linear attention: `relu` (SANA, default) or `elu1` (ELU + 1).
    #[config(default = "FeatureMap::Relu")]
    pub linear_feature_map: FeatureMap,
    /// `eps` added to linear attention's normaliser `phi(q) . sum phi(k)`.
    #[config(default = 1e-6)]
    pub linear_eps: f64,
    /// Standard deviation of the normal initialisation of every projection (output
    /// projections of the blocks are further divided by `sqrt(2 (M + N))`).
    #[config(default = 0.02)]
    pub init_std: f64,
    /// `eps` of every LayerNorm and QK RMSNorm.
    #[config(default = 1e-5)]
    pub norm_eps: f64,
}

impl PrismConfig {
    /// `M + N`, the transformer blocks of the whole cascade.
    pub fn num_blocks(&self) -> usize {
        self.stage_one_blocks + self.stage_three_blocks
    }

    /// Head dimension `d / heads`.
    pub fn head_dim(&self) -> usize {
        self.width / self.heads.max(1)
    }

    /// Tokens of one (source, target) sequence at `height x width` pixels: `2 (H/p)(W/p)`.
    pub fn tokens_per_sequence(&self, height: usize, width: usize) -> usize {
        2 * (height / self.patch_size) * (width / self.patch_size)
    }

    /// The attention kind of each block, in global order.
    ///
    /// # Errors
    /// When the `attention` pattern's length is not `M + N`.
    pub fn attention_kinds(&self) -> Result<Vec<AttentionKind>, ModelError> {
        self.attention.resolve(self.num_blocks())
    }

    /// Checks that a model can be built from this config.
    ///
    /// # Errors
    /// [`ModelError::Invalid`] naming the first offending field.
    pub fn validate(&self) -> Result<(), ModelError> {
        let fail = |field: &str, message: String| Err(ModelError::invalid(field, message));
        if self.width == 0 {
            return fail("model.width", "must be positive".into());
        }
        if self.heads == 0 || !self.width.is_multiple_of(self.heads) {
            return fail(
                "model.heads",
                format!("{} does not divide width {}", self.heads, self.width),
            );
        }
        if self.patch_size == 0 {
            return fail("model.patch_size", "must be positive".into());
        }
        if self.resolution == 0 || !self.resolution.is_multiple_of(self.patch_size) {
            return fail(
                "model.resolution",
                format!(
                    "{} is not a positive multiple of patch_size {}",
                    self.resolution, self.patch_size
                ),
            );
        }
        if self.stage_one_blocks == 0 {
            return fail("model.stage_one_blocks", "must be at least 1".into());
        }
        if self.stage_three_blocks == 0 {
            return fail("model.stage_three_blocks", "must be at least 1".into());
        }
        if self.mlp_ratio == 0 {
            return fail("model.mlp_ratio", "must be at least 1".into());
        }
        for (field, value) in [
            ("model.linear_eps", self.linear_eps),
            ("model.init_std", self.init_std),
            ("model.norm_eps", self.norm_eps),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return fail(field, format!("{value} is not a positive number"));
            }
        }
        self.attention_kinds().map(|_| ())
    }
}

/// The sections of a config file that this crate reads: `[model]` and `[distill]`. Other
/// sections are ignored.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct ModelConfigFile {
    /// The `[model]` section.
    pub model: PrismConfig,
    /// The `[distill]` section.
    pub distill: DistillConfig,
}

impl ModelConfigFile {
    /// Checks both sections (see [`PrismConfig::validate`] and [`DistillConfig::validate`]).
    ///
    /// # Errors
    /// [`ModelError::Invalid`] naming the first offending field.
    pub fn validate(&self) -> Result<(), ModelError> {
        self.model.validate()?;
        self.distill.validate(self.model.num_blocks())
    }
}

/// Parses the `[model]` and `[distill]` sections of a TOML text and checks them. `origin`
/// (usually the file's path) names the text in errors.
///
/// # Errors
/// [`ModelError::Parse`] with the line and the field for bad TOML, a missing or mistyped
/// field; [`ModelError::InvalidInFile`] for a value the model cannot be built with.
pub fn parse_config(text: &str, origin: &Path) -> Result<ModelConfigFile, ModelError> {
    let file: ModelConfigFile = toml::from_str(text).map_err(|err| ModelError::Parse {
        path: origin.to_path_buf(),
        message: describe_toml_error(text, &err),
    })?;
    file.validate().map_err(|err| err.in_file(origin))?;
    Ok(file)
}

/// Reads a config file and returns its `[model]` and `[distill]` sections, checked.
///
/// # Errors
/// [`ModelError::Read`] when the file cannot be read, otherwise as [`parse_config`].
pub fn load_config(path: impl AsRef<Path>) -> Result<ModelConfigFile, ModelError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|source| ModelError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    parse_config(&text, path)
}

/// One line for a TOML error: `line L: message (in [section])`.
fn describe_toml_error(text: &str, err: &toml::de::Error) -> String {
    let message = err.message().trim().to_string();
    let Some(span) = err.span() else {
        return message;
    };
    let before = &text[..span.start.min(text.len())];
    let line = before.matches('\n').count() + 1;
    // The innermost `[section]` header at or before the error.
    let section = before
        .lines()
        .chain(text[span.start.min(text.len())..].lines().take(1))
        .filter_map(|l| {
            let l = l.trim();
            (l.starts_with('[') && l.ends_with(']')).then(|| l.to_string())
        })
        .last();
    match section {
        Some(section) if !message.contains(&section) => {
            format!("line {line}: {message} (in {section})")
        }
        _ => format!("line {line}: {message}"),
    }
}
