//! Pose refinement end to end on the tiny synthetic subject: the corrections are saved with the run,
//! resumed bit-exactly, written out beside the given fits, and used wherever the run renders a training
//! frame.

mod common;

use std::path::Path;
use std::sync::atomic::AtomicBool;

use anerf_core::geometry::Pose;
use anerf_core::model::FrameInputs;
use anerf_core::FrameId;
use anerf_device::cpu_device;
use anerf_train::experiment::Experiment;
use anerf_train::render::{render_shot, Shot};
use anerf_train::run_start::RunStart;
use anerf_train::stage::Stage;
use anerf_train::training::checkpoint::Checkpoint;
use common::{quiet, tiny};
use serde_json::Value;

fn refined_poses(run: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("refined_poses.json")).unwrap()).unwrap()
}

#[test]
fn refined_poses_resume_bit_exactly_and_serve_every_render_of_a_training_frame() {
    let dir = tempfile::tempdir().unwrap();
    let config = tiny(
        dir.path(),
        &[
            "train.iterations=8",
            "train.checkpoint_every=100",
            "model.pose_refinement.enabled=true",
        ],
    );
    let (straight, split) = (dir.path().join("straight"), dir.path().join("split"));
    let never = AtomicBool::new(false);
    let train = |run: &Path, start, steps| {
        anerf_run::train(config.clone(), run, &quiet(), start, steps, &never).unwrap()
    };
    train(&straight, RunStart::Fresh, None);
    assert!(train(&split, RunStart::Fresh, Some(3)).interrupted);
    train(&split, RunStart::Resume, None);
    let poses = refined_poses(&straight);
    assert_eq!(
        poses,
        refined_poses(&split),
        "refined poses of the uninterrupted and the resumed run"
    );

    // Every training frame is listed with its given fit (the dataset's) and a refined one that moved.
    let device = cpu_device();
    let mut exp = Experiment::open(config.clone(), device.clone(), false).unwrap();
    let frames = poses.as_array().unwrap();
    assert_eq!(frames.len(), exp.train_frames.len());
    let model = Checkpoint::latest(&straight.join("checkpoints"), Stage::Train)
        .unwrap()
        .unwrap()
        .load_model(&config.model, &device)
        .unwrap()
        .0;
    for (entry, &id) in frames.iter().zip(&exp.train_frames) {
        assert_eq!(entry["frame"], id.0);
        let given: Pose = serde_json::from_value(entry["given"].clone()).unwrap();
        let refined: Pose = serde_json::from_value(entry["refined"].clone()).unwrap();
        assert_eq!(given, exp.prepared.frame(id).unwrap().pose);
        assert_ne!(refined, given, "frame {id}: eight steps moved its fit");
        // The run's own account of the frame's pose (mesh, export) is the refined one.
        assert_eq!(exp.frame_pose(&model, id).unwrap(), refined);
    }

    // A render of a training frame (what `eval --split training-view` measures) uses the corrected bones:
    // without its given fit attached, the same frame renders differently.
    let id = FrameId(0);
    let inputs = exp.frame_inputs(id).unwrap();
    assert!(inputs.basis.is_some());
    let given_only = FrameInputs {
        basis: None,
        ..inputs.clone()
    };
    let camera = exp.prepared.cameras[1].clone();
    let render = |inputs: &FrameInputs| {
        let shot = Shot {
            inputs,
            bounds: exp.frame_bounds(id).unwrap(),
            camera: &camera,
            ground_truth: None,
        };
        render_shot(&model, exp.canonical(), &shot, &exp.config.eval)
            .unwrap()
            .prediction
    };
    let (refined, given) = (render(&inputs), render(&given_only));
    let changed = refined
        .as_raw()
        .iter()
        .zip(given.as_raw())
        .filter(|(a, b)| (*a - *b).abs() > 1e-4)
        .count();
    assert!(changed > 0, "the corrections changed no pixel");
}
