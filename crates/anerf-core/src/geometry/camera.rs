//! Pinhole cameras with OpenCV-style lens distortion: pixel ↔ ray, world → pixel, resizing.

use glam::{Mat3, Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::GeometryError;

/// Where a pixel's ray passes through the pixel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PixelConvention {
    /// Through `(u, v)` for column `u`, row `v`: the reference code's convention (no +0.5), the default,
    /// because the published numbers were rendered with it.
    #[default]
    Integer,
    /// Through the pixel centre `(u + 0.5, v + 0.5)`.
    Center,
}

impl PixelConvention {
    fn offset(self) -> f32 {
        match self {
            PixelConvention::Integer => 0.0,
            PixelConvention::Center => 0.5,
        }
    }
}

/// OpenCV's radial–tangential distortion `(k1, k2, p1, p2, k3)` on normalised image coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Distortion(pub [f32; 5]);

impl Distortion {
    /// True when all coefficients are zero.
    pub fn is_identity(&self) -> bool {
        self.0.iter().all(|&c| c == 0.0)
    }

    /// Distorts a normalised point `(x, y) = (X/Z, Y/Z)`.
    pub fn apply(&self, p: Vec2) -> Vec2 {
        let [k1, k2, p1, p2, k3] = self.0;
        let r2 = p.length_squared();
        let radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
        Vec2::new(
            p.x * radial + 2.0 * p1 * p.x * p.y + p2 * (r2 + 2.0 * p.x * p.x),
            p.y * radial + p1 * (r2 + 2.0 * p.y * p.y) + 2.0 * p2 * p.x * p.y,
        )
    }

    /// Inverts [`Distortion::apply`] by OpenCV's fixed-point iteration (`cv::undistortPoints`).
    pub fn remove(&self, distorted: Vec2) -> Vec2 {
        let [k1, k2, p1, p2, k3] = self.0;
        let mut p = distorted;
        for _ in 0..20 {
            let r2 = p.length_squared();
            let icdist = 1.0 / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)));
            let dx = 2.0 * p1 * p.x * p.y + p2 * (r2 + 2.0 * p.x * p.x);
            let dy = p1 * (r2 + 2.0 * p.y * p.y) + 2.0 * p2 * p.x * p.y;
            p = Vec2::new((distorted.x - dx) * icdist, (distorted.y - dy) * icdist);
        }
        p
    }
}

/// A ray in world space: `origin + t · direction`, unit `direction`, `t` in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ray {
    pub origin: Vec3,
    pub direction: Vec3,
}

impl Ray {
    /// The point at depth `t`.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + self.direction * t
    }
}

/// A calibrated camera: `x_cam = R x_world + T` (metres), pixel `~ K x_cam` (column `u`, row `v`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Intrinsics `K` in pixels of an image `width × height`.
    pub intrinsics: Mat3,
    /// World → camera rotation `R`.
    pub rotation: Mat3,
    /// World → camera translation `T`, metres (the datasets store millimetres; loaders convert).
    pub translation: Vec3,
    /// Lens distortion of the raw images (zero once images are undistorted).
    pub distortion: Distortion,
    pub width: u32,
    pub height: u32,
}

impl Camera {
    /// Builds and validates a camera from row-major `K` and `R` (the datasets' layout).
    pub fn from_rows(
        k: [[f32; 3]; 3],
        r: [[f32; 3]; 3],
        t_metres: [f32; 3],
        distortion: [f32; 5],
        width: u32,
        height: u32,
    ) -> Result<Self, GeometryError> {
        let cam = Self {
            intrinsics: Mat3::from_cols_array_2d(&k).transpose(),
            rotation: Mat3::from_cols_array_2d(&r).transpose(),
            translation: Vec3::from(t_metres),
            distortion: Distortion(distortion),
            width,
            height,
        };
        cam.validate()?;
        Ok(cam)
    }

