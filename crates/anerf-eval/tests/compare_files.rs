//! `compare_files` on 8-bit PNGs written by `scripts/fixtures/metrics.py`, and its errors.

use std::path::PathBuf;

use anerf_eval::compare::compare_files;
use anerf_eval::EvalError;
use serde_json::Value;

mod support;

fn png_dir() -> PathBuf {
    support::fixture_path("metrics", "png")
}

fn expected() -> Value {
    support::load_json("metrics", "png.json")
}

fn assert_metrics(got: &anerf_eval::ImageMetrics, expected: &Value) {
    let (psnr, ssim) = (
        expected["psnr"].as_f64().unwrap(),
        expected["ssim"].as_f64().unwrap(),
    );
    assert!(
        (got.psnr - psnr).abs() <= 1e-6,
        "PSNR {} vs numpy {psnr}",
        got.psnr
    );
    assert!(
        (got.ssim - ssim).abs() <= 1e-6,
        "SSIM {} vs scikit-image {ssim}",
        got.ssim
    );
}

#[test]
fn whole_image_comparison_matches_the_reference() {
    let dir = png_dir();
    let result = compare_files(&dir.join("pred.png"), &dir.join("gt.png"), None).unwrap();
    assert_metrics(&result.metrics, &expected()["whole"]);
    assert!(result.mask.is_none());
    println!("{result}");
}

#[test]
fn masked_comparison_applies_the_protocol_for_0_255_and_0_1_masks() {
    let dir = png_dir();
    for mask in ["mask.png", "mask_ones.png"] {
        let result = compare_files(
            &dir.join("pred.png"),
            &dir.join("gt.png"),
            Some(&dir.join(mask)),
        )
        .unwrap();
        assert_metrics(&result.metrics, &expected()["masked"]);
        let (path, pixels) = result.mask.clone().unwrap();
        assert_eq!(path, dir.join(mask));
        assert!(pixels > 100 && pixels < 21 * 26, "{pixels} mask pixels");
        println!("{result}");
    }
}

fn message(err: EvalError) -> String {
    err.to_string()
}

#[test]
fn errors_name_the_file_and_what_was_expected() {
    let dir = png_dir();
    let (pred, gt) = (dir.join("pred.png"), dir.join("gt.png"));

    let missing = dir.join("no_such_image.png");
    let err = compare_files(&missing, &gt, None).unwrap_err();
    assert!(
        matches!(err, EvalError::MissingFile { ref path, .. } if *path == missing),
        "{err}"
    );
    assert!(message(err).contains("no_such_image.png"));

    let err = compare_files(&pred, &dir.join("small.png"), None).unwrap_err();
    assert!(matches!(err, EvalError::SizeMismatch { .. }), "{err}");
    let text = message(err);
    assert!(
        text.contains("pred.png") && text.contains("small.png") && text.contains("26x21"),
        "{text}"
    );

    let err = compare_files(&pred, &gt, Some(&dir.join("mask_empty.png"))).unwrap_err();
    assert!(matches!(err, EvalError::EmptyMask { .. }), "{err}");
    assert!(message(err).contains("mask_empty.png"));

    let err = compare_files(&pred, &gt, Some(&dir.join("small.png"))).unwrap_err();
    assert!(matches!(err, EvalError::SizeMismatch { .. }), "{err}");

    let scratch = tempfile::tempdir().unwrap();
    let garbage = scratch.path().join("garbage.png");
    std::fs::write(&garbage, b"not an image at all").unwrap();
    let err = compare_files(&garbage, &gt, None).unwrap_err();
    assert!(matches!(err, EvalError::UnreadableImage { .. }), "{err}");
    assert!(message(err).contains("garbage.png"));

    // A mask whose bounding crop is smaller than SSIM's 7x7 window.
    let tiny = scratch.path().join("tiny_mask.png");
    image::GrayImage::from_fn(26, 21, |x, y| image::Luma([u8::from(x < 3 && y < 3) * 255]))
        .save(&tiny)
        .unwrap();
    let err = compare_files(&pred, &gt, Some(&tiny)).unwrap_err();
    assert!(matches!(err, EvalError::Metric { .. }), "{err}");
    assert!(message(err).contains("tiny_mask.png"));
}

#[test]
fn cut_images_are_refused_naming_the_file() {
    let dir = png_dir();
    let gt = dir.join("gt.png");
    let scratch = tempfile::tempdir().unwrap();
    // A JPEG of the prediction cut in half (the decoder alone fills the rest with grey), and the
    // prediction PNG without its final IEND chunk.
    let jpeg = scratch.path().join("pred.jpg");
    image::open(dir.join("pred.png"))
        .unwrap()
        .to_rgb8()
        .save(&jpeg)
        .unwrap();
    let png = scratch.path().join("pred_no_iend.png");
    std::fs::copy(dir.join("pred.png"), &png).unwrap();
    type Keep = fn(usize) -> usize;
    let cases: [(&PathBuf, Keep); 2] = [(&jpeg, |n| n / 2), (&png, |n| n - 12)];
    for (path, keep) in cases {
        compare_files(path, &gt, None).unwrap();
        let bytes = std::fs::read(path).unwrap();
        std::fs::write(path, &bytes[..keep(bytes.len())]).unwrap();
        let err = compare_files(path, &gt, None).unwrap_err();
        assert!(matches!(err, EvalError::UnreadableImage { .. }), "{err}");
        let text = message(err);
        assert!(
            text.contains(&path.display().to_string()) && text.contains("cut short"),
            "{text}"
        );
        let err = compare_files(&dir.join("pred.png"), &gt, Some(path)).unwrap_err();
        assert!(message(err).contains("cut short"), "as a mask too");
    }
}
