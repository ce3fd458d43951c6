//! The injection point between stage I and stage III (paper Sec. 3.2, Stage II, Eq. 4):
//!
//! `T'_mid = T_mid + g_smpl Flatten(Conv_zero(F_smpl)) + g_pts Flatten(Conv_zero(F_pts)) + g_res T_in`
//!
//! - `Conv_zero`: a convolution with kernel `p` and stride `p` from a feature map to width `d`,
//!   weights and bias initialised to zero (ControlNet's zero convolution). A kernel-`p`,
//!   stride-`p` convolution sees every patch exactly once, so it is computed as a linear map of
//!   the patchified map (`patchify`, then `Linear(p^2 C, d)` with bias): the same function,
//!   without a convolution's backward pass (slow on ndarray).
//! - Its tokens are the target positions of the sequence; the source positions get zeros (the
//!   feature maps are rendered in the target view).
//! - Gates: learned scalars. `g_res` (the long skip from `T_in`) starts at 0. `g_smpl` and
//!   `g_pts` start at `gate_init`: with a zero convolution behind a gate, a gate that also
//!   started at 0 would never move (its gradient is the zero convolution's output, and the
//!   convolution's gradient is scaled by the gate: both stay exactly 0 under any optimizer), so
//!   the shipped configs use `gate_init = 1`, ControlNet's choice.
//!
//! At initialisation every added term is exactly zero (`0 * x` and a zero map), so `T'_mid`
//! equals `T_mid` bit for bit and the model equals the plain backbone.

use burn::config::Config;
use burn::module::{Module, Param};
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::tensor::{Device, Tensor};

use crate::tokenizer::patch::patchify;

/// Configuration of an [`Injection`].
#[derive(Config, Debug)]
pub(crate) struct InjectionConfig {
    /// Token width `d`.
    pub width: usize,
    /// Patch size `p` (kernel and stride of the zero convolutions).
    pub patch_size: usize,
    /// Channels of `F_smpl`; `None` without the SMPL-X branch.
    pub smpl_channels: Option<usize>,
    /// Channels of `F_pts`; `None` without the point branch.
    pub pts_channels: Option<usize>,
    /// Initial value of `g_smpl` and `g_pts`.
    #[config(default = 1.0)]
    pub gate_init: f64,
}

impl InjectionConfig {
    /// Builds the injection: zero convolutions, `g_res = 0`, the branch gates at `gate_init`.
    pub(crate) fn init(&self, device: &Device) -> Injection {
        let p2 = self.patch_size * self.patch_size;
        let zero_conv = |channels: usize| ZeroConv {
            linear: LinearConfig::new(p2 * channels, self.width)
                .with_bias(true)
                .with_initializer(Initializer::Zeros)
                .init(device),
            channels,
        };
        let gate = |value: f64| Param::from_tensor(Tensor::<1>::full([1], value, device));
        Injection {
            smpl_conv: self.smpl_channels.map(zero_conv),
            pts_conv: self.pts_channels.map(zero_conv),
            gate_smpl: self.smpl_channels.map(|_| gate(self.gate_init)),
            gate_pts: self.pts_channels.map(|_| gate(self.gate_init)),
            gate_res: gate(0.0),
            patch_size: self.patch_size,
        }
    }
}

/// `Conv_zero`: a kernel-`p`, stride-`p` convolution to width `d` as a linear map of patches.
#[derive(Module, Debug)]
pub struct ZeroConv {
    /// `Linear(p^2 C, d)` with bias, both zero at initialisation.
    pub linear: Linear,
    #[module(skip)]
    channels: usize,
}

impl ZeroConv {
    /// `Flatten(Conv(x))`: `[B, C, H, W]` to tokens `[B, (H/p)(W/p), d]`, patches row-major.
    pub fn forward(&self, x: Tensor<4>, patch_size: usize) -> Tensor<3> {
        assert_eq!(
            x.dims()[1],
            self.channels,
            "Conv_zero expects {} channels",
            self.channels
        );
        prism_kernels::linear(&self.linear, patchify(x, patch_size))
    }
}

/// The injection (see the module docs). Branches that are switched off have no convolution
/// and no gate.
#[derive(Module, Debug)]
pub struct Injection {
    /// `Conv_zero` of `F_smpl`.
    pub smpl_conv: Option<ZeroConv>,
    /// `Conv_zero` of `F_pts`.
    pub pts_conv: Option<ZeroConv>,
    /// `g_smpl`, `[1]`.
    pub gate_smpl: Option<Param<Tensor<1>>>,
    /// `g_pts`, `[1]`.
    pub gate_pts: Option<Param<Tensor<1>>>,
    /// `g_res`, `[1]`.
    pub gate_res: Param<Tensor<1>>,
    patch_size: usize,
}

/// `gate * tokens` for a `[1]` gate.
fn gated(gate: &Param<Tensor<1>>, tokens: Tensor<3>) -> Tensor<3> {
    tokens * gate.val().reshape([1, 1, 1])
}

impl Injection {
    /// `T'_mid` from `T_mid` and `T_in` (`[B, T_s + T_t, d]`, source tokens first) and the
    /// feature maps of the enabled branches (`[B, C, H, W]` in the target view).
    ///
    /// # Panics
    /// If a map is given for a branch without a convolution, or a branch's map is missing.
    pub fn forward(
        &self,
        t_mid: Tensor<3>,
        t_in: &Tensor<3>,
        f_smpl: Option<Tensor<4>>,
        f_pts: Option<Tensor<4>>,
    ) -> Tensor<3> {
        let [b, total, d] = t_mid.dims();
        let mut target: Option<Tensor<3>> = None;
        let mut add = |term: Tensor<3>| {
            target = Some(match target.take() {
                Some(t) => t + term,
                None => term,
            });
        };
        match (&self.smpl_conv, &self.gate_smpl, f_smpl) {
            (Some(conv), Some(gate), Some(f)) => add(gated(gate, conv.forward(f, self.patch_size))),
            (None, None, None) => {}
            _ => panic!("F_smpl must be given exactly when the SMPL-X branch is enabled"),
        }
        match (&self.pts_conv, &self.gate_pts, f_pts) {
            (Some(conv), Some(gate), Some(f)) => add(gated(gate, conv.forward(f, self.patch_size))),
            (None, None, None) => {}
            _ => panic!("F_pts must be given exactly when the point branch is enabled"),
        }
        let mut out = t_mid + gated(&self.gate_res, t_in.clone());
        if let Some(target) = target {
            let [_, targets, _] = target.dims();
            let zeros = Tensor::<3>::zeros([b, total - targets, d], &target.device());
            out = out + Tensor::cat(vec![zeros, target], 1);
        }
        out
    }
}
