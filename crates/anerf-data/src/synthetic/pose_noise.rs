//! Fit errors in the training frames' files: the poses a body fitter would give, with per-frame errors,
//! while the images stay rendered from the true poses (`anerf synth --pose-noise`).

use anerf_core::geometry::{axis_angle_to_matrix, matrix_to_axis_angle, GlobalTransform, Pose};
use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::body::joint::PELVIS;
use super::rng::SplitMix64;
use super::SynthError;

/// Keeps the noise's random streams apart from every other use of the subject's seed.
const SALT: u64 = 0x706f_7365_6e6f_6973; // "posenois"

/// Largest error the generator accepts, for both fields (degrees, centimetres).
const MAX: f32 = 20.0;

/// Per-frame errors of a pose fit, independent between frames. Each joint below the root gets an error
/// rotation composed on the right (in the joint's own frame), `R_noisy = R_true · exp(ε)`, with per-axis
/// Gaussian angles `ε`; the root's rotation stays zero (as in ZJU-MoCap) and its error lies in `Rh`,
/// composed the same way; `Th` gets a per-axis Gaussian offset in the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseNoise {
    /// Standard deviation of each axis of a joint's error angle (degrees); `Rh`'s is a third of it.
    pub degrees: f32,
    /// Standard deviation of each axis of `Th`'s error (centimetres, world frame).
    pub cm: f32,
}

impl PoseNoise {
    /// Errors of `degrees` with the matching translation error, `degrees / 1.5` centimetres (1.5° → 1 cm).
    pub fn new(degrees: f32) -> Self {
        Self {
            degrees,
            cm: degrees / 1.5,
        }
    }

    /// Both fields finite and within `0 ..= 20`; the error names the field and the range.
    pub fn validate(&self) -> Result<(), SynthError> {
        SynthError::check_ranges(&[
            ("pose_noise.degrees", self.degrees, 0.0, MAX),
            ("pose_noise.cm", self.cm, 0.0, MAX),
        ])
    }

    /// `pose` with the errors of frame `index` (the file index) of the subject of `seed`.
    pub(super) fn perturb(&self, pose: &Pose, seed: u64, index: usize) -> Pose {
        let mut rng = SplitMix64::keyed(seed, SALT, index as u64);
        let mut draw =
            |sigma: f32| Vec3::new(rng.gaussian(), rng.gaussian(), rng.gaussian()) * sigma;
        let sigma = self.degrees.to_radians();
        let joint_rotations = pose
            .joint_rotations
            .iter()
            .enumerate()
            .map(|(k, &r)| {
                if k == PELVIS {
                    r
                } else {
                    compose(r, draw(sigma))
                }
            })
            .collect();
        let rh = compose(pose.global.rh, draw(sigma / 3.0));
        let th = pose.global.th + draw(self.cm / 100.0);
        Pose {
            joint_rotations,
            global: GlobalTransform { rh, th },
        }
    }
}

/// `log(exp(r) · exp(ε))`: axis-angle `r` with the error `ε` (radians) composed on the right.
fn compose(r: Vec3, epsilon: Vec3) -> Vec3 {
    matrix_to_axis_angle(axis_angle_to_matrix(r) * axis_angle_to_matrix(epsilon))
}

/// `<degrees>` or `<degrees>,<cm>`, as `--pose-noise` takes it; the values are checked by
/// [`PoseNoise::validate`].
impl std::str::FromStr for PoseNoise {
    type Err = SynthError;

    fn from_str(s: &str) -> Result<Self, SynthError> {
        let number = |text: &str, what: &str| {
            text.trim().parse::<f32>().map_err(|_| {
                SynthError::invalid(
                    format!("pose_noise.{what}"),
                    format!(
                        "'{text}' of '{s}' is not a number (expected <degrees>[,<cm>], e.g. 1.5 or 1.5,1)"
                    ),
                )
            })
        };
        let noise = match s.split_once(',') {
            None => Self::new(number(s, "degrees")?),
            Some((degrees, cm)) => Self {
                degrees: number(degrees, "degrees")?,
                cm: number(cm, "cm")?,
            },
        };
        noise.validate()?;
        Ok(noise)
    }
}

impl std::fmt::Display for PoseNoise {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}°, {} cm", self.degrees, self.cm)
    }
}

