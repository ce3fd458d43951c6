//! Which kernel softmax attention takes on the GPU backends, and where that choice comes from.
//!
//! The backends without a fused host kernel (the GPU backends) have three ways to compute
//! attention ([`AttentionKernel`]), and a choice ([`GpuAttention`]) names one for inference and
//! one for training. In order of precedence, the choice in force on a thread is:
//! 1. the one [`GpuAttention::run`] put in force around the current call (tests compare the
//!    kernels in one process this way);
//! 2. the `PRISM_ATTENTION` environment variable, read once per process (so one binary can
//!    time each: `PRISM_ATTENTION=flash prism bench`);
//! 3. the one measured for the device's adapter in the inputs' dtype, when a program registered
//!    where measurements are kept ([`GpuAttention::measured_by`]; the `prism` binary registers
//!    the files of `prism tune attention`);
//! 4. [`GpuAttention::BURN`], Burn's ops only.

use std::sync::{Mutex, OnceLock};

use burn::tensor::{DType, Device};

/// One way to compute softmax attention on a GPU backend.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AttentionKernel {
    /// Burn's attention op: fused on the backends that have one (with cooperative matrices
    /// where the adapter has them). Without a gradient only: under autodiff Burn decomposes it
    /// as [`AttentionKernel::Unfused`] does, so a training choice of `Burn` means `Unfused`.
    Burn,
    /// prism's flash kernels (module `device`): forward and backward without the `T x T`
    /// scores.
    Flash,
    /// prism's matmul-softmax-matmul ([`crate::unfused`]), which keeps the scores for the
    /// backward pass.
    Unfused,
}

impl AttentionKernel {
    /// Every kernel, in the order they are reported.
    pub const ALL: [Self; 3] = [Self::Burn, Self::Flash, Self::Unfused];

    /// The kernels a training step can take (Burn's op is `Unfused` under a gradient).
    pub const TRAINING: [Self; 2] = [Self::Flash, Self::Unfused];

    /// Its name in `PRISM_ATTENTION`'s values, tables and files: `burn`, `flash`, `unfused`.
    pub fn name(self) -> &'static str {
        match self {
            Self::Burn => "burn",
            Self::Flash => "flash",
            Self::Unfused => "unfused",
        }
    }

    /// The kernel of that [`name`](Self::name).
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|k| k.name() == name)
    }
}

/// Which kernel attention takes on a GPU backend: without a gradient (`inference`) and with one
/// (`training`).
///
/// The default stays on Burn's ops ([`GpuAttention::BURN`]) until the kernels have been timed
/// against each other on a GPU: `prism tune attention` times them on the user's adapter and
/// keeps its choice for that adapter. lavapipe checks the flash kernels' values and gradients
/// (`tests/cli/device/flash_attention.rs`) and runs the tiny model's forward pass and training
/// step through them (`tests/cli/device/backend.rs`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct GpuAttention {
    /// The kernel attention takes when no gradient is needed.
    pub inference: AttentionKernel,
    /// The kernel attention takes under a gradient ([`AttentionKernel::Burn`] runs
    /// [`AttentionKernel::Unfused`] there).
    pub training: AttentionKernel,
}

impl Default for GpuAttention {
    fn default() -> Self {
        Self::BURN
    }
}

/// Where the choice in force on a thread came from ([`GpuAttention::in_force`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ChoiceOrigin {
    /// [`GpuAttention::run`], around the current call.
    Thread,
    /// The `PRISM_ATTENTION` environment variable.
    Environment,
    /// The measurement registered with [`GpuAttention::measured_by`] for the device's adapter
    /// and the inputs' dtype.
    Measured,
    /// None of those: [`GpuAttention::BURN`].
    Default,
}

/// Finds the choice measured for a device's adapter with inputs of a dtype, `None` where none
/// was measured.
pub type MeasuredChoice = fn(&Device, DType) -> Option<GpuAttention>;

thread_local! {
    /// The choice [`GpuAttention::run`] put in force on this thread, if any.
    static ON_THIS_THREAD: std::cell::Cell<Option<GpuAttention>> = const {
        std::cell::Cell::new(None)
    };
}

/// Where measured choices are found, once registered.
static MEASURED_BY: OnceLock<MeasuredChoice> = OnceLock::new();

/// The measured choice of each device and dtype asked about so far (the lookup reads a file:
/// once per device, dtype and process).
static MEASURED: Mutex<Vec<(MeasuredKey, Option<GpuAttention>)>> = Mutex::new(Vec::new());

/// What a measurement is kept for: a device (without autodiff) and its inputs' dtype.
type MeasuredKey = (Device, DType);

