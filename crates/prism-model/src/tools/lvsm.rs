//! Pretrained LVSM backbones (the paper initialises its backbone from one): the decoder-only
//! scene checkpoints that LVSM's authors publish, read and mapped into a [`Prism`].
//!
//! A checkpoint is a PyTorch file holding a dict whose `model` entry is the state dict of
//! LVSM's decoder-only model. Its tensors, by name (`L` blocks, width `d`, head dim `d_h`,
//! patch `p`; PyTorch's `Linear` weights are `[out, in]`, Burn's `[in, out]`):
//!
//! | LVSM tensor | shape | prism parameter |
//! |---|---|---|
//! | `image_tokenizer.1.weight` | `[d, 9 p^2]` | `tokenizer.source` |
//! | `target_pose_tokenizer.1.weight` | `[d, 6 p^2]` | `tokenizer.target` |
//! | `transformer_input_layernorm.weight` | `[d]` | `tokenizer.norm` |
//! | `transformer_blocks.i.norm1.weight` | `[d]` | block `attention_norm` |
//! | `transformer_blocks.i.attn.to_qkv.weight` | `[3d, d]` | block `attention.qkv` |
//! | `transformer_blocks.i.attn.q_norm.weight`, `k_norm` | `[d_h]` | `attention.q_norm`, `k_norm` |
//! | `transformer_blocks.i.attn.fc.weight` | `[d, d]` | `attention.out` |
//! | `transformer_blocks.i.norm2.weight` | `[d]` | block `mlp_norm` |
//! | `transformer_blocks.i.mlp.mlp.0.weight`, `.2` | `[4d, d]`, `[d, 4d]` | `mlp.fc_in`, `mlp.fc_out` |
//! | `image_token_decoder.0.weight` | `[d]` | `nvs_head.norm` |
//! | `image_token_decoder.1.weight` | `[3 p^2, d]` | `nvs_head.linear` |
//!
//! Tensors under `loss_computer.` (the perceptual loss's network) are skipped; any other tensor
//! prism has no place for (a bias, say) is an error, not silently dropped.
//!
//! The two models compute the same function: LayerNorms without bias and RMSNorm QK-norm with
//! `eps` 1e-5, GELU MLPs, no biases, no positional embedding, `[source, target]` token order,
//! patches `(ph pw c)` with the channel fastest, images entering as `2x - 1`, a sigmoid decoder.
//! One convention differs: LVSM's Plücker channels are `(o x d, d)`, prism's `(d, o x d)`. The
//! converter permutes the tokenizers' input columns accordingly, so that prism, fed its own rays,
//! computes what LVSM computes on LVSM's.
//!
//! When the config has more blocks than the checkpoint (the paper: 36 against LVSM's 24), a
//! [`BlockPlacement`] says which prism blocks receive LVSM's `L` blocks, in order. The others
//! are new: their output projections (`attention.out`, `mlp.fc_out`) are set to zero, so each
//! is the identity at the start and the converted model computes exactly LVSM's function (the
//! geometry parts enter through zero convolutions and a zero gate, so they do not change it
//! either).

use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use burn::module::Param;
use burn::nn::Linear;
use burn::store::pytorch::PytorchReader;
use burn::store::pytorch_reader::DType as PtDType;
use burn::tensor::{Device, Tensor, TensorData, bf16, f16};

use crate::config::PrismConfig;
use crate::error::ModelError;
use crate::heads::nvs::NvsOutput;
use crate::prism::Prism;
use crate::stages::block::PrismBlock;
use crate::tokenizer::{SOURCE_CHANNELS, TARGET_CHANNELS};
use crate::tools::info::named_parameters;

/// The dict entry of the checkpoint that holds the state dict.
pub(crate) const MODEL_KEY: &str = "model";
/// Prefix of the tensors that are skipped (LVSM's perceptual loss network).
pub(crate) const SKIPPED_PREFIX: &str = "loss_computer.";
/// `eps` of LVSM's LayerNorms and QK RMSNorms.
pub(crate) const LVSM_NORM_EPS: f64 = 1e-5;

