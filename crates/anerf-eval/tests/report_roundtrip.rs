//! The report's numbers equal a recomputation from the saved images, through two independent paths:
//! `recompute_from_saved` and `compare_files` on each saved prediction, ground truth and mask.

use anerf_core::{FrameId, ViewId};
use anerf_eval::compare_files;
use anerf_eval::images::{quantised, PngDepth};
use anerf_eval::report::{
    read_records_json, read_summary_json, recompute_from_saved, EvalRecorder, EvalSplit,
    ImageRecord,
};
use anerf_eval::silhouette::{SilhouetteMetrics, Silhouettes};
use anerf_eval::{ImageMetrics, ImageSize, PixelMask, RgbImageExt};
use image::Rgb32FImage;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// A smooth ground truth with a black background outside an ellipse, a noisy prediction of it, and the
/// "ray hits the box" mask: a rectangle around the ellipse.
fn sample(rng: &mut StdRng, size: ImageSize) -> (Rgb32FImage, Rgb32FImage, PixelMask) {
    let (w, h) = (size.width as f32, size.height as f32);
    let (cx, cy) = (
        w * rng.random_range(0.4..0.6),
        h * rng.random_range(0.4..0.6),
    );
    let body = |x: u32, y: u32| {
        ((x as f32 - cx) / (0.3 * w)).powi(2) + ((y as f32 - cy) / (0.35 * h)).powi(2) <= 1.0
    };
    let mut gt = Rgb32FImage::black(size);
    let mut pred = Rgb32FImage::black(size);
    for y in 0..size.height {
        for x in 0..size.width {
            if body(x, y) {
                let colour = [
                    0.3 + 0.4 * x as f32 / w,
                    0.5 + 0.3 * (0.3 * y as f32).sin(),
                    0.6,
                ];
                gt.set_pixel(x, y, colour);
                pred.set_pixel(
                    x,
                    y,
                    colour.map(|c| (c + rng.random_range(-0.1..0.1)).clamp(0.0, 1.0)),
                );
            } else {
                pred.set_pixel(x, y, [0.02; 3].map(|c| c * rng.random::<f32>()));
            }
        }
    }
    let mask = PixelMask::from_fn(size, |x, y| {
        (x as f32 - cx).abs() <= 0.4 * w && (y as f32 - cy).abs() <= 0.45 * h
    });
    (pred, gt, mask)
}

