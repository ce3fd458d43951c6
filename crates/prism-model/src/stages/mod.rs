//! Stage I and stage III of the cascade (paper Sec. 3.2): runs of transformer blocks, with
//! taps on the hidden states that distillation reads.

pub(crate) mod attention;
pub(crate) mod block;

use burn::module::Module;
use burn::nn::Linear;
use burn::tensor::{DType, FloatDType, Tensor};

use block::PrismBlock;

/// Collects the hidden states (block outputs) of chosen blocks during a forward pass, in the
/// order they were asked for. Blocks are named by their global index `0..M+N` (stage I's
/// blocks first).
#[derive(Debug)]
pub struct HiddenStates {
    wanted: Vec<usize>,
    found: Vec<Option<Tensor<3>>>,
}

impl HiddenStates {
    /// Taps the outputs of the blocks `wanted` (global indices; repeats allowed).
    pub fn new(wanted: &[usize]) -> Self {
        Self {
            wanted: wanted.to_vec(),
            found: vec![None; wanted.len()],
        }
    }

    /// Whether nothing is asked for.
    pub fn is_empty(&self) -> bool {
        self.wanted.is_empty()
    }

    /// Whether the output of block `index` is asked for.
    pub fn wants(&self, index: usize) -> bool {
        self.wanted.contains(&index)
    }

    /// Records `x` as the output of block `index` if that block was asked for.
    pub fn record(&mut self, index: usize, x: &Tensor<3>) {
        for (slot, &wanted) in self.found.iter_mut().zip(&self.wanted) {
            if wanted == index {
                *slot = Some(x.clone());
            }
        }
    }

    /// The recorded output of block `index`, if it was asked for and has run.
    pub fn state(&self, index: usize) -> Option<Tensor<3>> {
        self.wanted
            .iter()
            .zip(&self.found)
            .find(|(w, f)| **w == index && f.is_some())
            .and_then(|(_, f)| f.clone())
    }

    /// The recorded states, in the order asked for.
    ///
    /// # Panics
    /// If a block that was asked for did not run (an index beyond the network).
    pub fn into_vec(self) -> Vec<Tensor<3>> {
        self.found
            .into_iter()
            .zip(self.wanted)
            .map(|(state, index)| {
                state.unwrap_or_else(|| panic!("hidden state of block {index} was not computed"))
            })
            .collect()
    }
}

/// `x` in `dtype` (no op when it already is).
pub(crate) fn cast<const D: usize>(x: Tensor<D>, dtype: impl Into<DType>) -> Tensor<D> {
    let dtype = dtype.into();
    if x.dtype() == dtype {
        x
    } else {
        x.cast(FloatDType::from(dtype))
    }
}

/// `layer` on `x`, its product's operands rounded to bf16 when `bf16_products` (the blocks'
/// bf16 on the CPU backends, see [`prism_kernels::linear_bf16`]), in f32 otherwise
/// ([`prism_kernels::linear`]: the host kernel on the CPU backends, Burn's product elsewhere).
pub(crate) fn linear<const D: usize>(
    layer: &Linear,
    x: Tensor<D>,
    bf16_products: bool,
) -> Tensor<D> {
    if bf16_products {
        prism_kernels::linear_bf16(layer, x)
    } else {
        prism_kernels::linear(layer, x)
    }
}

/// Runs `blocks` on `x`, tapping block outputs; the first block has global index `first`.
/// Each block computes in its own precision ([`crate::Precision`]; the first casts `x` to it),
/// and the output and the tapped states are cast back to `x`'s dtype.
fn run_blocks(
    blocks: &[PrismBlock],
    x: Tensor<3>,
    first: usize,
    hidden: &mut HiddenStates,
) -> Tensor<3> {
    let outer = x.dtype();
    let mut x = x;
    for (offset, block) in blocks.iter().enumerate() {
        x = block.forward(x);
        if hidden.wants(first + offset) {
            hidden.record(first + offset, &cast(x.clone(), outer));
        }
    }
    cast(x, outer)
}

/// Stage I, the encoder: `T_mid = T^(0 -> M-1)(T_in)`.
#[derive(Module, Debug)]
pub struct StageOne {
    /// The `M` blocks, global indices `0..M`.
    pub blocks: Vec<PrismBlock>,
}

impl StageOne {
    /// `T_mid` from `T_in` (`[B, T, d]`), recording the requested hidden states.
    pub fn forward(&self, t_in: Tensor<3>, hidden: &mut HiddenStates) -> Tensor<3> {
        run_blocks(&self.blocks, t_in, 0, hidden)
    }
}

/// Stage III, the decoder: `T_out = T_dec^(0 -> N-1)(T'_mid)`.
#[derive(Module, Debug)]
pub struct StageThree {
    /// The `N` blocks, global indices `M..M+N`.
    pub blocks: Vec<PrismBlock>,
}

impl StageThree {
    /// `T_out` from `T'_mid` (`[B, T, d]`) through the first `blocks` blocks (all `N` for
    /// `T_out`; fewer where only earlier hidden states are wanted), recording the requested
    /// hidden states; `first` is the global index of this stage's first block (`M`).
    pub fn forward(
        &self,
        t_mid: Tensor<3>,
        first: usize,
        blocks: usize,
        hidden: &mut HiddenStates,
    ) -> Tensor<3> {
        let blocks = blocks.min(self.blocks.len());
        run_blocks(&self.blocks[..blocks], t_mid, first, hidden)
    }
}
