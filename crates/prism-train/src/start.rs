//! Where a run starts: its folder prepared (or the checkpoint it resumes read and checked)
//! and the model it starts from.

use std::fs;
use std::path::Path;

use burn::module::{Module, ModuleVisitor, Param};
use burn::tensor::{Device, Tensor};
use prism_core::backend::is_served;
use prism_model::{Precision, Prism};

use crate::checkpoint::{
    Checkpoint, check_architecture, check_resumable, latest_checkpoint, recover_checkpoints,
};
use crate::config::TrainingConfig;
use crate::error::{Result, TrainError};
use crate::loss_scale::{LossScaleConfig, LossScaleState, LossScaler};
use crate::trainer::{RunOptions, Task};

/// The run folder's copy of the config it was started with.
pub const RUN_CONFIG_FILE: &str = "config.toml";

/// The model a run starts from.
pub struct Start {
    /// The model, on the main training device.
    pub model: Prism,
    /// Steps already done (those of the resumed checkpoint, else 0).
    pub step: usize,
    /// The blocks newly initialised when the model was made from a pretrained backbone (see
    /// [`crate::CheckpointState::new_blocks`]).
    pub new_blocks: Vec<usize>,
    /// The precision the model's transformer blocks compute in (its parameters are `f32`).
    pub precision: Precision,
    /// Dynamic loss scaling, where the run scales its loss ([`loss_scaler`]).
    pub loss_scale: Option<LossScaler>,
}

/// Checks the run folder against the options (a fresh run needs a folder without checkpoints,
/// `--resume` one with), removes half-written checkpoints and, for a fresh run, writes its
/// [`RUN_CONFIG_FILE`]. Returns the checkpoint to resume from.
///
/// # Errors
/// A folder that does not fit the options, a checkpoint of another job or config, I/O errors.
pub fn prepare_run_folder(
    run: &Path,
    config: &TrainingConfig,
    task: &dyn Task,
    options: &RunOptions,
) -> Result<Option<Checkpoint>> {
    let fail = |message: String| {
        Err(TrainError::RunFolder {
            path: run.to_path_buf(),
            message,
        })
    };
    if options.resume && options.init.is_some() {
        return fail(
            "--resume and --init cannot be combined: --resume continues the run's own checkpoint"
                .into(),
        );
    }
    recover_checkpoints(run)?;
    let latest = latest_checkpoint(run)?;
    if !options.resume {
        if let Some(latest) = latest {
            return fail(format!(
                "already holds a run (latest checkpoint {}); pass --resume to continue it or \
                 choose another --out",
                latest.display()
            ));
        }
        fs::create_dir_all(run).map_err(|e| TrainError::io(run, e))?;
        let path = run.join(RUN_CONFIG_FILE);
        prism_core::files::write_bytes(&path, config.to_toml().as_bytes())
            .map_err(|e| TrainError::io(&path, e))?;
        return Ok(None);
    }
    let Some(latest) = latest else {
        return fail("holds no checkpoint to resume from; start the run without --resume".into());
    };
    let checkpoint = Checkpoint::read(&latest)?;
    if checkpoint.state.task != task.name() {
        return Err(TrainError::ConfigMismatch {
            path: checkpoint.dir.clone(),
            what: format!(
                "it is a {} run, this is a {} run",
                checkpoint.state.task,
                task.name()
            ),
        });
    }
    check_resumable(&checkpoint, config)?;
    Ok(Some(checkpoint))
}

