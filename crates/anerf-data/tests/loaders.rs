//! ZJU-MoCap and Human3.6M loaders on the tiny fake datasets of `scripts/fixtures/datasets.py`, and one
//! clear error per kind of bad input.

mod common;

use std::path::{Path, PathBuf};

use anerf_core::geometry::{forward_lbs_point, CanonicalPose};
use anerf_data::{load_h36m, load_zju_mocap, DataError, LoadOptions};
use anerf_testing::{fixture, floats, json};
use common::copy_tree;
use glam::Vec3;

fn body_npz() -> LoadOptions {
    LoadOptions {
        body_model: Some(fixture("body_model/tiny_body.npz")),
        ..Default::default()
    }
}

#[test]
fn zju_313_style_folders_with_spaces_and_the_file_index_offset() {
    let root = fixture("zju_mocap/CoreView_313");
    let info = &json("zju_mocap/index.json")["313"];
    let s = load_zju_mocap(&root, &body_npz()).unwrap();
    assert_eq!(s.name, "CoreView_313");
    assert_eq!(s.cameras.len(), 3);
    assert_eq!(s.frames.len(), 3);
    let idx: Vec<usize> = s.frames.iter().map(|f| f.file_index).collect();
    assert_eq!(idx, [1, 2, 3]);
    assert!(s.frames[0].images[1]
        .to_string_lossy()
        .contains("Camera (2)/CoreView_313_Camera_(2)_0001"));
    assert!(s.frames[0].masks[0].starts_with(root.join("mask_cihp")));
    assert!(
        s.frames[0].masks[1].starts_with(root.join("mask"))
            && !s.frames[0].masks[1].starts_with(root.join("mask_cihp"))
    );
    assert!(s.frames[2]
        .vertices
        .file()
        .unwrap()
        .ends_with("new_vertices/3.npy"));
    assert!(s.notes.is_empty(), "{:?}", s.notes);
    for (c, cam) in s.cameras.iter().enumerate() {
        assert_eq!((cam.width, cam.height), (48, 40));
        let t = floats(&info["T_m"][c]);
        let d = floats(&info["D"][c]);
        for (i, t) in t.iter().enumerate() {
            assert!(
                (cam.translation[i] as f64 - t).abs() < 1e-6,
                "T of camera {c} in metres"
            );
        }
        for (got, want) in cam.distortion.0.iter().zip(&d) {
            assert!((*got as f64 - want).abs() < 1e-7);
        }
        let k = floats(&info["K"][c]);
        assert!((cam.intrinsics.z_axis.x as f64 - k[2]).abs() < 1e-6, "cx");
    }
    // End to end: LBS of the canonical body with this frame's pose reproduces numpy's posed vertices.
    let expected: Vec<Vec3> = floats(&info["posed_vertices_frame0"])
        .chunks(3)
        .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
        .collect();
    let pose = &s.frames[0].pose;
    let bones = s
        .body
        .skeleton
        .bone_transforms(pose, CanonicalPose::TPose)
        .unwrap();
    for (v, (x, e)) in s.body.canonical_vertices.iter().zip(expected).enumerate() {
        let posed = forward_lbs_point(*x, s.body.weights.row(v), &bones).unwrap();
        let world = pose.global.pose_to_world(posed);
        assert!((world - e).length() < 1e-5, "vertex {v}: {world} vs {e}");
    }
}

#[test]
fn zju_377_style_falls_back_to_old_params_and_reads_lbs_weights() {
    let s = load_zju_mocap(&fixture("zju_mocap/CoreView_377"), &LoadOptions::default()).unwrap();
    assert_eq!((s.cameras.len(), s.frames.len()), (4, 4));
    assert_eq!(
        s.frames.iter().map(|f| f.file_index).collect::<Vec<_>>(),
        [0, 1, 2, 3]
    );
    assert!(s.frames[0].images[3].ends_with("Camera_B4/000000.jpg"));
    assert!(s.frames[1]
        .vertices
        .file()
        .unwrap()
        .ends_with("vertices/1.npy"));
    assert_eq!(s.notes.len(), 2, "{:?}", s.notes);
    assert!(
        s.notes.iter().any(|n| n.contains("params/"))
            && s.notes.iter().any(|n| n.contains("vertices/"))
    );
    let index = json("zju_mocap/index.json");
    assert_eq!(
        s.body.skeleton.num_joints(),
        index["joints"].as_u64().unwrap() as usize
    );
    assert_eq!(
        s.body.canonical_vertices.len(),
        index["vertices"].as_u64().unwrap() as usize
    );
    assert_eq!(
        s.body.faces.len(),
        index["faces"].as_u64().unwrap() as usize
    );
    assert_eq!(s.body.skeleton.parents()[0], None);
}

