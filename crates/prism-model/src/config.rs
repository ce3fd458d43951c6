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

use crate::distill::DistillConfig;
use crate::error::ModelError;
use crate::heads::gaussian::{GsColour, GsDepth};
use crate::heads::nvs::NvsOutput;
use crate::stages::attention::{AttentionKind, FeatureMap};

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
            fn expecting(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
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
    /// Build the SMPL-X branch and inject its position-map features `F_smpl` (the paper's
    /// ablation "w/o pos. map feat." is `false`).
    #[config(default = false)]
    pub smplx_branch: bool,
    /// Build the point branch and inject its point-map features `F_pts` (the paper's ablation
    /// "w/o point map feat." is `false`).
    #[config(default = false)]
    pub point_branch: bool,
    /// Build the 3DGS head (`I_gs`, trained with `L_gs`).
    #[config(default = false)]
    pub gs_head: bool,
    /// The body model of the SMPL-X branch: `procedural:SEED` (the procedural humanoid that
    /// `prism data synth` uses with seed 0) or the path of an SMPL-X `.npz`. Must be the model
    /// the dataset's `body.json` fits were made with.
    #[config(default = "String::from(\"procedural:0\")")]
    pub body_model: String,
    /// World height in metres given to the predicted posed body when it is placed from the
    /// weak-perspective camera (see `geometry/smplx/placement.rs`; 1.77 for the procedural
    /// people scaled to 1.80 m with hair and shoes).
    #[config(default = 1.77)]
    pub body_height: f64,
    /// Width of the SMPL-X branch's adapter and regressor.
    #[config(default = 128)]
    pub smplx_width: usize,
    /// Side `R` of each triplane plane (texels).
    #[config(default = 64)]
    pub triplane_resolution: usize,
    /// Channels of the triplane and of `F_smpl` (paper: 32).
    #[config(default = 32)]
    pub triplane_channels: usize,
    /// Channels of the point branch's DPT head.
    #[config(default = 64)]
    pub point_width: usize,
    /// Learned feature channels carried by each point (`F_pts` has 2 more: coverage and depth).
    #[config(default = 8)]
    pub point_features: usize,
    /// The points also carry their source pixel's colour into `F_pts` (3 more channels): stage
    /// III sees the source warped into the target view at the point branch's depths.
    #[config(default = false)]
    pub point_colours: bool,
    /// Distance (metres) from the source camera at which the point branch and the 3DGS head
    /// place their points at initialisation (the protocol's orbit radius, 2 m).
    #[config(default = 2.0)]
    pub depth_prior: f64,
    /// The point branch starts each source pixel's distance at the plane through the person
    /// that a person of this height (metres), spanning the source's foreground rows, stands in
    /// (`geometry/points/anchor.rs`), instead of at `depth_prior`: the distance judged from the
    /// photo and its camera. 0 (the default) keeps `depth_prior`.
    #[config(default = 0.0)]
    pub anchor_height: f64,
    /// Initial value of the gates `g_smpl` and `g_pts` (`g_res` starts at 0). Not 0: behind a
    /// zero-initialised convolution a zero gate never receives a gradient (see
    /// `geometry/injection.rs`).
    #[config(default = 1.0)]
    pub gate_init: f64,
    /// The 3DGS head's colours: `"regressed"` (the paper), `"source"` (the source pixel's
    /// colour plus a learned correction), `"pixel"` (the source pixel's colour as it is) or
    /// `"flow"` (see `heads/gaussian.rs`).
    #[config(default = "GsColour::Regressed")]
    pub gs_colour: GsColour,
    /// The 3DGS head's distances: `"head"` (the paper) or `"points"`, the point branch's
    /// distance (supervised by `L_pts`) plus a learned correction. `"points"` needs
    /// `point_branch`.
    #[config(default = "GsDepth::Head")]
    pub gs_depth: GsDepth,
    /// The 3DGS head's Gaussian scale at initialisation, in source-pixel footprints (paper 1;
    /// strictly between 0.1 and 10).
    #[config(default = 1.0)]
    pub gs_scale: f64,
    /// Start the 3DGS head's opacities from a key of the source image on the background colour
    /// (background pixels transparent, the person opaque; see `heads/gaussian.rs`).
    #[config(default = false)]
    pub gs_keying: bool,
    /// The 3DGS head's rim Gaussians: the source silhouette's edge pixels start as Gaussians
    /// reaching this far (metres) back along their rays, to cover the sides a turned view shows
    /// (`heads/rim.rs`). 0 (the default) for none.
    #[config(default = 0.0)]
    pub gs_rim_depth: f64,
    /// The NVS decoder's output: `"direct"` (the paper: `sigmoid` of the regressed colours) or
    /// `"residual"` (a correction of the 3DGS head's render `I_gs`; needs `gs_head`).
    #[config(default = "NvsOutput::Direct")]
    pub nvs_output: NvsOutput,
    /// The residual NVS decoder also sees `I_gs`: each target token gets its render patch
    /// (embedded, then one hidden layer; see `heads/nvs.rs`). Needs `nvs_output = "residual"`.
    #[config(default = false)]
    pub nvs_sees_render: bool,
    /// The NVS decoder's and the 3DGS head's output resolution: 0 (the paper) gives every
    /// pixel of a patch its own value (`Linear(d, C p^2)` and an unpatchify); `f`, a divisor
    /// of `patch_size`, gives `f x f` values per token, upsampled bilinearly to the pixels, so
    /// that the corrections and Gaussians vary smoothly instead of pixel by pixel.
    #[config(default = 0)]
    pub head_upsample: usize,
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
        for (field, value) in [
            ("model.smplx_width", self.smplx_width),
            ("model.triplane_resolution", self.triplane_resolution),
            ("model.triplane_channels", self.triplane_channels),
            ("model.point_features", self.point_features),
        ] {
            if value == 0 {
                return fail(field, "must be positive".into());
            }
        }
        if self.point_width < 2 {
            return fail("model.point_width", "must be at least 2".into());
        }
        for (field, value) in [
            ("model.body_height", self.body_height),
            ("model.depth_prior", self.depth_prior),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return fail(field, format!("{value} is not a positive number"));
            }
        }
        if !(self.anchor_height.is_finite() && self.anchor_height >= 0.0) {
            return fail(
                "model.anchor_height",
                format!("{} is not 0 or a positive number", self.anchor_height),
            );
        }
        if !(self.gs_rim_depth.is_finite() && self.gs_rim_depth >= 0.0) {
            return fail(
                "model.gs_rim_depth",
                format!("{} is not 0 or a positive number", self.gs_rim_depth),
            );
        }
        if !self.gate_init.is_finite() {
            return fail(
                "model.gate_init",
                format!("{} is not a number", self.gate_init),
            );
        }
        if !(self.gs_scale > 0.1 && self.gs_scale < 10.0) {
            return fail(
                "model.gs_scale",
                format!("{} is not strictly between 0.1 and 10", self.gs_scale),
            );
        }
        if self.head_upsample > 0 && !self.patch_size.is_multiple_of(self.head_upsample) {
            return fail(
                "model.head_upsample",
                format!(
                    "{} does not divide patch_size {} (0 for a value per pixel)",
                    self.head_upsample, self.patch_size
                ),
            );
        }
        if self.gs_depth == GsDepth::Points && !self.point_branch {
            return fail(
                "model.gs_depth",
                "\"points\" takes the point branch's depth: set point_branch = true".into(),
            );
        }
        if self.nvs_sees_render && self.nvs_output != NvsOutput::Residual {
            return fail(
                "model.nvs_sees_render",
                "the decoder sees the render it corrects: set nvs_output = \"residual\"".into(),
            );
        }
        if self.nvs_output == NvsOutput::Residual && !self.gs_head {
            return fail(
                "model.nvs_output",
                "\"residual\" corrects the 3DGS head's render: set gs_head = true".into(),
            );
        }
        if self.smplx_branch {
            crate::geometry::smplx::body_model::check_body_model(&self.body_model)?;
        }
        self.attention_kinds().map(|_| ())
    }

    /// This config with the paper's output parameterisation: the 3DGS head regresses colours
    /// and depths at a one-pixel scale without keying, and the NVS decoder regresses colours,
    /// both a value per pixel (`gs_colour = "regressed"`, `gs_depth = "head"`, `gs_scale = 1`,
    /// `gs_keying = false`, `gs_rim_depth = 0`, `nvs_output = "direct"`, `head_upsample = 0`).
    pub fn paper_outputs(self) -> Self {
        Self {
            gs_colour: GsColour::Regressed,
            gs_depth: GsDepth::Head,
            gs_scale: 1.0,
            gs_keying: false,
            gs_rim_depth: 0.0,
            nvs_output: NvsOutput::Direct,
            head_upsample: 0,
            ..self
        }
    }

    /// Whether any geometry part (SMPL-X branch, point branch, 3DGS head) is enabled: then the
    /// forward pass needs the cameras ([`crate::Prism::forward_views`]).
    pub fn has_geometry(&self) -> bool {
        self.smplx_branch || self.point_branch || self.gs_head
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
    let text = std::fs::read_to_string(path).map_err(|cause| ModelError::Read {
        path: path.to_path_buf(),
        cause,
    })?;
    parse_config(&text, path)
}

