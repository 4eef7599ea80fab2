//! Devices for anerf: the run-time backend choice (which backends exist is decided at build time by cargo
//! features: `flex` always, `ndarray` by default, `wgpu` and `cuda` opt-in; which one runs is chosen here,
//! e.g. from `--device`), the check that a GPU backend runs before relying on it (`probe`, in a child
//! process: the only process machinery of the project's libraries, kept out of `anerf-core`'s maths), the
//! CPU compute threads and the host's memory. Test helpers are behind the `testing` feature.

use std::fmt;
use std::str::FromStr;

use burn::prelude::Device;

pub mod probe;
#[cfg(feature = "testing")]
pub mod testing;
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
    pub fn device(self) -> Result<Device, DeviceError> {
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
            other => Err(DeviceError::NotCompiled { device: other }),
        }
    }
}

/// One device of a data-parallel run, as `--devices` names it: `cuda:1`, or a backend alone for its first
/// device (`cuda` is `cuda:0`). Only CUDA devices take an ordinal other than 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceSpec {
    pub choice: DeviceChoice,
    pub ordinal: usize,
}

impl DeviceSpec {
    /// The Burn device (without autodiff), or an error naming the feature to build with.
    pub fn device(self) -> Result<Device, DeviceError> {
        match (self.choice, self.ordinal) {
            (_, 0) => self.choice.device(),
            #[cfg(feature = "cuda")]
            (DeviceChoice::Cuda, n) => Ok(Device::cuda(n)),
            #[allow(unreachable_patterns)]
            (DeviceChoice::Cuda, _) => DeviceChoice::Cuda.device(),
            (other, n) => Err(DeviceError::OrdinalNotCuda {
                device: other,
                ordinal: n,
            }),
        }
    }

    /// Checks the devices of one data-parallel run: at least one, all CUDA devices (Burn 0.22.1 all-reduces
    /// gradients between CUDA devices only, through NCCL), none twice.
    pub fn check_data_parallel(devices: &[DeviceSpec]) -> Result<(), DeviceError> {
        if devices.is_empty() {
            return Err(DeviceError::NoDevices);
        }
        if let Some(&other) = devices.iter().find(|d| d.choice != DeviceChoice::Cuda) {
            return Err(DeviceError::NotAllCuda { device: other });
        }
        for (i, &d) in devices.iter().enumerate() {
            if let Some(j) = devices[..i].iter().position(|&e| e == d) {
                return Err(DeviceError::Twice {
                    device: d,
                    first: j + 1,
                    second: i + 1,
                });
            }
        }
        Ok(())
    }
}

impl fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.choice, self.ordinal)
    }
}

impl FromStr for DeviceSpec {
    type Err = DeviceError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let (name, ordinal) = match s.split_once(':') {
            Some((name, n)) => {
                let ordinal = n.parse().map_err(|_| DeviceError::BadOrdinal {
                    given: s.to_string(),
                })?;
                (name, ordinal)
            }
            None => (s, 0),
        };
        Ok(Self {
            choice: name.parse()?,
            ordinal,
        })
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
    type Err = DeviceError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|c| c.feature() == s.to_ascii_lowercase())
            .ok_or_else(|| DeviceError::Unknown {
                given: s.to_string(),
            })
    }
}

/// Why a device cannot be named or opened.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeviceError {
    #[error("unknown device '{given}': expected one of flex, ndarray, wgpu, cuda")]
    Unknown { given: String },
    #[error("device '{given}': expected a device ordinal after ':', e.g. cuda:1")]
    BadOrdinal { given: String },
    #[error(
        "device '{device}' is not compiled into this binary; rebuild with `--features {}`",
        device.feature()
    )]
    NotCompiled { device: DeviceChoice },
    #[error("device '{device}:{ordinal}': only cuda devices take an ordinal (use '{device}')")]
    OrdinalNotCuda {
        device: DeviceChoice,
        ordinal: usize,
    },
    #[error("--devices names no device")]
    NoDevices,
    #[error(
        "--devices {device}: data-parallel training all-reduces the gradients, which Burn 0.22.1 does only \
         between CUDA devices (NCCL); name cuda:N devices, or train on one device with --device"
    )]
    NotAllCuda { device: DeviceSpec },
    #[error("--devices names {device} twice (entries {first} and {second})")]
    Twice {
        device: DeviceSpec,
        first: usize,
        second: usize,
    },
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_name_and_rejects_others() {
        for c in DeviceChoice::ALL {
            assert_eq!(c.to_string().parse::<DeviceChoice>().unwrap(), c);
        }
        let err = "cuda9".parse::<DeviceChoice>().unwrap_err().to_string();
        assert!(err.contains("cuda,") || err.ends_with("cuda"), "{err}");
        assert!(err.contains("cuda9") && err.contains("flex"), "{err}");
    }

    #[test]
    fn device_specs_parse_with_and_without_an_ordinal() {
        let cuda1: DeviceSpec = "cuda:1".parse().unwrap();
        assert_eq!((cuda1.choice, cuda1.ordinal), (DeviceChoice::Cuda, 1));
        assert_eq!("flex".parse::<DeviceSpec>().unwrap().to_string(), "flex:0");
        let bad = "cuda:x".parse::<DeviceSpec>().unwrap_err().to_string();
        assert!(bad.contains("cuda:x") && bad.contains("ordinal"), "{bad}");
        assert!("tpu:0"
            .parse::<DeviceSpec>()
            .unwrap_err()
            .to_string()
            .contains("tpu"));
        let flex1 = DeviceSpec {
            choice: DeviceChoice::Flex,
            ordinal: 1,
        };
        assert!(flex1
            .device()
            .unwrap_err()
            .to_string()
            .contains("only cuda"));
        assert!(DeviceSpec {
            choice: DeviceChoice::Flex,
            ordinal: 0
        }
        .device()
        .is_ok());
    }

    #[test]
    fn a_data_parallel_run_takes_distinct_cuda_devices() {
        let specs =
            |s: &str| -> Vec<DeviceSpec> { s.split(',').map(|d| d.parse().unwrap()).collect() };
        let check = |s: &str| DeviceSpec::check_data_parallel(&specs(s));
        assert!(check("cuda:0,cuda:1").is_ok() && check("cuda:3").is_ok() && check("cuda").is_ok());
        assert!(DeviceSpec::check_data_parallel(&[])
            .unwrap_err()
            .to_string()
            .contains("no device"));
        let twice = check("cuda:0,cuda:1,cuda:0").unwrap_err().to_string();
        assert!(
            twice.contains("cuda:0 twice") && twice.contains("1 and 3"),
            "{twice}"
        );
        for other in ["flex", "cuda:0,flex", "wgpu:0,wgpu:1"] {
            let err = check(other).unwrap_err().to_string();
            assert!(
                err.contains("only between CUDA devices") && err.contains("--device"),
                "{err}"
            );
        }
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