impl GpuAttention {
    /// `burn` (the default): Burn's fused attention op for inference, matmul-softmax-matmul
    /// (which keeps the scores for the backward pass) for training.
    pub const BURN: Self = Self::new(AttentionKernel::Burn, AttentionKernel::Unfused);
    /// `auto`: Burn's fused attention op for inference, prism's flash kernels for training.
    pub const AUTO: Self = Self::new(AttentionKernel::Burn, AttentionKernel::Flash);
    /// `flash`: prism's flash kernels for both.
    pub const FLASH: Self = Self::new(AttentionKernel::Flash, AttentionKernel::Flash);
    /// `unfused`: prism's matmul-softmax-matmul for both (the reference the others are timed
    /// against).
    pub const UNFUSED: Self = Self::new(AttentionKernel::Unfused, AttentionKernel::Unfused);

    /// The choice of these two kernels; a training `Burn` is stored as `Unfused`, what it runs.
    pub const fn new(inference: AttentionKernel, training: AttentionKernel) -> Self {
        let training = match training {
            AttentionKernel::Burn => AttentionKernel::Unfused,
            other => other,
        };
        Self {
            inference,
            training,
        }
    }

    /// The choice a value of `PRISM_ATTENTION` names: `auto`, `flash`, `unfused` or `burn`.
    pub fn parse(value: &str) -> Option<Self> {
        match value {
            "auto" => Some(Self::AUTO),
            "flash" => Some(Self::FLASH),
            "unfused" => Some(Self::UNFUSED),
            "burn" => Some(Self::BURN),
            _ => None,
        }
    }

    /// The choice of `PRISM_ATTENTION`, read once per process; unset or empty is `None`, and
    /// any other value is reported on stderr and ignored.
    pub fn from_environment() -> Option<Self> {
        static CHOSEN: OnceLock<Option<GpuAttention>> = OnceLock::new();
        *CHOSEN.get_or_init(|| {
            let value = std::env::var("PRISM_ATTENTION").ok()?;
            if value.is_empty() {
                return None;
            }
            let chosen = Self::parse(&value);
            if chosen.is_none() {
                eprintln!(
                    "prism: PRISM_ATTENTION={value} is not one of auto, flash, unfused, burn; \
                     ignored"
                );
            }
            chosen
        })
    }

    /// Registers where the choices measured for an adapter are found. The first registration
    /// holds for the process; `false` when one was already made.
    pub fn measured_by(lookup: MeasuredChoice) -> bool {
        MEASURED_BY.set(lookup).is_ok()
    }

    /// The choice measured for `device`'s adapter with `dtype` inputs, asked of the registered
    /// lookup once per device and dtype (with or without autodiff, the same device).
    fn measured(device: &Device, dtype: DType) -> Option<Self> {
        let lookup = MEASURED_BY.get()?;
        let key = (device.clone().without_autodiff(), dtype);
        let mut known = MEASURED
            .lock()
            .unwrap_or_else(|poisoned| poisoned.into_inner());
        if let Some((_, choice)) = known.iter().find(|(k, _)| *k == key) {
            return *choice;
        }
        let choice = lookup(&key.0, dtype);
        known.push((key, choice));
        choice
    }

    /// The choice in force on this thread for attention on `device` with `dtype` inputs, and
    /// where it came from (see the module's docs for the order).
    pub fn in_force(device: &Device, dtype: DType) -> (Self, ChoiceOrigin) {
        if let Some(choice) = ON_THIS_THREAD.get() {
            (choice, ChoiceOrigin::Thread)
        } else if let Some(choice) = Self::from_environment() {
            (choice, ChoiceOrigin::Environment)
        } else if let Some(choice) = Self::measured(device, dtype) {
            (choice, ChoiceOrigin::Measured)
        } else {
            (Self::BURN, ChoiceOrigin::Default)
        }
    }

    /// The choice in force on this thread for attention on `device` with `dtype` inputs
    /// ([`in_force`](Self::in_force) without its origin).
    pub fn current(device: &Device, dtype: DType) -> Self {
        Self::in_force(device, dtype).0
    }

    /// Runs `f` with attention on this thread taking this choice, whatever `PRISM_ATTENTION`
    /// or a measurement says, and restores the previous choice after (also when `f` panics).
    /// The choice is made when [`crate::attention`] is called, so a backward pass runs the
    /// kernel its forward pass took, inside `f` or not.
    pub fn run<R>(self, f: impl FnOnce() -> R) -> R {
        /// Puts the previous choice back when dropped.
        struct Restore(Option<GpuAttention>);
        impl Drop for Restore {
            fn drop(&mut self) {
                ON_THIS_THREAD.set(self.0);
            }
        }
        let _restore = Restore(ON_THIS_THREAD.replace(Some(self)));
        f()
    }

