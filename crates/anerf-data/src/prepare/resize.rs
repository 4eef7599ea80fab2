//! Downscaling as OpenCV's `cv2.resize` does it: `INTER_AREA` (area averaging) for images and
//! `INTER_NEAREST` for masks. The output size is `int(size · ratio)` (truncated), as in the reference.

use anerf_core::InvalidValue;
use image::{GrayImage, Rgb32FImage};
use serde::{Deserialize, Serialize};

/// The factor from a camera's stored image size to the working size, `0 < ratio ≤ 1` (checked when built,
/// so every holder of one, a config or [`super::PrepareOptions`], is valid). Serialised as the number.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "f32", into = "f32")]
pub struct ImageScale(f32);

impl ImageScale {
    /// Full size (H36M's working resolution).
    pub const FULL: Self = Self(1.0);
    /// Half size (ZJU-MoCap's 1024² images at 512²).
    pub const HALF: Self = Self(0.5);

    /// The factor.
    pub fn get(self) -> f32 {
        self.0
    }
}

impl TryFrom<f32> for ImageScale {
    type Error = InvalidValue;

    fn try_from(ratio: f32) -> Result<Self, InvalidValue> {
        if ratio.is_finite() && ratio > 0.0 && ratio <= 1.0 {
            Ok(Self(ratio))
        } else {
            Err(InvalidValue::new(
                "image scale",
                ratio,
                "a factor 0 < ratio ≤ 1",
            ))
        }
    }
}

impl From<ImageScale> for f32 {
    fn from(scale: ImageScale) -> f32 {
        scale.0
    }
}

/// `int(n · ratio)`, at least 1.
pub fn scaled_size(n: u32, ratio: ImageScale) -> u32 {
    ((n as f64 * ratio.get() as f64) as u32).max(1)
}

/// Per output index, the source indices and weights of OpenCV's area interpolation along one axis
/// (`scale = src / dst ≥ 1`).
fn area_weights(src: u32, dst: u32) -> Vec<Vec<(u32, f32)>> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|d| {
            let fs1 = d as f64 * scale;
            let fs2 = fs1 + scale;
            let cell = scale.min(src as f64 - fs1);
            let s1 = fs1.ceil() as i64;
            let s2 = fs2.floor() as i64;
            let mut w = Vec::new();
            if s1 as f64 - fs1 > 1e-3 {
                w.push(((s1 - 1) as u32, ((s1 as f64 - fs1) / cell) as f32));
            }
            for s in s1..s2.min(src as i64) {
                w.push((s as u32, (1.0 / cell) as f32));
            }
            if fs2 - s2 as f64 > 1e-3 && s2 < src as i64 {
                w.push((
                    s2 as u32,
                    ((fs2 - s2 as f64).min(1.0).min(cell) / cell) as f32,
                ));
            }
            w
        })
        .collect()
}

/// Area-averaging downscale to `width × height` (each no larger than the source).
pub fn resize_area(img: &Rgb32FImage, width: u32, height: u32) -> Rgb32FImage {
    if (width, height) == img.dimensions() {
        return img.clone();
    }
    let wx = area_weights(img.width(), width);
    let wy = area_weights(img.height(), height);
    let mut out = Rgb32FImage::new(width, height);
    for (y, row) in wy.iter().enumerate() {
        for (x, col) in wx.iter().enumerate() {
            let mut acc = [0.0f32; 3];
            for &(sy, ay) in row {
                for &(sx, ax) in col {
                    let p = img.get_pixel(sx, sy).0;
                    for c in 0..3 {
                        acc[c] += ay * ax * p[c];
                    }
                }
            }
            out.put_pixel(x as u32, y as u32, image::Rgb(acc));
        }
    }
    out
}

/// Nearest-neighbour resize: output pixel `x` reads source `floor(x · src / dst)`, OpenCV's rule.
pub fn resize_nearest(mask: &GrayImage, width: u32, height: u32) -> GrayImage {
    let sx = mask.width() as f64 / width as f64;
    let sy = mask.height() as f64 / height as f64;
    GrayImage::from_fn(width, height, |x, y| {
        let u = ((x as f64 * sx).floor() as u32).min(mask.width() - 1);
        let v = ((y as f64 * sy).floor() as u32).min(mask.height() - 1);
        *mask.get_pixel(u, v)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_image_scale_is_a_factor_in_zero_to_one_and_serialises_as_the_number() {
        for bad in [0.0, -0.5, 1.5, f32::NAN, f32::INFINITY] {
            let err = ImageScale::try_from(bad).unwrap_err();
            assert!(err.expected.contains("0 < ratio ≤ 1"), "{bad}: {err}");
            assert!(serde_json::from_str::<ImageScale>(&format!("{bad:?}")).is_err());
        }
        let half: ImageScale = serde_json::from_str("0.5").unwrap();
        assert_eq!(half, ImageScale::HALF);
        assert_eq!(serde_json::to_string(&ImageScale::FULL).unwrap(), "1.0");
        assert_eq!(scaled_size(1024, half), 512);
        assert_eq!(scaled_size(1, half), 1);
    }
}
