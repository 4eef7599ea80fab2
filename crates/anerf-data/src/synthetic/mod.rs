//! Synthetic subjects: a procedural animated human filmed by a ring of calibrated cameras, written in
//! the ZJU-MoCap layout (docs/REFERENCE.md §1.1, §1.3) with ground truth for novel views and novel poses.
//! Needs no dataset and no SMPL licence; deterministic under a seed.

pub mod appearance;
pub mod backdrop;
pub mod body;
pub mod cameras;
pub mod clothing;
mod layout;
pub mod lighting;
mod mask_noise;
pub mod motion;
mod pose_noise;
pub mod raster;
mod rng;

use std::path::{Path, PathBuf};
use std::time::Duration;

use anerf_core::named::Named;
use anerf_core::GeometryError;
use glam::Vec3;
use serde::{Deserialize, Serialize};
use thiserror::Error;

pub use backdrop::Backdrop;
pub use body::{build_body, Body, BodyShape};
pub use cameras::RigSpec;
pub use clothing::ClothingSpec;
pub use layout::write_subject;
pub use lighting::{Lighting, PointLight, StudioLights};
pub use motion::{ClipSpec, MotionKind};
pub use pose_noise::{PoseNoise, PoseNoiseReport};

use crate::formats::FormatWriteError;
use crate::subject::Subject;

/// Everything that defines a synthetic subject. The same spec and seed give the same files.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SyntheticSpec {
    pub seed: u64,
    pub body: BodyShape,
    pub rig: RigSpec,
    /// Frames `0 .. training.frames` on disk.
    pub training: ClipSpec,
    /// Frames that follow the training frames on disk; poses the training clip never shows.
    pub novel_pose: ClipSpec,
    /// Camera indices used for training; the others are the novel-view test cameras. `None` takes
    /// every other camera (0, 2, 4, …).
    pub training_views: Option<Vec<usize>>,
    /// Samples per pixel along each axis (anti-aliasing by supersampling).
    pub supersampling: u32,
    /// JPEG quality of the images (1–100).
    pub jpeg_quality: u8,
    /// How the body is lit (absent: one light fixed to the body).
    #[serde(default)]
    pub lighting: Lighting,
    /// A garment rendered over the body while the files hold the bare body (absent: the files hold
    /// exactly the rendered surface and its weights).
    #[serde(default)]
    pub clothing: Option<ClothingSpec>,
    /// Fit errors in the training frames' `new_params/` and `new_vertices/`, with the true poses in
    /// `true_params/`; the images stay rendered from the true poses (absent: the files hold them).
    #[serde(default)]
    pub pose_noise: Option<PoseNoise>,
    /// Segmentation-like errors of every mask's edge, up to this many pixels (a real number in 0–10;
    /// 0: the masks are exact). The images stay exact.
    #[serde(default)]
    pub mask_noise: f32,
    /// What the images show behind the body (absent: black, as every earlier subject). The masks stay the
    /// body's exact coverage either way.
    #[serde(default)]
    pub backdrop: Backdrop,
}

/// The named subjects of `anerf synth --preset`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SynthPreset {
    Tiny,
    Demo,
    Realistic,
    RealisticExact,
}

impl SynthPreset {
    pub const ALL: [SynthPreset; 4] = [
        SynthPreset::Tiny,
        SynthPreset::Demo,
        SynthPreset::Realistic,
        SynthPreset::RealisticExact,
    ];

    pub fn spec(self) -> SyntheticSpec {
        match self {
            SynthPreset::Tiny => SyntheticSpec::tiny(),
            SynthPreset::Demo => SyntheticSpec::demo(),
            SynthPreset::Realistic => SyntheticSpec::realistic(),
            SynthPreset::RealisticExact => SyntheticSpec::realistic_exact(),
        }
    }
}

impl Named for SynthPreset {
    const KIND: &'static str = "synthetic preset";

    fn all() -> &'static [Self] {
        &Self::ALL
    }

    /// The preset's name on the command line.
    fn name(self) -> &'static str {
        match self {
            SynthPreset::Tiny => "tiny",
            SynthPreset::Demo => "demo",
            SynthPreset::Realistic => "realistic",
            SynthPreset::RealisticExact => "realistic-exact",
        }
    }
}

