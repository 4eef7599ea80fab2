//! `inspect`: summaries of good folders, and every problem of a folder with several defects at once.

mod common;

use std::path::Path;

use anerf_data::formats::{self, ArrayData, NdArray};
use anerf_data::{inspect, DatasetKind, InspectOptions, LoadOptions};
use anerf_testing::fixture;
use common::{copy_tree, cut_file};

#[test]
fn summaries_of_the_fake_datasets() {
    let r = inspect(
        &fixture("zju_mocap/CoreView_377"),
        &InspectOptions::default(),
    );
    assert_eq!(r.kind, DatasetKind::ZjuMocap);
    assert!(!r.has_fatal(), "{r}");
    assert_eq!(
        (r.cameras, r.frames, r.joints, r.vertices, r.faces),
        (Some(4), Some(4), Some(5), Some(40), Some(60))
    );
    assert_eq!(r.image_sizes, vec![((48, 40), 4)]);
    assert_eq!(r.file_indices, Some((0, 3)));
    assert_eq!(r.problems.len(), 2, "two non-fatal fallbacks: {r}");
    let present: Vec<&str> = r
        .optional_files
        .iter()
        .filter(|o| o.present)
        .map(|o| o.name)
        .collect();
    assert!(
        present.contains(&"lbs/tbw.npy")
            && present.contains(&"lbs/bweights")
            && !present.contains(&"new_params")
    );
    let split = r.split.as_ref().unwrap();
    assert_eq!(
        (split.train_views.clone(), split.test_views.clone()),
        (vec![0], vec![1, 2, 3])
    );
    assert_eq!(
        split.train_frames.count, 4,
        "clamped to the 4 frames present"
    );
    let text = r.to_string();
    assert!(
        text.contains("cameras: 4") && text.contains("5 joints"),
        "{text}"
    );

    let h = inspect(&fixture("h36m/S9/Posing"), &InspectOptions::default());
    assert_eq!(h.kind, DatasetKind::H36m);
    assert!(h.problems.is_empty(), "{h}");
    assert_eq!(h.image_sizes, vec![((40, 42), 2), ((40, 40), 2)]);
    let s = h.split.unwrap();
    assert_eq!(
        (s.train_views, s.test_views, s.train_frames.frames()),
        (vec![0, 1, 2], vec![3], vec![0, 5, 10])
    );

    let z = inspect(
        &fixture("zju_mocap/CoreView_313"),
        &InspectOptions {
            kind: None,
            load: LoadOptions {
                body_model: Some(fixture("body_model/tiny_body.npz")),
                ..Default::default()
            },
        },
    );
    assert!(z.problems.is_empty(), "{z}");
    assert_eq!(z.file_indices, Some((1, 3)));
}

#[test]
fn every_problem_is_listed_not_only_the_first() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("CoreView_377");
    copy_tree(&fixture("zju_mocap/CoreView_377"), &root);
    std::fs::remove_file(root.join("params/2.npy")).unwrap();
    std::fs::copy(fixture("bad/params_nan.npy"), root.join("params/1.npy")).unwrap();
    std::fs::remove_file(root.join("vertices/3.npy")).unwrap();
    image::RgbImage::new(50, 40)
        .save(root.join("Camera_B3/000002.jpg"))
        .unwrap();
    std::fs::write(root.join("Camera_B1/000003.jpg"), b"not a jpeg").unwrap();
    std::fs::remove_file(root.join("mask_cihp/Camera_B4/000000.png")).unwrap();
    std::fs::remove_file(root.join("mask_cihp/Camera_B2/000003.png")).unwrap();
    std::fs::create_dir(root.join("Camera_B9")).unwrap();
    let r = inspect(&root, &InspectOptions::default());
    assert!(r.has_fatal());
    let text = r.to_string();
    for needle in [
        "params/2.npy",
        "params/1.npy",
        "vertices/3.npy",
        "Camera_B3/000002.jpg",
        "Camera_B1/000003.jpg",
        "params/ (fits",
        "Camera_B4/000000.png",
        "Camera_B2/000003.png",
        "not listed in annots.npy (ignored): Camera_B9",
    ] {
        assert!(text.contains(needle), "{needle} not reported:\n{text}");
    }
    assert_eq!(r.problems.iter().filter(|p| p.fatal).count(), 7, "{text}");
    // What could still be counted is summarised.
    assert_eq!((r.cameras, r.frames, r.joints), (Some(4), Some(4), Some(5)));
}

#[test]
fn a_folder_without_annots_reports_that_and_still_checks_lbs() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("CoreView_377");
    copy_tree(&fixture("zju_mocap/CoreView_377"), &root);
    std::fs::remove_file(root.join("annots.npy")).unwrap();
    std::fs::write(root.join("lbs/tvertices.npy"), b"\x93NUMPY").unwrap();
    let r = inspect(&root, &InspectOptions::default());
    let text = r.to_string();
    assert!(
        text.contains("annots.npy") && text.contains("tvertices.npy"),
        "{text}"
    );
    assert_eq!(r.problems.iter().filter(|p| p.fatal).count(), 2, "{text}");
}

