//! Checking, in a child process, that a backend runs before relying on it.
//!
//! A broken GPU driver need not return an error: it can kill the process with a signal while building a
//! compute pipeline (reported for Mesa's software Vulkan driver, lavapipe, with Burn's SPIR-V `vulkan`
//! backend; docs/PERFORMANCE.md, "GPU backends"). No panic hook can catch that, so the first kernels run in a
//! child process that re-executes the current program; the parent only reads its exit status and output.

use std::io::Read;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use burn::prelude::*;
use burn::tensor::activation::relu;
use thiserror::Error;

use super::DeviceChoice;

/// Environment variable that turns a process into a probe child: it names the backend to check.
pub const PROBE_ENV: &str = "ANERF_PROBE_DEVICE";

/// Line a probe child prints on standard output when the smoke test passed: the parent demands it, so a
/// child that exits 0 without running the probe (e.g. a test filter that matched nothing) does not count.
const PASSED: &str = "anerf-probe: passed";

/// Prefix of the line on which a probe child reports, on standard error, why the smoke test failed.
const REPORT: &str = "anerf-probe: ";

/// Prefix of the line on which a probe child names the adapter it ran on.
const ADAPTER: &str = "anerf-probe: adapter ";

/// Prefix of the lines on which a probe child lists, before running anything, the adapters it found.
const FOUND: &str = "anerf-probe: found ";

/// The adapter's name where the backend reports none.
const UNNAMED: &str = "(unnamed)";

/// How long a probe child may take (its shaders take up to ~30 s to compile on a software driver).
const TIMEOUT: Duration = Duration::from_secs(180);

/// Why the smoke test failed where it ran (in a probe child, which reports it to the parent as a line).
#[derive(Debug, Error)]
pub enum SmokeFailure {
    #[error("opening {what}: {detail}")]
    Open { what: &'static str, detail: String },
    #[error(transparent)]
    Device(#[from] crate::DeviceError),
    #[error("no gradient for {0}")]
    NoGradient(&'static str),
    #[error("reading the gradient of {name} back: {detail}")]
    ReadBack { name: &'static str, detail: String },
    #[error("the gradient of {name} is not finite: {values:?}")]
    NotFinite {
        name: &'static str,
        values: Vec<f32>,
    },
}

/// Why a backend failed its check.
#[derive(Debug, Error)]
pub enum ProbeError {
    #[error("{source}")]
    NotCompiled {
        device: DeviceChoice,
        source: crate::DeviceError,
    },
    #[error("device '{device}': could not start the probe process {program}: {source}")]
    Spawn {
        device: DeviceChoice,
        program: String,
        source: std::io::Error,
    },
    #[error(
        "device '{device}' failed its smoke test ({status}){}{}{}",
        found_note(.found),
        stderr_tail(.stderr),
        needs_note(*.device)
    )]
    Failed {
        device: DeviceChoice,
        status: String,
        found: Vec<String>,
        stderr: String,
    },
    #[error(
        "device '{device}' crashed its smoke test: the probe process was killed by signal {signal} ({name}), \
         typically a driver bug{}{}{}",
        found_note(.found),
        stderr_tail(.stderr),
        needs_note(*.device)
    )]
    Crashed {
        device: DeviceChoice,
        signal: i32,
        name: &'static str,
        found: Vec<String>,
        stderr: String,
    },
    #[error("device '{device}': the probe process exited 0 without running the smoke test")]
    NotRun { device: DeviceChoice },
    #[error(
        "device '{device}': the smoke test did not finish within {} s{}",
        .timeout.as_secs(),
        found_note(.found)
    )]
    TimedOut {
        device: DeviceChoice,
        timeout: Duration,
        found: Vec<String>,
    },
}

/// What the backend needs on the machine, for error messages.
fn needs_note(device: DeviceChoice) -> String {
    device
        .needs()
        .map(|n| format!("\n({n})"))
        .unwrap_or_default()
}

/// The adapters a probe child found, for error messages.
fn found_note(found: &[String]) -> String {
    if found.is_empty() {
        return String::new();
    }
    format!("; adapters found:\n  {}", found.join("\n  "))
}

