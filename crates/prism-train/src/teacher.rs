//! Teacher pretraining (`prism train-teacher`): the full-attention model trained with the
//! objective of paper Sec. 3.3.

use std::path::PathBuf;
use std::sync::Arc;

use burn::tensor::Device;
use prism_data::PrismBatch;
use prism_losses::{
    CentreInputs, LossInputs, LossTerms, Lpips, Objective, OpacityInputs, PointInputs, SmplxInputs,
    SmplxParams, pixel_rows,
};
use prism_model::{Prism, PrismOutput};

use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::step::StepLoss;
use crate::trainer::{Task, TaskData};

/// The teacher's objective on one device (paper Sec. 3.3, Eq. 6):
/// `L = l_nvs (MSE + l_lpips LPIPS)(I_t, I_t^gt) + l_gs (MSE + l_lpips LPIPS)(I_gs, I_t^gt)
///  + l_pts L_pts + l_smplx L_smplx`, plus the terms beyond the paper that the config weighs
/// (`L_opacity`, `L_centres`, `L_holes`).
///
/// A term is computed only when the model has the part it supervises (a config without the
/// point branch has no `L_pts`) and its weight is nonzero; `L_smplx` skips the pairs whose
/// subject has no `body.json`.
pub struct TeacherLoss {
    objective: Objective,
    background: [f32; 3],
}

impl TeacherLoss {
    /// The objective with `config`'s weights, LPIPS when its weight is nonzero, and the
    /// dataset's `background` (what the 3DGS head composites over).
    ///
    /// # Errors
    /// A zero NVS weight (the teacher trains the NVS decoder), or unreadable LPIPS weights.
    pub fn new(
        config: &TrainingConfig,
        background: [f32; 3],
        lpips_weights: Option<&std::path::Path>,
        device: &Device,
    ) -> Result<Self> {
        let weights = config.losses.clone();
        if weights.nvs <= 0.0 {
            return Err(TrainError::InvalidConfig {
                path: PathBuf::from("config"),
                field: "losses.nvs".into(),
                message: "the NVS decoder is always trained: its weight must be positive".into(),
            });
        }
        let lpips = if weights.lpips > 0.0 {
            Some(Lpips::load_default(lpips_weights, device)?)
        } else {
            None
        };
        Ok(Self {
            objective: Objective::new(weights, lpips)?,
            background,
        })
    }

    /// The forward pass of `model` on `batch` with the dataset's background, returning the
    /// hidden states of `hidden_layers` too (for distillation).
    pub fn forward(
        &self,
        model: &Prism,
        batch: &PrismBatch,
        hidden_layers: &[usize],
    ) -> PrismOutput {
        model.forward_batch(batch, self.background, hidden_layers)
    }

    /// The supervised pairs of the paper's objective for `model`'s output `out` on `batch`:
    /// the NVS image, and where the model has them the 3DGS render, the point map with its
    /// confidence and the SMPL-X parameters against the fit.
    pub fn inputs(&self, model: &Prism, batch: &PrismBatch, out: &PrismOutput) -> LossInputs {
        let mut inputs = LossInputs::new()
            .with_target(batch.target_image.clone())
            .with_nvs(out.image.clone());
        if let Some(gaussians) = &out.gaussians {
            if self.objective.weights().nvs_holes != 0.0 {
                // The holes of I_gs: the target's foreground its render leaves uncovered.
                let uncovered = gaussians.alpha.clone().neg().add_scalar(1.0);
                let holes = batch.target_mask.clone() * uncovered;
                inputs = inputs.with_nvs_holes(holes.detach());
            }
            let mask = pixel_rows(batch.source_mask.clone());
            inputs = inputs
                .with_gs(gaussians.image.clone())
                .with_gs_opacity(OpacityInputs {
                    logits: gaussians.gaussians.opacity_logits.clone(),
                    mask: mask.clone(),
                })
                .with_gs_centres(CentreInputs {
                    centres: gaussians.surface.clone(),
                    points: pixel_rows(batch.source_points.clone()),
                    mask,
                });
        }
        if let Some(points) = &out.points {
            inputs = inputs.with_pts(PointInputs {
                points: points.points.clone(),
                points_gt: batch.source_points.clone(),
                confidence: points.confidence.clone(),
                mask: batch.source_mask.clone(),
            });
        }
        if let (Some(branch), Some(smplx)) = (&model.smplx_branch, &out.smplx) {
            let device = smplx.betas.device();
            let fits = branch.targets(&batch.body_tensors(&device), &batch.source_cameras);
            inputs = inputs.with_smplx(SmplxInputs {
                pred: SmplxParams {
                    beta: smplx.betas.clone(),
                    theta: smplx.flat_rotations(),
                    psi: smplx.expression.clone(),
                    pi: smplx.camera.clone(),
                },
                gt: SmplxParams {
                    beta: fits.betas.clone(),
                    theta: fits.flat_rotations(),
                    psi: fits.expression.clone(),
                    pi: fits.camera.clone(),
                },
                has_fit: Some(fits.present),
            });
        }
        inputs
    }

    /// The weighted terms of `inputs`.
    pub fn terms(&self, inputs: LossInputs) -> LossTerms {
        self.objective
            .forward(inputs)
            .expect("the objective has a weighted NVS term (checked when built)")
    }
}

impl StepLoss for TeacherLoss {
    fn loss(&self, model: &Prism, batch: &PrismBatch, _step: usize) -> LossTerms {
        let out = self.forward(model, batch, &[]);
        let inputs = self.inputs(model, batch, &out);
        self.terms(inputs)
    }
}

/// The teacher pretraining job.
#[derive(Clone, Debug, Default)]
pub struct TeacherTask {
    /// LPIPS weight file (default: the project's search order).
    pub lpips_weights: Option<PathBuf>,
}

impl Task for TeacherTask {
    fn name(&self) -> &str {
        "teacher"
    }

    fn step_loss(
        &self,
        config: &TrainingConfig,
        data: &TaskData,
        device: &Device,
    ) -> Result<Arc<dyn StepLoss>> {
        Ok(Arc::new(TeacherLoss::new(
            config,
            data.background,
            self.lpips_weights.as_deref(),
            device,
        )?))
    }
}
