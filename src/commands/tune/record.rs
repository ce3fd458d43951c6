//! The record `prism tune attention` keeps for one adapter: what it timed, what it chose, and
//! where the file lies; and the lookup that puts a recorded choice in force
//! ([`register`], called once by `main`).

use std::path::{Path, PathBuf};

use anyhow::Context;
use burn::tensor::{DType, Device};
use prism_kernels::{AttentionKernel, GpuAttention};
use prism_model::Precision;
use serde::{Deserialize, Serialize};

/// The folder under the cache folder that holds one record per adapter.
const FOLDER: &str = "attention";

/// Who a GPU device is: its adapter's name (as the driver gives it) and the fingerprint its
/// compiled kernels are keyed to (vendor and device ids), which names its records.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Adapter {
    /// `NVIDIA H200`, `llvmpipe (LLVM 15.0.7, 256 bits)`.
    pub name: String,
    /// `spirv_4318_8963`: two cards of one model share it, and so share a record.
    pub fingerprint: String,
}

impl Adapter {
    /// The adapter behind `device`, `None` on a device that is no GPU (the CPU backends).
    pub fn of(device: &Device) -> Option<Self> {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        {
            device.identity().map(|identity| Self {
                name: identity.name,
                fingerprint: identity.fingerprint,
            })
        }
        #[cfg(not(any(feature = "wgpu", feature = "cuda")))]
        {
            let _ = device;
            None
        }
    }

    /// Where this adapter's record for inputs in `precision` lies:
    /// `<cache folder>/attention/<fingerprint>-<precision>.json`, the fingerprint's characters
    /// outside `[A-Za-z0-9_-]` written as `_`.
    pub fn record_path(&self, precision: Precision) -> PathBuf {
        let file: String = self
            .fingerprint
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                    c
                } else {
                    '_'
                }
            })
            .collect();
        prism_synth::cache_dir()
            .join(FOLDER)
            .join(format!("{file}-{precision}.json"))
    }
}

/// The median time of one kernel, and with a gradient the memory it keeps for the backward pass.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct KernelTime {
    /// `burn`, `flash` or `unfused` ([`AttentionKernel::name`]).
    pub kernel: String,
    /// Median milliseconds of one call (with a gradient: forward and backward).
    pub ms: f64,
    /// With a gradient, the bytes its forward pass keeps for the backward pass (its output
    /// included): the `T x T` scores for `unfused`, an output and a log-sum-exp per row for
    /// `flash`. `None` without a gradient, or where the backend does not report its pools.
    pub kept_bytes: Option<u64>,
}

/// The shapes the kernels were timed at: `[batch, heads, tokens, head_dim]` in `precision`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shape {
    /// The config file the shapes come from.
    pub config: String,
    /// Image side in pixels.
    pub resolution: usize,
    /// (source, target) pairs per call.
    pub batch: usize,
    /// Attention heads.
    pub heads: usize,
    /// Tokens per sequence (a source's and a target's patches).
    pub tokens: usize,
    /// Width of one head.
    pub head_dim: usize,
    /// The inputs' precision: f32, f16 or bf16.
    pub precision: String,
}

/// What `prism tune attention` measured on one adapter, and the choice it keeps for it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Record {
    /// The adapter measured.
    pub adapter: Adapter,
    /// The backend it was measured through (`wgpu`, `cuda`).
    pub backend: String,
    /// The prism version that measured it.
    pub prism: String,
    /// The shapes timed.
    pub shape: Shape,
    /// Each kernel without a gradient.
    pub inference: Vec<KernelTime>,
    /// Each kernel a training step can take, forward and backward.
    pub training: Vec<KernelTime>,
    /// The fastest of each: the choice in force on this adapter.
    pub choice: Choice,
}

/// The kernels chosen, by name.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Choice {
    /// Without a gradient.
    pub inference: String,
    /// With one.
    pub training: String,
}

impl Choice {
    /// The fastest kernel of each list (the first listed of equal times).
    ///
    /// # Errors
    /// When a list is empty.
    pub fn fastest(inference: &[KernelTime], training: &[KernelTime]) -> anyhow::Result<Self> {
        let fastest = |times: &[KernelTime]| {
            times
                .iter()
                .reduce(|best, t| if t.ms < best.ms { t } else { best })
                .map(|t| t.kernel.clone())
                .context("no kernel was timed")
        };
        Ok(Self {
            inference: fastest(inference)?,
            training: fastest(training)?,
        })
    }

