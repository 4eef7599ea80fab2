//! Visual hulls: the world points every chosen camera sees inside its (dilated) foreground mask, as the
//! reference carves its mesh-extraction grid (docs/REFERENCE.md §5).

use anerf_core::geometry::{Camera, PixelConvention};
use anerf_core::{FrameId, ViewId};
use glam::Vec3;
use image::GrayImage;

use crate::error::DataError;
use crate::prepare::PreparedSubject;

/// One camera's silhouette: its mask, dilated.
struct Silhouette {
    camera: Camera,
    /// Row-major, `camera.width × camera.height`.
    inside: Vec<bool>,
}

/// The intersection of the cones of several cameras' silhouettes.
pub struct VisualHull {
    silhouettes: Vec<Silhouette>,
}

impl VisualHull {
    /// The hull of frame `frame` seen by `views`, masks at the working resolution dilated by a square of
    /// side `2·radius + 1` pixels. The reference dilates its full-resolution masks by 5 × 5 (radius 2): at a
    /// working ratio `r` that is radius `round(2r)` ([`Self::reference_radius`]).
    pub fn of_frame(
        prepared: &PreparedSubject,
        frame: FrameId,
        views: &[ViewId],
        radius: u32,
    ) -> Result<Self, DataError> {
        let silhouettes = views
            .iter()
            .map(|&v| {
                let camera = prepared.cameras[v.0].clone();
                let mask = prepared.mask(frame, v)?;
                Ok(Silhouette {
                    inside: dilate(&mask, radius),
                    camera,
                })
            })
            .collect::<Result<_, DataError>>()?;
        Ok(Self { silhouettes })
    }

    /// The dilation radius (working-resolution pixels) matching the reference's 5 × 5 full-resolution one.
    pub fn reference_radius(ratio: f32) -> u32 {
        (2.0 * ratio).round() as u32
    }

    /// True when world point `x` (metres) projects inside every silhouette: pixel coordinates rounded and
    /// clamped to the image, as the reference does; a point behind a camera is outside.
    pub fn contains(&self, x: Vec3) -> bool {
        self.silhouettes.iter().all(|s| {
            let Some(p) = s.camera.project(x, PixelConvention::Integer) else {
                return false;
            };
            let (w, h) = (s.camera.width as f32, s.camera.height as f32);
            let u = p.x.round().clamp(0.0, w - 1.0) as usize;
            let v = p.y.round().clamp(0.0, h - 1.0) as usize;
            s.inside[v * s.camera.width as usize + u]
        })
    }
}

/// `mask ≠ 0` dilated by a `(2r + 1)²` square, row-major.
fn dilate(mask: &GrayImage, r: u32) -> Vec<bool> {
    let (w, h) = (mask.width() as usize, mask.height() as usize);
    let r = r as usize;
    let on: Vec<bool> = mask.pixels().map(|p| p[0] != 0).collect();
    // Separable: rows, then columns.
    let mut rows = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            rows[y * w + x] = (x.saturating_sub(r)..=(x + r).min(w - 1)).any(|i| on[y * w + i]);
        }
    }
    let mut out = vec![false; w * h];
    for y in 0..h {
        for x in 0..w {
            out[y * w + x] = (y.saturating_sub(r)..=(y + r).min(h - 1)).any(|j| rows[j * w + x]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_grows_a_pixel_into_a_clamped_square() {
        let mut mask = GrayImage::new(7, 5);
        mask.put_pixel(1, 1, image::Luma([255]));
        let d = dilate(&mask, 2);
        for y in 0..5 {
            for x in 0..7 {
                assert_eq!(d[y * 7 + x], x <= 3 && y <= 3, "({x}, {y})");
            }
        }
        assert_eq!(dilate(&mask, 0).iter().filter(|&&b| b).count(), 1);
        assert_eq!(VisualHull::reference_radius(0.5), 1);
        assert_eq!(VisualHull::reference_radius(1.0), 2);
    }
}
