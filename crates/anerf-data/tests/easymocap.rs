//! EasyMocap capture folders (`scripts/fixtures/easymocap.py`): read directly, they give the same subject as
//! their ZJU-layout twin written from the same fits by numpy; OpenCV's YAML reads as cv2 reads it; every
//! kind of bad input is named, and `inspect` lists all of a folder's problems at once.

mod common;

use std::path::Path;

use anerf_data::formats::opencv_yaml::FileStorage;
use anerf_data::loaders::{detect_kind, load};
use anerf_data::zju_layout::{write_subject, LayoutError};
use anerf_data::{inspect, DatasetKind, InspectOptions, LoadOptions, Subject};
use anerf_testing::{assert_close, fixture, floats, json, Tolerance};
use common::{array, f64s, flat, ordered, relative};
use serde_json::json;

fn options() -> LoadOptions {
    LoadOptions {
        body_model: Some(fixture("easymocap/body.npz")),
        ..Default::default()
    }
}

fn capture(root: &Path, options: &LoadOptions) -> Result<Subject, anerf_data::DataError> {
    load(root, DatasetKind::EasyMocap, options)
}

fn flat3(v: &[glam::Vec3]) -> Vec<f64> {
    v.iter().flat_map(|p| p.to_array()).map(f64::from).collect()
}

#[test]
fn a_capture_reads_as_the_zju_layout_subject_made_from_the_same_fits() {
    let root = fixture("easymocap/capture");
    assert_eq!(detect_kind(&root), DatasetKind::EasyMocap);
    let ours = capture(&root, &options()).unwrap();
    let zju =
        anerf_data::load_zju_mocap(&fixture("easymocap/zju"), &LoadOptions::default()).unwrap();
    assert_eq!(ours.kind, DatasetKind::EasyMocap);
    assert_eq!((ours.cameras.len(), ours.frames.len()), (3, 4));
    assert_same_subject(&ours, &zju);
}

/// Same cameras (1e-6), body, poses, image and mask bytes, and posed vertices (1e-5 m).
fn assert_same_subject(ours: &Subject, zju: &Subject) {
    assert_eq!(ours.cameras.len(), zju.cameras.len());
    for (c, (a, b)) in ours.cameras.iter().zip(&zju.cameras).enumerate() {
        assert_eq!((a.width, a.height), (b.width, b.height));
        // Camera 02 has only the Rodrigues R_ (rebuilt here); T is metres in extri.yml, mm in annots.
        let m = |cam: &anerf_core::geometry::Camera| -> Vec<f64> {
            [cam.intrinsics.to_cols_array(), cam.rotation.to_cols_array()]
                .concat()
                .into_iter()
                .chain(cam.translation.to_array())
                .chain(cam.distortion.0)
                .map(f64::from)
                .collect()
        };
        assert_close(
            &format!("camera {c}"),
            &m(a),
            &m(b),
            Tolerance::Absolute(1e-6),
        );
    }
    let body = |s: &Subject| {
        [
            flat3(s.body.skeleton.rest_joints()),
            flat3(&s.body.canonical_vertices),
            s.body
                .weights
                .as_slice()
                .iter()
                .map(|&w| f64::from(w))
                .collect(),
        ]
    };
    for (what, (a, b)) in ["joints", "T-pose vertices", "weights"]
        .iter()
        .zip(body(&ours).iter().zip(&body(&zju)))
    {
        assert_close(what, a, b, Tolerance::Absolute(1e-6));
    }
    assert_eq!(ours.body.skeleton.parents(), zju.body.skeleton.parents());
    assert_eq!(ours.body.faces, zju.body.faces);
    for (a, b) in ours.frames.iter().zip(&zju.frames) {
        assert_eq!(a.file_index, b.file_index);
        assert_eq!(a.pose, b.pose, "frame {}", a.file_index);
        for (x, y) in a
            .images
            .iter()
            .chain(&a.masks)
            .zip(b.images.iter().chain(&b.masks))
        {
            assert_eq!(
                std::fs::read(x).unwrap(),
                std::fs::read(y).unwrap(),
                "{}",
                x.display()
            );
        }
        // Posed by the body model from the fit (with pose correctives) against numpy's new_vertices.
        let mine = a
            .vertices
            .read(Some(ours.body.canonical_vertices.len()))
            .unwrap();
        let theirs = b.vertices.read(None).unwrap();
        assert_close(
            &format!("frame {} posed vertices", a.file_index),
            &flat3(&mine),
            &flat3(&theirs),
            Tolerance::Absolute(1e-5),
        );
    }
}

