//! Teacher pretraining (`prism train-teacher`): the full-attention model trained with the
//! objective of paper Sec. 3.3.

use std::path::PathBuf;
use std::sync::Arc;

use burn::tensor::Device;
use prism_data::dataset::PrismBatch;
use prism_losses::{LossInputs, LossTerms, Lpips, Objective};
use prism_model::Prism;

use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::step::StepLoss;
use crate::trainer::Task;

/// The teacher's objective on one device:
/// `L = l_nvs (MSE + l_lpips LPIPS)(I_t, I_t^gt)` (the terms of the heads and branches the
/// model does not have yet are not computed).
pub struct TeacherLoss {
    objective: Objective,
}

impl StepLoss for TeacherLoss {
    fn loss(&self, model: &Prism, batch: &PrismBatch, _step: usize) -> LossTerms {
        let out = model.forward(
            batch.source_image.clone(),
            batch.source_rays.clone(),
            batch.target_rays.clone(),
            &[],
        );
        self.objective
            .forward(LossInputs::new().with_nvs(out.image, batch.target_image.clone()))
            .expect("the teacher's objective has a weighted NVS term (checked when built)")
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

    fn step_loss(&self, config: &TrainingConfig, device: &Device) -> Result<Arc<dyn StepLoss>> {
        let weights = config.losses.clone();
        if weights.nvs <= 0.0 {
            return Err(TrainError::InvalidConfig {
                path: PathBuf::from("config"),
                field: "losses.nvs".into(),
                message: "the teacher trains the NVS decoder: its weight must be positive".into(),
            });
        }
        let lpips = if weights.lpips > 0.0 {
            Some(Lpips::load_default(self.lpips_weights.as_deref(), device)?)
        } else {
            None
        };
        Ok(Arc::new(TeacherLoss {
            objective: Objective::new(weights, lpips)?,
        }))
    }
}
