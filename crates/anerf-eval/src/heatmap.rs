//! Per-pixel error heat maps of evaluation images: the mean absolute RGB error on a fixed scale, so that
//! maps of different images and runs compare by colour.

use image::{Rgb, Rgb32FImage};

use crate::pixels::PixelMask;
use crate::RgbImageExt;

/// The error (mean of |pred − gt| over R, G, B, in `[0, 1]` units) drawn at the top of the scale.
pub const FULL_SCALE: f32 = 0.25;

/// Pixels outside the evaluation mask.
pub const OUTSIDE: [f32; 3] = [0.3, 0.3, 0.3];

/// Control points of the colour scale (inferno-like: black, purple, red-orange, yellow), evenly spaced.
const SCALE: [[f32; 3]; 5] = [
    [0.0, 0.0, 0.015],
    [0.34, 0.06, 0.43],
    [0.73, 0.21, 0.33],
    [0.98, 0.55, 0.04],
    [0.99, 1.0, 0.64],
];

/// The colour of error `e` (clamped to `[0, FULL_SCALE]`).
pub fn error_color(e: f32) -> [f32; 3] {
    let t = (e / FULL_SCALE).clamp(0.0, 1.0) * (SCALE.len() - 1) as f32;
    let i = (t.floor() as usize).min(SCALE.len() - 2);
    let w = t - i as f32;
    std::array::from_fn(|c| SCALE[i][c] * (1.0 - w) + SCALE[i + 1][c] * w)
}

/// The heat map of `pred` against `gt` (same size) inside `mask`; [`OUTSIDE`] elsewhere.
pub fn error_heat_map(pred: &Rgb32FImage, gt: &Rgb32FImage, mask: &PixelMask) -> Rgb32FImage {
    let mut out = Rgb32FImage::black(pred.size());
    for (x, y, p) in out.enumerate_pixels_mut() {
        *p = Rgb(if mask.contains(x, y) {
            let (a, b) = (pred.get_pixel(x, y).0, gt.get_pixel(x, y).0);
            let e = (0..3).map(|c| (a[c] - b[c]).abs()).sum::<f32>() / 3.0;
            error_color(e)
        } else {
            OUTSIDE
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pixels::ImageSize;

    fn luminance(c: [f32; 3]) -> f32 {
        0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
    }

    #[test]
    fn the_scale_runs_from_black_to_yellow_with_rising_luminance() {
        assert_eq!(error_color(0.0), SCALE[0]);
        assert_eq!(error_color(FULL_SCALE), SCALE[4]);
        assert_eq!(error_color(10.0), SCALE[4], "clamped above");
        let mut last = -1.0;
        for i in 0..=100 {
            let l = luminance(error_color(FULL_SCALE * i as f32 / 100.0));
            assert!(l > last, "luminance falls at {i}");
            last = l;
        }
    }

    #[test]
    fn a_pixel_gets_the_colour_of_its_mean_channel_error_and_outside_is_grey() {
        let size = ImageSize::new(3, 1);
        let mut pred = Rgb32FImage::black(size);
        let gt = Rgb32FImage::black(size);
        pred.put_pixel(1, 0, Rgb([0.3, 0.0, 0.0])); // mean error 0.1
        pred.put_pixel(2, 0, Rgb([0.9, 0.9, 0.9]));
        let mask = PixelMask::from_fn(size, |x, _| x < 2);
        let map = error_heat_map(&pred, &gt, &mask);
        assert_eq!(map.get_pixel(0, 0).0, error_color(0.0));
        let expected = error_color(0.1);
        let got = map.get_pixel(1, 0).0;
        assert!(
            (0..3).all(|c| (got[c] - expected[c]).abs() < 1e-6),
            "{got:?}"
        );
        assert_eq!(map.get_pixel(2, 0).0, OUTSIDE);
    }
}