/// For error messages: the child's own report of why it failed (its `anerf-probe:` lines) when it made
/// one, else the last lines of its standard error.
fn stderr_tail(stderr: &str) -> String {
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    let own: Vec<&str> = lines
        .iter()
        .copied()
        .filter(|l| l.starts_with(REPORT))
        .collect();
    let (heading, shown) = match (own.is_empty(), lines.is_empty()) {
        (false, _) => ("its report", &own[..]),
        (true, false) => ("its last output", &lines[lines.len().saturating_sub(6)..]),
        (true, true) => return String::new(),
    };
    format!("; {heading}:\n  {}", shown.join("\n  "))
}

/// Runs a small forward and backward pass on `device` in this process: linear layers with ReLU, a
/// concatenation, a gather, `exp` and reductions, then reads the gradients back and checks they are finite.
///
/// This checks that kernels compile and run, not that they are right (the backend comparison tests do that).
/// A broken driver may kill the process instead of returning: use [`probe_in_child`] to find out safely.
pub fn smoke_test(device: &Device) -> Result<(), SmokeFailure> {
    let device = device.clone().autodiff();
    let (n, d, w) = (64, 6, 16);
    let ramp = |len: usize, scale: f32| -> Vec<f32> {
        (0..len)
            .map(|i| ((i * 37 % 23) as f32 / 11.0 - 1.0) * scale)
            .collect()
    };
    let x = Tensor::<1>::from_floats(ramp(n * d, 1.0).as_slice(), &device).reshape([n, d]);
    let w1 = Tensor::<1>::from_floats(ramp(d * w, 0.4).as_slice(), &device)
        .reshape([d, w])
        .require_grad();
    let w2 = Tensor::<1>::from_floats(ramp((w + d) * 3, 0.3).as_slice(), &device)
        .reshape([w + d, 3])
        .require_grad();
    let h = Tensor::cat(vec![relu(x.clone().matmul(w1.clone())), x], 1);
    let y = h.matmul(w2.clone());
    let index = Tensor::<1, Int>::from_ints([3, 1, 4, 1, 5, 9, 2, 6].as_slice(), &device);
    let loss = (y.select(0, index).powi_scalar(2).neg().exp().sum_dim(1) + 1.0)
        .log()
        .sum();
    let grads = loss.backward();
    for (name, grad) in [("w1", w1.grad(&grads)), ("w2", w2.grad(&grads))] {
        let grad = grad.ok_or(SmokeFailure::NoGradient(name))?;
        let values = grad
            .try_into_vec_as::<f32>()
            .map_err(|e| SmokeFailure::ReadBack {
                name,
                detail: format!("{e:?}"),
            })?;
        if values.is_empty() || values.iter().any(|v| !v.is_finite()) {
            return Err(SmokeFailure::NotFinite { name, values });
        }
    }
    Ok(())
}

/// Makes a panic anywhere in a probe child its report, and ends the child at once (a panicking backend
/// thread would otherwise leave the main thread waiting). cudarc panics when it cannot load the CUDA
/// driver or NVRTC; that message then reaches the parent's error.
fn report_panics() {
    std::panic::set_hook(Box::new(|info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".into());
        eprintln!("{REPORT}panicked: {message}");
        std::process::exit(1);
    }));
}

/// When this process was started by [`probe_in_child`] (the [`PROBE_ENV`] variable names a backend), runs
/// [`smoke_test`] on it and exits: status 0 when it passed, 1 with the reason on standard error otherwise.
/// On standard output it lists the adapters found and names the one used. Does nothing in any other
/// process. Programs that probe call this first thing in `main`; tests, first thing in the test that the
/// child runs.
pub fn exit_if_probe_child() {
    let Some(name) = std::env::var_os(PROBE_ENV) else {
        return;
    };
    // On lines of their own: the test harness has already printed `test <name> ... ` unterminated.
    println!();
    report_panics();
    let outcome = name
        .to_string_lossy()
        .parse::<DeviceChoice>()
        .map_err(SmokeFailure::from)
        .and_then(|choice| {
            let (device, adapter) = open_for_probe(choice)?;
            smoke_test(&device)?;
            Ok(adapter)
        });
    match outcome {
        Ok(adapter) => {
            println!("{ADAPTER}{adapter}\n{PASSED}");
            std::process::exit(0)
        }
        Err(e) => {
            eprintln!("{REPORT}{e}");
            std::process::exit(1)
        }
    }
}

