use anerf_core::model::ModelPreset;
use anerf_core::named::Named;

use super::frames::MAX_RANGE_FRAMES;
use super::presets::{mask_note, plateau_note};
use super::*;

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

const SUBJECT: &str = r#"
name = "s"
[dataset]
format = "zju_mocap"
root = "data/x"
ratio = 0.5
train_views = [0, 6]
iccv = { train_frames = "0:60", novel_pose_frames = "60:1060" }
[model]
preset = "tiny"
width = 48
"#;

#[test]
fn inheritance_overrides_and_presets() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "base.toml", SUBJECT);
    let child = write(
        dir.path(),
        "child.toml",
        "base = \"base.toml\"\nname = \"child\"\n[train]\niterations = 7\n",
    );
    let c = load(
        &child,
        &["train.batch=64".into(), "dataset.ranges=iccv".into()],
    )
    .unwrap();
    assert_eq!(c.name, "child");
    assert_eq!(
        (c.train.iterations, c.train.batch, c.train.lr),
        (7, 64, 5e-4)
    );
    // The preset's sizes with the file's override on top.
    let tiny = ModelPreset::Tiny.config();
    assert_eq!((c.model.width, c.model.depth), (48, tiny.depth));
    assert_eq!(
        c.dataset.split().train_frames.frames(),
        (0..60).collect::<Vec<_>>()
    );
    // The resolved config round-trips through its TOML.
    let again = from_table(toml::from_str(&to_toml(&c)).unwrap()).unwrap();
    assert_eq!(again, c);
    let saved = write(dir.path(), "resolved.toml", &to_toml(&c));
    assert_eq!(load(&saved, &[]).unwrap(), c);
}

/// Without `lr` in any file, the rates follow the encoding; a given rate is kept.
#[test]
fn learning_rates_default_by_encoding() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "s.toml", SUBJECT);
    let rates = |c: &ExperimentConfig| {
        (
            c.train.lr,
            c.train.lr_final,
            c.animate.lr,
            c.animate.lr_final,
        )
    };
    assert_eq!(rates(&load(&p, &[]).unwrap()), (5e-4, 5e-5, 5e-4, 5e-5));
    let fast = load(&p, &["model.preset=fast".into()]).unwrap();
    assert_eq!(rates(&fast), (1e-2, 1e-3, 1e-2, 1e-3));
    let given = load(&p, &["model.preset=fast".into(), "train.lr=3e-3".into()]).unwrap();
    assert_eq!(rates(&given), (3e-3, 1e-3, 1e-2, 1e-3));
}

/// A config that names only its subject gets the documented defaults: the paper's model and schedule,
/// checkpoints every 5,000 steps in stage 1 and 2,000 in stage 2 (which never validates), ZJU-MoCap's
/// evaluation interval, seed 0 on the CPU.
#[test]
fn a_minimal_config_gets_the_documented_defaults() {
    let dir = tempfile::tempdir().unwrap();
    let minimal = SUBJECT.replace("[model]\npreset = \"tiny\"\nwidth = 48\n", "");
    assert!(!minimal.contains("[model]"));
    let c = load(&write(dir.path(), "s.toml", &minimal), &[]).unwrap();
    assert_eq!(c.model, ModelPreset::Paper.config());
    assert_eq!((c.seed, c.device), (0, DeviceChoice::Flex));
    let stage = |s: &StageConfig| {
        (
            s.iterations,
            s.batch,
            s.checkpoint_every,
            s.validate_every,
            s.log_every,
            s.grad_clip,
            s.schedule,
        )
    };
    assert_eq!(
        stage(&c.train),
        (200_000, 1024, 5000, 5000, 100, 40.0, LrSchedule::Paper)
    );
    assert_eq!(
        stage(&c.animate),
        (10_000, 65_536, 2000, 0, 100, 40.0, LrSchedule::Paper)
    );
    assert_eq!(
        (
            c.train.edge_scale,
            c.train.plateau_tolerance,
            c.train.residual_weight,
            c.train.views_per_step
        ),
        (0.1, 0.01, 0.0, 1)
    );
    assert_eq!(
        (c.eval.frame_interval, c.eval.chunk, c.eval.termination),
        (30, 4096, 1e-4)
    );
}

/// The rates follow the model's encoding, not its preset's name: the paper's model switched to the fast
/// preset's hash grids trains at the hash grids' rates.
#[test]
fn learning_rates_follow_an_encoding_set_over_a_preset() {
    let dir = tempfile::tempdir().unwrap();
    let encoding = toml::Table::try_from(ModelPreset::Fast.config()).unwrap()["encoding"].clone();
    let mut table: toml::Table = toml::from_str(SUBJECT).unwrap();
    let model = table["model"].as_table_mut().unwrap();
    model.insert("preset".into(), "paper".into());
    model.insert("encoding".into(), encoding);
    let path = write(dir.path(), "s.toml", &toml::to_string(&table).unwrap());
    let c = load(&path, &[]).unwrap();
    assert_eq!(
        (c.model.width, c.model.depth),
        (48, ModelPreset::Paper.config().depth)
    );
    assert_eq!((c.train.lr, c.animate.lr_final), (1e-2, 1e-3));
    assert_eq!(c.train.iterations, 200_000, "the paper preset's schedule");
}

