//! Parametric motion clips (walk, arm swing, squat, twist, wave) within joint limits, as ZJU-MoCap poses:
//! per-joint axis-angle `poses` with a zero root rotation, and the global `Rh`, `Th` that place the body in
//! a z-up world.

use std::f32::consts::{FRAC_PI_2, TAU};

use anerf_core::geometry::{axis_angle_to_matrix, matrix_to_axis_angle};
use glam::{Mat3, Vec3};
use serde::{Deserialize, Serialize};

use super::body::{joint::*, NUM_JOINTS};

/// One kind of movement; a clip plays several at once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MotionKind {
    /// Walking in place: hips and knees, one stride per `period_frames`.
    Walk,
    /// Arms swinging against the legs, elbows slightly bent.
    ArmSwing,
    /// One deep squat over the clip, torso leaning forward, arms raised for balance.
    Squat,
    /// Torso twisting left and right.
    Twist,
    /// Right arm raised, forearm waving.
    Wave,
}

/// A clip: the motions it plays, its length, stride period and how far the body turns about the vertical.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClipSpec {
    pub motions: Vec<MotionKind>,
    pub frames: usize,
    /// Frames per cycle of the periodic motions (walk, arm swing, wave).
    pub period_frames: f32,
    /// Heading change over the clip (degrees, about the world's vertical).
    pub turn_degrees: f32,
    /// Heading at the first frame (degrees).
    pub start_heading_degrees: f32,
}

/// Per-joint local rotation as angles `(x, y, z)` (radians) about the parent's axes, applied z first:
/// `R = Rx(x) · Ry(y) · Rz(z)`.
pub type JointAngles = [Vec3; NUM_JOINTS];

/// Joint limits `(min, max)` of the angles of [`JointAngles`], radians. Left and right mirror each other
/// (left = `+x` side: abduction of a left limb is a positive z angle).
pub fn joint_limits() -> [(Vec3, Vec3); NUM_JOINTS] {
    let sym = |v: Vec3| (-v, v);
    let mut l = [sym(Vec3::splat(0.1)); NUM_JOINTS];
    l[PELVIS] = sym(Vec3::ZERO);
    for s in [SPINE1, SPINE2, SPINE3] {
        l[s] = (Vec3::new(-0.3, -0.5, -0.3), Vec3::new(0.5, 0.5, 0.3));
    }
    l[NECK] = sym(Vec3::new(0.5, 0.7, 0.4));
    l[HEAD] = sym(Vec3::new(0.5, 0.7, 0.4));
    l[L_COLLAR] = sym(Vec3::splat(0.3));
    l[R_COLLAR] = sym(Vec3::splat(0.3));
    // Hip flexion brings the leg forwards (negative x); abduction moves it outwards.
    l[L_HIP] = (Vec3::new(-2.0, -0.6, -0.3), Vec3::new(0.6, 0.6, 0.8));
    l[R_HIP] = (Vec3::new(-2.0, -0.6, -0.8), Vec3::new(0.6, 0.6, 0.3));
    l[L_KNEE] = (Vec3::new(0.0, -0.1, -0.1), Vec3::new(2.4, 0.1, 0.1));
    l[R_KNEE] = l[L_KNEE];
    l[L_ANKLE] = sym(Vec3::new(0.8, 0.3, 0.3));
    l[R_ANKLE] = l[L_ANKLE];
    l[L_FOOT] = sym(Vec3::new(0.5, 0.0, 0.0));
    l[R_FOOT] = l[L_FOOT];
    // Shoulders: z lowers the arm from the T-pose (negative on the left), x swings it forwards/backwards.
    l[L_SHOULDER] = (Vec3::new(-1.8, -1.2, -1.5), Vec3::new(1.8, 1.2, 1.3));
    l[R_SHOULDER] = (Vec3::new(-1.8, -1.2, -1.3), Vec3::new(1.8, 1.2, 1.5));
    // Elbows bend the forearm forwards (y) or, with the arm raised, upwards (z).
    l[L_ELBOW] = (Vec3::new(-0.3, -2.4, -0.2), Vec3::new(0.3, 0.0, 1.8));
    l[R_ELBOW] = (Vec3::new(-0.3, 0.0, -1.8), Vec3::new(0.3, 2.4, 0.2));
    l
}