/// `choice`'s device, opened in a probe child, and the adapter it runs on. For wgpu, first prints every
/// adapter found (so that the parent can name them should the next steps crash), then initialises the
/// device explicitly: a missing adapter becomes an error here instead of a panic in a worker thread.
fn open_for_probe(choice: DeviceChoice) -> Result<(Device, String), SmokeFailure> {
    #[cfg(feature = "wgpu")]
    if choice == DeviceChoice::Wgpu {
        for adapter in wgpu_adapters() {
            println!("{FOUND}{}", describe_adapter(&adapter));
        }
        let (device, setup) =
            Device::wgpu_options()
                .init_with_setup()
                .map_err(|e| SmokeFailure::Open {
                    what: "wgpu",
                    detail: e.to_string(),
                })?;
        return Ok((device, describe_adapter(&setup.adapter.get_info())));
    }
    #[cfg(feature = "cuda")]
    if choice == DeviceChoice::Cuda {
        // Loads the driver library first, so that a missing one is reported before Burn starts threads.
        let name = cudarc::driver::CudaContext::new(0)
            .and_then(|context| context.name())
            .map_err(|e| SmokeFailure::Open {
                what: "CUDA device 0",
                detail: format!("{e:?}"),
            })?;
        println!("{FOUND}CUDA device 0: {name}");
        return Ok((choice.device()?, format!("CUDA: {name}")));
    }
    Ok((choice.device()?, UNNAMED.to_string()))
}

/// Every adapter wgpu finds on this machine, in the order Burn's automatic choice tries the graphics APIs
/// (Vulkan before OpenGL).
#[cfg(feature = "wgpu")]
fn wgpu_adapters() -> Vec<burn::tensor::wgpu::wgpu::AdapterInfo> {
    use burn::tensor::wgpu::wgpu;
    let backends = wgpu::Backends::PRIMARY | wgpu::Backends::SECONDARY;
    let instance = wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends,
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    });
    futures_lite::future::block_on(instance.enumerate_adapters(backends))
        .iter()
        .map(|adapter| adapter.get_info())
        .collect()
}

/// An adapter on one line: graphics API, name, device type and driver, e.g. `Vulkan: llvmpipe (LLVM 15.0.6,
/// 256 bits), Cpu, llvmpipe Mesa 22.3.6 (LLVM 15.0.6)` for Mesa's software driver (which runs on the CPU).
#[cfg(feature = "wgpu")]
fn describe_adapter(info: &burn::tensor::wgpu::wgpu::AdapterInfo) -> String {
    let driver = [info.driver.as_str(), info.driver_info.as_str()].join(" ");
    format!(
        "{:?}: {}, {:?}, {}",
        info.backend,
        info.name,
        info.device_type,
        driver.trim()
    )
}

/// Runs [`smoke_test`] for `choice` in `child`, a command that re-executes the current program (which must
/// call [`exit_if_probe_child`] early), with [`PROBE_ENV`] set; waits up to three minutes.
///
/// `Ok` with the adapter's name when the child printed its success line and exited 0; otherwise why not,
/// including the signal that killed it. The CPU backends are only checked to be compiled: they need no child
/// (`Ok(None)`).
pub fn probe_in_child(choice: DeviceChoice, child: Command) -> Result<Option<String>, ProbeError> {
    choice.device().map_err(|source| ProbeError::NotCompiled {
        device: choice,
        source,
    })?;
    if !choice.is_gpu() {
        return Ok(None);
    }
    run_child(choice, child).map(Some)
}

