//! Nothing lost, nothing wrong accepted: run folders are never overwritten by accident, damaged checkpoints
//! fall back to intact ones, the metrics log survives faults and resumes to an uninterrupted run's windows,
//! impossible configs are refused before any work, and a run's paths hold from any working directory.

// The helpers are the run crate's test helpers (tiny subjects and configs, quiet jobs), shared, not copied.
#[path = "../../../crates/anerf-run/tests/common/mod.rs"]
mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;

use anerf_device::cpu_device;
use anerf_train::config::{self, ExperimentConfig};
use anerf_train::run_start::RunStart;
use anerf_train::stage::Stage;
use anerf_train::training::checkpoint::Checkpoint;
use anerf_train::training::StageOutcome;
use common::{quiet, tiny, tiny_config};

fn train(config: &ExperimentConfig, run: &Path, start: RunStart) -> anyhow::Result<StageOutcome> {
    train_steps(config, run, start, None)
}

fn train_steps(
    config: &ExperimentConfig,
    run: &Path,
    start: RunStart,
    steps: Option<usize>,
) -> anyhow::Result<StageOutcome> {
    anerf_run::train(
        config.clone(),
        run,
        &quiet(),
        start,
        steps,
        &AtomicBool::new(false),
    )
}

fn animate(run: &Path, start: RunStart) -> anyhow::Result<StageOutcome> {
    anerf_run::animate(run, &quiet(), start, None, &AtomicBool::new(false))
}

/// The records of `metrics.jsonl` of one stage, without the wall-clock throughput.
fn records(run: &Path, stage: u64) -> Vec<serde_json::Value> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["stage"] == stage)
        .map(|mut v| {
            v.as_object_mut().unwrap().remove("items_per_second");
            v
        })
        .collect()
}

/// Names of the checkpoint folders of a run, sorted.
fn checkpoint_names(run: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(run.join("checkpoints"))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .filter(|n| n.starts_with("stage"))
        .collect();
    names.sort();
    names
}

fn message(e: anyhow::Error) -> String {
    format!("{e:#}")
}

fn anerf() -> Command {
    Command::new(env!("CARGO_BIN_EXE_anerf"))
}

#[test]
fn an_existing_run_is_kept_unless_overwrite_is_asked_for() {
    let dir = tempfile::tempdir().unwrap();
    let long = tiny(
        dir.path(),
        &["train.iterations=8", "train.checkpoint_every=2"],
    );
    let run = dir.path().join("run");
    train(&long, &run, RunStart::Fresh).unwrap();
    let config_before = std::fs::read(run.join("config.toml")).unwrap();
    let log_before = std::fs::read(run.join("metrics.jsonl")).unwrap();
    assert_eq!(
        checkpoint_names(&run),
        ["stage1-00000006", "stage1-00000008"]
    );

    let short = tiny(
        dir.path(),
        &["train.iterations=4", "train.checkpoint_every=2"],
    );
    let e = message(train(&short, &run, RunStart::Fresh).unwrap_err());
    assert!(e.contains("--resume") && e.contains("--overwrite"), "{e}");
    assert_eq!(
        std::fs::read(run.join("config.toml")).unwrap(),
        config_before
    );
    assert_eq!(
        std::fs::read(run.join("metrics.jsonl")).unwrap(),
        log_before
    );
    assert_eq!(
        checkpoint_names(&run),
        ["stage1-00000006", "stage1-00000008"]
    );

    // --overwrite replaces the run whole: the new run's log and checkpoints only (the old higher-step
    // checkpoints used to survive and the new ones were pruned).
    train(&short, &run, RunStart::Overwrite).unwrap();
    assert_eq!(records(&run, 1).len(), 4);
    assert_eq!(
        checkpoint_names(&run),
        ["stage1-00000002", "stage1-00000004"]
    );
    assert_eq!(
        Checkpoint::latest(&run.join("checkpoints"), Stage::Train)
            .unwrap()
            .unwrap()
            .dir,
        run.join("checkpoints/stage1-00000004")
    );

    // Stage 2 likewise: a second `animate` is refused, --overwrite fits it again with a log of its own.
    animate(&run, RunStart::Fresh).unwrap();
    let e = message(animate(&run, RunStart::Fresh).unwrap_err());
    assert!(e.contains("--resume") && e.contains("--overwrite"), "{e}");
    animate(&run, RunStart::Overwrite).unwrap();
    assert_eq!(
        records(&run, 2).len(),
        4,
        "the tiny config's 4 stage-2 steps"
    );
}

