//! `L_pts`: the confidence-weighted multi-scale gradient loss of the point branch (paper
//! Sec. 3.3), made well-posed by a confidence-weighted point term and the `-a log C`
//! regulariser (as in VGGT's confidence losses).

use burn::tensor::{Int, Tensor};

/// Number of scales of the gradient term (`k = 0..3`).
pub const POINT_LOSS_SCALES: usize = 4;

/// The three parts of [`point_loss`], each a scalar `[1]`, unweighted except as documented.
#[derive(Clone, Debug)]
pub struct PointLoss {
    /// `sum_k 2^-k G_k`: the confidence-weighted multi-scale gradient term.
    pub gradient: Tensor<1>,
    /// `sum_fg C |X - X_gt|_1 / N`: the confidence-weighted point term.
    pub point: Tensor<1>,
    /// `-a sum_fg log C / N`: the confidence regulariser (already multiplied by `a`).
    pub confidence: Tensor<1>,
}

impl PointLoss {
    /// `L_pts = gradient + point + confidence`.
    pub fn total(&self) -> Tensor<1> {
        self.gradient
            .clone()
            .add(self.point.clone())
            .add(self.confidence.clone())
    }
}

/// `L_pts` of predicted points `x` against `x_gt`, both `[B, 3, H, W]` (world coordinates per
/// source pixel), with the predicted confidence `conf` `[B, 1, H, W]` (`C = 1 + exp(.) > 0`)
/// and the foreground `mask` `[B, 1, H, W]` (a pixel is foreground where `mask > 0.5`):
///
/// `L_pts = mean_b [ sum_{k=0..3} 2^-k G_k + (1/N) sum_fg C |X - X_gt|_1 - (a/N) sum_fg log C ]`
///
/// - `G_k = (1/N_k) sum_d C_d |grad_d X_k - grad_d X_gt,k|_1`, with `X_k = X[::2^k, ::2^k]`
///   (every `2^k`-th row and column), `d` running over the forward differences in x and in y
///   whose two pixels are both foreground, `C_d` the mean confidence of those two pixels, and
///   `N_k` the number of foreground pixels of the subsampled mask;
/// - `|.|_1` sums over the three coordinates; `N = N_0` is the number of foreground pixels;
/// - the bracket is one image's loss (sums and counts over that image), averaged over the
///   batch: every image weighs the same, and the loss of a batch split over devices is the
///   pair-weighted mean of the shares' losses (what data-parallel training sums);
/// - every count is clamped to at least 1, so an empty mask gives a zero loss.
///
/// A prediction shifted by a constant has a zero gradient term and a positive point term.
pub fn point_loss(
    x: Tensor<4>,
    x_gt: Tensor<4>,
    conf: Tensor<4>,
    mask: Tensor<4>,
    alpha: f64,
) -> PointLoss {
    let [batch, channels, height, width] = x.dims();
    assert_eq!(
        x.dims(),
        x_gt.dims(),
        "L_pts: points and targets differ in shape"
    );
    assert_eq!(channels, 3, "L_pts: points must have 3 channels");
    assert_eq!(
        conf.dims(),
        [batch, 1, height, width],
        "L_pts: confidence must be [B, 1, H, W]"
    );
    assert_eq!(
        mask.dims(),
        [batch, 1, height, width],
        "L_pts: mask must be [B, 1, H, W]"
    );

    let fg = mask.greater_elem(0.5).float();
    let residual = x.sub(x_gt);
    let count = |m: &Tensor<4>| per_image(m.clone()).clamp_min(1.0);
    let n = count(&fg);

    let point = per_image(
        residual
            .clone()
            .abs()
            .sum_dim(1)
            .mul(conf.clone())
            .mul(fg.clone()),
    )
    .div(n.clone())
    .mean();
    // log C on the foreground only; background pixels read C = 1 (log 0), so any value there
    // (even 0) leaves the loss and its gradient finite.
    let background = fg.clone().neg().add_scalar(1.0);
    let confidence = per_image(conf.clone().mul(fg.clone()).add(background).log())
        .div(n)
        .mean()
        .mul_scalar(-alpha);

    let mut gradient: Option<Tensor<1>> = None;
    for k in 0..POINT_LOSS_SCALES {
        let step = 1usize << k;
        if height.div_ceil(step) < 2 && width.div_ceil(step) < 2 {
            break;
        }
        let (r, c, m) = (
            subsample(residual.clone(), step),
            subsample(conf.clone(), step),
            subsample(fg.clone(), step),
        );
        let term = gradient_term(r, c, m.clone())
            .div(count(&m))
            .mean()
            .mul_scalar(1.0 / step as f64);
        gradient = Some(match gradient {
            Some(g) => g.add(term),
            None => term,
        });
    }
    let gradient = gradient.unwrap_or_else(|| point.clone().mul_scalar(0.0));
    PointLoss {
        gradient,
        point,
        confidence,
    }
}

/// `sum_d C_d |grad_d r|_1` per image, `[B]`, over the x and y forward differences of the
/// residual `r = X - X_gt` (so `grad X - grad X_gt = grad r`) whose two pixels are both
/// foreground.
fn gradient_term(r: Tensor<4>, c: Tensor<4>, m: Tensor<4>) -> Tensor<1> {
    let [b, ch, h, w] = r.dims();
    let mut sum: Option<Tensor<1>> = None;
    // x differences: columns 1.. minus columns ..w-1; y differences: rows likewise.
    let along: [(usize, usize); 2] = [(3, w), (2, h)];
    for (dim, len) in along {
        if len < 2 {
            continue;
        }
        let cut = |t: Tensor<4>, channels: usize, from: usize| {
            let mut ranges = [0..b, 0..channels, 0..h, 0..w];
            ranges[dim] = from..from + len - 1;
            t.slice(ranges)
        };
        let diff = cut(r.clone(), ch, 1).sub(cut(r.clone(), ch, 0));
        let both = cut(m.clone(), 1, 1).mul(cut(m.clone(), 1, 0));
        let c_d = cut(c.clone(), 1, 1)
            .add(cut(c.clone(), 1, 0))
            .mul_scalar(0.5);
        let s = per_image(diff.abs().sum_dim(1).mul(c_d).mul(both));
        sum = Some(match sum {
            Some(acc) => acc.add(s),
            None => s,
        });
    }
    sum.expect("at least one side has two pixels")
}

/// The sum of each image of `t` `[B, C, H, W]`, `[B]`.
fn per_image(t: Tensor<4>) -> Tensor<1> {
    let [b, ..] = t.dims();
    t.sum_dim(1).sum_dim(2).sum_dim(3).reshape([b])
}

/// Every `step`-th row and column (rows and columns `0, step, 2 step, ...`).
fn subsample(t: Tensor<4>, step: usize) -> Tensor<4> {
    if step == 1 {
        return t;
    }
    let [_, _, h, w] = t.dims();
    let device = t.device();
    let index = |len: usize| {
        let idx: Vec<i64> = (0..len).step_by(step).map(|i| i as i64).collect();
        Tensor::<1, Int>::from_ints(idx.as_slice(), &device)
    };
    t.select(2, index(h)).select(3, index(w))
}