    /// Checks finiteness, a usable `K` (positive focal lengths, last row `0 0 1`) and that `R` is a rotation.
    pub fn validate(&self) -> Result<(), GeometryError> {
        let invalid = |what, detail: String| Err(GeometryError::InvalidCamera { what, detail });
        let k = self.intrinsics;
        if k.to_cols_array().iter().any(|v| !v.is_finite())
            || k.x_axis.x <= 0.0
            || k.y_axis.y <= 0.0
        {
            return invalid(
                "K",
                format!("{k:?} (expected finite entries and positive focal lengths)"),
            );
        }
        if k.row(2) != Vec3::Z {
            return invalid("K", format!("last row {} (expected 0 0 1)", k.row(2)));
        }
        let r = self.rotation;
        let orth = (r * r.transpose() - Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        if !r.is_finite() || orth > 1e-3 || (r.determinant() - 1.0).abs() > 1e-3 {
            return invalid(
                "R",
                format!(
                    "{r:?} is not a rotation (|RRᵀ − I| = {orth:e}, det = {})",
                    r.determinant()
                ),
            );
        }
        if !self.translation.is_finite() {
            return invalid("T", format!("{}", self.translation));
        }
        if self.distortion.0.iter().any(|v| !v.is_finite()) {
            return invalid("D", format!("{:?}", self.distortion.0));
        }
        if self.width == 0 || self.height == 0 {
            return invalid("image size", format!("{}×{}", self.width, self.height));
        }
        Ok(())
    }

    /// Camera centre in world space, `−Rᵀ T`.
    pub fn center(&self) -> Vec3 {
        -(self.rotation.transpose() * self.translation)
    }

    /// The ray through pixel (column `u`, row `v`) of the undistorted image.
    pub fn pixel_ray(&self, u: f32, v: f32, convention: PixelConvention) -> Ray {
        let o = convention.offset();
        let dir_cam = self.intrinsics.inverse() * Vec3::new(u + o, v + o, 1.0);
        Ray {
            origin: self.center(),
            direction: (self.rotation.transpose() * dir_cam).normalize(),
        }
    }

    /// The ray through point `p` of the raw (distorted) image, integer convention: the inverse of
    /// [`Camera::project_distorted`] (`D` removed by [`Distortion::remove`]).
    pub fn raw_pixel_ray(&self, p: Vec2) -> Ray {
        let n = self.intrinsics.inverse() * p.extend(1.0);
        let undistorted = self.distortion.remove(Vec2::new(n.x / n.z, n.y / n.z));
        Ray {
            origin: self.center(),
            direction: (self.rotation.transpose() * undistorted.extend(1.0)).normalize(),
        }
    }

    /// Rays of every pixel of a `width × height` image, row by row.
    pub fn image_rays(&self, convention: PixelConvention) -> Vec<Ray> {
        let k_inv = self.intrinsics.inverse();
        let rt = self.rotation.transpose();
        let origin = self.center();
        let o = convention.offset();
        (0..self.height)
            .flat_map(|v| (0..self.width).map(move |u| (u, v)))
            .map(|(u, v)| Ray {
                origin,
                direction: (rt * (k_inv * Vec3::new(u as f32 + o, v as f32 + o, 1.0))).normalize(),
            })
            .collect()
    }

    /// World point → camera frame.
    pub fn world_to_camera(&self, x: Vec3) -> Vec3 {
        self.rotation * x + self.translation
    }

    /// World point → continuous pixel coordinates `(u, v)` of the undistorted image, in the same
    /// convention as [`Camera::pixel_ray`]; `None` behind the camera.
    pub fn project(&self, x: Vec3, convention: PixelConvention) -> Option<Vec2> {
        let c = self.world_to_camera(x);
        (c.z > 1e-9).then(|| {
            let p = self.intrinsics * (c / c.z);
            Vec2::new(p.x, p.y) - Vec2::splat(convention.offset())
        })
    }

    /// World point → pixel of the raw (distorted) image, applying `D`; integer convention.
    pub fn project_distorted(&self, x: Vec3) -> Option<Vec2> {
        let c = self.world_to_camera(x);
        (c.z > 1e-9).then(|| {
            let d = self.distortion.apply(Vec2::new(c.x / c.z, c.y / c.z));
            let p = self.intrinsics * d.extend(1.0);
            Vec2::new(p.x, p.y)
        })
    }

    /// The same camera for an image resized by `ratio` (e.g. 0.5): `K[:2] *= ratio`, as the reference does
    /// (no half-pixel correction), image size rounded to the nearest pixel.
    pub fn resized(&self, ratio: f32) -> Self {
        let mut k = self.intrinsics;
        for col in [&mut k.x_axis, &mut k.y_axis, &mut k.z_axis] {
            col.x *= ratio;
            col.y *= ratio;
        }
        Self {
            intrinsics: k,
            width: (self.width as f32 * ratio).round() as u32,
            height: (self.height as f32 * ratio).round() as u32,
            ..self.clone()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    pub(crate) fn test_camera() -> Camera {
        Camera::from_rows(
            [[500.0, 0.0, 320.0], [0.0, 520.0, 240.0], [0.0, 0.0, 1.0]],
            crate::geometry::axis_angle_to_matrix(Vec3::new(0.2, -2.5, 0.1))
                .transpose()
                .to_cols_array_2d(),
            [0.1, 0.2, 3.0],
            [0.0; 5],
            640,
            480,
        )
        .unwrap()
    }

    #[test]
    fn points_along_a_pixel_ray_project_back_onto_that_pixel() {
        let cam = test_camera();
        for conv in [PixelConvention::Integer, PixelConvention::Center] {
            for &(u, v) in &[(0.0, 0.0), (17.0, 300.0), (639.0, 479.0), (320.0, 240.0)] {
                let ray = cam.pixel_ray(u, v, conv);
                assert!((ray.direction.length() - 1.0).abs() < 1e-6);
                for t in [0.5f32, 1.0, 3.7, 10.0] {
                    let px = cam.project(ray.at(t), conv).unwrap();
                    assert!(
                        (px - Vec2::new(u, v)).length() < 2e-3,
                        "{conv:?} {u},{v} t={t}: {px}"
                    );
                }
            }
        }
        let rays = cam.image_rays(PixelConvention::Integer);
        let r = rays[5 * 640 + 9];
        assert!(
            (r.direction - cam.pixel_ray(9.0, 5.0, PixelConvention::Integer).direction).length()
                < 1e-6
        );
    }

    #[test]
    fn resizing_scales_projections() {
        let cam = test_camera();
        let half = cam.resized(0.5);
        assert_eq!((half.width, half.height), (320, 240));
        let x = Vec3::new(0.3, -0.2, 0.4);
        let full = cam.project(x, PixelConvention::Integer).unwrap();
        assert!((half.project(x, PixelConvention::Integer).unwrap() - full * 0.5).length() < 1e-3);
    }

    #[test]
    fn distortion_round_trips() {
        let d = Distortion([-0.25, 0.08, 0.001, -0.002, 0.01]);
        for &(x, y) in &[(0.0f32, 0.0f32), (0.2, -0.1), (-0.35, 0.3), (0.4, 0.25)] {
            let p = Vec2::new(x, y);
            assert!((d.remove(d.apply(p)) - p).length() < 1e-5);
        }
    }

    #[test]
    fn points_along_a_raw_pixel_ray_project_back_onto_that_raw_pixel() {
        let cam = Camera {
            distortion: Distortion([-0.2, 0.05, 0.001, -0.002, 0.0]),
            ..test_camera()
        };
        for &(u, v) in &[(0.0, 0.0), (17.5, 300.25), (639.0, 479.0), (320.0, 240.0)] {
            let ray = cam.raw_pixel_ray(Vec2::new(u, v));
            assert!((ray.direction.length() - 1.0).abs() < 1e-6);
            for t in [0.5f32, 3.7, 10.0] {
                let px = cam.project_distorted(ray.at(t)).unwrap();
                assert!(
                    (px - Vec2::new(u, v)).length() < 1e-2,
                    "{u},{v} t={t}: {px}"
                );
            }
        }
    }

    #[test]
    fn invalid_cameras_are_rejected() {
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let k = [[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]];
        let bad_r = [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let err = Camera::from_rows(k, bad_r, [0.0; 3], [0.0; 5], 4, 4).unwrap_err();
        assert!(err.to_string().contains("R"), "{err}");
        let err = Camera::from_rows(k, id, [f32::NAN, 0.0, 0.0], [0.0; 5], 4, 4).unwrap_err();
        assert!(err.to_string().contains("T"), "{err}");
        let err = Camera::from_rows([[0.0; 3]; 3], id, [0.0; 3], [0.0; 5], 4, 4).unwrap_err();
        assert!(err.to_string().contains("K"), "{err}");
    }
}
