//! For tests that compare a GPU backend with flex (behind the `testing` feature, a dev-dependency's): the
//! GPU devices that pass the probe, each checked in a child process that re-runs the test binary with only
//! the asking test, and the tolerance of results that pass through matmuls on each backend.

use std::process::Command;

use burn::prelude::Device;

use crate::probe::{checked_device, exit_if_probe_child, ProbeError};
use crate::DeviceChoice;

/// For tests that compare a GPU backend with flex: the device of `choice` when a child process re-running
/// this test binary with only `test` (its full path, e.g. `model::tests::wgpu_renders_like_flex`) passed the
/// smoke test; `None`, with the reason printed, when the backend is not compiled, has no adapter, fails or
/// crashes. The child is started once per process and backend. `test` must call this first: in the child it
/// runs the smoke test and exits.
///
/// Panics when the child ran no smoke test (`test` names no test that calls this).
pub fn device_for_test(choice: DeviceChoice, test: &str) -> Option<Device> {
    exit_if_probe_child();
    let checked = checked_device(choice, || {
        let mut command = Command::new(std::env::current_exe().expect("the test binary's path"));
        command.args([test, "--exact", "--nocapture", "--test-threads=1"]);
        command
    });
    match checked {
        Ok(checked) => {
            let adapter = checked.adapter.as_deref().unwrap_or("the CPU");
            eprintln!("running {test} on {choice} ({adapter})");
            Some(checked.device)
        }
        Err(e) if matches!(*e, ProbeError::NotRun { .. }) => {
            panic!("{e}: is `{test}` the full path of a test that calls device_for_test?")
        }
        Err(reason) => {
            eprintln!("skipping {test} on {choice}: {reason}");
            None
        }
    }
}

/// Relative tolerance for comparing, against f32 on the CPU, a result that passes through matmuls on
/// `choice`: `f32_tolerance`, except on CUDA, whose CubeCL matmuls run f32 inputs on TF32 tensor cores
/// (10-bit mantissa, unit roundoff 2⁻¹¹; a dot product's error grows with its length), as PyTorch does with
/// `allow_tf32`. Measured on an H200: up to 0.5 % on an MLP output whose inputs round that way (docs/GPU.md).
pub fn matmul_tolerance(choice: DeviceChoice, f32_tolerance: f64) -> f64 {
    const TF32: f64 = 1e-2;
    if choice == DeviceChoice::Cuda {
        f32_tolerance.max(TF32)
    } else {
        f32_tolerance
    }
}

/// [`device_for_test`] for every GPU backend (wgpu, CUDA): the devices that passed, in that order; a test
/// runs its comparison on each. Empty (with each reason printed) on a machine without a working GPU backend.
pub fn gpu_devices_for_test(test: &str) -> Vec<(DeviceChoice, Device)> {
    DeviceChoice::ALL
        .into_iter()
        .filter(|c| c.is_gpu())
        .filter_map(|c| device_for_test(c, test).map(|d| (c, d)))
        .collect()
}
