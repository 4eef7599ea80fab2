//! EasyMocap capture folders (`scripts/fixtures/easymocap.py`): read directly, they give the same subject as
//! their ZJU-layout twin written from the same fits by numpy; OpenCV's YAML reads as cv2 reads it; every
//! kind of bad input is named, and `inspect` lists all of a folder's problems at once.

mod common;

use std::path::Path;

use anerf_data::formats::opencv_yaml::FileStorage;
use anerf_data::loaders::{detect_kind, load};
use anerf_data::zju_layout::{write_subject, LayoutError};
use anerf_data::{inspect, DatasetKind, InspectOptions, LoadOptions, Subject};
use anerf_testing::{assert_close, fixture, floats, json, tree_snapshot, Tolerance};
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
    let mut files = vec![
        common::annots_entry(imported),
        // The marker that lets a later `import --overwrite` replace this folder.
        json!({"path": ".anerf-import", "kind": "text", "starts_with": "written by anerf import"}),
    ];
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
    write_subject(&ours, &out, &[], false).unwrap();
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
    let err = write_subject(&ours, &out, &[], false).unwrap_err();
    assert!(matches!(err, LayoutError::Exists(_)), "{err}");
    std::fs::write(out.join("stale.txt"), "old run").unwrap();
    write_subject(&ours, &out, &[], true).unwrap();
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
    let err = write_subject(&subject, &root.join("zju"), &[], false).unwrap_err();
    assert!(matches!(err, LayoutError::InsideSource { .. }), "{err}");
    assert!(!root.join("zju").exists());

    // An image gone after loading: the copy fails, naming it, and no output or staging folder remains.
    let lost = subject.frames[2].images[1].clone();
    std::fs::remove_file(&lost).unwrap();
    let out = dir.path().join("imported");
    let err = write_subject(&subject, &out, &[], false)
        .unwrap_err()
        .to_string();
    assert!(err.contains(&lost.display().to_string()), "{err}");
    let entries: Vec<_> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(entries, ["capture"]);
}

/// `--overwrite` deletes only a folder `import` made (its marker), and never one that holds an input: the
/// capture, or the body-model file beside it.
#[test]
fn overwrite_never_deletes_an_input_or_a_folder_import_did_not_make() {
    let dir = tempfile::tempdir().unwrap();
    let work = dir.path().join("work");
    let root = work.join("capture");
    common::copy_tree(&fixture("easymocap/capture"), &root);
    let body_model = work.join("body.npz");
    std::fs::write(&body_model, b"stands for the body model").unwrap();
    let subject = capture(&root, &options()).unwrap();
    let files_before = tree_snapshot(&work);

    // The folder that holds the capture (and the body model beside it).
    let err = write_subject(&subject, &work, &[&body_model], true).unwrap_err();
    assert!(matches!(err, LayoutError::HoldsSource { .. }), "{err}");
    assert!(err.to_string().contains("would delete"), "{err}");
    // Through a link to it, and through `..`.
    let link = dir.path().join("link");
    std::os::unix::fs::symlink(&work, &link).unwrap();
    let err = write_subject(&subject, &link, &[], true).unwrap_err();
    assert!(matches!(err, LayoutError::HoldsSource { .. }), "{err}");
    let err = write_subject(&subject, &root.join(".."), &[], true).unwrap_err();
    assert!(matches!(err, LayoutError::HoldsSource { .. }), "{err}");
    // A folder that holds only the body model.
    let models = dir.path().join("models");
    std::fs::create_dir(&models).unwrap();
    let model_there = models.join("body.npz");
    std::fs::write(&model_there, b"model").unwrap();
    let err = write_subject(&subject, &models, &[&model_there], true).unwrap_err();
    assert!(matches!(err, LayoutError::HoldsSource { .. }), "{err}");
    assert!(model_there.is_file());
    assert_eq!(tree_snapshot(&work), files_before);

    // An unrelated folder that `import` did not write.
    let mine = dir.path().join("mine");
    std::fs::create_dir(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), b"keep me").unwrap();
    let err = write_subject(&subject, &mine, &[], true).unwrap_err();
    assert!(matches!(err, LayoutError::NotOurs(_)), "{err}");
    assert!(err.to_string().contains(".anerf-import"), "{err}");
    assert_eq!(std::fs::read(mine.join("notes.txt")).unwrap(), b"keep me");

    // One that it wrote is replaced.
    let out = dir.path().join("imported");
    write_subject(&subject, &out, &[], false).unwrap();
    assert!(anerf_data::paths::has_marker(
        &out,
        anerf_data::zju_layout::IMPORT_MARKER
    ));
    write_subject(&subject, &out, &[], true).unwrap();
    assert!(out.join("annots.npy").is_file());
}