    /// The kernel attention with (`tracked`) or without a gradient takes.
    pub fn kernel(self, tracked: bool) -> AttentionKernel {
        if tracked {
            self.training
        } else {
            self.inference
        }
    }
}

impl std::fmt::Display for GpuAttention {
    /// `inference burn, training flash`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "inference {}, training {}",
            self.inference.name(),
            self.training.name()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_environment_values_name_their_kernels() {
        use AttentionKernel::*;
        for (value, inference, training) in [
            ("burn", Burn, Unfused),
            ("auto", Burn, Flash),
            ("flash", Flash, Flash),
            ("unfused", Unfused, Unfused),
        ] {
            let choice = GpuAttention::parse(value).unwrap();
            assert_eq!((choice.inference, choice.training), (inference, training));
            assert_eq!(choice.kernel(false), inference, "{value}");
            assert_eq!(choice.kernel(true), training, "{value}");
        }
        assert_eq!(GpuAttention::parse("fast"), None);
        assert_eq!(GpuAttention::default(), GpuAttention::BURN);
    }

    #[test]
    fn a_training_burn_is_what_it_runs() {
        let choice = GpuAttention::new(AttentionKernel::Flash, AttentionKernel::Burn);
        assert_eq!(choice.training, AttentionKernel::Unfused);
        assert_eq!(choice.to_string(), "inference flash, training unfused");
        for kernel in AttentionKernel::ALL {
            assert_eq!(AttentionKernel::parse(kernel.name()), Some(kernel));
        }
    }

    #[test]
    fn a_thread_choice_comes_first_and_is_put_back() {
        let device = Device::flex();
        let before = GpuAttention::in_force(&device, DType::F32);
        assert_ne!(before.1, ChoiceOrigin::Thread);
        let inside = GpuAttention::UNFUSED.run(|| {
            let nested = GpuAttention::FLASH.run(|| GpuAttention::in_force(&device, DType::F32));
            (nested, GpuAttention::in_force(&device, DType::F32))
        });
        assert_eq!(inside.0, (GpuAttention::FLASH, ChoiceOrigin::Thread));
        assert_eq!(inside.1, (GpuAttention::UNFUSED, ChoiceOrigin::Thread));
        assert_eq!(GpuAttention::in_force(&device, DType::F32), before);
        let panicked = std::panic::catch_unwind(|| GpuAttention::FLASH.run(|| panic!("inside")));
        assert!(panicked.is_err());
        assert_eq!(GpuAttention::in_force(&device, DType::F32), before);
    }

    /// How often the registered lookup was asked.
    static LOOKUPS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

    /// A lookup that measured `auto` for ndarray devices in f32 (where it runs what the default
    /// runs: no flash kernels on a CPU, and f32 attention takes the host kernel) and nothing
    /// else.
    fn ndarray_measured_auto(device: &Device, dtype: DType) -> Option<GpuAttention> {
        LOOKUPS.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        #[allow(deprecated)]
        let ndarray = Device::ndarray();
        (*device == ndarray && dtype == DType::F32).then_some(GpuAttention::AUTO)
    }

    #[test]
    fn a_measured_choice_is_asked_once_per_device_and_dtype_and_yields_to_the_others() {
        if GpuAttention::from_environment().is_some() {
            eprintln!("skipped: PRISM_ATTENTION is set");
            return;
        }
        assert!(GpuAttention::measured_by(ndarray_measured_auto));
        assert!(
            !GpuAttention::measured_by(|_, _| None),
            "a second registration"
        );
        #[allow(deprecated)]
        let ndarray = Device::ndarray();
        let measured = (GpuAttention::AUTO, ChoiceOrigin::Measured);
        assert_eq!(GpuAttention::in_force(&ndarray, DType::F32), measured);
        let asked = LOOKUPS.load(std::sync::atomic::Ordering::SeqCst);
        let tracked = ndarray.clone().autodiff();
        assert_eq!(GpuAttention::in_force(&tracked, DType::F32), measured);
        assert_eq!(
            LOOKUPS.load(std::sync::atomic::Ordering::SeqCst),
            asked,
            "asked again"
        );
        let thread = GpuAttention::FLASH.run(|| GpuAttention::in_force(&ndarray, DType::F32));
        assert_eq!(thread, (GpuAttention::FLASH, ChoiceOrigin::Thread));
        let default = (GpuAttention::BURN, ChoiceOrigin::Default);
        assert_eq!(
            GpuAttention::in_force(&ndarray, DType::F16),
            default,
            "another dtype"
        );
        assert_eq!(GpuAttention::in_force(&Device::flex(), DType::F32), default);
    }
}