/// The angles of `motions` at frame `f` of a clip of `frames` frames.
pub fn clip_angles(clip: &ClipSpec, f: usize) -> JointAngles {
    let phase = TAU * f as f32 / clip.period_frames;
    let progress = if clip.frames > 1 {
        f as f32 / (clip.frames - 1) as f32
    } else {
        0.0
    };
    let mut a = [Vec3::ZERO; NUM_JOINTS];
    // Relaxed stance: arms hanging at the sides, elbows a little bent.
    a[L_SHOULDER].z = -1.15;
    a[R_SHOULDER].z = 1.15;
    a[L_ELBOW].y = -0.2;
    a[R_ELBOW].y = 0.2;
    for motion in &clip.motions {
        match motion {
            MotionKind::Walk => {
                let (s, c) = phase.sin_cos();
                a[L_HIP].x += -0.4 * s;
                a[R_HIP].x += 0.4 * s;
                // The knee bends while its leg swings forwards.
                a[L_KNEE].x += 0.35 + 0.3 * (-c).max(0.0) + 0.2 * s.max(0.0);
                a[R_KNEE].x += 0.35 + 0.3 * c.max(0.0) + 0.2 * (-s).max(0.0);
                a[L_ANKLE].x += 0.1 * s;
                a[R_ANKLE].x += -0.1 * s;
                a[SPINE1].y += 0.08 * s;
            }
            MotionKind::ArmSwing => {
                let s = phase.sin();
                a[L_SHOULDER].x += 0.4 * s;
                a[R_SHOULDER].x += -0.4 * s;
                a[L_ELBOW].y += -0.25 * (1.0 + s) * 0.5;
                a[R_ELBOW].y += 0.25 * (1.0 - s) * 0.5;
                a[NECK].y += -0.05 * s;
            }
            MotionKind::Squat => {
                let depth = (std::f32::consts::PI * progress).sin().powi(2);
                let (hip, knee) = (-1.3 * depth, 1.9 * depth);
                a[L_HIP].x += hip;
                a[R_HIP].x += hip;
                a[L_KNEE].x += knee;
                a[R_KNEE].x += knee;
                // Feet stay flat: the ankle undoes the thigh and shin tilt.
                a[L_ANKLE].x += -(hip + knee);
                a[R_ANKLE].x += -(hip + knee);
                a[SPINE1].x += 0.3 * depth;
                a[L_SHOULDER].x += -1.1 * depth;
                a[R_SHOULDER].x += -1.1 * depth;
            }
            MotionKind::Twist => {
                let t = 0.45 * (TAU * progress).sin();
                for s in [SPINE1, SPINE2, SPINE3] {
                    a[s].y += t;
                }
                a[NECK].y += -0.5 * t;
            }
            MotionKind::Wave => {
                // Right arm up to just above horizontal, forearm vertical and waving sideways.
                a[R_SHOULDER].z += -1.45;
                a[R_SHOULDER].x += 0.2;
                a[R_ELBOW].y += -0.2;
                a[R_ELBOW].z += -1.3 + 0.35 * (2.0 * phase).sin();
                a[HEAD].z += 0.15;
            }
        }
    }
    a
}

/// A joint of a synthetic clip bent past [`joint_limits`] (angles in radians, per axis).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "joint {joint} at frame {frame} has angles {angles} outside its limits {min}..{max} (radians)"
)]
pub struct OutOfLimits {
    pub joint: usize,
    pub frame: usize,
    pub angles: Vec3,
    pub min: Vec3,
    pub max: Vec3,
}

/// Checks every frame of `clip` against [`joint_limits`]; the error names the first joint and frame out of
/// range.
pub fn check_limits(clip: &ClipSpec) -> Result<(), OutOfLimits> {
    let limits = joint_limits();
    for frame in 0..clip.frames {
        for (joint, &angles) in clip_angles(clip, frame).iter().enumerate() {
            let (min, max) = limits[joint];
            if !(angles.cmpge(min).all() && angles.cmple(max).all()) {
                return Err(OutOfLimits {
                    joint,
                    frame,
                    angles,
                    min,
                    max,
                });
            }
        }
    }
    Ok(())
}

/// Axis-angle `poses` (24 × 3, radians) of joint angles; the root's stays zero as in ZJU-MoCap.
pub fn angles_to_axis_angle(angles: &JointAngles) -> [Vec3; NUM_JOINTS] {
    angles.map(|v| {
        let r: Mat3 = axis_angle_to_matrix(Vec3::X * v.x)
            * axis_angle_to_matrix(Vec3::Y * v.y)
            * axis_angle_to_matrix(Vec3::Z * v.z);
        matrix_to_axis_angle(r)
    })
}