/// A `rows × 3` float32 `.npy` file, with NaN as its first value when `nan`.
fn write_points(path: &Path, rows: usize, nan: bool) {
    let mut data = vec![0.5f32; rows * 3];
    if nan {
        data[0] = f32::NAN;
    }
    formats::write_npy(
        path,
        &NdArray::new(vec![rows, 3], ArrayData::F32(data)).unwrap(),
    )
    .unwrap();
}

/// One defect in each file, none of which may hide another: a NaN camera and two refused image paths in
/// annots.npy, bad skinning weights, a pose with NaN, posed vertices of random bytes, NaN and the wrong
/// row count, a cut JPEG, a cut mask and a mask of another size.
#[test]
fn independent_problems_in_every_file_are_reported_in_one_run() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("CoreView_377");
    copy_tree(&fixture("zju_mocap/CoreView_377"), &root);
    let copy = |bad: &str, rel: &str| std::fs::copy(fixture(bad), root.join(rel)).unwrap();
    copy("bad/annots_nan_camera_and_bad_paths.npy", "annots.npy");
    copy("bad/weights_wrong_rows.npy", "lbs/weights.npy");
    copy("bad/params_nan.npy", "params/1.npy");
    std::fs::write(root.join("vertices/1.npy"), [0x5a, 0x93, 0x07, 0xee, 0x41]).unwrap();
    write_points(&root.join("vertices/2.npy"), 40, true);
    write_points(&root.join("vertices/3.npy"), 39, false);
    cut_file(&root.join("Camera_B2/000001.jpg"), |n| n / 2);
    cut_file(&root.join("mask_cihp/Camera_B3/000002.png"), |n| n - 12);
    image::GrayImage::new(50, 40)
        .save(root.join("mask_cihp/Camera_B4/000002.png"))
        .unwrap();
    let r = inspect(&root, &InspectOptions::default());
    let text = r.to_string();
    let expected: [&[&str]; 11] = [
        &["annots.npy", "cams['K'][1] is not finite"],
        &["annots.npy", "../outside/000002.jpg", "frame 2, camera 1"],
        &["annots.npy", "/etc/passwd", "frame 3, camera 3"],
        &["lbs/weights.npy", "expected (40, 5)"],
        &["params/1.npy", "non-finite"],
        &["vertices/1.npy", "magic"],
        &["vertices/2.npy", "non-finite"],
        &["vertices/3.npy", "39 vertices, expected 40"],
        &["Camera_B2/000001.jpg", "cut short"],
        &["mask_cihp/Camera_B3/000002.png", "cut short"],
        &["mask_cihp/Camera_B4/000002.png", "mask is 50×40", "48×40"],
    ];
    for needles in expected {
        assert!(
            r.problems
                .iter()
                .any(|p| p.fatal && needles.iter().all(|n| p.to_string().contains(n))),
            "no problem with {needles:?}:\n{text}"
        );
    }
    assert_eq!(
        r.problems.iter().filter(|p| p.fatal).count(),
        expected.len(),
        "{text}"
    );
}

/// The camera's size is what most of its images have, so the odd image is blamed even when it comes first.
#[test]
fn an_odd_first_image_is_blamed_not_the_cameras_other_images() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("CoreView_377");
    copy_tree(&fixture("zju_mocap/CoreView_377"), &root);
    let odd = root.join("Camera_B3/000000.jpg");
    image::RgbImage::new(50, 40).save(&odd).unwrap();
    let r = inspect(&root, &InspectOptions::default());
    let fatal: Vec<_> = r.problems.iter().filter(|p| p.fatal).collect();
    assert_eq!(fatal.len(), 1, "{r}");
    assert_eq!(fatal[0].path, odd, "{r}");
    assert!(
        fatal[0].message.contains("50×40") && fatal[0].message.contains("48×40"),
        "{r}"
    );
    let err = anerf_data::load_zju_mocap(&root, &LoadOptions::default()).unwrap_err();
    assert_eq!(err.path(), odd, "{err}");
}

/// A body in millimetres or centimetres is named with its probable unit by `inspect`, and loading refuses
/// it: volumes are sized from the body, so it must be a person's size in metres before anything else.
#[test]
fn a_body_in_millimetres_or_centimetres_is_named_with_its_unit() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("CoreView_377");
    copy_tree(&fixture("zju_mocap/CoreView_377"), &root);
    let scale = |rel: &str, by: f32| {
        let path = root.join(rel);
        let a = formats::read_npy(&path).unwrap();
        let v: Vec<f32> = a.to_f64().iter().map(|&x| x as f32 * by).collect();
        formats::write_npy(
            &path,
            &NdArray::new(a.shape().to_vec(), ArrayData::F32(v)).unwrap(),
        )
        .unwrap();
    };
    scale("lbs/tvertices.npy", 1000.0);
    scale("vertices/2.npy", 100.0);
    let r = inspect(&root, &InspectOptions::default());
    let text = r.to_string();
    for (file, unit) in [
        ("lbs/tvertices.npy", "millimetres"),
        ("vertices/2.npy", "centimetres"),
    ] {
        assert!(
            r.problems.iter().any(|p| p.fatal
                && p.path.ends_with(file)
                && p.message.contains(unit)
                && p.message.contains("between 0.3 and 3 m")),
            "{file}: {text}"
        );
    }
    let err = anerf_data::load_zju_mocap(&root, &LoadOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("tvertices.npy") && err.contains("millimetres"),
        "{err}"
    );
}
