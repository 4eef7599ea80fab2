//! Lens undistortion as OpenCV's `cv2.undistort` does it (`initUndistortRectifyMap` with `R = I` and the
//! same `K`, then `remap`): every pixel of the undistorted image looks up where it came from in the raw
//! image. Pixel coordinates are integer positions (column `u`, row `v`), as in OpenCV.

use anerf_core::geometry::Distortion;
use glam::Mat3;
use image::{GrayImage, Rgb32FImage};

/// For each pixel of the undistorted image, its source position in the raw image (row-major).
#[derive(Debug, Clone)]
pub struct UndistortMap {
    pub width: u32,
    pub height: u32,
    /// Source `(u, v)` in pixels of the raw image.
    pub source: Vec<[f32; 2]>,
}

impl UndistortMap {
    /// OpenCV's map for intrinsics `k` and distortion `d` (computed in `f64`, as OpenCV does).
    pub fn new(k: Mat3, d: &Distortion, width: u32, height: u32) -> Self {
        let (fx, fy) = (k.x_axis.x as f64, k.y_axis.y as f64);
        let (cx, cy) = (k.z_axis.x as f64, k.z_axis.y as f64);
        let [k1, k2, p1, p2, k3] = d.0.map(|c| c as f64);
        let mut source = Vec::with_capacity((width * height) as usize);
        for v in 0..height {
            let y = (v as f64 - cy) / fy;
            for u in 0..width {
                let x = (u as f64 - cx) / fx;
                let (x2, y2) = (x * x, y * y);
                let r2 = x2 + y2;
                let xy2 = 2.0 * x * y;
                let kr = 1.0 + ((k3 * r2 + k2) * r2 + k1) * r2;
                let su = fx * (x * kr + p1 * xy2 + p2 * (r2 + 2.0 * x2)) + cx;
                let sv = fy * (y * kr + p1 * (r2 + 2.0 * y2) + p2 * xy2) + cy;
                source.push([su as f32, sv as f32]);
            }
        }
        Self {
            width,
            height,
            source,
        }
    }

    /// Bilinear resampling with a zero border, at source positions rounded to 1/32 pixel like OpenCV's
    /// `remap` (`INTER_BITS = 5`), so results agree with `cv2.undistort` to float precision.
    pub fn remap_rgb(&self, raw: &Rgb32FImage) -> Rgb32FImage {
        let (w, h) = (raw.width() as i64, raw.height() as i64);
        let tap = |x: i64, y: i64| -> [f32; 3] {
            if x >= 0 && y >= 0 && x < w && y < h {
                raw.get_pixel(x as u32, y as u32).0
            } else {
                [0.0; 3]
            }
        };
        let mut out = Rgb32FImage::new(self.width, self.height);
        for (px, s) in out.pixels_mut().zip(&self.source) {
            let qx = (s[0] as f64 * 32.0).round() as i64;
            let qy = (s[1] as f64 * 32.0).round() as i64;
            let (x0, y0) = (qx.div_euclid(32), qy.div_euclid(32));
            let (fx, fy) = (
                qx.rem_euclid(32) as f32 / 32.0,
                qy.rem_euclid(32) as f32 / 32.0,
            );
            let (a, b, c, d) = (
                tap(x0, y0),
                tap(x0 + 1, y0),
                tap(x0, y0 + 1),
                tap(x0 + 1, y0 + 1),
            );
            for ch in 0..3 {
                px.0[ch] = (a[ch] * (1.0 - fx) + b[ch] * fx) * (1.0 - fy)
                    + (c[ch] * (1.0 - fx) + d[ch] * fx) * fy;
            }
        }
        out
    }

    /// Nearest-neighbour resampling with a zero border (masks keep their labels).
    pub fn remap_nearest(&self, raw: &GrayImage) -> GrayImage {
        let mut out = GrayImage::new(self.width, self.height);
        for (px, s) in out.pixels_mut().zip(&self.source) {
            let (x, y) = (s[0].round_ties_even() as i64, s[1].round_ties_even() as i64);
            if x >= 0 && y >= 0 && x < raw.width() as i64 && y < raw.height() as i64 {
                *px = *raw.get_pixel(x as u32, y as u32);
            }
        }
        out
    }
}