/// A folder that looks like a run (it has a config.toml) but holds the dataset is never replaced, and a
/// config named `..` is refused before it can name the current folder as the run.
#[test]
fn overwrite_never_deletes_the_dataset_and_a_dot_dot_name_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(dir.path(), &["train.iterations=2"]);
    let work = dir.path();
    std::fs::write(work.join("config.toml"), "name = 'looks like a run'").unwrap();
    let before = anerf_testing::tree_snapshot(work);
    let e = message(train(&config, work, RunStart::Overwrite).unwrap_err());
    assert!(
        e.contains("holds the input") && e.contains("subject"),
        "{e}"
    );
    assert_eq!(anerf_testing::tree_snapshot(work), before);

    for name in ["..", "."] {
        let e = tiny_config(dir.path(), &[&format!("name=\"{name}\"")])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("name") && e.contains("one folder name"),
            "{name}: {e}"
        );
    }
    assert_eq!(anerf_testing::tree_snapshot(work), before);
}

#[test]
fn overwrite_refuses_a_folder_that_is_not_a_run_and_a_bad_start_keeps_the_old_run() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(dir.path(), &["train.iterations=2"]);
    let other = dir.path().join("papers");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::write(other.join("thesis.tex"), "years of work").unwrap();
    let e = message(train(&config, &other, RunStart::Overwrite).unwrap_err());
    assert!(e.contains("not a run folder"), "{e}");
    assert!(other.join("thesis.tex").is_file());
    let e = message(train(&config, &other, RunStart::Fresh).unwrap_err());
    assert!(e.contains("other file"), "{e}");

    let run = dir.path().join("run");
    train(&config, &run, RunStart::Fresh).unwrap();
    let log = std::fs::read(run.join("metrics.jsonl")).unwrap();
    let broken = tiny(dir.path(), &["dataset.root=\"/nonexistent/subject\""]);
    let e = message(train(&broken, &run, RunStart::Overwrite).unwrap_err());
    assert!(e.contains("dataset.root"), "{e}");
    assert_eq!(std::fs::read(run.join("metrics.jsonl")).unwrap(), log);
    assert_eq!(checkpoint_names(&run), ["stage1-00000002"]);
}

#[test]
fn resume_without_something_to_resume_is_refused_and_a_failed_start_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(dir.path(), &["train.iterations=2"]);
    let missing = dir.path().join("missing");
    let e = message(train(&config, &missing, RunStart::Resume).unwrap_err());
    assert!(
        e.contains("--resume") && e.contains("does not exist"),
        "{e}"
    );
    assert!(!missing.exists(), "--resume created {}", missing.display());

    let empty_run = dir.path().join("empty");
    std::fs::create_dir_all(&empty_run).unwrap();
    std::fs::write(empty_run.join("config.toml"), config::to_toml(&config)).unwrap();
    let e = message(train(&config, &empty_run, RunStart::Resume).unwrap_err());
    assert!(e.contains("no stage-1 checkpoint"), "{e}");

    let run = dir.path().join("run");
    train(&config, &run, RunStart::Fresh).unwrap();
    let e = message(animate(&run, RunStart::Resume).unwrap_err());
    assert!(e.contains("no stage-2 checkpoint"), "{e}");

    // Bad data: refused before the folder is made.
    let fresh = dir.path().join("fresh");
    let broken = tiny(dir.path(), &["dataset.root=\"/nonexistent/subject\""]);
    assert!(train(&broken, &fresh, RunStart::Fresh).is_err());
    assert!(!fresh.exists());
    // A run that diverges before its first checkpoint leaves no half-made folder behind.
    let diverging = tiny(
        dir.path(),
        &[
            "train.lr=1e30",
            "train.lr_final=1e30",
            "train.grad_clip=0",
            "train.checkpoint_every=1000",
            "train.iterations=20",
        ],
    );
    let e = message(train(&diverging, &fresh, RunStart::Fresh).unwrap_err());
    assert!(e.contains("the loss is"), "{e}");
    assert!(!fresh.exists(), "a failed start left {}", fresh.display());
}