#[test]
fn body_model_from_pkl_matches_npz_and_lbs() {
    let root = fixture("zju_mocap/CoreView_313");
    let a = load_zju_mocap(&root, &body_npz()).unwrap();
    let b = load_zju_mocap(
        &root,
        &LoadOptions {
            body_model: Some(fixture("body_model/tiny_body.pkl")),
            ..Default::default()
        },
    )
    .unwrap();
    let c = load_zju_mocap(&fixture("zju_mocap/CoreView_377"), &LoadOptions::default()).unwrap();
    assert_eq!(a.body.weights, b.body.weights);
    assert_eq!(a.body.faces, b.body.faces);
    assert_eq!(a.body.weights, c.body.weights);
    let err = load_zju_mocap(&root, &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("weights.npy") && err.contains("body-model file"),
        "{err}"
    );
}

#[test]
fn h36m_cameras_of_two_sizes_and_the_images_to_mask_rule() {
    let root = fixture("h36m/S9/Posing");
    let s = load_h36m(&root, &LoadOptions::default()).unwrap();
    assert_eq!(s.name, "S9");
    assert_eq!((s.cameras.len(), s.frames.len()), (4, 12));
    let sizes: Vec<(u32, u32)> = s.cameras.iter().map(|c| (c.width, c.height)).collect();
    assert_eq!(sizes, [(40, 42), (40, 40), (40, 42), (40, 40)]);
    assert_eq!(s.frames[7].masks[2], root.join("mask/cam2/000007.png"));
    assert_eq!(s.frames[11].file_index, 11);
}

/// A copy of the 377-style fixture with one defect; returns the error of loading it.
fn broken(edit: impl FnOnce(&Path)) -> (tempfile::TempDir, PathBuf, DataError) {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("CoreView_377");
    copy_tree(&fixture("zju_mocap/CoreView_377"), &root);
    edit(&root);
    let err = load_zju_mocap(&root, &LoadOptions::default()).unwrap_err();
    (dir, root, err)
}

fn replace(root: &Path, rel: &str, bad: &str) {
    std::fs::copy(fixture(&format!("bad/{bad}")), root.join(rel)).unwrap();
}

