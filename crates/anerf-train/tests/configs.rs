//! Every experiment file in `configs/` loads, validates, and selects the frames and the mask-edge setting of
//! the paper's protocol.

use std::path::Path;

use anerf_train::config::{self, FrameRange, MaskEdges, RangeSet};

fn configs_dir() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs")
}

fn count(range: &FrameRange, interval: usize) -> usize {
    range.frames().into_iter().step_by(interval).count()
}

#[test]
fn every_experiment_file_loads_and_validates() {
    let mut seen = 0;
    for folder in ["", "zju_mocap", "h36m"] {
        for entry in std::fs::read_dir(configs_dir().join(folder)).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") && path.file_stem().unwrap() != "base"
            {
                let c =
                    config::load(&path, &[]).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                // The paper's experiments keep its protocol: the band around mask edges unsampled.
                if !folder.is_empty() {
                    assert_eq!(c.train.mask_edges, MaskEdges::Skip, "{}", path.display());
                }
                let tpami = config::load(&path, &["dataset.ranges=tpami".into()]);
                assert!(
                    tpami.is_ok() || c.dataset.tpami.is_none(),
                    "{}: {tpami:?}",
                    path.display()
                );
                seen += 1;
            }
        }
    }
    assert_eq!(
        seen,
        1 + 9 + 7,
        "demo, nine ZJU-MoCap sequences, seven Human3.6M subjects"
    );
}

/// Training and novel-pose frame counts of Human3.6M: the paper's supplementary table.
#[test]
fn human36m_frame_counts_match_the_paper() {
    let table = [
        ("S1", 150, 49),
        ("S5", 250, 127),
        ("S6", 150, 83),
        ("S7", 300, 200),
        ("S8", 250, 87),
        ("S9", 260, 133),
        ("S11", 200, 82),
    ];
    for (subject, train, novel) in table {
        let c = config::load(&configs_dir().join(format!("h36m/{subject}.toml")), &[]).unwrap();
        let split = c.dataset.split();
        let interval = c.dataset.frame_interval;
        assert_eq!(interval, 5);
        assert_eq!(
            count(&split.train_frames, interval),
            train,
            "{subject} training frames"
        );
        assert_eq!(
            count(&split.novel_pose_frames, interval),
            novel,
            "{subject} novel-pose frames"
        );
        assert_eq!(
            (
                c.dataset.train_views.as_slice(),
                c.dataset.test_views.as_slice()
            ),
            (&[0, 1, 2][..], &[3][..])
        );
        assert_eq!(c.eval.frame_interval, 6);
    }
}

/// ZJU-MoCap: docs/REFERENCE.md §4.1 (training views 0, 6, 12, 18; the ICCV and TPAMI frame ranges).
#[test]
fn zju_mocap_ranges_match_the_reference() {
    let iccv = [
        ("313", 0, 60, 60, 1000),
        ("315", 0, 400, 400, 1000),
        ("377", 0, 300, 300, 200),
        ("386", 0, 300, 300, 346),
    ];
    for (seq, t0, tn, n0, nn) in iccv {
        let c = config::load(&configs_dir().join(format!("zju_mocap/{seq}.toml")), &[]).unwrap();
        assert_eq!(c.dataset.ranges, RangeSet::Iccv);
        let s = c.dataset.split();
        assert_eq!(
            (s.train_frames.start, s.train_frames.len()),
            (t0, tn),
            "{seq}"
        );
        assert_eq!(
            (s.novel_pose_frames.start, s.novel_pose_frames.len()),
            (n0, nn),
            "{seq}"
        );
        assert_eq!(c.dataset.train_views, vec![0, 6, 12, 18]);
        assert_eq!((c.dataset.ratio.get(), c.eval.frame_interval), (0.5, 30));
    }
    let c = config::load(
        &configs_dir().join("zju_mocap/390.toml"),
        &["dataset.ranges=tpami".into()],
    )
    .unwrap();
    let s = c.dataset.split();
    assert_eq!(
        (
            s.train_frames.start,
            s.train_frames.end,
            s.novel_pose_frames.start,
            s.novel_pose_frames.end
        ),
        (700, 1000, 0, 700)
    );
}