/// A copy of `run` in `dir/name` with `damage` applied to it.
fn damaged_copy(run: &Path, dir: &Path, name: &str, damage: impl Fn(&Path)) -> PathBuf {
    let copy = dir.join(name);
    let status = Command::new("cp")
        .args(["-r", run.to_str().unwrap(), copy.to_str().unwrap()])
        .status()
        .unwrap();
    assert!(status.success());
    damage(&copy.join("checkpoints"));
    copy
}

fn truncate(path: &Path) {
    let bytes = std::fs::read(path).unwrap();
    std::fs::write(path, &bytes[..bytes.len() / 2]).unwrap();
}

#[test]
fn a_damaged_checkpoint_falls_back_to_the_newest_intact_one() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(
        dir.path(),
        &["train.iterations=4", "train.checkpoint_every=2"],
    );
    let run = dir.path().join("run");
    train(&config, &run, RunStart::Fresh).unwrap();
    let newest = "stage1-00000004";
    let cases: Vec<(&str, Box<dyn Fn(&Path)>)> = vec![
        (
            "model",
            Box::new(|c: &Path| truncate(&c.join(newest).join("model.bpk"))),
        ),
        (
            "optim",
            Box::new(|c: &Path| truncate(&c.join(newest).join("optim.bpk"))),
        ),
        (
            "state",
            Box::new(|c: &Path| truncate(&c.join(newest).join("state.json"))),
        ),
        (
            "flipped",
            Box::new(|c: &Path| {
                // Same length, one byte changed: only the manifest's digest can tell.
                let path = c.join(newest).join("model.bpk");
                let mut bytes = std::fs::read(&path).unwrap();
                let i = bytes.len() - 9;
                bytes[i] ^= 0x40;
                std::fs::write(&path, bytes).unwrap();
            }),
        ),
        (
            "pointer",
            Box::new(|c: &Path| std::fs::remove_dir_all(c.join(newest)).unwrap()),
        ),
    ];
    let device = cpu_device().autodiff();
    for (name, damage) in &cases {
        let copy = damaged_copy(&run, dir.path(), name, damage);
        let checkpoints = copy.join("checkpoints");
        // With the optimiser (resume) every case falls back to step 2.
        let restored = Checkpoint::restore_newest(
            &checkpoints,
            Stage::Train,
            &config.model,
            &device,
            Some(&|| burn::optim::AdamConfig::new().init()),
        )
        .unwrap()
        .unwrap();
        assert_eq!(restored.state.counters.step, 2, "{name}");
        // Resuming continues from there and gives the uninterrupted run's log.
        let resumed = train(&config, &copy, RunStart::Resume).unwrap();
        assert_eq!(resumed.steps, 4, "{name}");
        assert_eq!(records(&copy, 1), records(&run, 1), "{name}");
        assert!(!checkpoint_names(&copy).is_empty());
    }

    // `eval` says which file is bad and which checkpoint it used.
    let copy = damaged_copy(&run, dir.path(), "eval", &cases[0].1);
    let out = anerf()
        .args(["eval", copy.to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("model.bpk") && stderr.contains("damaged"),
        "{stderr}"
    );
    assert!(stderr.contains("stage1-00000002"), "{stderr}");
    // A `latest` pointer to a missing folder is named too.
    let copy = damaged_copy(&run, dir.path(), "eval-pointer", &cases[4].1);
    let out = anerf()
        .args(["eval", copy.to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("latest-stage1") && stderr.contains("does not exist"),
        "{stderr}"
    );

    // Every checkpoint damaged: an error that lists each.
    let all = damaged_copy(&run, dir.path(), "all", |c: &Path| {
        for n in ["stage1-00000002", newest] {
            truncate(&c.join(n).join("model.bpk"));
        }
    });
    let e = message(train(&config, &all, RunStart::Resume).unwrap_err());
    assert!(
        e.contains("stage1-00000002") && e.contains(newest) && e.contains("damaged"),
        "{e}"
    );
}

/// The issue's case: with `log_every = 3`, a run stopped at step 4 and resumed logs the same windows
/// (steps 4..6 at step 6) as an uninterrupted run; a half-written line left by a fault is dropped.
#[test]
fn a_resumed_log_equals_an_uninterrupted_one_and_drops_a_partial_line() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(
        dir.path(),
        &[
            "train.iterations=9",
            "train.log_every=3",
            "train.checkpoint_every=1000",
        ],
    );
    let straight = dir.path().join("straight");
    train(&config, &straight, RunStart::Fresh).unwrap();
    let split = dir.path().join("split");
    assert!(
        train_steps(&config, &split, RunStart::Fresh, Some(4))
            .unwrap()
            .interrupted
    );
    let log = split.join("metrics.jsonl");
    let mut text = std::fs::read_to_string(&log).unwrap();
    text.push_str("{\"stage\":1,\"step\":5,\"lo");
    std::fs::write(&log, text).unwrap();
    train(&config, &split, RunStart::Resume).unwrap();
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(text.ends_with('\n'));
    let (a, b) = (records(&straight, 1), records(&split, 1));
    assert_eq!(a.len(), 3);
    assert_eq!(a, b);
}