/// Which prism blocks receive LVSM's blocks (`--blocks` of `prism convert lvsm`).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum BlockPlacement {
    /// LVSM's `L` blocks into prism's first `L` blocks; the later blocks are new (the default:
    /// stage I then holds LVSM's first `M` blocks, so the geometry branches fork from pretrained
    /// features, and the new blocks sit after all of LVSM's, where they start as the identity).
    #[default]
    First,
    /// LVSM's blocks into prism's last `L` blocks; the first blocks are new.
    Last,
    /// LVSM's block `i` into prism block `list[i]` (global indices, strictly increasing).
    List(Vec<usize>),
}

impl BlockPlacement {
    /// The prism block (global index) of each of LVSM's `layers` blocks, for a model of
    /// `blocks` blocks.
    ///
    /// # Errors
    /// More LVSM blocks than prism blocks, or a list that is not `layers` strictly increasing
    /// indices below `blocks`.
    pub fn resolve(&self, layers: usize, blocks: usize) -> Result<Vec<usize>, String> {
        if layers > blocks {
            return Err(format!(
                "model.stage_one_blocks + model.stage_three_blocks = {blocks}, the checkpoint \
                 has {layers} blocks (a prism config needs at least as many)"
            ));
        }
        match self {
            Self::First => Ok((0..layers).collect()),
            Self::Last => Ok((blocks - layers..blocks).collect()),
            Self::List(list) => {
                if list.len() != layers {
                    return Err(format!(
                        "--blocks lists {} blocks, the checkpoint has {layers}",
                        list.len()
                    ));
                }
                if let Some(&bad) = list.iter().find(|&&b| b >= blocks) {
                    return Err(format!(
                        "--blocks names block {bad}, the config has blocks 0..{blocks}"
                    ));
                }
                if list.windows(2).any(|w| w[0] >= w[1]) {
                    return Err("--blocks must be strictly increasing".into());
                }
                Ok(list.clone())
            }
        }
    }
}

impl FromStr for BlockPlacement {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "first" => Ok(Self::First),
            "last" => Ok(Self::Last),
            list => list
                .split(',')
                .map(|v| v.trim().parse::<usize>())
                .collect::<Result<Vec<_>, _>>()
                .map(Self::List)
                .map_err(|_| {
                    format!(
                        "`{s}`: expected `first`, `last` or a comma-separated list of block \
                         indices"
                    )
                }),
        }
    }
}

impl fmt::Display for BlockPlacement {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::First => f.write_str("first"),
            Self::Last => f.write_str("last"),
            Self::List(list) => {
                let parts: Vec<String> = list.iter().map(usize::to_string).collect();
                f.write_str(&parts.join(","))
            }
        }
    }
}

/// One tensor of a checkpoint, in f32, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct LvsmTensor {
    /// Extents, outermost first.
    pub shape: Vec<usize>,
    /// The values.
    pub values: Vec<f32>,
}

/// The sizes of an LVSM checkpoint's model, read from its tensors' shapes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LvsmLayout {
    /// Token width `d`.
    pub width: usize,
    /// Head dimension (the QK-norm's size).
    pub head_dim: usize,
    /// Patch size `p`.
    pub patch_size: usize,
    /// Transformer blocks `L`.
    pub layers: usize,
    /// Hidden width of the MLPs.
    pub mlp_hidden: usize,
}

impl LvsmLayout {
    /// Attention heads `d / d_h`.
    pub fn heads(&self) -> usize {
        self.width / self.head_dim.max(1)
    }
}

/// The tensors of an LVSM checkpoint.
#[derive(Clone, Debug)]
pub struct LvsmCheckpoint {
    /// Where they were read from (for messages).
    pub path: PathBuf,
    /// The state dict, without the skipped tensors.
    pub tensors: BTreeMap<String, LvsmTensor>,
    /// Names of the skipped tensors (`loss_computer.*`).
    pub skipped: Vec<String>,
}

/// What [`LvsmCheckpoint::convert`] did.
#[derive(Clone, Debug)]
pub struct LvsmConversion {
    /// The checkpoint's sizes.
    pub layout: LvsmLayout,
    /// The prism block (global index) that received each LVSM block.
    pub placement: Vec<usize>,
    /// Prism blocks that are new (identity at the start: zero output projections).
    pub new_blocks: Vec<usize>,
    /// LVSM tensors mapped.
    pub mapped: usize,
    /// Prism parameters (module paths) that keep their fresh initialisation, grouped: the
    /// geometry parts and the new blocks.
    pub fresh: Vec<FreshPart>,
    /// Remarks (e.g. a `norm_eps` other than LVSM's).
    pub notes: Vec<String>,
}

