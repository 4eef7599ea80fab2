//! End-to-end training on the tiny synthetic subject: learning, exact resume, interrupts, full disks and bad
//! configurations.

// The helpers are the run crate's test helpers (tiny subjects and configs, quiet jobs), shared, not copied.
#[path = "../../../crates/anerf-run/tests/common/mod.rs"]
mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use anerf_device::cpu_device;
use anerf_eval::ImageMetrics;
use anerf_train::config::{self, ExperimentConfig};
use anerf_train::experiment::Experiment;
use anerf_train::render::render_view;
use anerf_train::run_start::RunStart;
use anerf_train::stage::Stage;
use anerf_train::training::checkpoint::Checkpoint;
use common::{quiet, tiny, train, trained};

fn losses(run: &Path) -> Vec<f32> {
    std::fs::read_to_string(run.join("metrics.jsonl"))
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v["stage"] == 1)
        .map(|v| v["loss"].as_f64().unwrap() as f32)
        .collect()
}

/// PSNR of frame 0 seen from held-out camera 1 under the run's latest stage-1 model (or an untrained one).
fn held_out_psnr(config: &ExperimentConfig, run: Option<&Path>) -> f64 {
    let device = cpu_device();
    let mut exp = Experiment::open(config.clone(), device.clone(), false).unwrap();
    let model = match run {
        Some(r) => {
            Checkpoint::latest(&r.join("checkpoints"), Stage::Train)
                .unwrap()
                .unwrap()
                .load_model(&config.model, &device)
                .unwrap()
                .0
        }
        None => {
            device.seed(config.seed);
            anerf_core::model::AnimatableNerf::new(&config.model, exp.model_sizes(), &device)
        }
    };
    let camera = exp.prepared.cameras[1].clone();
    let image = render_view(
        &model,
        &mut exp,
        anerf_core::FrameId(0),
        &camera,
        Some(anerf_core::ViewId(1)),
    )
    .unwrap();
    ImageMetrics::compute(
        &image.prediction,
        image.ground_truth.as_ref().unwrap(),
        Some(&image.mask),
    )
    .unwrap()
    .psnr
}

/// Sixty logged steps whose last ten average below 0.8 of the first ten.
fn assert_loss_falls(l: &[f32]) {
    assert_eq!(l.len(), 60);
    let (first, last) = (
        l[..10].iter().sum::<f32>() / 10.0,
        l[50..].iter().sum::<f32>() / 10.0,
    );
    assert!(
        last < 0.8 * first,
        "mean loss of the first ten steps {first}, of the last ten {last}"
    );
}

#[test]
fn a_few_steps_lower_the_loss_and_improve_a_held_out_view() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(dir.path(), &[]);
    let before = held_out_psnr(&config, None);
    let run = trained(&config, dir.path());
    assert_loss_falls(&losses(&run));
    let after = held_out_psnr(&config, Some(&run));
    assert!(
        after > before + 1.0,
        "held-out PSNR {before:.2} dB before, {after:.2} dB after training"
    );
}

/// `train --data <capture> --body-model <file>` on the EasyMocap fixture (the folder read directly, the
/// body posed from the fits, which are refined): the loss falls.
#[test]
fn a_short_run_on_an_easymocap_capture_lowers_the_loss() {
    let dir = tempfile::tempdir().unwrap();
    let load = anerf_data::LoadOptions {
        body_model: Some(anerf_testing::fixture("easymocap/body.npz")),
        ..Default::default()
    };
    let table = config::folder_table(&anerf_testing::fixture("easymocap/capture"), &load).unwrap();
    let settings = config::Settings {
        cache: Some(dir.path().join("cache")),
        preset: Some(anerf_core::model::ModelPreset::Tiny),
        iterations: Some(60),
        ..Default::default()
    };
    let set: Vec<String> = ["train.batch=256", "train.lr=4e-3", "train.log_every=1"]
        .map(String::from)
        .to_vec();
    let config = config::assemble(table, &settings, &set).unwrap();
    assert_eq!(config.dataset.format, config::DatasetFormat::Easymocap);
    assert!(
        config.model.pose_refinement.enabled,
        "a capture's fitted poses are refined"
    );
    assert_eq!(
        config.train.frames_per_step,
        config::REFINED_FRAMES_PER_STEP,
        "with several frames a step"
    );
    assert_eq!(
        config.model.pose_refinement.silhouette_weight,
        config::REFINED_SILHOUETTE_WEIGHT,
        "and the body silhouette term"
    );
    let run = trained(&config, dir.path());
    assert_loss_falls(&losses(&run));
}

