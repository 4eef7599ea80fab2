//! Helpers shared by the data integration tests: running the numpy checker on written files, copying and
//! cutting files (fixtures and comparison: the `anerf-testing` crate).

#![allow(dead_code)]

use std::path::Path;
use std::process::Command;

/// Runs `scripts/fixtures/check_synthetic.py <folder> <manifest>` and fails the test, with the script's
/// output, when python3 or numpy is missing or any file does not read back as the manifest says.
pub fn numpy_check(folder: &Path, manifest: &serde_json::Value) {
    let manifest_path = folder.with_extension("manifest.json");
    std::fs::write(&manifest_path, serde_json::to_vec(manifest).unwrap()).unwrap();
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/fixtures/check_synthetic.py");
    let out = Command::new("python3")
        .arg(&script)
        .arg(folder)
        .arg(&manifest_path)
        .output()
        .unwrap_or_else(|e| {
            panic!(
                "cannot run python3 {}: {e} (python3 with numpy is required)",
                script.display()
            )
        });
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "{} failed ({}):\n{stdout}\n{stderr}\n(install numpy: pip install -r scripts/fixtures/requirements.txt)",
        script.display(),
        out.status
    );
    println!("{}", stdout.trim());
}

/// Copies a fixture folder into a fresh temporary folder (for tests that break it).
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_tree(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// Cuts the file at `path` to its first `keep(len)` bytes, as an interrupted copy leaves it.
pub fn cut_file(path: &Path, keep: impl FnOnce(usize) -> usize) {
    let bytes = std::fs::read(path).unwrap();
    std::fs::write(path, &bytes[..keep(bytes.len())]).unwrap();
}