/// One line for an error of `toml` in `text`: `line L: message (in [section])`, the section
/// being the innermost `[section]` header at or before the error; without a position, the
/// message alone. Every section of a config file reports its errors this way, whichever crate
/// parses it.
pub fn describe_toml_error(text: &str, err: &toml::de::Error) -> String {
    let message = err.message().trim().to_string();
    let Some(span) = err.span() else {
        return message;
    };
    let start = span.start.min(text.len());
    let before = &text[..start];
    let line = before.matches('\n').count() + 1;
    // The innermost `[section]` header at or before the error.
    let section = before
        .lines()
        .chain(text[start..].lines().take(1))
        .filter_map(|l| {
            // A header may carry a comment: `[train]  # ...`.
            let l = l.split('#').next().unwrap_or("").trim();
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::distill::DistillLayers;
    use std::path::PathBuf;

    fn configs_dir() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs")
    }

    const TINY_MODEL: &str = r#"
[model]
width = 64
heads = 4
patch_size = 8
stage_one_blocks = 2
stage_three_blocks = 4
resolution = 64
mlp_ratio = 4
attention = "full"
linear_feature_map = "relu"
linear_eps = 1e-6
init_std = 0.02
norm_eps = 1e-5
smplx_branch = true
point_branch = true
gs_head = true
body_model = "procedural:0"
body_height = 1.77
smplx_width = 64
triplane_resolution = 32
triplane_channels = 32
point_width = 32
point_features = 8
point_colours = false
depth_prior = 2.0
anchor_height = 0.0
gate_init = 1.0
gs_colour = "regressed"
gs_depth = "head"
gs_scale = 1.0
gs_keying = false
gs_rim_depth = 0.0
nvs_output = "direct"
nvs_sees_render = false
head_upsample = 0

[distill]
mode = "progressive"
group_size = 3
start = 1
interval = 1
layers = 2
steps = 10
batch_size = 2
lr = 1e-4
"#;

    fn parse(text: &str) -> Result<ModelConfigFile, ModelError> {
        parse_config(text, Path::new("test.toml"))
    }

    #[test]
    fn shipped_configs_load() {
        for (name, width, blocks, resolution) in [
            ("tiny", 64, 6, 64),
            ("small", 128, 12, 128),
            ("paper", 768, 36, 512),
        ] {
            let file = load_config(configs_dir().join(format!("{name}.toml"))).unwrap();
            assert_eq!(file.model.width, width, "{name}");
            assert_eq!(file.model.num_blocks(), blocks, "{name}");
            assert_eq!(file.model.resolution, resolution, "{name}");
            assert_eq!(
                file.model.attention_kinds().unwrap(),
                vec![AttentionKind::Full; blocks]
            );
        }
        let paper = load_config(configs_dir().join("paper.toml")).unwrap();
        assert_eq!(
            (paper.model.heads, paper.model.patch_size),
            (12, 8),
            "paper: 12 heads, patch 8"
        );
        assert_eq!(
            (paper.model.stage_one_blocks, paper.model.stage_three_blocks),
            (12, 24)
        );
        assert_eq!(
            (
                paper.distill.group_size,
                paper.distill.start,
                paper.distill.interval
            ),
            (6, 5000, 5000)
        );
    }

    #[test]
    fn unknown_sections_are_ignored() {
        let text = format!(
            "[losses]\nnvs = 1.0\n\n[train]\nsteps = 10\nlr = 1e-4\n{TINY_MODEL}\n[data]\nroot = \"x\"\n"
        );
        let file = parse(&text).unwrap();
        assert_eq!(file.model.heads, 4);
        assert_eq!(file.distill.layers, DistillLayers::Count(2));
    }

    #[test]
    fn attention_patterns_in_every_form() {
        let with = |value: &str| TINY_MODEL.replace("attention = \"full\"", value);
        let kinds = |value: &str| {
            parse(&with(value))
                .unwrap()
                .model
                .attention_kinds()
                .unwrap()
        };
        use AttentionKind::{Full as F, Linear as L};
        assert_eq!(kinds("attention = \"linear\""), vec![L; 6]);
        assert_eq!(kinds("attention = \"LLF LLF\""), vec![L, L, F, L, L, F]);
        assert_eq!(
            kinds("attention = [\"full\", \"linear\", \"full\", \"linear\", \"full\", \"linear\"]"),
            vec![F, L, F, L, F, L]
        );
        let err = parse(&with("attention = \"LLF\"")).unwrap_err().to_string();
        assert!(
            err.contains("test.toml") && err.contains("model.attention"),
            "{err}"
        );
        let err = parse(&with("attention = \"LXF\"")).unwrap_err().to_string();
        assert!(err.contains("test.toml") && err.contains("`X`"), "{err}");
        // The compact form round-trips through serde (checkpoints store configs as JSON).
        let model = parse(&with("attention = \"LFLFLF\"")).unwrap().model;
        let json = serde_json::to_string(&model).unwrap();
        assert!(json.contains("\"LFLFLF\""), "{json}");
        let back: PrismConfig = serde_json::from_str(&json).unwrap();
        assert_eq!(back.attention, model.attention);
    }

    #[test]
    fn errors_name_the_file_and_the_field() {
        let missing = TINY_MODEL.replace("heads = 4\n", "");
        let err = parse(&missing).unwrap_err().to_string();
        assert!(err.starts_with("test.toml"), "{err}");
        assert!(err.contains("heads") && err.contains("[model]"), "{err}");

        let mistyped = TINY_MODEL.replace("heads = 4", "heads = \"four\"");
        let err = parse(&mistyped).unwrap_err().to_string();
        assert!(err.contains("test.toml") && err.contains("line 4"), "{err}");

        let indivisible = TINY_MODEL.replace("heads = 4", "heads = 5");
        let err = parse(&indivisible).unwrap_err().to_string();
        assert!(
            err.contains("test.toml") && err.contains("model.heads"),
            "{err}"
        );

        let bad_res = TINY_MODEL.replace("resolution = 64", "resolution = 60");
        let err = parse(&bad_res).unwrap_err().to_string();
        assert!(err.contains("model.resolution"), "{err}");

        let bad_group = TINY_MODEL.replace("group_size = 3", "group_size = 0");
        let err = parse(&bad_group).unwrap_err().to_string();
        assert!(err.contains("distill.group_size"), "{err}");

        let no_distill = TINY_MODEL.split("[distill]").next().unwrap().to_string();
        let err = parse(&no_distill).unwrap_err().to_string();
        assert!(err.contains("distill"), "{err}");

        let err = load_config("/nonexistent/prism.toml")
            .unwrap_err()
            .to_string();
        assert!(err.contains("/nonexistent/prism.toml"), "{err}");
    }

    /// [`describe_toml_error`] (which the other crates' sections use too) names the line and
    /// the section, also under a header that carries a comment.
    #[test]
    fn toml_errors_name_the_line_and_the_section() {
        let describe = |text: &str| {
            let err = toml::from_str::<ModelConfigFile>(text).unwrap_err();
            describe_toml_error(text, &err)
        };
        let mistyped = TINY_MODEL.replace("heads = 4", "heads = \"four\"");
        let plain = describe(&mistyped);
        assert!(
            plain.starts_with("line 4: ") && plain.ends_with(" (in [model])"),
            "{plain}"
        );
        let commented = describe(&mistyped.replace("[model]", "[model]  # the network"));
        assert_eq!(commented, plain);
        let missing = describe(&TINY_MODEL.replace("group_size = 3\n", ""));
        assert!(
            missing.contains("group_size") && missing.matches("[distill]").count() == 1,
            "{missing}"
        );
    }
}
