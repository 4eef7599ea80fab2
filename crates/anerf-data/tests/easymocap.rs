//! EasyMocap capture folders (`scripts/fixtures/easymocap.py`): read directly, they give the same subject as
//! their ZJU-layout twin written from the same fits by numpy; OpenCV's YAML reads as cv2 reads it; every
//! kind of bad input is named, and `inspect` lists all of a folder's problems at once.

use std::path::Path;

use anerf_data::formats::opencv_yaml::FileStorage;
use anerf_data::loaders::{detect_kind, load};
use anerf_data::{inspect, DatasetKind, InspectOptions, LoadOptions, Subject};
use anerf_testing::{assert_close, fixture, floats, json, Tolerance};

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