/// What the files of a subject with pose noise got wrong.
#[derive(Debug, Clone)]
pub struct PoseNoiseReport {
    /// Per training frame, the true pose (`true_params/<i>.npy`); the noisy ones are the subject's.
    pub true_poses: Vec<Pose>,
    /// Mean distance (metres) between the true and the noisy posed vertices, over every vertex of every
    /// training frame.
    pub mean_vertex_error: f32,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_degrees_with_or_without_centimetres_and_refuses_the_rest() {
        assert_eq!("1.5".parse().ok(), Some(PoseNoise::new(1.5)));
        assert_eq!(PoseNoise::new(1.5).cm, 1.0);
        assert_eq!(
            " 2 , 0.5".parse().ok(),
            Some(PoseNoise {
                degrees: 2.0,
                cm: 0.5
            })
        );
        for bad in ["", "x", "1.5,", ",1", "1,2,3", "1.5cm"] {
            let err = bad.parse::<PoseNoise>().unwrap_err().to_string();
            assert!(err.contains("expected <degrees>[,<cm>]"), "{bad}: {err}");
        }
        for (bad, field) in [
            ("-1", "degrees"),
            ("nan", "degrees"),
            ("21", "degrees"),
            ("1,25", "cm"),
        ] {
            let err = bad.parse::<PoseNoise>().unwrap_err().to_string();
            assert!(
                err.contains(&format!("pose_noise.{field}")) && err.contains("expected 0 to 20"),
                "{bad}: {err}"
            );
        }
    }

    #[test]
    fn errors_compose_on_the_right_and_leave_the_root_alone() {
        let pose = Pose {
            joint_rotations: vec![
                Vec3::ZERO,
                Vec3::new(0.3, -0.2, 0.1),
                Vec3::new(0.0, 1.0, 0.0),
            ],
            global: GlobalTransform {
                rh: Vec3::new(1.2, 0.0, 0.4),
                th: Vec3::new(0.1, 0.2, 0.9),
            },
        };
        let noise = PoseNoise::new(3.0);
        let noisy = noise.perturb(&pose, 5, 2);
        assert_eq!(noisy, noise.perturb(&pose, 5, 2));
        assert_ne!(noisy, noise.perturb(&pose, 5, 3));
        assert_eq!(noisy.joint_rotations[PELVIS], Vec3::ZERO);
        // The error read back in the joint's frame is a small rotation, not the difference of axis-angles.
        for (t, n) in pose
            .joint_rotations
            .iter()
            .zip(&noisy.joint_rotations)
            .skip(1)
        {
            let error = matrix_to_axis_angle(
                axis_angle_to_matrix(*t).transpose() * axis_angle_to_matrix(*n),
            );
            assert!(error.length() > 1e-4 && error.length() < 0.5, "{error}");
        }
        assert!((noisy.global.th - pose.global.th).length() < 0.2);
    }

    #[test]
    fn errors_have_the_standard_deviations_asked_for() {
        let truth = Pose::zero(4);
        let noise = PoseNoise {
            degrees: 2.0,
            cm: 3.0,
        };
        let frames = 3000;
        let (mut joints, mut rh, mut th) = (Vec3::ZERO, Vec3::ZERO, Vec3::ZERO);
        for index in 0..frames {
            let noisy = noise.perturb(&truth, 11, index);
            joints += noisy.joint_rotations[1..]
                .iter()
                .map(|e| *e * *e)
                .sum::<Vec3>();
            rh += noisy.global.rh * noisy.global.rh;
            th += noisy.global.th * noisy.global.th;
        }
        let sigma = noise.degrees.to_radians();
        let ratio = |sum: Vec3, n: usize, sigma: f32| (sum / n as f32).powf(0.5) / sigma;
        // n samples: the RMS's relative standard deviation is 1/√(2n), 1.3% at n = 3000; 6% is 4.6 of them.
        for (what, r) in [
            ("joints", ratio(joints, 3 * frames, sigma)),
            ("Rh", ratio(rh, frames, sigma / 3.0)),
            ("Th", ratio(th, frames, noise.cm / 100.0)),
        ] {
            assert!((r - Vec3::ONE).abs().max_element() < 0.06, "{what}: {r}");
        }
    }
}