/// A backend that passed its check.
#[derive(Debug, Clone)]
pub struct CheckedDevice {
    pub device: Device,
    /// The adapter a GPU backend ran on, as the probe child reported it; `None` for CPU backends.
    pub adapter: Option<String>,
}

/// `choice`'s device once [`probe_in_child`] passed with the command `child` makes. The check runs once per
/// process and backend; later calls reuse its outcome (a program checks one backend with one command).
pub fn checked_device(
    choice: DeviceChoice,
    child: impl FnOnce() -> Command,
) -> Result<CheckedDevice, Arc<ProbeError>> {
    type Outcome = Result<Option<String>, Arc<ProbeError>>;
    static OUTCOMES: Mutex<Vec<(DeviceChoice, Outcome)>> = Mutex::new(Vec::new());

    let mut outcomes = OUTCOMES.lock().unwrap_or_else(|e| e.into_inner());
    let outcome = match outcomes.iter().find(|(c, _)| *c == choice) {
        Some((_, outcome)) => outcome.clone(),
        None => {
            let outcome = probe_in_child(choice, child()).map_err(Arc::new);
            outcomes.push((choice, outcome.clone()));
            outcome
        }
    };
    let adapter = outcome?;
    Ok(CheckedDevice {
        device: choice.device().expect("the probe created this device"),
        adapter,
    })
}

/// Runs `child` as a probe of `choice` (with [`PROBE_ENV`] set) and reads its outcome: the adapter it named
/// when it printed its success line and exited 0, else why not.
fn run_child(choice: DeviceChoice, mut child: Command) -> Result<String, ProbeError> {
    let program = child.get_program().to_string_lossy().into_owned();
    let mut process = child
        .env(PROBE_ENV, choice.to_string())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|source| ProbeError::Spawn {
            device: choice,
            program,
            source,
        })?;
    let stdout = read_in_background(process.stdout.take());
    let stderr = read_in_background(process.stderr.take());
    let status = wait_with_timeout(&mut process, TIMEOUT);
    let stdout = stdout.join().unwrap_or_default();
    let stderr = stderr.join().unwrap_or_default();
    let found: Vec<String> = stdout
        .lines()
        .filter_map(|l| l.trim().strip_prefix(FOUND))
        .map(str::to_string)
        .collect();
    let Some(status) = status else {
        return Err(ProbeError::TimedOut {
            device: choice,
            timeout: TIMEOUT,
            found,
        });
    };
    let passed = stdout.lines().any(|l| l.trim() == PASSED);
    match (status.success(), signal_of(&status)) {
        (true, _) if passed => Ok(stdout
            .lines()
            .find_map(|l| l.trim().strip_prefix(ADAPTER))
            .unwrap_or(UNNAMED)
            .to_string()),
        (true, _) => Err(ProbeError::NotRun { device: choice }),
        (false, Some(signal)) => Err(ProbeError::Crashed {
            device: choice,
            signal,
            name: signal_name(signal),
            found,
            stderr,
        }),
        (false, None) => Err(ProbeError::Failed {
            device: choice,
            status: status.to_string(),
            found,
            stderr,
        }),
    }
}

fn read_in_background<R: Read + Send + 'static>(
    pipe: Option<R>,
) -> std::thread::JoinHandle<String> {
    std::thread::spawn(move || {
        let mut text = String::new();
        if let Some(mut pipe) = pipe {
            let mut bytes = Vec::new();
            let _ = pipe.read_to_end(&mut bytes);
            text = String::from_utf8_lossy(&bytes).into_owned();
        }
        text
    })
}

/// The child's exit status, or `None` after killing it when it runs past `timeout`.
fn wait_with_timeout(child: &mut Child, timeout: Duration) -> Option<ExitStatus> {
    let start = Instant::now();
    loop {
        match child.try_wait() {
            Ok(Some(status)) => return Some(status),
            Ok(None) if start.elapsed() < timeout => std::thread::sleep(Duration::from_millis(50)),
            _ => {
                let _ = child.kill();
                let _ = child.wait();
                return None;
            }
        }
    }
}

