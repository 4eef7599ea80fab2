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

fn script(name: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../scripts/gpu")
        .join(name)
}

/// The bundle as the GPU machine receives it, one `.tar.xz` made by scripts/gpu/pack.sh: the check unpacks
/// it and runs from it; a damaged archive stops the check with a message naming it; a bundle over the size
/// limit is refused with no archive left behind.
#[test]
fn the_packed_bundle_is_unpacked_and_one_over_the_limit_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = dir.path().join("bundle");
    std::fs::create_dir_all(bundle.join("vulkan")).unwrap();
    std::os::unix::fs::symlink(env!("CARGO_BIN_EXE_anerf"), bundle.join("anerf")).unwrap();
    let archive = dir.path().join("gpu-bundle.tar.xz");
    let packed = Command::new("bash")
        .arg(script("pack.sh"))
        .arg(&bundle)
        .arg(&archive)
        .output()
        .unwrap();
    assert!(
        packed.status.success(),
        "{}",
        String::from_utf8_lossy(&packed.stderr)
    );
    let out = dir.path().join("out");
    let result = Command::new("bash")
        .arg(script("device_check.sh"))
        .arg(&out)
        .env("BUNDLE", &archive)
        .env("DEVICES", "flex")
        .env("PRESETS", "tiny")
        .env("POINTS", "1024")
        .env("STEPS", "1")
        .env("DEMO", "0")
        .env("PYTHON", "/bin/false")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(result.status.success(), "{stderr}");
    assert!(stderr.contains("unpacking"), "{stderr}");
    let figures: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("figures.json")).unwrap()).unwrap();
    let bench = figures["steps"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["step"] == "bench_flex_tiny")
        .unwrap_or_else(|| panic!("{figures:#}"));
    assert_eq!(bench["outcome"], "passed", "{bench:#}");
    // CPU backends name no adapter; the libraries record says what was added to the loader's path.
    assert!(bench["result"]["adapter"].is_null(), "{bench:#}");
    assert!(figures["libraries"]["added"].is_array(), "{figures:#}");

    // A damaged archive: the check stops, naming it.
    let broken = dir.path().join("broken.tar.xz");
    std::fs::write(&broken, b"not an xz stream").unwrap();
    let result = Command::new("bash")
        .arg(script("device_check.sh"))
        .arg(dir.path().join("out2"))
        .env("BUNDLE", &broken)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(
        !result.status.success()
            && stderr.contains("cannot unpack")
            && stderr.contains("broken.tar.xz"),
        "{stderr}"
    );

    // Over the limit (1 MiB here, 60 by default): refused, nothing left.
    let big = dir.path().join("big");
    std::fs::create_dir(&big).unwrap();
    // Pseudo-random bytes xz cannot compress.
    let mut random = anerf_testing::Xorshift::default();
    let noise: Vec<u8> = (0..3 << 20)
        .map(|_| (random.next_bits() >> 32) as u8)
        .collect();
    std::fs::write(big.join("noise"), noise).unwrap();
    let too_big = dir.path().join("big.tar.xz");
    let packed = Command::new("bash")
        .arg(script("pack.sh"))
        .arg(&big)
        .arg(&too_big)
        .env("LIMIT_MIB", "1")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&packed.stderr);
    assert!(
        !packed.status.success() && stderr.contains("over the 1 MiB limit"),
        "{stderr}"
    );
    assert!(!too_big.exists() && !dir.path().join("big.tar.xz.tmp").exists());
}

/// scripts/gpu/llvm.sh, given an llvm-config (a stand-in here, Debian's LLVM in CI), writes the bundler's
/// marker and a wrapper that turns absolute library paths into -l flags; a second run changes nothing.
#[test]
fn the_llvm_stand_in_is_set_up_once_and_rewrites_library_paths() {
    let dir = tempfile::tempdir().unwrap();
    let fake = dir.path().join("llvm-config");
    std::fs::write(
        &fake,
        "#!/bin/sh\ncase \"$*\" in\n  *--system-libs*) echo '-lrt -ldl /usr/lib/x86_64-linux-gnu/libz3.so -lz /opt/x/libxml2.so.2' ;;\n  *) echo '-lLLVMCore -lLLVMSupport' ;;\nesac\n",
    )
    .unwrap();
    let chmod = Command::new("chmod").arg("+x").arg(&fake).status().unwrap();
    assert!(chmod.success());
    let data = dir.path().join("data");
    let run = || {
        let out = Command::new("bash")
            .arg(script("llvm.sh"))
            .env("LLVM_CONFIG", &fake)
            .env("XDG_DATA_HOME", &data)
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "{stdout}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        stdout
    };
    assert!(run().starts_with("set up"));
    let prefix = std::fs::read_dir(data.join("tracel"))
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    assert!(prefix
        .file_name()
        .unwrap()
        .to_string_lossy()
        .starts_with("tracel-llvm-"));
    let snapshot = anerf_testing::tree_snapshot(&prefix);
    let mtime = |p: &Path| std::fs::metadata(p).unwrap().modified().unwrap();
    let wrapper = prefix.join("bin/llvm-config");
    let before = (
        mtime(&wrapper),
        mtime(&prefix.join(".tracel-llvm-installed")),
    );
    assert!(run().starts_with("unchanged"));
    assert_eq!(anerf_testing::tree_snapshot(&prefix), snapshot);
    assert_eq!(
        (
            mtime(&wrapper),
            mtime(&prefix.join(".tracel-llvm-installed"))
        ),
        before
    );
    let libs = Command::new(&wrapper)
        .args(["--link-static", "--system-libs"])
        .output()
        .unwrap();
    assert_eq!(
        String::from_utf8_lossy(&libs.stdout).trim(),
        "-lrt -ldl -lz3 -lz -lxml2"
    );
}
