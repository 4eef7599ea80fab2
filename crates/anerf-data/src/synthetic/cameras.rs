//! A ring of calibrated cameras around the subject, in the z-up world of ZJU-MoCap (metres).

use anerf_core::geometry::{Camera, Distortion};
use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};

use super::rng::SplitMix64;
use super::SynthError;

/// Where the cameras stand and how they see.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RigSpec {
    pub views: usize,
    /// Square image side (pixels).
    pub resolution: u32,
    /// Horizontal distance from the ring's axis (the world's `z` axis) to each camera (metres).
    pub radius: f32,
    /// Mean camera height above the ground (metres).
    pub height: f32,
    /// Camera heights in turn around the ring (metres), repeated; empty gives every camera `height`.
    /// Lets held-out cameras see the body from heights the training cameras never had.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub heights: Vec<f32>,
    /// Camera heights vary by up to this much around `height` (metres).
    pub height_jitter: f32,
    /// Height of the point every camera looks at (metres).
    pub target_height: f32,
    /// Half the height of the world region every image must show, at the ring's axis (metres).
    pub half_field: f32,
    /// Largest `|k1|` of the radial–tangential lens distortion; 0 gives ideal pinholes.
    pub distortion: f32,
}

impl Default for RigSpec {
    fn default() -> Self {
        Self {
            views: 8,
            resolution: 256,
            radius: 3.0,
            height: 1.1,
            heights: Vec::new(),
            height_jitter: 0.4,
            target_height: 0.9,
            half_field: 1.1,
            distortion: 0.0,
        }
    }
}

impl RigSpec {
    pub fn validate(&self) -> Result<(), SynthError> {
        if self.views == 0 || self.views > 1000 {
            return Err(SynthError::invalid(
                "rig.views",
                format!("{} (expected 1 to 1000)", self.views),
            ));
        }
        if !(16..=8192).contains(&self.resolution) {
            return Err(SynthError::invalid(
                "rig.resolution",
                format!("{} (expected 16 to 8192 pixels)", self.resolution),
            ));
        }
        SynthError::check_ranges(&[
            ("rig.radius", self.radius, 1.0, 100.0),
            ("rig.height", self.height, 0.0, 10.0),
            ("rig.height_jitter", self.height_jitter, 0.0, 2.0),
            ("rig.target_height", self.target_height, 0.0, 3.0),
            ("rig.half_field", self.half_field, 0.3, 5.0),
            ("rig.distortion", self.distortion, 0.0, 0.2),
        ])?;
        let heights: Vec<_> = self
            .heights
            .iter()
            .map(|&h| ("rig.heights", h, 0.0, 10.0))
            .collect();
        SynthError::check_ranges(&heights)
    }

    /// The mean height of camera `c` (metres): `heights` in turn, else `height`.
    fn base_height(&self, c: usize) -> f32 {
        if self.heights.is_empty() {
            self.height
        } else {
            self.heights[c % self.heights.len()]
        }
    }
}

/// The world-to-camera rotation of a camera at `centre` looking at `target` in the z-up world: rows are
/// the camera's axes in world coordinates (x right, y down in the image, z forwards).
pub fn look_at(centre: Vec3, target: Vec3) -> Mat3 {
    let forward = (target - centre).normalize();
    let right = forward.cross(Vec3::Z).normalize();
    let down = forward.cross(right);
    Mat3::from_cols(right, down, forward).transpose()
}

/// The cameras of `rig`: evenly spread around the ring with a little jitter in angle and height, each
/// looking at the target with a focal length that fits `half_field` into the image at the nearest
/// distance of the body, a principal point near the centre and, when asked for, mild distortion.
pub fn ring_cameras(rig: &RigSpec, rng: &mut SplitMix64) -> Result<Vec<Camera>, SynthError> {
    let size = rig.resolution as f32;
    let target = Vec3::new(0.0, 0.0, rig.target_height);
    (0..rig.views)
        .map(|c| {
            let angle =
                std::f32::consts::TAU * (c as f32 + rng.range(-0.1, 0.1)) / rig.views as f32;
            let centre = Vec3::new(
                rig.radius * angle.cos(),
                rig.radius * angle.sin(),
                rig.base_height(c) + rng.range(-rig.height_jitter, rig.height_jitter),
            );
            let rotation = look_at(centre, target);
            let distance = (target - centre).length() - 0.5;
            let focal = 0.5 * size * distance / rig.half_field * rng.range(0.97, 1.03);
            let principal = [
                0.5 * size + rng.range(-0.02, 0.02) * size,
                0.5 * size + rng.range(-0.02, 0.02) * size,
            ];
            let k1 = rng.range(-rig.distortion, rig.distortion);
            let distortion = Distortion([
                k1,
                -0.3 * k1 * rng.range(0.0, 1.0),
                rng.range(-0.05, 0.05) * rig.distortion,
                rng.range(-0.05, 0.05) * rig.distortion,
                0.0,
            ]);
            let camera = Camera {
                intrinsics: Mat3::from_cols(
                    Vec3::new(focal, 0.0, 0.0),
                    Vec3::new(0.0, focal * rng.range(0.995, 1.005), 0.0),
                    Vec3::new(principal[0], principal[1], 1.0),
                ),
                rotation,
                translation: -(rotation * centre),
                distortion,
                width: rig.resolution,
                height: rig.resolution,
            };
            camera
                .validate()
                .map_err(|e| SynthError::invalid(format!("camera {c}"), e.to_string()))?;
            Ok(camera)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use anerf_core::geometry::PixelConvention;

    #[test]
    fn cameras_ring_the_subject_and_see_it_in_the_middle() {
        let rig = RigSpec {
            views: 6,
            distortion: 0.05,
            ..Default::default()
        };
        let cams = ring_cameras(&rig, &mut SplitMix64::new(3)).unwrap();
        assert_eq!(cams.len(), 6);
        let mut heights = Vec::new();
        for cam in &cams {
            let c = cam.center();
            assert!((c.truncate().length() - rig.radius).abs() < 1e-4);
            heights.push(c.z);
            // The target projects near the image centre; a point 1 m above the ground is in the image.
            let t = cam
                .project(
                    Vec3::new(0.0, 0.0, rig.target_height),
                    PixelConvention::Integer,
                )
                .unwrap();
            assert!((t - glam::Vec2::splat(128.0)).length() < 10.0, "{t}");
            for p in [Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, 0.0, 1.8)] {
                let px = cam.project_distorted(p).unwrap();
                assert!(
                    px.min_element() > 0.0 && px.max_element() < 256.0,
                    "{p} -> {px}"
                );
            }
            // Image "down" is world −z near the centre.
            let a = cam
                .project(Vec3::new(0.0, 0.0, 1.0), PixelConvention::Integer)
                .unwrap();
            let b = cam
                .project(Vec3::new(0.0, 0.0, 0.5), PixelConvention::Integer)
                .unwrap();
            assert!(b.y > a.y);
        }
        let spread = heights.iter().copied().fold(f32::NEG_INFINITY, f32::max)
            - heights.iter().copied().fold(f32::INFINITY, f32::min);
        assert!(spread > 0.1, "heights {heights:?}");
    }
}
