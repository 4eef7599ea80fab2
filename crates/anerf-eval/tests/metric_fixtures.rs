//! PSNR and SSIM against numpy and scikit-image, the silhouette band and its figures against scipy's
//! morphology and numpy (`scripts/fixtures/metrics.py`).

use anerf_eval::silhouette::{edge_band, SilhouetteMetrics, Silhouettes, BAND_RADIUS};
use anerf_eval::{ImageMetrics, ImageSize, PixelMask, RgbImageExt};
use image::Rgb32FImage;
use serde_json::Value;

mod support;

use anerf_testing::Tolerance;

/// A metric value of the fixture: a number, or the string "inf" for identical pixels.
fn metric(v: &Value) -> f64 {
    match v {
        Value::String(s) if s == "inf" => f64::INFINITY,
        other => other
            .as_f64()
            .unwrap_or_else(|| panic!("not a metric value: {other}")),
    }
}

/// Checks `got` against the reference to 1e-6 and returns the absolute deviation (0 for matching infinities).
fn assert_close(name: &str, what: &str, got: f64, expected: f64) -> f64 {
    anerf_testing::assert_close(
        &format!("{name}: {what} against scikit-image/numpy"),
        &[got],
        &[expected],
        Tolerance::Absolute(1e-6),
    )
}

#[test]
fn psnr_and_ssim_match_numpy_and_scikit_image() {
    let fixture = support::load_json("metrics", "images.json");
    let cases = fixture["cases"].as_array().unwrap();
    assert!(
        cases.len() >= 15,
        "expected the full fixture set, got {} cases",
        cases.len()
    );
    let (mut masked, mut worst_psnr, mut worst_ssim) = (0, 0.0f64, 0.0f64);
    for case in cases {
        let name = case["name"].as_str().unwrap();
        let size = ImageSize::new(
            case["width"].as_u64().unwrap() as u32,
            case["height"].as_u64().unwrap() as u32,
        );
        let image = |key: &str| {
            let data = case[key]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap() as f32)
                .collect();
            Rgb32FImage::from_values(size, data).unwrap()
        };
        let mask = case.get("mask").map(|m| {
            PixelMask::new(
                size,
                m.as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_u64() == Some(1))
                    .collect(),
            )
            .unwrap()
        });
        masked += usize::from(mask.is_some());
        let got = ImageMetrics::compute(&image("pred"), &image("gt"), mask.as_ref()).unwrap();
        worst_psnr = worst_psnr.max(assert_close(name, "PSNR", got.psnr, metric(&case["psnr"])));
        worst_ssim = worst_ssim.max(assert_close(name, "SSIM", got.ssim, metric(&case["ssim"])));
    }
    println!(
        "{} cases: largest deviation PSNR {worst_psnr:e} dB, SSIM {worst_ssim:e}",
        cases.len()
    );
    assert!(masked >= 8, "expected the masked cases, got {masked}");
}

/// A 0/1 list of the fixture as a mask.
fn fixture_mask(case: &Value, key: &str, size: ImageSize) -> PixelMask {
    let bits = case[key]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64() == Some(1))
        .collect();
    PixelMask::new(size, bits).unwrap()
}

fn fixture_floats(case: &Value, key: &str) -> Vec<f32> {
    case[key]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap() as f32)
        .collect()
}

#[test]
fn the_silhouette_band_and_its_figures_match_scipy_and_numpy() {
    let fixture = support::load_json("metrics", "silhouette.json");
    let cases = fixture["cases"].as_array().unwrap();
    assert!(cases.len() >= 3, "{} cases", cases.len());
    for case in cases {
        let name = case["name"].as_str().unwrap();
        let size = ImageSize::new(
            case["width"].as_u64().unwrap() as u32,
            case["height"].as_u64().unwrap() as u32,
        );
        let truth = fixture_mask(case, "truth", size);
        assert_eq!(
            edge_band(&truth, BAND_RADIUS),
            fixture_mask(case, "band", size),
            "{name}: band"
        );
        let image = |key| Rgb32FImage::from_values(size, fixture_floats(case, key)).unwrap();
        let opacity = fixture_floats(case, "opacity");
        let got = SilhouetteMetrics::compute(
            &image("pred"),
            &image("gt"),
            &fixture_mask(case, "mask", size),
            &Silhouettes {
                truth: &truth,
                opacity: &opacity,
            },
        )
        .unwrap();
        for (what, value, key) in [
            ("band PSNR", got.band_psnr, "band_psnr"),
            (
                "outside-band PSNR",
                got.outside_band_psnr,
                "outside_band_psnr",
            ),
            ("area ratio", got.area_ratio, "area_ratio"),
        ] {
            assert_close(name, what, value, metric(&case[key]));
        }
    }
}