/// `Rh` of heading `degrees`: SMPL's `+y`-up canonical frame turned into the z-up world (the body then
/// faces the world's `−y` at heading 0), then rotated about the world's `z`.
pub fn global_rotation(degrees: f32) -> Vec3 {
    let up = axis_angle_to_matrix(Vec3::X * FRAC_PI_2);
    let heading = axis_angle_to_matrix(Vec3::Z * degrees.to_radians());
    matrix_to_axis_angle(heading * up)
}

/// Heading of frame `f` of `clip` (degrees).
pub fn heading(clip: &ClipSpec, f: usize) -> f32 {
    let progress = if clip.frames > 1 {
        f as f32 / (clip.frames - 1) as f32
    } else {
        0.0
    };
    clip.start_heading_degrees + clip.turn_degrees * progress
}

#[cfg(test)]
mod tests {
    use super::*;

    fn clip(motions: Vec<MotionKind>, frames: usize) -> ClipSpec {
        ClipSpec {
            motions,
            frames,
            period_frames: 24.0,
            turn_degrees: 90.0,
            start_heading_degrees: 0.0,
        }
    }

    fn range(clip: &ClipSpec) -> [(Vec3, Vec3); NUM_JOINTS] {
        let mut r = [(Vec3::INFINITY, Vec3::NEG_INFINITY); NUM_JOINTS];
        for f in 0..clip.frames {
            for (k, v) in clip_angles(clip, f).iter().enumerate() {
                r[k] = (r[k].0.min(*v), r[k].1.max(*v));
            }
        }
        r
    }

    #[test]
    fn each_motion_and_the_preset_mixes_stay_within_joint_limits() {
        use MotionKind::*;
        let mut mixes: Vec<Vec<MotionKind>> = [Walk, ArmSwing, Squat, Twist, Wave]
            .map(|m| vec![m])
            .to_vec();
        mixes.push(vec![Walk, ArmSwing]);
        mixes.push(vec![Squat, Wave, Twist]);
        for motions in mixes {
            for frames in [1, 7, 60, 301] {
                let c = clip(motions.clone(), frames);
                check_limits(&c).unwrap();
                // An independent restatement of the check, from the clip's angle ranges.
                for (k, (lo, hi)) in range(&c).iter().enumerate() {
                    let (min, max) = joint_limits()[k];
                    assert!(
                        lo.cmpge(min).all() && hi.cmple(max).all(),
                        "joint {k} of {motions:?}"
                    );
                }
            }
        }
        // Walking and squatting at once bends the knees too far.
        let err = check_limits(&clip(vec![Walk, Squat], 60)).unwrap_err();
        assert!([4, 5].contains(&err.joint), "{err}");
        assert!(
            !(err.angles.cmpge(err.min).all() && err.angles.cmple(err.max).all()),
            "{err}"
        );
    }

    #[test]
    fn axis_angle_reproduces_the_composed_rotation() {
        let c = clip(
            vec![MotionKind::Squat, MotionKind::Wave, MotionKind::Twist],
            30,
        );
        let angles = clip_angles(&c, 13);
        let poses = angles_to_axis_angle(&angles);
        assert_eq!(poses[PELVIS], Vec3::ZERO);
        for (v, p) in angles.iter().zip(&poses) {
            let r = Mat3::from_rotation_x(v.x)
                * Mat3::from_rotation_y(v.y)
                * Mat3::from_rotation_z(v.z);
            assert!((axis_angle_to_matrix(*p) - r)
                .abs()
                .to_cols_array()
                .iter()
                .all(|&e| e < 1e-5));
        }
    }

    #[test]
    fn heading_zero_turns_y_up_into_z_up() {
        let r = axis_angle_to_matrix(global_rotation(0.0));
        assert!((r * Vec3::Y - Vec3::Z).length() < 1e-6);
        assert!((r * Vec3::Z + Vec3::Y).length() < 1e-6);
        let r = axis_angle_to_matrix(global_rotation(90.0));
        assert!((r * Vec3::Z - Vec3::X).length() < 1e-5, "{}", r * Vec3::Z);
    }
}
