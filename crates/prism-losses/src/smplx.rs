//! `L_smplx`: supervision of the SMPL-X branch's regressed parameters (paper Sec. 3.3).

use burn::tensor::Tensor;

/// SMPL-X parameters of a batch, each `[B, n]`: what the SMPL-X branch regresses and what a
/// body-model fit provides.
#[derive(Clone, Debug)]
pub struct SmplxParams {
    /// Shape `beta`, `[B, 10]`.
    pub beta: Tensor<2>,
    /// Pose `theta`, flattened per subject: 55 joints x 3 axis-angle (`[B, 165]`), or, as the
    /// teacher's objective uses it, 55 rotation matrices (`[B, 495]`, see
    /// `prism_model::SmplxBranch`: matrices compare smoothly where axis-angle vectors jump).
    pub theta: Tensor<2>,
    /// Expression `psi`, `[B, 10]`.
    pub psi: Tensor<2>,
    /// Weak-perspective camera `pi = (s, tx, ty)` in the source view, `[B, 3]`.
    pub pi: Tensor<2>,
}

impl SmplxParams {
    /// The parameters from a pose given per joint, `theta` `[B, 55, 3]`.
    pub fn from_joint_pose(
        beta: Tensor<2>,
        theta: Tensor<3>,
        psi: Tensor<2>,
        pi: Tensor<2>,
    ) -> Self {
        let [batch, joints, three] = theta.dims();
        Self {
            beta,
            theta: theta.reshape([batch, joints * three]),
            psi,
            pi,
        }
    }

    fn parts(&self) -> [&Tensor<2>; 4] {
        [&self.beta, &self.theta, &self.psi, &self.pi]
    }
}

/// `L_smplx = (1 / B) sum_b m_b (|beta_b - beta*_b|^2 + |theta_b - theta*_b|^2 +
/// |psi_b - psi*_b|^2 + |pi_b - pi*_b|^2)`: the summed squared errors of the four parameter
/// groups, averaged over the batch, where the pairs whose subject has no fit count zero.
///
/// `has_fit` is `[B]` with 1 for subjects with a body-model fit and 0 for those without
/// (`None`: all have one); with no fit in the batch the loss is 0. Dividing by `B` (not by the
/// number of fits) keeps the loss a mean over pairs, so a batch split over devices gives the
/// pair-weighted mean of the shares' losses. Returns `[1]`.
pub fn smplx_loss(pred: &SmplxParams, gt: &SmplxParams, has_fit: Option<Tensor<1>>) -> Tensor<1> {
    let per_subject = pred
        .parts()
        .into_iter()
        .zip(gt.parts())
        .map(|(p, g)| {
            assert_eq!(p.dims(), g.dims(), "L_smplx: parameter shapes differ");
            let d = p.clone().sub(g.clone());
            d.clone().mul(d).sum_dim(1)
        })
        .reduce(|a, b| a.add(b))
        .expect("four parameter groups");
    let [batch, _] = per_subject.dims();
    let per_subject = per_subject.reshape([batch]);
    match has_fit {
        None => per_subject.mean(),
        Some(mask) => per_subject.mul(mask).mean(),
    }
}