/// A part of the model that keeps its fresh initialisation.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct FreshPart {
    /// Its module path (e.g. `injection`, `stage_three.blocks.4`).
    pub module: String,
    /// Its parameter tensors.
    pub tensors: usize,
    /// Its parameters (scalars).
    pub parameters: usize,
}

impl LvsmCheckpoint {
    /// Reads a checkpoint with Burn's PyTorch reader: the `model` entry of the file's dict, or
    /// the file's tensors themselves when there is no such entry (a bare state dict).
    ///
    /// # Errors
    /// An unreadable file, or tensors of a type other than float.
    pub fn read(path: &Path) -> Result<Self, ModelError> {
        let fail = |message: String| ModelError::Lvsm {
            path: path.to_path_buf(),
            message,
        };
        let reader = match PytorchReader::with_top_level_key(path, MODEL_KEY) {
            Ok(reader) => reader,
            Err(_) => PytorchReader::new(path).map_err(|e| fail(e.to_string()))?,
        };
        let mut tensors = BTreeMap::new();
        let mut skipped = Vec::new();
        for (name, tensor) in reader.into_tensors() {
            let name = canonical_name(&name);
            if name.starts_with(SKIPPED_PREFIX) {
                // Not read at all (the perceptual loss's network is large).
                skipped.push(name);
                continue;
            }
            let bytes = tensor.read().map_err(|e| fail(e.to_string()))?;
            let values: Vec<f32> = match tensor.dtype() {
                PtDType::F32 => bytes
                    .chunks_exact(4)
                    .map(|b| f32::from_ne_bytes([b[0], b[1], b[2], b[3]]))
                    .collect(),
                PtDType::F64 => bytes
                    .chunks_exact(8)
                    .map(|b| f64::from_ne_bytes(b.try_into().expect("8 bytes")) as f32)
                    .collect(),
                PtDType::F16 => bytes
                    .chunks_exact(2)
                    .map(|b| f16::from_ne_bytes([b[0], b[1]]).to_f32())
                    .collect(),
                PtDType::BF16 => bytes
                    .chunks_exact(2)
                    .map(|b| bf16::from_ne_bytes([b[0], b[1]]).to_f32())
                    .collect(),
                other => {
                    return Err(fail(format!(
                        "tensor `{name}` is {other:?}, not a float tensor"
                    )));
                }
            };
            let shape = tensor.shape().to_vec();
            tensors.insert(name, LvsmTensor { shape, values });
        }
        skipped.sort();
        Ok(Self {
            path: path.to_path_buf(),
            tensors,
            skipped,
        })
    }

    /// A checkpoint from its tensors (state-dict names); `loss_computer.*` is set aside.
    pub fn from_tensors(path: &Path, all: BTreeMap<String, LvsmTensor>) -> Self {
        let mut tensors = BTreeMap::new();
        let mut skipped = Vec::new();
        for (name, tensor) in all {
            let name = canonical_name(&name);
            if name.starts_with(SKIPPED_PREFIX) {
                skipped.push(name);
            } else {
                tensors.insert(name, tensor);
            }
        }
        Self {
            path: path.to_path_buf(),
            tensors,
            skipped,
        }
    }

    fn error(&self, message: impl Into<String>) -> ModelError {
        ModelError::Lvsm {
            path: self.path.clone(),
            message: message.into(),
        }
    }

    fn get(&self, name: &str) -> Result<&LvsmTensor, ModelError> {
        self.tensors.get(name).ok_or_else(|| {
            self.error(format!(
                "no tensor `{name}`: not a decoder-only LVSM checkpoint{}",
                if name.contains("q_norm") {
                    " with QK-norm (prism's blocks always normalise queries and keys)"
                } else {
                    ""
                }
            ))
        })
    }