anerf_core::by_name!(SynthPreset);

impl SyntheticSpec {
    /// 4 views, 10 frames (6 training + 4 novel-pose), 64 px, mild lens distortion, a coarser surface:
    /// for tests.
    pub fn tiny() -> Self {
        Self {
            seed: 0,
            body: BodyShape {
                voxel: 0.025,
                ..BodyShape::default()
            },
            rig: RigSpec {
                views: 4,
                resolution: 64,
                distortion: 0.03,
                ..RigSpec::default()
            },
            training: ClipSpec {
                motions: vec![MotionKind::Walk, MotionKind::ArmSwing],
                frames: 6,
                period_frames: 6.0,
                turn_degrees: 30.0,
                start_heading_degrees: 0.0,
            },
            novel_pose: ClipSpec {
                motions: vec![MotionKind::Squat, MotionKind::Wave, MotionKind::Twist],
                frames: 4,
                period_frames: 6.0,
                turn_degrees: 0.0,
                start_heading_degrees: 30.0,
            },
            training_views: None,
            supersampling: 3,
            jpeg_quality: 95,
            lighting: Lighting::BodyFixed,
            clothing: None,
            pose_noise: None,
            mask_noise: 0.0,
            backdrop: Backdrop::Black,
        }
    }

    /// 8 views, 60 training + 30 novel-pose frames, 256 px: the data of `anerf demo`.
    pub fn demo() -> Self {
        Self {
            seed: 0,
            body: BodyShape::default(),
            rig: RigSpec::default(),
            training: ClipSpec {
                motions: vec![MotionKind::Walk, MotionKind::ArmSwing],
                frames: 60,
                period_frames: 30.0,
                turn_degrees: 90.0,
                start_heading_degrees: 0.0,
            },
            novel_pose: ClipSpec {
                motions: vec![MotionKind::Squat, MotionKind::Wave, MotionKind::Twist],
                frames: 30,
                period_frames: 20.0,
                turn_degrees: -45.0,
                start_heading_degrees: 60.0,
            },
            training_views: None,
            supersampling: 3,
            jpeg_quality: 95,
            lighting: Lighting::BodyFixed,
            clothing: None,
            pose_noise: None,
            mask_noise: 0.0,
            backdrop: Backdrop::Black,
        }
    }

    /// The development subject of a realistic capture: 8 cameras at 512², the training cameras (0, 2, 4,
    /// 6) at 1.3 m and the held-out ones at 0.6 m and 2.0 m; studio lights fixed in the world with cast
    /// shadows and specular highlights; 100 training frames in which the body walks and turns once
    /// around, then 50 novel-pose frames (squat, wave, twist) beyond anything the training frames show;
    /// and a garment up to 2 cm over the body the files describe, skinned by sharper weights than the
    /// files' (as SMPL is to a real person).
    pub fn realistic() -> Self {
        Self {
            clothing: Some(ClothingSpec::loose()),
            ..Self::realistic_exact()
        }
    }

    /// [`Self::realistic`] without the garment: the files hold exactly the rendered body and its weights.
    pub fn realistic_exact() -> Self {
        Self {
            seed: 0,
            body: BodyShape::default(),
            rig: RigSpec {
                views: 8,
                resolution: 512,
                heights: vec![1.3, 0.6, 1.3, 2.0],
                height_jitter: 0.05,
                ..RigSpec::default()
            },
            training: ClipSpec {
                motions: vec![MotionKind::Walk, MotionKind::ArmSwing],
                frames: 100,
                period_frames: 25.0,
                turn_degrees: 360.0,
                start_heading_degrees: 0.0,
            },
            novel_pose: ClipSpec {
                motions: vec![MotionKind::Squat, MotionKind::Wave, MotionKind::Twist],
                frames: 50,
                period_frames: 20.0,
                turn_degrees: -90.0,
                start_heading_degrees: 45.0,
            },
            training_views: Some(vec![0, 2, 4, 6]),
            supersampling: 2,
            jpeg_quality: 95,
            lighting: Lighting::Studio(StudioLights::three_point()),
            clothing: None,
            pose_noise: None,
            mask_noise: 0.0,
            backdrop: Backdrop::Black,
        }
    }