/// A full disk while appending to the log (a file-size limit that the next line crosses) leaves only
/// whole lines; a later resume completes the log as an uninterrupted run's.
#[test]
fn a_full_disk_while_logging_leaves_only_whole_lines() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(
        dir.path(),
        &["train.iterations=60", "train.checkpoint_every=1000"],
    );
    let run = dir.path().join("run");
    train_steps(&config, &run, RunStart::Fresh, Some(2)).unwrap();
    let path = dir.path().join("tiny.toml");
    std::fs::write(&path, config::to_toml(&config)).unwrap();
    // 4 KiB: more than the log so far and the config, less than 60 lines of log.
    let script = format!(
        "trap '' XFSZ; ulimit -f 8; exec {} train {} --resume --quiet --out {}",
        env!("CARGO_BIN_EXE_anerf"),
        path.display(),
        run.display()
    );
    let out = Command::new("bash").args(["-c", &script]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(stderr.contains("metrics.jsonl"), "{stderr}");
    let text = std::fs::read_to_string(run.join("metrics.jsonl")).unwrap();
    assert!(text.len() > 3 * 1024, "the log reached the limit");
    assert!(text.ends_with('\n'), "a partial line was left behind");
    for line in text.lines() {
        serde_json::from_str::<serde_json::Value>(line).unwrap();
    }
}

#[test]
fn impossible_config_values_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let cases: [(&[&str], &[&str]); 7] = [
        (&["train.iterations=0"], &["train.iterations", "0"]),
        (
            &[
                "dataset.iccv.train_frames=\"0:1000\"",
                "dataset.iccv.novel_pose_frames=\"0:0\"",
            ],
            &["dataset.iccv.train_frames", "0:1000", "10 frames"],
        ),
        (
            &["dataset.iccv.novel_pose_frames=\"50:60\""],
            &["dataset.iccv.novel_pose_frames", "50:60", "10 frames"],
        ),
        (
            &["dataset.iccv.novel_pose_frames=\"4:10\""],
            &["dataset.iccv.novel_pose_frames", "4:10", "train_frames"],
        ),
        (&["train.lr_final=inf"], &["train.lr_final", "inf"]),
        (
            &["train.batch=99999999999"],
            &["train.batch", "99999999999", "GiB"],
        ),
        (
            &["model.samples_per_ray=100000000"],
            &["model.samples_per_ray", "100000000", "GiB"],
        ),
    ];
    for (overrides, expected) in cases {
        let e = match tiny_config(dir.path(), overrides) {
            Err(e) => e.to_string(),
            Ok(c) => message(train(&c, &run, RunStart::Fresh).unwrap_err()),
        };
        for word in expected {
            assert!(e.contains(word), "{overrides:?}: {e}");
        }
        assert!(!run.exists(), "{overrides:?} left {}", run.display());
    }
}