#[test]
fn resuming_gives_the_losses_of_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(
        dir.path(),
        &["train.iterations=8", "train.checkpoint_every=100"],
    );
    let straight = dir.path().join("straight");
    let split = dir.path().join("split");
    let never = AtomicBool::new(false);
    anerf_run::train(
        config.clone(),
        &straight,
        &quiet(),
        RunStart::Fresh,
        None,
        &never,
    )
    .unwrap();
    let first = anerf_run::train(
        config.clone(),
        &split,
        &quiet(),
        RunStart::Fresh,
        Some(3),
        &never,
    )
    .unwrap();
    assert!(first.interrupted && first.steps == 3);
    let second = anerf_run::train(
        config.clone(),
        &split,
        &quiet(),
        RunStart::Resume,
        None,
        &never,
    )
    .unwrap();
    assert_eq!(second.steps, 8);
    let (a, b) = (losses(&straight), losses(&split));
    assert_eq!(a.len(), 8);
    assert_eq!(a, b, "losses of the uninterrupted and the resumed run");

    // Stage 2 resumes the same way.
    let never = AtomicBool::new(false);
    anerf_run::animate(&straight, &quiet(), RunStart::Fresh, None, &never).unwrap();
    anerf_run::animate(&split, &quiet(), RunStart::Fresh, Some(2), &never).unwrap();
    anerf_run::animate(&split, &quiet(), RunStart::Resume, None, &never).unwrap();
    let stage2 = |run: &Path| -> Vec<String> {
        std::fs::read_to_string(run.join("metrics.jsonl"))
            .unwrap()
            .lines()
            .filter(|l| l.contains("\"stage\":2"))
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap()["loss"].to_string())
            .collect()
    };
    assert_eq!(stage2(&straight).len(), 4);
    assert_eq!(stage2(&straight), stage2(&split));
}

fn anerf() -> Command {
    Command::new(env!("CARGO_BIN_EXE_anerf"))
}

fn write_config(dir: &Path, config: &ExperimentConfig) -> PathBuf {
    let path = dir.join("tiny.toml");
    std::fs::write(&path, config::to_toml(config)).unwrap();
    path
}

#[test]
fn an_interrupt_leaves_a_loadable_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(
        dir.path(),
        &["train.iterations=100000", "train.checkpoint_every=100000"],
    );
    let path = write_config(dir.path(), &config);
    let run = dir.path().join("run");
    let mut child = anerf()
        .args([
            "train",
            path.to_str().unwrap(),
            "--quiet",
            "--out",
            run.to_str().unwrap(),
        ])
        .spawn()
        .unwrap();
    let started = Instant::now();
    while !run.join("metrics.jsonl").is_file() || losses(&run).len() < 3 {
        assert!(
            started.elapsed() < Duration::from_secs(300),
            "training did not start"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let exit = child.wait().unwrap();
    assert_eq!(exit.code(), Some(130), "an interrupted run exits with 130");
    let ck = Checkpoint::latest(&run.join("checkpoints"), Stage::Train)
        .unwrap()
        .expect("a checkpoint after Ctrl-C");
    let (_, state) = ck.load_model(&config.model, &cpu_device()).unwrap();
    assert!(
        state.counters.step >= 3 && state.counters.step < 100000,
        "{}",
        state.counters.step
    );
}

#[test]
fn a_full_disk_while_checkpointing_keeps_the_previous_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(
        dir.path(),
        &["train.iterations=4", "train.checkpoint_every=2"],
    );
    let path = write_config(dir.path(), &config);
    let run = dir.path().join("run");
    let never = AtomicBool::new(false);
    anerf_run::train(
        config.clone(),
        &run,
        &quiet(),
        RunStart::Fresh,
        Some(2),
        &never,
    )
    .unwrap();
    let before = Checkpoint::latest(&run.join("checkpoints"), Stage::Train)
        .unwrap()
        .unwrap();
    let model_bytes = std::fs::read(before.dir.join("model.bpk")).unwrap();
    // Resume with files limited to 8 KiB: the log still fits, the model file does not (EFBIG, as on a full
    // disk). SIGXFSZ is ignored so that the write fails instead of killing the process.
    let script = format!(
        "trap '' XFSZ; ulimit -f 16; exec {} train {} --resume --quiet --out {}",
        env!("CARGO_BIN_EXE_anerf"),
        path.display(),
        run.display()
    );
    let out = Command::new("bash").args(["-c", &script]).output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("writing checkpoint")
            && stderr.contains("previous checkpoint is unchanged"),
        "{stderr}"
    );
    let after = Checkpoint::latest(&run.join("checkpoints"), Stage::Train)
        .unwrap()
        .unwrap();
    assert_eq!(after.dir, before.dir);
    assert_eq!(
        std::fs::read(after.dir.join("model.bpk")).unwrap(),
        model_bytes
    );
    after.load_model(&config.model, &cpu_device()).unwrap();
    assert!(std::fs::read_dir(run.join("checkpoints"))
        .unwrap()
        .all(|e| !e.unwrap().file_name().to_string_lossy().starts_with(".tmp")));
}