    /// The model's sizes, from the tensors' shapes (the head dim from the QK-norm's gain).
    ///
    /// # Errors
    /// Missing tensors or inconsistent shapes.
    pub fn layout(&self) -> Result<LvsmLayout, ModelError> {
        let norm = self.get("transformer_input_layernorm.weight")?;
        let width = norm.shape[0];
        let source = self.get("image_tokenizer.1.weight")?;
        let features = source.shape.get(1).copied().unwrap_or(0);
        let patch_size = (1..=features)
            .find(|p| SOURCE_CHANNELS * p * p == features)
            .ok_or_else(|| {
                self.error(format!(
                    "image_tokenizer.1.weight has {features} input features, not 9 p^2"
                ))
            })?;
        let prefix = "transformer_blocks.";
        let layers = self
            .tensors
            .keys()
            .filter_map(|k| {
                k.strip_prefix(prefix)?
                    .split('.')
                    .next()?
                    .parse::<usize>()
                    .ok()
            })
            .max()
            .map_or(0, |m| m + 1);
        if layers == 0 {
            return Err(self.error("no transformer_blocks.* tensors"));
        }
        let head_dim = self.get("transformer_blocks.0.attn.q_norm.weight")?.shape[0];
        let mlp_hidden = self.get("transformer_blocks.0.mlp.mlp.0.weight")?.shape[0];
        if head_dim == 0 || !width.is_multiple_of(head_dim) {
            return Err(self.error(format!(
                "head dim {head_dim} does not divide the width {width}"
            )));
        }
        Ok(LvsmLayout {
            width,
            head_dim,
            patch_size,
            layers,
            mlp_hidden,
        })
    }

    /// Checks that `config` can hold the checkpoint; the first mismatch is the error, naming
    /// the config field and both values.
    ///
    /// # Errors
    /// [`ModelError::Lvsm`] naming the first field that does not fit.
    pub fn check_fits(
        &self,
        config: &PrismConfig,
        placement: &BlockPlacement,
    ) -> Result<(LvsmLayout, Vec<usize>), ModelError> {
        let layout = self.layout()?;
        let mismatch = |field: &str, ours: usize, theirs: usize, what: &str| {
            self.error(format!(
                "does not fit the config: {field} = {ours}, the checkpoint's {what} is {theirs}"
            ))
        };
        if config.width != layout.width {
            return Err(mismatch("model.width", config.width, layout.width, "width"));
        }
        if config.heads != layout.heads() {
            return Err(mismatch(
                "model.heads",
                config.heads,
                layout.heads(),
                &format!(
                    "head count (width {} / head dim {})",
                    layout.width, layout.head_dim
                ),
            ));
        }
        if config.patch_size != layout.patch_size {
            return Err(mismatch(
                "model.patch_size",
                config.patch_size,
                layout.patch_size,
                "patch size",
            ));
        }
        if config.width * config.mlp_ratio != layout.mlp_hidden {
            return Err(mismatch(
                "model.mlp_ratio",
                config.mlp_ratio,
                layout.mlp_hidden / layout.width.max(1),
                "MLP ratio",
            ));
        }
        let placement = placement
            .resolve(layout.layers, config.num_blocks())
            .map_err(|m| self.error(format!("does not fit the config: {m}")))?;
        if config.nvs_output != NvsOutput::Direct {
            return Err(self.error(
                "does not fit the config: model.nvs_output must be \"direct\" (LVSM's decoder \
                 regresses the colours through a sigmoid)",
            ));
        }
        Ok((layout, placement))
    }