#[test]
fn opencv_yaml_reads_as_cv2_reads_it() {
    let fs = FileStorage::read(&fixture("easymocap/yaml/matrices.yml")).unwrap();
    let expected = json("easymocap/yaml/matrices.json");
    for (key, m) in expected["matrices"].as_object().unwrap() {
        let ours = fs.matrix(key).unwrap().unwrap();
        assert_eq!(
            (ours.rows as u64, ours.cols as u64),
            (m["rows"].as_u64().unwrap(), m["cols"].as_u64().unwrap()),
            "{key}"
        );
        assert_close(
            key,
            &ours.data,
            &floats(&m["data"]),
            Tolerance::Relative(1e-15),
        );
    }
    let names: Vec<String> = serde_json::from_value(expected["names"].clone()).unwrap();
    assert_eq!(fs.strings("names").unwrap().unwrap(), names);
}

/// What numpy must read from the imported folder `root`, stated from the capture it came from.
fn import_manifest(capture: &Subject, imported: &Subject) -> serde_json::Value {
    let root = &imported.root;
    let mut files = vec![common::annots_entry(imported)];
    let k = capture.body.skeleton.num_joints();
    for (frame, mine) in imported.frames.iter().zip(&capture.frames) {
        let i = frame.file_index;
        let anerf_data::PosedVertices::Fitted(fit) = &mine.vertices else {
            panic!("a capture's vertices come from its fits")
        };
        files.push(json!({
            "path": format!("new_params/{i}.npy"),
            "kind": "object",
            "expected": ordered(&[
                ("poses", array("<f8", &[1, 3 * k], f64s(flat(&mine.pose.joint_rotations)))),
                ("Rh", array("<f8", &[1, 3], f64s(mine.pose.global.rh.to_array()))),
                ("Th", array("<f8", &[1, 3], f64s(mine.pose.global.th.to_array()))),
                ("shapes", array("<f8", &[1, fit.params.betas.len()], json!(fit.params.betas))),
            ])
        }));
        let verts = mine.vertices.read(None).unwrap();
        files.push(json!({"path": format!("new_vertices/{i}.npy"), "kind": "npy", "expected": array("<f4", &[verts.len(), 3], json!(flat(&verts)))}));
        for (v, (image, mask)) in frame.images.iter().zip(&frame.masks).enumerate() {
            let (w, h) = (capture.cameras[v].width, capture.cameras[v].height);
            let foreground = image::open(&mine.masks[v])
                .unwrap()
                .to_luma8()
                .pixels()
                .filter(|p| p.0[0] > 0)
                .count();
            files.push(
                json!({"path": relative(root, image), "kind": "jpeg", "width": w, "height": h}),
            );
            files.push(json!({"path": relative(root, mask), "kind": "png", "width": w, "height": h, "foreground": foreground}));
        }
    }
    files.extend(common::lbs_entries(&capture.body));
    files.push(json!({"path": "lbs/bigpose_vertices.npy", "kind": "npy", "expected": array("<f4", &[capture.body.canonical_vertices.len(), 3], json!(big_pose(&capture.body)))}));
    json!({ "files": files })
}

/// The canonical vertices in the big pose, computed here from the bone transforms: hips abducted ±30°
/// about z, so every vertex moves by the weighted rotation of its bones about the hip joints.
fn big_pose(body: &anerf_data::BodyModel) -> Vec<f32> {
    let transforms = body
        .skeleton
        .bone_transforms(
            &body.skeleton.big_pose(),
            anerf_core::geometry::CanonicalPose::TPose,
        )
        .unwrap();
    body.canonical_vertices
        .iter()
        .enumerate()
        .flat_map(|(v, &x)| {
            let m = body
                .weights
                .row(v)
                .iter()
                .zip(transforms.matrices())
                .fold(glam::Mat4::ZERO, |acc, (&w, a)| acc + *a * w);
            m.transform_point3(x).to_array()
        })
        .collect()
}

