//! The ablation drivers of `scripts/ablation/` run in `--quick` mode and tabulate what `anerf eval` measured.

use std::path::Path;
use std::process::Command;

/// Runs `scripts/ablation/<name>.sh --quick --out <out>` and returns its table.
fn run_quick(name: &str, out: &Path) -> String {
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../scripts/ablation/{name}.sh"));
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
    std::fs::read_to_string(out.join("table.md")).unwrap()
}

#[test]
fn quick_view_ablation_runs_and_tabulates_each_variant() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("views");
    let table = run_quick("views", &out);
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

#[test]
fn quick_generalisation_ablation_puts_the_three_splits_side_by_side() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("generalisation");
    let table = run_quick("generalisation", &out);
    let read = |variant: &str, split: &str| -> serde_json::Value {
        let path = out.join(format!("{variant}/eval/{split}/summary.json"));
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap()
    };
    for variant in [
        "authors",
        "zero_residual",
        "canonical_dirs",
        "no_view_dependence",
        "fast",
        "fast_random_residual",
        "fast_without_silhouette",
    ] {
        let [train, view, pose] =
            ["training-view", "novel-view", "novel-pose"].map(|s| read(variant, s));
        let psnr = |v: &serde_json::Value| v["psnr"].as_f64().unwrap();
        let ssim = |v: &serde_json::Value| v["ssim"].as_f64().unwrap();
        let row = format!(
            "| {variant} | {:.2} | {:.3} | {:.2} | {:.3} | {:.2} | {:.3} | {:.2} |",
            psnr(&train),
            ssim(&train),
            psnr(&view),
            ssim(&view),
            psnr(&pose),
            ssim(&pose),
            psnr(&train) - psnr(&view)
        );
        assert!(table.contains(&row), "{row} not in\n{table}");
    }
    // The variants' configs say what they changed.
    let saved = |variant: &str| -> toml::Table {
        toml::from_str(
            &std::fs::read_to_string(out.join(format!("{variant}/config.toml"))).unwrap(),
        )
        .unwrap()
    };
    assert_eq!(
        saved("authors")["model"]["residual_init"].as_str(),
        Some("random")
    );
    assert_eq!(
        saved("no_view_dependence")["model"]["view_direction"].as_str(),
        Some("none")
    );
    assert_eq!(
        saved("fast_random_residual")["model"]["residual_init"].as_str(),
        Some("random")
    );
    assert_eq!(
        saved("fast_without_silhouette")["train"]["mask_weight"].as_float(),
        Some(0.0)
    );
}
