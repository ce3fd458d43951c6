//! Run-time choice of the Burn backend (`--backend ndarray|flex|wgpu`).

use std::fmt;
use std::str::FromStr;

use burn::tensor::Device;

/// A Burn backend that prism can run on. The backend is picked at run time through the
/// [`Device`]; the code is the same for all of them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    /// Burn's NdArray CPU backend (deprecated upstream; the end-to-end tests run on it).
    Ndarray,
    /// Burn's pure-Rust Flex CPU backend, the fast CPU default.
    #[default]
    Flex,
    /// The wgpu GPU backend (Vulkan, Metal, DX12); needs the `wgpu` cargo feature.
    Wgpu,
    /// Burn's CUDA backend (NVIDIA GPUs, CUDA driver loaded at run time); needs the `cuda`
    /// cargo feature.
    Cuda,
}

impl BackendKind {
    /// Every backend name, for help texts.
    pub const NAMES: [&'static str; 4] = ["ndarray", "flex", "wgpu", "cuda"];

    /// Whether the backend computes on the CPU (ndarray, flex).
    pub fn is_cpu(self) -> bool {
        matches!(self, Self::Ndarray | Self::Flex)
    }

    /// The inference device of this backend.
    ///
    /// # Errors
    /// When the backend was not compiled in (wgpu without the `wgpu` feature).
    pub fn device(self) -> Result<Device, BackendError> {
        match self {
            #[allow(deprecated)]
            Self::Ndarray => Ok(Device::ndarray()),
            Self::Flex => Ok(Device::flex()),
            #[cfg(feature = "wgpu")]
            Self::Wgpu => Ok(Device::wgpu(Default::default())),
            #[cfg(not(feature = "wgpu"))]
            Self::Wgpu => Err(BackendError::NotCompiled("wgpu")),
            #[cfg(feature = "cuda")]
            Self::Cuda => Ok(Device::cuda(0)),
            #[cfg(not(feature = "cuda"))]
            Self::Cuda => Err(BackendError::NotCompiled("cuda")),
        }
    }

    /// `count` devices of this backend (without autodiff): the GPUs `0..count` of a GPU
    /// backend (wgpu's discrete GPUs, CUDA's ordinals; one device is the backend's default),
    /// the one CPU device `count` times for the CPU backends (one worker thread each).
    ///
    /// # Errors
    /// When the backend was not compiled in.
    pub fn devices(self, count: usize) -> Result<Vec<Device>, BackendError> {
        let first = self.device()?;
        if count <= 1 {
            return Ok(vec![first]);
        }
        Ok(match self {
            #[cfg(feature = "wgpu")]
            Self::Wgpu => (0..count)
                .map(|i| Device::wgpu(burn::tensor::DeviceKind::DiscreteGpu(i)))
                .collect(),
            #[cfg(feature = "cuda")]
            Self::Cuda => (0..count).map(|i| Device::cuda(i)).collect(),
            _ => vec![first; count],
        })
    }

    /// The training device of this backend: the same device with autodiff enabled.
    pub fn autodiff_device(self) -> Result<Device, BackendError> {
        Ok(self.device()?.autodiff())
    }
}

/// Whether `device` computes on this machine's CPU (a flex or ndarray device, with or without
/// autodiff).
pub fn is_cpu_device(device: &Device) -> bool {
    use burn::backend::DispatchDevice;
    fn cpu(device: &DispatchDevice) -> bool {
        match device {
            DispatchDevice::Flex(_) | DispatchDevice::NdArray(_) => true,
            DispatchDevice::Autodiff(inner) => cpu(inner),
            _ => false,
        }
    }
    cpu(device.clone().inner().as_dispatch())
}

/// Whether `device` is served by another process (`prism serve`, Burn's remote backend).
pub fn is_served(device: &Device) -> bool {
    matches!(
        device.clone().inner().as_dispatch(),
        burn::backend::DispatchDevice::Remote(_)
    )
}

/// A backend that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum BackendError {
    /// The name is not a backend.
    #[error("unknown backend `{0}` (expected one of: ndarray, flex, wgpu, cuda)")]
    Unknown(String),
    /// The backend exists but this build does not include it.
    #[error("the `{0}` backend is not compiled in: rebuild with `--features {0}`")]
    NotCompiled(&'static str),
}

impl FromStr for BackendKind {
    type Err = BackendError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "ndarray" => Ok(Self::Ndarray),
            "flex" => Ok(Self::Flex),
            "wgpu" => Ok(Self::Wgpu),
            "cuda" => Ok(Self::Cuda),
            _ => Err(BackendError::Unknown(s.to_string())),
        }
    }
}

impl fmt::Display for BackendKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Ndarray => "ndarray",
            Self::Flex => "flex",
            Self::Wgpu => "wgpu",
            Self::Cuda => "cuda",
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_is_an_error() {
        for name in BackendKind::NAMES {
            assert_eq!(name.parse::<BackendKind>().unwrap().to_string(), name);
        }
        let err = "cuda9".parse::<BackendKind>().unwrap_err();
        assert!(err.to_string().contains("cuda9"));
    }

    /// The CPU backends' devices count as CPU devices, with autodiff too; a GPU's does not.
    #[test]
    fn cpu_devices_are_told_apart() {
        for kind in [BackendKind::Ndarray, BackendKind::Flex] {
            assert!(is_cpu_device(&kind.device().unwrap()), "{kind}");
            assert!(is_cpu_device(&kind.autodiff_device().unwrap()), "{kind}");
        }
        if let Ok(gpu) = BackendKind::Wgpu.device() {
            assert!(!is_cpu_device(&gpu));
            assert!(!is_cpu_device(&gpu.autodiff()));
        }
    }
}