#[cfg(unix)]
fn signal_of(status: &ExitStatus) -> Option<i32> {
    std::os::unix::process::ExitStatusExt::signal(status)
}

#[cfg(not(unix))]
fn signal_of(_: &ExitStatus) -> Option<i32> {
    None
}

fn signal_name(signal: i32) -> &'static str {
    match signal {
        4 => "SIGILL",
        6 => "SIGABRT",
        7 => "SIGBUS",
        8 => "SIGFPE",
        9 => "SIGKILL",
        11 => "SIGSEGV",
        15 => "SIGTERM",
        _ => "unknown signal",
    }
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    /// A probe child played by `sh -c script`.
    fn shell(script: &str) -> Result<String, ProbeError> {
        let mut command = Command::new("sh");
        command.args(["-c", script]);
        run_child(DeviceChoice::Wgpu, command)
    }

    #[test]
    fn a_child_that_passed_names_its_adapter() {
        let adapter = shell(&format!(
            "echo; echo '{ADAPTER}Mesa llvmpipe'; echo '{PASSED}'"
        ))
        .unwrap();
        assert_eq!(adapter, "Mesa llvmpipe");
    }

    #[test]
    fn a_child_killed_by_a_signal_is_a_crash_with_its_output() {
        let script =
            format!("echo '{FOUND}Vulkan: lavapipe'; echo 'building pipeline' >&2; kill -SEGV $$");
        let err = shell(&script).unwrap_err();
        assert!(
            matches!(err, ProbeError::Crashed { signal: 11, .. }),
            "{err:?}"
        );
        let message = err.to_string();
        for part in ["SIGSEGV", "building pipeline", "Vulkan: lavapipe"] {
            assert!(message.contains(part), "{part} missing from: {message}");
        }
    }

    #[test]
    fn a_failing_child_reports_its_status_and_output() {
        let script = format!("echo '{REPORT}no adapter' >&2; echo 'stack frame' >&2; exit 1");
        let err = shell(&script).unwrap_err();
        assert!(matches!(err, ProbeError::Failed { .. }), "{err:?}");
        let message = err.to_string();
        assert!(
            message.contains("exit status: 1") && message.contains("no adapter"),
            "{message}"
        );
        assert!(
            !message.contains("stack frame"),
            "only the child's own report: {message}"
        );
    }

    #[test]
    fn a_child_that_exits_0_without_the_probe_line_did_not_run() {
        let err = shell("echo 'running 0 tests'").unwrap_err();
        assert!(matches!(err, ProbeError::NotRun { .. }), "{err:?}");
    }

    /// cudarc's words when the driver library is missing (`cudarc::panic_no_lib_found`).
    const NO_CUDA: &str =
        "Unable to dynamically load the \"cuda\" shared library - searched for library \
                           names: [\"libcuda.so\", \"libcuda.so.1\"]";

    #[test]
    fn a_panic_in_a_probe_child_is_its_report_with_what_the_backend_needs() {
        if std::env::var_os(PROBE_ENV).is_some() {
            // The child: a backend that cannot load its driver.
            report_panics();
            panic!("{NO_CUDA}");
        }
        let mut child = Command::new(std::env::current_exe().unwrap());
        child.args([
            "probe::tests::a_panic_in_a_probe_child_is_its_report_with_what_the_backend_needs",
            "--exact",
            "--nocapture",
        ]);
        let err = run_child(DeviceChoice::Cuda, child).unwrap_err();
        assert!(matches!(err, ProbeError::Failed { .. }), "{err:?}");
        let message = err.to_string();
        for part in [
            "device 'cuda' failed",
            "panicked: Unable to dynamically load the \"cuda\" shared library",
            "libcuda.so.1",
            "libnvrtc.so.12",
        ] {
            assert!(message.contains(part), "{part} missing from: {message}");
        }
    }

    #[test]
    fn the_probe_environment_variable_reaches_the_child() {
        let script = format!("test \"${PROBE_ENV}\" = wgpu && echo '{PASSED}'");
        assert_eq!(shell(&script).unwrap(), UNNAMED);
    }
}