    /// The choice these names make.
    ///
    /// # Errors
    /// A name that is no kernel.
    pub fn attention(&self) -> anyhow::Result<GpuAttention> {
        let kernel = |name: &str| {
            AttentionKernel::parse(name)
                .with_context(|| format!("`{name}` is not one of burn, flash, unfused"))
        };
        Ok(GpuAttention::new(
            kernel(&self.inference)?,
            kernel(&self.training)?,
        ))
    }
}

impl Record {
    /// Writes the record to `path` (atomically, its folder made first).
    ///
    /// # Errors
    /// A folder or file that cannot be written, naming it.
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("{}: cannot create the folder", dir.display()))?;
        }
        prism_core::files::write_json(path, self)
            .with_context(|| format!("{}: cannot write the record", path.display()))
    }

    /// Reads the record at `path`.
    ///
    /// # Errors
    /// An unreadable file, or one that is not a record of this layout, naming it.
    pub fn read(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        serde_json::from_str(&text).with_context(|| {
            format!(
                "{}: not a record of `prism tune attention` (run it again)",
                path.display()
            )
        })
    }
}

/// The choice recorded for `device`'s adapter with `dtype` inputs, `None` where none was
/// recorded (or the dtype is none of f32, f16, bf16). A record that cannot be read, or names
/// no kernel, is reported on stderr and ignored; a record in force is named on stderr (once
/// per device and dtype: the caller keeps the answer), so a run's log says which attention it
/// ran.
fn recorded_choice(device: &Device, dtype: DType) -> Option<GpuAttention> {
    let precision = match dtype {
        DType::F32 => Precision::F32,
        DType::F16 => Precision::F16,
        DType::BF16 => Precision::Bf16,
        _ => return None,
    };
    let adapter = Adapter::of(device)?;
    let path = adapter.record_path(precision);
    if !path.exists() {
        return None;
    }
    let choice = Record::read(&path).and_then(|record| {
        record
            .choice
            .attention()
            .with_context(|| format!("{}: its choice", path.display()))
    });
    match choice {
        Ok(choice) => {
            eprintln!(
                "prism: attention on {} in {precision}: {choice} (measured by `prism tune \
                 attention`, {})",
                adapter.name,
                path.display()
            );
            Some(choice)
        }
        Err(err) => {
            eprintln!("prism: {err:#}; attention takes Burn's ops");
            None
        }
    }
}

/// Puts the choices `prism tune attention` recorded in force for the process: attention on a
/// GPU device with no `PRISM_ATTENTION` set takes its adapter's recorded kernels.
pub fn register() {
    GpuAttention::measured_by(recorded_choice);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn time(kernel: &str, ms: f64) -> KernelTime {
        KernelTime {
            kernel: kernel.into(),
            ms,
            kept_bytes: None,
        }
    }

    #[test]
    fn the_fastest_kernel_of_each_list_is_chosen() {
        let inference = [time("burn", 3.0), time("flash", 2.5), time("unfused", 2.5)];
        let training = [time("flash", 9.0), time("unfused", 7.0)];
        let choice = Choice::fastest(&inference, &training).unwrap();
        assert_eq!(
            (&*choice.inference, &*choice.training),
            ("flash", "unfused")
        );
        let attention = choice.attention().unwrap();
        assert_eq!(attention.inference, AttentionKernel::Flash);
        assert_eq!(attention.training, AttentionKernel::Unfused);
        assert!(Choice::fastest(&[], &training).is_err());
        let bad = Choice {
            inference: "fast".into(),
            training: "flash".into(),
        };
        let err = format!("{:#}", bad.attention().unwrap_err());
        assert!(err.contains("`fast`"), "{err}");
    }

    #[test]
    fn a_fingerprint_names_a_file_in_the_cache_folder() {
        let adapter = Adapter {
            name: "card".into(),
            fingerprint: "spirv_4318/../8963".into(),
        };
        let path = adapter.record_path(Precision::Bf16);
        assert_eq!(path.file_name().unwrap(), "spirv_4318____8963-bf16.json");
        assert_eq!(path.parent().unwrap().file_name().unwrap(), FOLDER);
    }
}