    /// Checks every option; the error names the field.
    pub fn validate(&self) -> Result<(), SynthError> {
        self.body.validate()?;
        self.rig.validate()?;
        if let Lighting::Studio(lights) = &self.lighting {
            lights.validate()?;
        }
        if let Some(c) = &self.clothing {
            c.validate()?;
        }
        if let Some(noise) = &self.pose_noise {
            noise.validate()?;
        }
        mask_noise::validate(self.mask_noise)?;
        for (name, clip) in [
            ("training", &self.training),
            ("novel_pose", &self.novel_pose),
        ] {
            if clip.frames == 0 || clip.frames > 100_000 {
                return Err(SynthError::invalid(
                    format!("{name}.frames"),
                    format!("{} (expected 1 to 100000)", clip.frames),
                ));
            }
            if !(clip.period_frames.is_finite() && clip.period_frames >= 2.0) {
                return Err(SynthError::invalid(
                    format!("{name}.period_frames"),
                    format!("{} (expected at least 2)", clip.period_frames),
                ));
            }
            if !(clip.turn_degrees.is_finite() && clip.start_heading_degrees.is_finite()) {
                return Err(SynthError::invalid(
                    format!("{name}.turn_degrees"),
                    "not finite",
                ));
            }
            motion::check_limits(clip)
                .map_err(|e| SynthError::invalid(format!("{name}.motions"), e))?;
        }
        let views = self.training_view_list();
        if views.is_empty() || views.iter().any(|&v| v >= self.rig.views) {
            return Err(SynthError::invalid(
                "training_views",
                format!(
                    "{views:?} (expected indices below {} views)",
                    self.rig.views
                ),
            ));
        }
        if !(1..=8).contains(&self.supersampling) {
            return Err(SynthError::invalid(
                "supersampling",
                format!("{} (expected 1 to 8)", self.supersampling),
            ));
        }
        if !(1..=100).contains(&self.jpeg_quality) {
            return Err(SynthError::invalid(
                "jpeg_quality",
                format!("{} (expected 1 to 100)", self.jpeg_quality),
            ));
        }
        Ok(())
    }

    /// The training cameras (explicit, or every other one).
    pub fn training_view_list(&self) -> Vec<usize> {
        match &self.training_views {
            Some(v) => v.clone(),
            None => (0..self.rig.views).step_by(2).collect(),
        }
    }
}

/// Which cameras and frames serve which purpose (`splits.json`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Splits {
    pub training_views: Vec<usize>,
    /// Novel-view test cameras: all the others.
    pub test_views: Vec<usize>,
    /// Training frames (also the novel-view test frames), as indices into `annots['ims']`.
    pub training_frames: Vec<usize>,
    /// Novel-pose frames, after the training frames.
    pub novel_pose_frames: Vec<usize>,
}

/// Wall-clock time of each stage of [`write_subject`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Timings {
    /// Surface, skinning weights, cameras and poses.
    pub body: Duration,
    /// Rasterising and encoding every image and mask.
    pub images: Duration,
    /// The arrays and pickles.
    pub arrays: Duration,
    pub total: Duration,
}

/// What [`write_subject`] wrote, in memory: for tests and for the loader's round trip.
#[derive(Debug, Clone)]
pub struct SyntheticSummary {
    /// The subject as a loader should read it back (paths inside the final folder, `T` in metres).
    pub subject: Subject,
    /// Per frame, the posed vertices in world space (metres) stored in `new_vertices/<i>.npy`.
    pub posed_vertices: Vec<Vec<Vec3>>,
    /// Per frame and camera, the number of foreground pixels of the mask.
    pub foreground_pixels: Vec<Vec<usize>>,
    /// Under pose noise, the training frames' true poses and how far the noisy vertices lie from the true.
    pub pose_noise: Option<PoseNoiseReport>,
    pub splits: Splits,
    pub timings: Timings,
}