    /// The model of `config` with LVSM's weights (see the module docs); the geometry parts
    /// and the new blocks keep a fresh initialisation (seeded by the caller through
    /// `device.seed`).
    ///
    /// # Errors
    /// A checkpoint that does not fit the config ([`LvsmCheckpoint::check_fits`]), tensors
    /// of unexpected shapes, or tensors prism has no place for.
    pub fn convert(
        &self,
        config: &PrismConfig,
        placement: &BlockPlacement,
        device: &Device,
    ) -> Result<(Prism, LvsmConversion), ModelError> {
        let (layout, placement) = self.check_fits(config, placement)?;
        let mut model = config.try_init(device)?;
        let mut used = BTreeSet::new();
        let (d, p) = (layout.width, layout.patch_size);
        let (hidden, dh) = (layout.mlp_hidden, layout.head_dim);
        // Tokenizers: LVSM's channel order to prism's ((o x d, d) -> (d, o x d)).
        let source_order = [0, 1, 2, 6, 7, 8, 3, 4, 5];
        let target_order = [3, 4, 5, 0, 1, 2];
        let key = "image_tokenizer.1.weight";
        let source = Self::permuted_inputs(
            self.take(&mut used, key, &[d, SOURCE_CHANNELS * p * p])?,
            &source_order,
            p,
            d,
        );
        set_linear(&mut model.tokenizer.source, &source, device);
        let key = "target_pose_tokenizer.1.weight";
        let target = Self::permuted_inputs(
            self.take(&mut used, key, &[d, TARGET_CHANNELS * p * p])?,
            &target_order,
            p,
            d,
        );
        set_linear(&mut model.tokenizer.target, &target, device);
        let gain = self.take(&mut used, "transformer_input_layernorm.weight", &[d])?;
        set_gain(&mut model.tokenizer.norm.gamma, gain, device);

        let mut blocks: Vec<&mut PrismBlock> = model
            .stage_one
            .blocks
            .iter_mut()
            .chain(model.stage_three.blocks.iter_mut())
            .collect();
        for (i, &target) in placement.iter().enumerate() {
            let block = &mut *blocks[target];
            let name = |part: &str| format!("transformer_blocks.{i}.{part}");
            for (part, shape, dst) in [
                ("attn.to_qkv.weight", [3 * d, d], &mut block.attention.qkv),
                ("attn.fc.weight", [d, d], &mut block.attention.out),
                ("mlp.mlp.0.weight", [hidden, d], &mut block.mlp.fc_in),
                ("mlp.mlp.2.weight", [d, hidden], &mut block.mlp.fc_out),
            ] {
                set_linear(dst, self.take(&mut used, &name(part), &shape)?, device);
            }
            for (part, size, dst) in [
                ("norm1.weight", d, &mut block.attention_norm.gamma),
                ("norm2.weight", d, &mut block.mlp_norm.gamma),
                ("attn.q_norm.weight", dh, &mut block.attention.q_norm.gamma),
                ("attn.k_norm.weight", dh, &mut block.attention.k_norm.gamma),
            ] {
                set_gain(dst, self.take(&mut used, &name(part), &[size])?, device);
            }
        }
        let new_blocks: Vec<usize> = (0..blocks.len())
            .filter(|b| !placement.contains(b))
            .collect();
        for &b in &new_blocks {
            let block = &mut *blocks[b];
            for linear in [&mut block.attention.out, &mut block.mlp.fc_out] {
                let dims = linear.weight.val().dims();
                linear.weight = Param::from_tensor(Tensor::zeros(dims, device));
            }
        }
        drop(blocks);

        let gain = self.take(&mut used, "image_token_decoder.0.weight", &[d])?;
        set_gain(&mut model.nvs_head.norm.gamma, gain, device);
        let out = self.take(&mut used, "image_token_decoder.1.weight", &[3 * p * p, d])?;
        set_linear(&mut model.nvs_head.linear, out, device);

        let unused: Vec<&String> = self.tensors.keys().filter(|k| !used.contains(*k)).collect();
        if let Some(first) = unused.first() {
            return Err(self.error(format!(
                "{} tensor(s) prism has no place for, first `{first}` (a decoder-only LVSM \
                 without biases is expected)",
                unused.len()
            )));
        }
        let mut notes = Vec::new();
        if (config.norm_eps - LVSM_NORM_EPS).abs() > 1e-12 {
            notes.push(format!(
                "model.norm_eps = {} while LVSM's norms use {LVSM_NORM_EPS}: the outputs will \
                 differ slightly",
                config.norm_eps
            ));
        }
        let fresh = fresh_parts(&model, &new_blocks, config.stage_one_blocks);
        Ok((
            model,
            LvsmConversion {
                layout,
                placement,
                new_blocks,
                mapped: used.len(),
                fresh,
                notes,
            },
        ))
    }

    /// The tensor `name`, checked to have `shape`, marked as used.
    fn take(
        &self,
        used: &mut BTreeSet<String>,
        name: &str,
        shape: &[usize],
    ) -> Result<&LvsmTensor, ModelError> {
        used.insert(name.to_string());
        let t = self.get(name)?;
        if t.shape == shape {
            Ok(t)
        } else {
            Err(self.error(format!(
                "tensor `{name}` has shape {:?}, the config needs {shape:?}",
                t.shape
            )))
        }
    }