/// Shape coefficients far outside a person's (100, 1e10, 1e300) make an absurd body: `inspect` names the
/// fit file whichever frame holds them, and loading refuses the capture before anything is sized from the
/// body (a volume around it would need petabytes).
#[test]
fn absurd_shapes_are_named_by_inspection_and_refused_by_loading() {
    for (frame, value) in [("000000", 100.0), ("000002", 1e10), ("000001", 1e300)] {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("capture");
        common::copy_tree(&fixture("easymocap/capture"), &root);
        let fit = root.join(format!("output-smpl-3d/smpl/{frame}.json"));
        let mut people: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&fit).unwrap()).unwrap();
        for shape in people[0]["shapes"][0].as_array_mut().unwrap() {
            *shape = json!(value);
        }
        std::fs::write(&fit, people.to_string()).unwrap();
        let report = inspect(
            &root,
            &InspectOptions {
                load: options(),
                ..Default::default()
            },
        );
        let text = report.to_string();
        assert!(
            report.problems.iter().any(|p| p.fatal
                && p.path == fit
                && p.message.contains("m tall")
                && p.message.contains("between 0.3 and 3")),
            "{frame} = {value}: {text}"
        );
        let loaded = capture(&root, &options()).and_then(|s| {
            s.frames
                .iter()
                .try_for_each(|f| f.vertices.read(None).map(drop))
        });
        let err = loaded.unwrap_err().to_string();
        assert!(
            err.contains(&format!("{frame}.json")) && err.contains("m tall"),
            "{err}"
        );
    }
}

/// Captures are checked as datasets are: a camera listed twice, a camera name that is a path, and
/// calibration or fit files that are links out of the capture are named by `inspect` and refused.
#[test]
fn camera_names_and_links_out_of_the_capture_are_refused() {
    let fresh = |dir: &Path| {
        let root = dir.join("capture");
        common::copy_tree(&fixture("easymocap/capture"), &root);
        root
    };
    let fatal = |root: &Path| {
        let report = inspect(
            root,
            &InspectOptions {
                load: options(),
                ..Default::default()
            },
        );
        let problems: Vec<String> = report
            .problems
            .iter()
            .filter(|p| p.fatal)
            .map(|p| format!("{}: {}", p.path.display(), p.message))
            .collect();
        assert!(
            capture(root, &options()).is_err(),
            "loading accepted {}",
            root.display()
        );
        problems.join("\n")
    };
    let rename = |root: &Path, from: &str, to: &str| {
        let intri = root.join("intri.yml");
        let text = std::fs::read_to_string(&intri).unwrap();
        std::fs::write(&intri, text.replacen(from, to, 1)).unwrap();
    };
    for (listed, wanted) in [
        ("\"01\"", "lists the camera '02' twice"),
        ("\"/etc\"", "camera name \"/etc\" contains a path separator"),
        ("\"..\"", "camera name \"..\" is '.' or '..'"),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let root = fresh(dir.path());
        // The first name replaced: "02" listed twice, or a name that is a path.
        let replacement = if listed == "\"01\"" { "\"02\"" } else { listed };
        rename(&root, "\"01\"", replacement);
        let text = fatal(&root);
        assert!(
            text.contains("intri.yml") && text.contains(wanted),
            "{listed}: {text}"
        );
    }

    // Calibration and fits that lead out of the capture through a link, each on its own.
    for rel in ["intri.yml", "extri.yml", "output-smpl-3d/smpl/000001.json"] {
        let dir = tempfile::tempdir().unwrap();
        let root = fresh(dir.path());
        let outside = dir.path().join("elsewhere");
        std::fs::create_dir(&outside).unwrap();
        let moved = outside.join(Path::new(rel).file_name().unwrap());
        std::fs::rename(root.join(rel), &moved).unwrap();
        std::os::unix::fs::symlink(&moved, root.join(rel)).unwrap();
        let text = fatal(&root);
        let name = Path::new(rel).file_name().unwrap().to_string_lossy();
        assert!(
            text.lines()
                .any(|l| l.contains(name.as_ref()) && l.contains("outside the dataset folder")),
            "{rel}: {text}"
        );
    }
}

/// A FIFO where an image should be is refused by name; reading it would block for ever.
#[test]
fn a_named_pipe_where_an_image_should_be_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("capture");
    common::copy_tree(&fixture("easymocap/capture"), &root);
    let image = root.join("images/02/000001.jpg");
    std::fs::remove_file(&image).unwrap();
    let made = std::process::Command::new("mkfifo")
        .arg(&image)
        .status()
        .unwrap();
    assert!(made.success());
    let (tx, rx) = std::sync::mpsc::channel();
    let inspected = root.clone();
    std::thread::spawn(move || {
        let report = inspect(
            &inspected,
            &InspectOptions {
                load: options(),
                ..Default::default()
            },
        );
        tx.send(report.to_string()).unwrap();
    });
    // A guard against hanging, not a timing: inspection of this capture takes well under a second.
    let text = rx
        .recv_timeout(std::time::Duration::from_secs(120))
        .expect("inspection finished");
    assert!(
        text.contains("000001.jpg") && text.contains("named pipe"),
        "{text}"
    );
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