#[test]
fn errors_name_the_key_and_the_allowed_values() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "s.toml", SUBJECT);
    let err = load(&p, &["model.preset=huge".into()])
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("model.preset") && err.contains("paper, cpu, tiny"),
        "{err}"
    );
    let err = load(&p, &["dataset.ratio=2".into()])
        .unwrap_err()
        .to_string();
    assert!(err.contains("dataset.ratio"), "{err}");
    let err = load(&p, &["train.schedule=cosine".into()])
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("cosine") && err.contains("paper") && err.contains("code"),
        "{err}"
    );
    let err = load(&p, &["train.mask_edges=sometimes".into()])
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("sometimes") && err.contains(r#""skip", "train", "robust" or "backdrop""#),
        "{err}"
    );
    for scale in ["0", "-0.1", "nan"] {
        let err = load(&p, &[format!("train.edge_scale={scale}")])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("train.edge_scale") && err.contains("positive, finite"),
            "{err}"
        );
    }
    for share in ["-0.1", "1.5", "nan"] {
        let err = load(&p, &[format!("train.detail_fraction={share}")])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("train.detail_fraction") && err.contains("from 0 to 1"),
            "{share}: {err}"
        );
    }
    for weight in ["-0.1", "inf", "nan", "1e7"] {
        let err = load(
            &p,
            &[format!("model.pose_refinement.silhouette_weight={weight}")],
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("model.pose_refinement.silhouette_weight")
                && err.contains("0 or a positive number up to"),
            "{weight}: {err}"
        );
    }
    let err = load(&p, &["train.views_per_step=0".into()])
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("train.views_per_step") && err.contains("1 up to the batch"),
        "{err}"
    );
    for frames in [
        "train.frames_per_step=0",
        "train.frames_per_step=100000",
        "train.frames_per_step=9223372036854775807",
    ] {
        // Four views a step: the largest count times four does not fit a usize.
        let err = load(&p, &[frames.into(), "train.views_per_step=4".into()])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("train.frames_per_step") && err.contains("batch over views_per_step"),
            "{frames}: {err}"
        );
    }
    let err = load(&p, &["train.typo=1".into()]).unwrap_err().to_string();
    assert!(err.contains("typo"), "{err}");
    let err = load(&p, &["device=tpu".into()]).unwrap_err().to_string();
    assert!(err.contains("tpu") && err.contains("flex"), "{err}");
    let err = load(&p, &["dataset.iccv.train_frames=9:3".into()])
        .unwrap_err()
        .to_string();
    assert!(err.contains("9:3"), "{err}");
    assert!(matches!(
        load(&p, &["nonsense".into()]),
        Err(ConfigError::BadOverride(_))
    ));
}

/// Without step counts in any file, each preset trains its own schedule; given ones are kept.
#[test]
fn presets_carry_their_schedules() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "s.toml", SUBJECT);
    let steps = |c: &ExperimentConfig| (c.train.iterations, c.animate.iterations, c.animate.batch);
    for preset in ModelPreset::ALL {
        let c = load(&p, &[format!("model.preset={}", preset.name())]).unwrap();
        let s = preset_schedule(preset);
        assert_eq!(
            steps(&c),
            (s.train_iterations, s.animate_iterations, s.animate_batch)
        );
    }
    assert_eq!(preset_schedule(ModelPreset::Fast).train_iterations, 5_000);
    assert_eq!(
        preset_schedule(ModelPreset::Paper).train_iterations,
        200_000
    );
    let given = load(
        &p,
        &["model.preset=fast".into(), "train.iterations=7".into()],
    )
    .unwrap();
    assert_eq!(steps(&given), (7, 300, 16_384));
    assert_eq!(given.animate.plateau_steps, 100);
    assert_eq!(given.train.mask_weight, 0.1);
    assert_eq!(given.train.views_per_step, 4);
    let paper = load(&p, &["model.preset=paper".into()]).unwrap();
    assert_eq!(paper.train.mask_weight, 0.0, "the paper fits colours alone");
    assert_eq!(
        paper.train.views_per_step, 1,
        "one image a step, as the reference"
    );
    let set = load(
        &p,
        &["model.preset=fast".into(), "train.mask_weight=0".into()],
    )
    .unwrap();
    assert_eq!(set.train.mask_weight, 0.0, "a config's value wins");
    let help = preset_help();
    for preset in ModelPreset::ALL {
        let s = preset_schedule(preset);
        assert!(
            help.contains(&format!(
                "{:<6} stage 1 {} iterations{}, stage 2 {} iterations of {} points{}",
                preset.name(),
                s.train_iterations,
                mask_note(s.train_mask_weight),
                s.animate_iterations,
                s.animate_batch,
                plateau_note(s.animate_plateau_steps)
            )),
            "{help}"
        );
    }
}