/// The model to start from, its step and its newly initialised blocks (which train at
/// `lr_heads`, see [`CheckpointState::new_blocks`](crate::CheckpointState::new_blocks)): the
/// resumed checkpoint's, `--init`'s weights, or a fresh initialisation seeded by `train.seed`;
/// its blocks computing in the run's precision ([`run_precision`]), with its loss scaling.
///
/// # Errors
/// Unreadable weights, an `--init` checkpoint of another architecture, a precision that
/// differs from the resumed run's or that `device` cannot compute in.
pub fn initial_model(
    config: &TrainingConfig,
    resumed: Option<&Checkpoint>,
    options: &RunOptions,
    device: &Device,
) -> Result<Start> {
    let precision = run_precision(options, resumed)?;
    if !precision.supported_on(device) {
        return Err(TrainError::UnsupportedPrecision {
            precision,
            backend: options.backend.to_string(),
        });
    }
    let loss_scale = loss_scaler(
        precision,
        options.loss_scale,
        resumed.and_then(|c| c.state.loss_scale),
    );
    let (model, step, new_blocks) = initial_weights(config, resumed, options, device)?;
    Ok(Start {
        model: model.with_compute_precision(precision),
        step,
        new_blocks,
        precision,
        loss_scale,
    })
}

/// The precision of a run: the resumed checkpoint's, else `options.precision` (f32 when not
/// given).
///
/// # Errors
/// [`TrainError::ConfigMismatch`] when `options.precision` differs from the resumed run's: a
/// run continues in the precision it was trained in.
pub fn run_precision(options: &RunOptions, resumed: Option<&Checkpoint>) -> Result<Precision> {
    match (resumed, options.precision) {
        (Some(c), Some(asked)) if asked != c.state.precision => Err(TrainError::ConfigMismatch {
            path: c.dir.clone(),
            what: format!(
                "precision: {} in the checkpoint, {asked} from --precision",
                c.state.precision
            ),
        }),
        (Some(c), _) => Ok(c.state.precision),
        (None, asked) => Ok(asked.unwrap_or_default()),
    }
}

/// The loss scaling of a run computing in `precision`: with `asked` (the run's options), the
/// scaling they set, continuing `resumed`'s scale when there is one; without, the resumed
/// run's own scaling, or for a fresh f16 run the defaults ([`LossScaleConfig::default`]).
/// `None`: the loss is not scaled (f32 and bf16 by default).
pub fn loss_scaler(
    precision: Precision,
    asked: Option<LossScaleConfig>,
    resumed: Option<LossScaleState>,
) -> Option<LossScaler> {
    match (asked, resumed) {
        (None, Some(state)) => Some(LossScaler::restored(state)),
        (Some(config), Some(state)) => Some(LossScaler::restored(LossScaleState {
            growth_interval: config.growth_interval,
            ..state
        })),
        (Some(config), None) => Some(LossScaler::new(config)),
        (None, None) => (precision == Precision::F16).then(|| LossScaler::new(Default::default())),
    }
}

/// The weights a run starts from, with its step and newly initialised blocks (see
/// [`initial_model`]).
fn initial_weights(
    config: &TrainingConfig,
    resumed: Option<&Checkpoint>,
    options: &RunOptions,
    device: &Device,
) -> Result<(Prism, usize, Vec<usize>)> {
    if let Some(checkpoint) = resumed {
        return Ok((
            checkpoint.load_model(device)?,
            checkpoint.state.step,
            checkpoint.state.new_blocks.clone(),
        ));
    }
    if let Some(init) = &options.init {
        let checkpoint = Checkpoint::read(init)?;
        check_architecture(&checkpoint, &config.model)?;
        return Ok((
            checkpoint.load_model(device)?,
            0,
            checkpoint.state.new_blocks.clone(),
        ));
    }
    // A served main device is initialised on this machine and sent: the same weights as a
    // local run, whatever the server's random generator.
    let host = if is_served(device) {
        options.backend.autodiff_device()?
    } else {
        device.clone()
    };
    host.seed(config.train.seed);
    let model = config.model.init(&host);
    let model = if host == *device {
        model
    } else {
        initialized(&model);
        model.fork(device)
    };
    Ok((model, 0, Vec::new()))
}

/// Draws every lazily initialised parameter of `model` now, on its device: Burn initialises a
/// parameter at its first use, on the device it is on then, with that device's random
/// generator; a model moved to a served device first would be drawn by the server.
fn initialized(model: &Prism) {
    struct Draw;
    impl ModuleVisitor for Draw {
        fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
            let _ = param.val();
        }
    }
    model.visit(&mut Draw);
}
