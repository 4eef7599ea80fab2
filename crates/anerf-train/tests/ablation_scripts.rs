//! The ablation drivers of `scripts/ablation/` run in `--quick` mode and tabulate what `anerf eval` measured.

use std::path::Path;
use std::process::Command;

#[test]
fn quick_view_ablation_runs_and_tabulates_each_variant() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("views");
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/ablation/views.sh");
    let result = Command::new("bash")
        .arg(&script)
        .args(["--quick", "--out", out.to_str().unwrap()])
        .env("ANERF", env!("CARGO_BIN_EXE_anerf"))
        .output()
        .unwrap();
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    let table = std::fs::read_to_string(out.join("table.md")).unwrap();
    for n in 1..=3 {
        let summary: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join(format!("views_{n}/eval/novel-pose/summary.json")))
                .unwrap(),
        )
        .unwrap();
        let row = format!(
            "| views_{n} | {:.2} | {:.3} |",
            summary["psnr"].as_f64().unwrap(),
            summary["ssim"].as_f64().unwrap()
        );
        assert!(table.contains(&row), "{row} not in\n{table}");
        let saved: toml::Table = toml::from_str(
            &std::fs::read_to_string(out.join(format!("views_{n}/config.toml"))).unwrap(),
        )
        .unwrap();
        assert_eq!(saved["dataset"]["train_views"].as_array().unwrap().len(), n);
    }
}