#[test]
fn each_bad_input_gives_one_error_naming_the_file_and_the_expectation() {
    type Edit = Box<dyn FnOnce(&Path)>;
    let cases: Vec<(&str, Edit, &str, &[&str])> = vec![
        (
            "missing annots",
            Box::new(|r: &Path| std::fs::remove_file(r.join("annots.npy")).unwrap()),
            "annots.npy",
            &["missing"],
        ),
        (
            "missing params",
            Box::new(|r: &Path| std::fs::remove_file(r.join("params/2.npy")).unwrap()),
            "params/2.npy",
            &["missing"],
        ),
        (
            "missing vertices",
            Box::new(|r: &Path| std::fs::remove_file(r.join("vertices/3.npy")).unwrap()),
            "vertices/3.npy",
            &["posed vertices of frame 3"],
        ),
        (
            "missing joints",
            Box::new(|r: &Path| std::fs::remove_file(r.join("lbs/joints.npy")).unwrap()),
            "lbs/joints.npy",
            &["missing"],
        ),
        (
            "truncated tvertices",
            Box::new(|r: &Path| {
                let p = r.join("lbs/tvertices.npy");
                let b = std::fs::read(&p).unwrap();
                std::fs::write(&p, &b[..b.len() / 2]).unwrap();
            }),
            "lbs/tvertices.npy",
            &["needs 960"],
        ),
        (
            "corrupt params",
            Box::new(|r: &Path| {
                std::fs::write(
                    r.join("params/0.npy"),
                    b"\x93NUMPY\x01\x00\x10\x00{'descr': '|O',",
                )
                .unwrap()
            }),
            "params/0.npy",
            &["truncated"],
        ),
        (
            "NaN in params",
            Box::new(|r: &Path| replace(r, "params/1.npy", "params_nan.npy")),
            "params/1.npy",
            &["Th", "non-finite"],
        ),
        (
            "short poses",
            Box::new(|r: &Path| replace(r, "params/1.npy", "params_short_poses.npy")),
            "params/1.npy",
            &["'poses'", "expected 15", "5 joints"],
        ),
        (
            "no Rh",
            Box::new(|r: &Path| replace(r, "params/0.npy", "params_no_rh.npy")),
            "params/0.npy",
            &["'Rh'"],
        ),
        (
            "weights rows",
            Box::new(|r: &Path| replace(r, "lbs/weights.npy", "weights_wrong_rows.npy")),
            "lbs/weights.npy",
            &["(7, 5)", "expected (40, 5)"],
        ),
        (
            "joints shape",
            Box::new(|r: &Path| replace(r, "lbs/joints.npy", "joints_wrong_shape.npy")),
            "lbs/joints.npy",
            &["expected (any, 3)"],
        ),
        (
            "dotdot path",
            Box::new(|r: &Path| replace(r, "annots.npy", "annots_dotdot.npy")),
            "annots.npy",
            &["'..'", "../outside/000001.jpg"],
        ),
        (
            "absolute path",
            Box::new(|r: &Path| replace(r, "annots.npy", "annots_absolute.npy")),
            "annots.npy",
            &["absolute", "/etc/passwd"],
        ),
        (
            "extra camera",
            Box::new(|r: &Path| replace(r, "annots.npy", "annots_extra_camera.npy")),
            "annots.npy",
            &["4 images", "5 cameras"],
        ),
        (
            "missing view",
            Box::new(|r: &Path| replace(r, "annots.npy", "annots_missing_view.npy")),
            "annots.npy",
            &["frame 2 lists 3 images"],
        ),
        (
            "missing camera folder",
            Box::new(|r: &Path| std::fs::remove_dir_all(r.join("Camera_B2")).unwrap()),
            "Camera_B2",
            &["image folder"],
        ),
        (
            "image of another size",
            Box::new(|r: &Path| {
                image::RgbImage::new(50, 40)
                    .save(r.join("Camera_B3/000002.jpg"))
                    .unwrap();
            }),
            "Camera_B3/000002.jpg",
            &["50×40", "48×40"],
        ),
        (
            "missing mask",
            Box::new(|r: &Path| {
                std::fs::remove_file(r.join("mask_cihp/Camera_B1/000001.png")).unwrap()
            }),
            "mask_cihp/Camera_B1/000001.png",
            &["tried"],
        ),
    ];
    for (name, edit, file, needles) in cases {
        let (_dir, root, err) = broken(edit);
        let msg = err.to_string();
        assert!(
            err.path().ends_with(file) || err.path() == root.join(file),
            "{name}: {msg} (path {})",
            err.path().display()
        );
        assert!(msg.contains(file), "{name}: {msg}");
        for n in needles {
            assert!(msg.contains(n), "{name}: {msg:?} lacks {n:?}");
        }
    }
}

/// A symbolic link out of the dataset folder is refused like a `..` path, by loading and by inspection,
/// naming the link; the error never shows the target's content.
#[test]
fn symlinks_that_leave_the_dataset_folder_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("CoreView_377");
    copy_tree(&fixture("zju_mocap/CoreView_377"), &root);
    // A valid image outside (so only the link is wrong), and a private file a mask link points to.
    let outside_image = dir.path().join("elsewhere.jpg");
    std::fs::copy(root.join("Camera_B1/000001.jpg"), &outside_image).unwrap();
    let secret = dir.path().join("secret.txt");
    std::fs::write(&secret, "SECRET-CONTENT").unwrap();
    let cases = [
        ("Camera_B1/000001.jpg", &outside_image),
        ("mask_cihp/Camera_B2/000003.png", &secret),
    ];
    for (rel, target) in cases {
        let link = root.join(rel);
        std::fs::remove_file(&link).unwrap();
        std::os::unix::fs::symlink(target, &link).unwrap();
    }
    let err = load_zju_mocap(&root, &LoadOptions::default()).unwrap_err();
    assert_eq!(err.path(), root.join(cases[0].0), "{err}");
    let report = anerf_data::inspect(&root, &Default::default());
    let text = report.to_string();
    for (rel, target) in cases {
        let problem = report
            .problems
            .iter()
            .find(|p| p.path == root.join(rel))
            .unwrap_or_else(|| panic!("{rel} not reported:\n{text}"));
        assert!(
            problem.fatal
                && problem.message.contains("symbolic link")
                && problem.message.contains("outside the dataset folder")
                && problem.message.contains(&target.display().to_string()),
            "{problem}"
        );
    }
    assert!(!text.contains("SECRET"), "{text}");
    assert_eq!(
        report.problems.iter().filter(|p| p.fatal).count(),
        2,
        "{text}"
    );
}