#[test]
fn report_numbers_equal_a_recomputation_from_the_saved_images() {
    let dir = tempfile::tempdir().unwrap();
    let eval_dir = dir.path().join("eval").join("novel-view");
    let mut rng = StdRng::seed_from_u64(7);
    let mut recorder = EvalRecorder::new(&eval_dir, EvalSplit::NovelView);
    let mut recorded = Vec::new();
    let mut worst_quantisation_shift = 0.0f64;
    for (frame, view) in [(0, 1), (0, 2), (30, 1), (30, 5)] {
        let size = ImageSize::new(37, 29);
        let (pred, gt, mask) = sample(&mut rng, size);
        // Frame 30's images carry silhouettes: an ellipse as the truth, a uniform half opacity.
        let truth = PixelMask::from_fn(size, |x, y| {
            ((x as f32 - 18.0) / 9.0).powi(2) + ((y as f32 - 14.0) / 11.0).powi(2) <= 1.0
        });
        let opacity = vec![0.5; size.pixels()];
        let silhouettes = Silhouettes {
            truth: &truth,
            opacity: &opacity,
        };
        let record = recorder
            .add(
                FrameId(frame),
                ViewId(view),
                &pred,
                &gt,
                &mask,
                (frame == 30).then_some(&silhouettes),
            )
            .unwrap();
        assert_eq!(record.silhouette.is_some(), frame == 30);
        recorded.push(record);
        let unquantised = ImageMetrics::compute(&pred, &gt, Some(&mask)).unwrap();
        worst_quantisation_shift =
            worst_quantisation_shift.max((unquantised.psnr - record.psnr).abs());
        assert!((unquantised.ssim - record.ssim).abs() < 1e-5);
    }
    let summary = recorder.finish().unwrap();
    println!("largest PSNR shift from saving at 16 bits: {worst_quantisation_shift:e} dB");
    assert!(worst_quantisation_shift < 1e-3);

    // Bit-for-bit equal numbers from the saved images.
    let records = recorded;
    assert_eq!(recompute_from_saved(&eval_dir).unwrap(), records);

    // metrics.json holds them up to serde_json's float parsing, which is not correctly rounded (it may be
    // one unit in the last place off) unless its `float_roundtrip` feature is on.
    let from_json = read_records_json(&eval_dir.join("metrics.json")).unwrap();
    assert_eq!(from_json.len(), 4);
    for (a, b) in from_json.iter().zip(&records) {
        assert_eq!((a.split, a.frame, a.view), (b.split, b.frame, b.view));
        assert!(
            (a.psnr - b.psnr).abs() <= 1e-12 * b.psnr.abs() && (a.ssim - b.ssim).abs() <= 1e-12
        );
    }

    for record in &records {
        let path = |suffix: &str| {
            eval_dir
                .join("images")
                .join(format!("{}_{suffix}.png", record.stem()))
        };
        let comparison = compare_files(&path("pred"), &path("gt"), Some(&path("mask"))).unwrap();
        assert_eq!(
            (comparison.metrics.psnr, comparison.metrics.ssim),
            (record.psnr, record.ssim)
        );
        assert!(eval_dir
            .join("side_by_side")
            .join(format!("{}.png", record.stem()))
            .is_file());
    }

    let from_file = read_summary_json(&eval_dir.join("summary.json")).unwrap();
    assert_eq!(from_file.images, summary.images);
    assert!(
        (from_file.psnr - summary.psnr).abs() < 1e-12
            && (from_file.ssim - summary.ssim).abs() < 1e-12
    );
    assert_eq!(summary.images, 4);
    let mean_psnr = records.iter().map(|r| r.psnr).sum::<f64>() / 4.0;
    assert!((summary.psnr - mean_psnr).abs() < 1e-12);
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(eval_dir.join("summary.json")).unwrap())
            .unwrap();
    let mut keys: Vec<_> = json.as_object().unwrap().keys().cloned().collect();
    keys.sort();
    assert_eq!(keys, ["images", "psnr", "ssim"]);

    // The CSV holds the same numbers (shortest round-trip decimal form).
    let csv = std::fs::read_to_string(eval_dir.join("metrics.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some("split,frame,view,psnr,ssim,band_psnr,outside_band_psnr,area_ratio")
    );
    let parsed: Vec<ImageRecord> = lines
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            ImageRecord {
                split: f[0].parse().unwrap(),
                frame: FrameId(f[1].parse().unwrap()),
                view: ViewId(f[2].parse().unwrap()),
                psnr: f[3].parse().unwrap(),
                ssim: f[4].parse().unwrap(),
                silhouette: (!f[5].is_empty()).then(|| SilhouetteMetrics {
                    band_psnr: f[5].parse().unwrap(),
                    outside_band_psnr: f[6].parse().unwrap(),
                    area_ratio: f[7].parse().unwrap(),
                }),
            }
        })
        .collect();
    assert_eq!(parsed, records);

    let table = std::fs::read_to_string(eval_dir.join("summary.md")).unwrap();
    assert!(
        table.contains(&format!(
            "| novel-view | {:.2} | {:.3} |",
            summary.psnr, summary.ssim
        )),
        "{table}"
    );
}

#[test]
fn a_tampered_image_changes_the_recomputation() {
    let dir = tempfile::tempdir().unwrap();
    let mut rng = StdRng::seed_from_u64(8);
    let mut recorder = EvalRecorder::new(dir.path(), EvalSplit::NovelPose);
    let (pred, gt, mask) = sample(&mut rng, ImageSize::new(20, 24));
    let record = recorder
        .add(FrameId(2), ViewId(3), &pred, &gt, &mask, None)
        .unwrap();
    recorder.finish().unwrap();
    let saved = dir
        .path()
        .join("images")
        .join(format!("{}_pred.png", record.stem()));
    let blank = quantised(&Rgb32FImage::black(pred.size()), PngDepth::Sixteen);
    anerf_eval::images::write_png(&saved, &blank, PngDepth::Sixteen).unwrap();
    let recomputed = recompute_from_saved(dir.path()).unwrap();
    assert_ne!(recomputed[0].psnr, record.psnr);
}

#[test]
fn an_empty_evaluation_is_an_error_and_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let err = EvalRecorder::new(dir.path().join("eval"), EvalSplit::NovelView)
        .finish()
        .unwrap_err();
    assert!(err.to_string().contains("no image was recorded"), "{err}");
    assert!(!dir.path().join("eval").exists());
}