    /// A tokenizer weight `[d, p^2 C]` (features `(ph pw c)`) with its channels reordered:
    /// prism's channel `c` reads LVSM's channel `order[c]`.
    fn permuted_inputs(t: &LvsmTensor, order: &[usize], p: usize, d: usize) -> LvsmTensor {
        let channels = order.len();
        let features = p * p * channels;
        let mut values = vec![0.0; d * features];
        for row in 0..d {
            for pixel in 0..p * p {
                for (c, &from) in order.iter().enumerate() {
                    values[row * features + pixel * channels + c] =
                        t.values[row * features + pixel * channels + from];
                }
            }
        }
        LvsmTensor {
            shape: t.shape.clone(),
            values,
        }
    }
}

/// A state-dict name without the prefixes of PyTorch's wrappers (`module.` of
/// DistributedDataParallel, `_orig_mod.` of `torch.compile`).
fn canonical_name(name: &str) -> String {
    let mut name = name;
    for prefix in ["module.", "_orig_mod."] {
        name = name.strip_prefix(prefix).unwrap_or(name);
    }
    name.to_string()
}

/// Sets a Burn `Linear` (`[in, out]`) from a PyTorch weight (`[out, in]`).
fn set_linear(linear: &mut Linear, torch: &LvsmTensor, device: &Device) {
    let (out, inp) = (torch.shape[0], torch.shape[1]);
    let weight = Tensor::<2>::from_data(TensorData::new(torch.values.clone(), [out, inp]), device)
        .transpose();
    assert_eq!(
        weight.dims(),
        linear.weight.val().dims(),
        "the shapes were checked against the config"
    );
    linear.weight = Param::from_tensor(weight);
}

/// Sets a norm's gain.
fn set_gain(gain: &mut Param<Tensor<1>>, t: &LvsmTensor, device: &Device) {
    let value = Tensor::<1>::from_data(TensorData::new(t.values.clone(), [t.values.len()]), device);
    assert_eq!(value.dims(), gain.val().dims(), "the shapes were checked");
    *gain = Param::from_tensor(value);
}

/// The parts of `model` that keep their fresh initialisation: every module other than the
/// tokenizer, the blocks and the NVS decoder (the geometry parts and the injection), and the
/// new blocks.
fn fresh_parts(model: &Prism, new_blocks: &[usize], stage_one: usize) -> Vec<FreshPart> {
    let block_path = |b: usize| {
        if b < stage_one {
            format!("stage_one.blocks.{b}")
        } else {
            format!("stage_three.blocks.{}", b - stage_one)
        }
    };
    let new: Vec<String> = new_blocks.iter().map(|&b| block_path(b)).collect();
    let mut parts: Vec<FreshPart> = Vec::new();
    for (path, tensor) in named_parameters(model) {
        let n = tensor.dims()[0];
        let top = path.split('.').next().unwrap_or("");
        let module = if ["tokenizer", "stage_one", "stage_three", "nvs_head"].contains(&top) {
            match new.iter().find(|b| path.starts_with(&format!("{b}."))) {
                Some(b) => b.clone(),
                None => continue,
            }
        } else {
            top.to_string()
        };
        match parts.iter_mut().find(|p| p.module == module) {
            Some(part) => {
                part.tensors += 1;
                part.parameters += n;
            }
            None => parts.push(FreshPart {
                module,
                tensors: 1,
                parameters: n,
            }),
        }
    }
    parts
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn block_placements_resolve_and_check() {
        assert_eq!(BlockPlacement::First.resolve(3, 5).unwrap(), vec![0, 1, 2]);
        assert_eq!(BlockPlacement::Last.resolve(3, 5).unwrap(), vec![2, 3, 4]);
        let list: BlockPlacement = "0, 2,4".parse().unwrap();
        assert_eq!(list.resolve(3, 5).unwrap(), vec![0, 2, 4]);
        assert_eq!(list.to_string(), "0,2,4");
        assert!(list.resolve(3, 4).unwrap_err().contains("block 4"));
        assert!(list.resolve(2, 5).unwrap_err().contains("3 blocks"));
        assert!(
            BlockPlacement::List(vec![1, 0])
                .resolve(2, 5)
                .unwrap_err()
                .contains("increasing")
        );
        assert!(
            BlockPlacement::First
                .resolve(6, 4)
                .unwrap_err()
                .contains("stage_one_blocks + model.stage_three_blocks = 4")
        );
        assert!("middle".parse::<BlockPlacement>().is_err());
        assert_eq!(
            "first".parse::<BlockPlacement>().unwrap(),
            BlockPlacement::First
        );
    }
}