#[test]
fn bad_configurations_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let never = AtomicBool::new(false);
    let err = |c: ExperimentConfig| {
        format!(
            "{:#}",
            anerf_run::train(
                c,
                &dir.path().join("bad"),
                &quiet(),
                RunStart::Fresh,
                None,
                &never
            )
            .unwrap_err()
        )
    };
    let missing = tiny(dir.path(), &["dataset.root=\"/nonexistent/CoreView_999\""]);
    let e = err(missing);
    assert!(
        e.contains("dataset.root") && e.contains("/nonexistent/CoreView_999"),
        "{e}"
    );
    let e = err(tiny(dir.path(), &["dataset.train_views=[0, 9]"]));
    assert!(e.contains("dataset.train_views") && e.contains('9'), "{e}");
    let e = err(tiny(dir.path(), &["dataset.iccv.train_frames=\"50:60\""]));
    assert!(e.contains("train_frames") && e.contains("50:60"), "{e}");

    // A checkpoint of another model config is refused.
    let run = dir.path().join("run");
    anerf_run::train(
        tiny(dir.path(), &["train.iterations=2"]),
        &run,
        &quiet(),
        RunStart::Fresh,
        None,
        &never,
    )
    .unwrap();
    let wider = tiny(dir.path(), &["train.iterations=4", "model.width=48"]);
    let e = format!(
        "{:#}",
        anerf_run::train(wider, &run, &quiet(), RunStart::Resume, None, &never).unwrap_err()
    );
    assert!(e.contains("model"), "{e}");
}

#[test]
fn a_diverging_run_stops_with_a_clear_message_and_keeps_the_last_good_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    // An absurd learning rate blows the weights up after the first step; the loss turns infinite or NaN.
    let config = tiny(
        dir.path(),
        &[
            "train.lr=1e30",
            "train.lr_final=1e30",
            "train.grad_clip=0",
            "train.checkpoint_every=1",
            "train.iterations=20",
        ],
    );
    let run = dir.path().join("run");
    let err = train(&config, &run).unwrap_err();
    let message = format!("{err:#}");
    assert!(
        message.contains("the loss is") && message.contains("last good checkpoint"),
        "{message}"
    );
    let ck = Checkpoint::latest(&run.join("checkpoints"), Stage::Train)
        .unwrap()
        .expect("a checkpoint before the divergence");
    let (_, state) = ck.load_model(&config.model, &cpu_device()).unwrap();
    assert!(
        state.counters.step >= 1 && state.counters.step < 20,
        "{}",
        state.counters.step
    );
}

/// With standard error redirected (as under nohup or SLURM) a run prints a start line, a plain line per
/// logged window with the step, loss, PSNR, throughput and ETA, and an end line, for both stages.
#[test]
fn a_redirected_run_prints_plain_progress_lines() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(
        dir.path(),
        &[
            "train.iterations=30",
            "train.log_every=10",
            "animate.log_every=2",
        ],
    );
    let path = write_config(dir.path(), &config);
    let run = dir.path().join("run");
    // `output()` gives the child a pipe for standard error: not a terminal.
    let train = anerf()
        .args([
            "train",
            path.to_str().unwrap(),
            "--out",
            run.to_str().unwrap(),
        ])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&train.stderr);
    assert!(train.status.success(), "{stderr}");
    assert!(
        stderr.contains("stage 1: starting at step 0 of 30"),
        "{stderr}"
    );
    for step in [10, 20, 30] {
        let line = stderr
            .lines()
            .find(|l| l.starts_with(&format!("stage 1 step {step}/30 ")))
            .unwrap_or_else(|| panic!("no line for step {step}:\n{stderr}"));
        for field in ["loss ", "psnr ", " rays/s", "elapsed ", "ETA "] {
            assert!(line.contains(field), "{line}");
        }
    }
    assert!(
        stderr.contains("stage 1: finished at step 30 of 30 after "),
        "{stderr}"
    );
    let animate = anerf()
        .args(["animate", run.to_str().unwrap()])
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&animate.stderr);
    assert!(animate.status.success(), "{stderr}");
    assert!(
        stderr.contains("stage 2: starting at step 0 of 4")
            && stderr
                .lines()
                .any(|l| l.starts_with("stage 2 step 2/4 loss "))
            && stderr.contains("stage 2: finished at step 4 of 4"),
        "{stderr}"
    );
}