#[test]
fn base_cycles_are_reported() {
    let dir = tempfile::tempdir().unwrap();
    write(dir.path(), "a.toml", "base = \"b.toml\"");
    let b = write(dir.path(), "b.toml", "base = \"a.toml\"");
    assert!(matches!(load(&b, &[]), Err(ConfigError::BaseCycle { .. })));
}

/// A range too long to list is refused by validation, naming the key and the bound, before anything lists
/// its frames (the list of `0:100000000000000` would need 800 TB).
#[test]
fn a_frame_range_too_long_to_list_is_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "s.toml", SUBJECT);
    for range in ["0:100000000000000", "0:18446744073709551615", "5:1000006"] {
        let err = load(&p, &[format!("dataset.iccv.train_frames={range:?}")])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("dataset.iccv.train_frames")
                && err.contains(range)
                && err.contains(&MAX_RANGE_FRAMES.to_string()),
            "{err}"
        );
    }
    let c = load(
        &p,
        &[
            "dataset.iccv.train_frames=\"0:1000000\"".into(),
            "dataset.iccv.novel_pose_frames=\"1000000:1000010\"".into(),
        ],
    )
    .unwrap();
    assert_eq!(c.dataset.split().train_frames.len(), MAX_RANGE_FRAMES);
}

/// `len` counts what `frames` lists, and `within` cuts to a dataset without listing.
#[test]
fn frame_range_len_and_within_agree_with_the_listed_frames() {
    for start in 0..7 {
        for end in start..20 {
            for step in 1..5 {
                let r = FrameRange { start, end, step };
                assert_eq!(r.len(), r.frames().len(), "{r}");
                for available in 0..22 {
                    let listed: Vec<usize> =
                        r.frames().into_iter().filter(|&f| f < available).collect();
                    assert_eq!(
                        r.within(available).frames(),
                        listed,
                        "{r} within {available}"
                    );
                }
            }
        }
    }
    let huge = FrameRange {
        start: 3,
        end: usize::MAX,
        step: 2,
    };
    assert_eq!(huge.within(10).frames(), vec![3, 5, 7, 9]);
}

#[test]
fn frame_ranges_parse_and_print() {
    let r: FrameRange = "10:20:5".parse().unwrap();
    assert_eq!(r.frames(), vec![10, 15]);
    assert_eq!(r.to_string(), "10:20:5");
    assert!("5".parse::<FrameRange>().is_err());
    assert!("0:10:0".parse::<FrameRange>().is_err());
}

/// A flag over a file whose section is a plain value is an error naming the key, not a panic.
#[test]
fn settings_over_a_value_where_a_section_belongs_are_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "s.toml", "name = \"s\"\ndataset = 5\n");
    let settings = Settings {
        train_frames: Some("0:4".parse().unwrap()),
        ..Settings::default()
    };
    let err = load_with(&p, &settings, &[]).unwrap_err().to_string();
    assert!(err.contains("`dataset` is not a section"), "{err}");
}

/// `train.mask_edges` reads its four names, defaults to `backdrop`, and reads earlier versions'
/// boolean `skip_mask_edges` (true: skip, false: train), in configs and in saved samplers alike.
#[test]
fn mask_edges_read_names_and_the_earlier_boolean() {
    let dir = tempfile::tempdir().unwrap();
    let p = write(dir.path(), "s.toml", SUBJECT);
    assert_eq!(load(&p, &[]).unwrap().train.mask_edges, MaskEdges::Backdrop);
    for (set, expected) in [
        ("train.mask_edges=train", MaskEdges::Train),
        ("train.mask_edges=robust", MaskEdges::Robust),
        ("train.mask_edges=skip", MaskEdges::Skip),
        ("train.mask_edges=backdrop", MaskEdges::Backdrop),
        ("train.skip_mask_edges=false", MaskEdges::Train),
        ("train.skip_mask_edges=true", MaskEdges::Skip),
    ] {
        assert_eq!(
            load(&p, &[set.into()]).unwrap().train.mask_edges,
            expected,
            "{set}"
        );
    }
    let both = load(
        &p,
        &[
            "train.skip_mask_edges=true".into(),
            "train.mask_edges=train".into(),
        ],
    )
    .unwrap_err()
    .to_string();
    assert!(both.contains("train.skip_mask_edges"), "{both}");
    let saved = r#"{"rays": 64, "body_fraction": 0.5, "skip_mask_edges": false, "near_far_padding": 0.01,
        "convention": "integer"}"#;
    let options: anerf_data::SamplerOptions = serde_json::from_str(saved).unwrap();
    assert_eq!(options.mask_edges, MaskEdges::Train);
    // Saved before detail rays existed: none drawn, as then.
    assert_eq!(options.detail_fraction, 0.0);
}
