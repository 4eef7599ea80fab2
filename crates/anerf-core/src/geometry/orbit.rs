//! Camera paths around a subject: the world's "up" as a rig of cameras sees it, and orbits of a reference
//! camera about that axis (world space, metres), for orbit renders and placing motions upright.

use glam::{Mat3, Vec3};

use super::Camera;

/// The world's "up" direction as the cameras see it: the mean of their image-up axes (`−y` of each camera
/// in world space), normalised.
pub fn mean_up(cameras: &[Camera]) -> Vec3 {
    let sum: Vec3 = cameras
        .iter()
        .map(|c| c.rotation.transpose() * -Vec3::Y)
        .sum();
    sum.try_normalize().unwrap_or(Vec3::Z)
}

/// `n` cameras orbiting `center` about the axis `up`, starting at `reference` and keeping its intrinsics,
/// distance and height: the reference camera moved with the world rotated about the axis.
pub fn orbit(reference: &Camera, center: Vec3, up: Vec3, n: usize) -> Vec<Camera> {
    (0..n)
        .map(|i| orbit_camera(reference, center, up, i as f32 / n as f32))
        .collect()
}

/// `reference` moved a fraction `turn` of a full circle about the axis `up` through `center`.
pub fn orbit_camera(reference: &Camera, center: Vec3, up: Vec3, turn: f32) -> Camera {
    let q = Mat3::from_axis_angle(up, std::f32::consts::TAU * turn);
    let eye = center + q * (reference.center() - center);
    let rotation = reference.rotation * q.transpose();
    Camera {
        rotation,
        translation: -(rotation * eye),
        ..reference.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::PixelConvention;

    #[test]
    fn orbit_keeps_the_subject_at_the_same_pixel_and_distance() {
        let reference = Camera::from_rows(
            [[100.0, 0.0, 32.0], [0.0, 100.0, 32.0], [0.0, 0.0, 1.0]],
            [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]],
            [0.1, 0.9, 3.0],
            [0.0; 5],
            64,
            64,
        )
        .unwrap();
        let center = Vec3::new(0.2, -0.1, 0.9);
        let up = mean_up(std::slice::from_ref(&reference));
        assert!((up - Vec3::Z).length() < 1e-6, "{up}");
        let px = reference.project(center, PixelConvention::Integer).unwrap();
        let cams = orbit(&reference, center, up, 8);
        for c in &cams {
            c.validate().unwrap();
            assert!((c.project(center, PixelConvention::Integer).unwrap() - px).length() < 1e-3);
            assert!(
                ((c.center() - center).length() - (reference.center() - center).length()).abs()
                    < 1e-5
            );
            assert!(
                ((c.center() - center).dot(up) - (reference.center() - center).dot(up)).abs()
                    < 1e-5
            );
        }
        // Half way round, the camera sits on the other side of the subject.
        let (a, b) = (reference.center() - center, cams[4].center() - center);
        assert!((a - a.dot(up) * up + (b - b.dot(up) * up)).length() < 1e-4);
    }
}