#[test]
fn an_imported_capture_reads_back_through_the_zju_loader_and_numpy_reads_every_file() {
    let ours = capture(&fixture("easymocap/capture"), &options()).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("imported");
    write_subject(&ours, &out, false).unwrap();
    let imported = anerf_data::load_zju_mocap(&out, &LoadOptions::default()).unwrap();
    assert_eq!(imported.frames.len(), ours.frames.len());
    assert_same_subject(&ours, &imported);
    common::numpy_check(&out, &import_manifest(&ours, &imported));
    // Nothing beside the result: the staging folder was renamed, not left behind.
    let entries: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| !n.ends_with(".manifest.json"))
        .collect();
    assert_eq!(entries, ["imported"]);

    // An existing folder is kept unless overwriting is asked for; then it is replaced whole.
    let err = write_subject(&ours, &out, false).unwrap_err();
    assert!(matches!(err, LayoutError::Exists(_)), "{err}");
    std::fs::write(out.join("stale.txt"), "old run").unwrap();
    write_subject(&ours, &out, true).unwrap();
    assert!(!out.join("stale.txt").exists());
    assert_same_subject(
        &ours,
        &anerf_data::load_zju_mocap(&out, &LoadOptions::default()).unwrap(),
    );
}

#[test]
fn an_import_that_fails_leaves_nothing_and_never_writes_into_the_capture() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("capture");
    common::copy_tree(&fixture("easymocap/capture"), &root);
    let subject = capture(&root, &options()).unwrap();
    let err = write_subject(&subject, &root.join("zju"), false).unwrap_err();
    assert!(matches!(err, LayoutError::InsideSource { .. }), "{err}");
    assert!(!root.join("zju").exists());

    // An image gone after loading: the copy fails, naming it, and no output or staging folder remains.
    let lost = subject.frames[2].images[1].clone();
    std::fs::remove_file(&lost).unwrap();
    let out = dir.path().join("imported");
    let err = write_subject(&subject, &out, false)
        .unwrap_err()
        .to_string();
    assert!(err.contains(&lost.display().to_string()), "{err}");
    let entries: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(entries, ["capture"]);
}

fn error_of(case: &str, options: &LoadOptions) -> String {
    capture(&fixture(&format!("easymocap/bad/{case}")), options)
        .unwrap_err()
        .to_string()
}

#[test]
fn bad_calibration_and_fits_are_named_by_file_and_key() {
    for (case, file, expected) in [
        ("missing_k", "intri.yml", "has no 'K_02'"),
        (
            "wrong_data_count",
            "intri.yml",
            "'K_03': !!opencv-matrix of 4 rows × 3 cols has 9 data values",
        ),
        (
            "fit_wrong_length",
            "000001.json",
            "'Th' has 2 numbers, expected 3",
        ),
        ("fit_nan", "000002.json", "is not valid JSON"),
        (
            "two_people",
            "000000.json",
            "holds 2 people (ids 0, 5); choose one with --person",
        ),
    ] {
        let err = error_of(case, &options());
        assert!(
            err.contains(file) && err.contains(expected),
            "{case}: {err}"
        );
    }
    let err = error_of(
        "two_people",
        &LoadOptions {
            person: Some(7),
            ..options()
        },
    );
    assert!(err.contains("has no person 7 (ids: 0, 5)"), "{err}");
    let chosen = capture(
        &fixture("easymocap/bad/two_people"),
        &LoadOptions {
            person: Some(5),
            ..options()
        },
    );
    assert_eq!(chosen.unwrap().frames.len(), 4);
    let err = capture(&fixture("easymocap/capture"), &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(err.contains("--body-model"), "{err}");
}

#[test]
fn inspect_lists_every_problem_of_a_capture_at_once() {
    let root = fixture("easymocap/bad/many_problems");
    let report = inspect(
        &root,
        &InspectOptions {
            kind: None,
            load: options(),
        },
    );
    assert_eq!(report.kind, DatasetKind::EasyMocap);
    let text = report.to_string();
    for expected in [
        "extri.yml: has no 'R_03'",
        "000003.json: missing; expected the fit of frame 3",
        "000001.json: 'shapes' has 12 betas, but the model has 10",
        "000002.jpg: image is 50×40",
    ] {
        assert!(text.contains(expected), "{expected:?} not in:\n{text}");
    }
    assert!(report.has_fatal());
}
