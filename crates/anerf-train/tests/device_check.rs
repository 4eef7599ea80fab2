//! scripts/gpu/device_check.sh on a machine without a GPU (DEVICES=flex): the script's own paths, which a
//! GPU machine runs the same way. A step that works brings back its figures; one that fails (a backend not
//! compiled in) or cannot run (no kernel test binary, no PyTorch) is recorded with why, and the rest go on.

use std::path::Path;
use std::process::Command;

#[test]
fn the_device_check_records_every_step_and_goes_on_past_a_failed_one() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = dir.path().join("bundle");
    std::fs::create_dir(&bundle).unwrap();
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_anerf"), bundle.join("anerf")).unwrap();
    let out = dir.path().join("out");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/gpu/device_check.sh");
    let result = Command::new("bash")
        .arg(&script)
        .arg(&out)
        .env("BUNDLE", &bundle)
        // `flex` works; `cuda` is not compiled into the test build.
        .env("DEVICES", "flex cuda")
        .env("PRESETS", "tiny")
        .env("POINTS", "2048")
        .env("STEPS", "2")
        .env("DEMO", "0")
        // An interpreter without torch, whatever this machine has.
        .env("PYTHON", "/bin/false")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(result.status.success(), "{stderr}");
    let figures: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("figures.json")).unwrap()).unwrap();
    let steps = figures["steps"].as_array().unwrap();
    let step = |name: &str| {
        steps
            .iter()
            .find(|s| s["step"] == name)
            .unwrap_or_else(|| panic!("no step {name} in {figures:#}"))
    };
    let kernels = step("kernel_tests");
    assert_eq!(kernels["outcome"], "skipped");
    assert!(kernels["reason"]
        .as_str()
        .unwrap()
        .contains("no test binary"));
    let bench = step("bench_flex_tiny");
    assert_eq!(bench["outcome"], "passed", "{bench:#}");
    assert_eq!(bench["result"]["preset"], "tiny");
    assert_eq!(bench["result"]["points"], 2048);
    assert_eq!(bench["result"]["step_seconds"].as_array().unwrap().len(), 2);
    assert!(bench["seconds"].as_f64().unwrap() > 0.0);
    // The backend that is not compiled fails its step, and the check goes on to the next.
    let cuda = step("bench_cuda_tiny");
    assert_eq!(cuda["outcome"], "failed", "{cuda:#}");
    let log = std::fs::read_to_string(out.join("check.log")).unwrap();
    assert!(
        log.contains("'cuda' is not compiled into this binary"),
        "{log}"
    );
    assert_eq!(step("torch")["outcome"], "skipped");
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(stdout.contains("failed: bench_cuda_tiny"), "{stdout}");
}