/// Errors of the generator; each names the option, file or folder at fault.
#[derive(Debug, Error)]
pub enum SynthError {
    #[error("invalid synthetic subject option {field}: {reason}")]
    InvalidSpec { field: String, reason: String },
    #[error("{} already exists; choose another folder or remove it first", .0.display())]
    AlreadyExists(PathBuf),
    #[error("cannot write {}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot encode {}: {source}", path.display())]
    Image {
        path: PathBuf,
        source: image::ImageError,
    },
    #[error(transparent)]
    Format(#[from] FormatWriteError),
    #[error("building an array: {0}")]
    Shape(#[from] crate::formats::ShapeMismatch),
    #[error("posing the body: {0}")]
    Geometry(#[from] GeometryError),
}

impl SynthError {
    /// Checks that each `(field, value, lo, hi)` is finite and within `lo..=hi`; the error names the first
    /// field out of range.
    pub(crate) fn check_ranges(fields: &[(&str, f32, f32, f32)]) -> Result<(), SynthError> {
        match fields
            .iter()
            .find(|(_, v, lo, hi)| !(v.is_finite() && (*lo..=*hi).contains(v)))
        {
            Some((name, v, lo, hi)) => Err(SynthError::invalid(
                *name,
                format!("{v} (expected {lo} to {hi})"),
            )),
            None => Ok(()),
        }
    }

    pub(crate) fn invalid(field: impl Into<String>, reason: impl std::fmt::Display) -> Self {
        SynthError::InvalidSpec {
            field: field.into(),
            reason: reason.to_string(),
        }
    }

    pub(crate) fn io(path: &Path) -> impl FnOnce(std::io::Error) -> Self + '_ {
        move |source| SynthError::Io {
            path: path.to_path_buf(),
            source,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::motion::clip_angles;
    use super::*;

    /// Per joint and axis, the angle range a clip covers.
    fn ranges(clip: &ClipSpec) -> Vec<(Vec3, Vec3)> {
        let mut r = vec![(Vec3::INFINITY, Vec3::NEG_INFINITY); body::NUM_JOINTS];
        for f in 0..clip.frames {
            for (k, a) in clip_angles(clip, f).iter().enumerate() {
                r[k] = (r[k].0.min(*a), r[k].1.max(*a));
            }
        }
        r
    }

    #[test]
    fn presets_are_valid_and_novel_poses_leave_the_training_range() {
        for spec in [SyntheticSpec::tiny(), SyntheticSpec::demo()] {
            spec.validate().unwrap();
            let (train, novel) = (ranges(&spec.training), ranges(&spec.novel_pose));
            let beyond: Vec<usize> = (0..body::NUM_JOINTS)
                .filter(|&k| {
                    (novel[k].0 - train[k].0).min_element() < -0.3
                        || (novel[k].1 - train[k].1).max_element() > 0.3
                })
                .collect();
            // Hips, knees, spine and the waving arm go at least 0.3 rad past anything seen in training.
            for k in [
                body::joint::L_HIP,
                body::joint::R_KNEE,
                body::joint::SPINE2,
                body::joint::R_SHOULDER,
                body::joint::R_ELBOW,
            ] {
                assert!(beyond.contains(&k), "joint {k}: {beyond:?}");
            }
        }
    }

    #[test]
    fn invalid_options_name_their_field() {
        let mut spec = SyntheticSpec::tiny();
        spec.training_views = Some(vec![0, 9]);
        assert!(spec
            .validate()
            .unwrap_err()
            .to_string()
            .contains("training_views"));
        let mut spec = SyntheticSpec::demo();
        spec.novel_pose.motions.push(MotionKind::Walk);
        let err = spec.validate().unwrap_err().to_string();
        assert!(
            err.contains("novel_pose.motions") && err.contains("joint"),
            "{err}"
        );
        let mut spec = SyntheticSpec::tiny();
        spec.rig.resolution = 8;
        assert!(spec
            .validate()
            .unwrap_err()
            .to_string()
            .contains("rig.resolution"));
        let spec: Result<SyntheticSpec, _> = serde_json::from_str(r#"{"seed": 1}"#);
        assert!(spec.is_err());
        let text = serde_json::to_string(&SyntheticSpec::demo()).unwrap();
        assert_eq!(
            serde_json::from_str::<SyntheticSpec>(&text).unwrap(),
            SyntheticSpec::demo()
        );
    }
}
