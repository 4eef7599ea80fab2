//! Run-time backend choice. Which backends exist is decided at build time by cargo features
//! (`flex` always, `ndarray` by default, `wgpu` and `cuda` opt-in); which one runs is chosen here, e.g. from
//! `--device`.

use std::fmt;
use std::str::FromStr;

use burn::prelude::Device;

pub mod probe;
pub mod threads;

/// A compute backend the user can ask for by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeviceChoice {
    /// Burn's pure-Rust CPU backend (multi-threaded with rayon and SIMD).
    #[default]
    Flex,
    /// The ndarray CPU backend (deprecated upstream, kept for cross-checking).
    Ndarray,
    /// The default wgpu adapter (a GPU when one exists).
    Wgpu,
    /// The first NVIDIA GPU through CUDA (CubeCL's CUDA runtime: the driver and NVRTC, loaded at run time).
    Cuda,
}

impl DeviceChoice {
    /// Every choice, in the order they are listed to users.
    pub const ALL: [DeviceChoice; 4] = [
        DeviceChoice::Flex,
        DeviceChoice::Ndarray,
        DeviceChoice::Wgpu,
        DeviceChoice::Cuda,
    ];

    fn feature(self) -> &'static str {
        match self {
            DeviceChoice::Flex => "flex",
            DeviceChoice::Ndarray => "ndarray",
            DeviceChoice::Wgpu => "wgpu",
            DeviceChoice::Cuda => "cuda",
        }
    }

    /// A GPU backend: checked in a child process before use ([`probe`]).
    pub fn is_gpu(self) -> bool {
        matches!(self, DeviceChoice::Wgpu | DeviceChoice::Cuda)
    }

    /// What the backend needs on the machine beyond this binary, for error messages.
    pub fn needs(self) -> Option<&'static str> {
        match self {
            DeviceChoice::Cuda => Some(
                "CUDA needs an NVIDIA GPU with its driver (libcuda.so.1) and NVRTC 12 (libnvrtc.so.12, from \
                 the CUDA toolkit or the nvidia-cuda-nvrtc-cu12 wheel PyTorch installs) on the library path \
                 (LD_LIBRARY_PATH)",
            ),
            DeviceChoice::Wgpu => Some("wgpu needs a Vulkan, Metal, DirectX 12 or OpenGL driver"),
            DeviceChoice::Flex | DeviceChoice::Ndarray => None,
        }
    }

    /// The Burn device (without autodiff), or an error naming the cargo feature to enable.
    pub fn device(self) -> Result<Device, String> {
        match self {
            DeviceChoice::Flex => Ok(Device::flex()),
            #[cfg(feature = "ndarray")]
            #[allow(deprecated)]
            DeviceChoice::Ndarray => Ok(Device::ndarray()),
            #[cfg(feature = "wgpu")]
            DeviceChoice::Wgpu => Ok(Device::wgpu(Default::default())),
            #[cfg(feature = "cuda")]
            DeviceChoice::Cuda => Ok(Device::cuda(0)),
            #[allow(unreachable_patterns)]
            other => Err(format!(
                "device '{other}' is not compiled into this binary; rebuild with `--features {}`",
                other.feature()
            )),
        }
    }
}

/// The CPU device (flex) for host-side tensor work and tests, whatever other backends are compiled
/// (`Device::default()` would prefer a GPU backend when one is compiled in).
pub fn cpu_device() -> Device {
    DeviceChoice::Flex
        .device()
        .expect("the flex backend is always compiled")
}

/// Whether `device` (with or without autodiff) is a GPU backend's: Burn's CubeCL backend, which the `wgpu`
/// and `cuda` features compile.
pub fn runs_on_gpu(device: &Device) -> bool {
    match device.as_dispatch().clone().inner() {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        burn::backend::DispatchDevice::Cube(_) => true,
        #[allow(unreachable_patterns)]
        _ => false,
    }
}

impl fmt::Display for DeviceChoice {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.feature())
    }
}

impl FromStr for DeviceChoice {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|c| c.feature() == s.to_ascii_lowercase())
            .ok_or_else(|| {
                format!("unknown device '{s}': expected one of flex, ndarray, wgpu, cuda")
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_name_and_rejects_others() {
        for c in DeviceChoice::ALL {
            assert_eq!(c.to_string().parse::<DeviceChoice>().unwrap(), c);
        }
        let err = "cuda9".parse::<DeviceChoice>().unwrap_err();
        assert!(err.contains("cuda,") || err.ends_with("cuda"), "{err}");
        assert!(err.contains("cuda9") && err.contains("flex"), "{err}");
    }

    #[test]
    fn default_backend_is_compiled_and_usable() {
        let device = DeviceChoice::default().device().unwrap();
        let t = burn::prelude::Tensor::<1>::from_floats([1.0, 2.0], &device);
        assert_eq!(t.sum().into_scalar::<f32>(), 3.0);
    }
}

/// Physical memory of this machine in bytes (`MemTotal` of `/proc/meminfo`); `None` where unknown.
pub fn host_memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}