/// `anerf train --data <relative folder>` stores paths that still resolve when the run is evaluated from
/// another working directory.
#[test]
fn a_run_trained_on_a_relative_folder_evaluates_from_anywhere() {
    let dir = tempfile::tempdir().unwrap();
    tiny(dir.path(), &[]);
    let out = anerf()
        .current_dir(dir.path())
        .args([
            "train",
            "--data",
            "subject",
            "--preset",
            "tiny",
            "--iterations",
            "2",
            "--out",
            "run",
            "--quiet",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let elsewhere = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let out = anerf()
        .current_dir(elsewhere.path())
        .args(["eval", run.to_str().unwrap(), "--quiet"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let saved = std::fs::read_to_string(run.join("config.toml")).unwrap();
    assert!(
        saved.contains(&format!("root = \"{}", dir.path().display())),
        "{saved}"
    );
}

/// `anerf import easymocap`: writes a folder the ZJU-MoCap loader reads, refuses to replace it unless
/// asked, and a capture without its body model writes nothing.
#[test]
fn import_writes_a_zju_folder_once_and_replaces_it_only_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("zju");
    let import = |extra: &[&str]| {
        anerf()
            .args(["import", "easymocap"])
            .arg(anerf_testing::fixture("easymocap/capture"))
            .arg("--out")
            .arg(&out)
            .args(extra)
            .output()
            .unwrap()
    };
    let body = anerf_testing::fixture("easymocap/body.npz");
    let body = body.to_str().unwrap();
    let without_model = import(&[]);
    assert!(!without_model.status.success());
    let stderr = String::from_utf8_lossy(&without_model.stderr);
    assert!(stderr.contains("--body-model"), "{stderr}");
    assert!(!out.exists());

    assert!(import(&["--body-model", body]).status.success());
    let subject = anerf_data::load_zju_mocap(&out, &anerf_data::LoadOptions::default()).unwrap();
    assert_eq!((subject.cameras.len(), subject.frames.len()), (3, 4));
    let again = import(&["--body-model", body]);
    assert!(!again.status.success());
    let stderr = String::from_utf8_lossy(&again.stderr);
    assert!(stderr.contains("--overwrite"), "{stderr}");
    assert!(import(&["--body-model", body, "--overwrite"])
        .status
        .success());
    assert!(anerf_data::load_zju_mocap(&out, &anerf_data::LoadOptions::default()).is_ok());
}

/// Output to a closed pipe (`anerf info DIR | true`) ends `anerf` by SIGPIPE, as it ends Unix tools, with
/// nothing on standard error: no panic about a broken pipe.
#[test]
fn output_to_a_closed_pipe_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    use std::process::Stdio;
    let dir = tempfile::tempdir().unwrap();
    tiny(dir.path(), &[]);
    let mut child = Command::new(env!("CARGO_BIN_EXE_anerf"))
        .arg("info")
        .arg(dir.path().join("subject"))
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before anything is written.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !stderr.contains("panicked") && !stderr.contains("Broken pipe"),
        "{stderr}"
    );
    const SIGPIPE: i32 = 13;
    assert_eq!(
        out.status.signal(),
        Some(SIGPIPE),
        "{:?}: {stderr}",
        out.status
    );
}
