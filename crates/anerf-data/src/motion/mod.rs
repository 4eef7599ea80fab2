//! Motions to drive a trained avatar with: AMASS `.npz` files (SMPL+H, SMPL-X, plain SMPL), EasyMocap fit
//! folders and ZJU-MoCap `params/` folders, read into one [`Motion`] (`readers.rs`), resampled and cut
//! here, then retargeted onto the trained subject (`retarget.rs`).
//!
//! Units and frames: radians (axis-angle, relative to the parent joint), metres, the motion's own world
//! until [`retarget`] places it in the capture's; column vectors.

mod readers;
mod retarget;

use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

use anerf_core::InvalidValue;
use glam::{DQuat, DVec3};

pub use retarget::{retarget, Placement, Scene, TargetBody};

use crate::error::DataError;

/// Joints every SMPL-family model shares, in the same order: the pelvis and 21 body joints.
pub const BODY_JOINTS: usize = 22;

/// A motion as its file records it.
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    /// The file or folder it was read from (errors name it).
    pub source: PathBuf,
    pub format: MotionFormat,
    /// Frames per second; `None` when the format records none (EasyMocap and ZJU folders).
    pub fps: Option<f64>,
    /// Joints of the motion's body model (its pose arrays' width / 3).
    pub model_joints: usize,
    pub frames: Vec<MotionFrame>,
    /// The motion world's up direction when the format fixes one (AMASS: +Z).
    pub up: Option<DVec3>,
}

/// One frame of a motion.
#[derive(Debug, Clone, PartialEq)]
pub struct MotionFrame {
    /// Axis-angle rotation of each of the model's joints (radians, relative to the parent).
    pub joints: Vec<DVec3>,
    pub root: Root,
}

/// How a frame places the body in its world.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Root {
    /// Standard SMPL (AMASS): joint 0's rotation turns the body about its rest pelvis, then `trans`
    /// (metres) moves it: `x = R₀ (x' − J₀) + J₀ + trans`.
    Standard { trans: DVec3 },
    /// The datasets' convention (ZJU-MoCap, EasyMocap): after skinning, `x = R(Rh) x' + Th` (metres).
    Placed { rh: DVec3, th: DVec3 },
}

/// The file layouts [`Motion::read`] knows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionFormat {
    /// AMASS-style `.npz` of SMPL (72 pose values a frame).
    AmassSmpl,
    /// AMASS SMPL+H `.npz` (156 values: body and hands).
    AmassSmplh,
    /// AMASS SMPL-X `.npz` (162 or 165 values, or `root_orient` + `pose_body`).
    AmassSmplx,
    /// EasyMocap fits: a folder of `<frame>.json`, each a list of people.
    EasyMocap,
    /// ZJU-MoCap pose files: a folder of `params/<i>.npy`.
    ZjuParams,
}

impl fmt::Display for MotionFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            MotionFormat::AmassSmpl => "AMASS-style SMPL .npz",
            MotionFormat::AmassSmplh => "AMASS SMPL+H .npz",
            MotionFormat::AmassSmplx => "AMASS SMPL-X .npz",
            MotionFormat::EasyMocap => "EasyMocap fits",
            MotionFormat::ZjuParams => "ZJU-MoCap params",
        })
    }
}

/// Which frames of a motion are wanted and at what rate ([`Motion::read_timed`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Timing {
    /// The motion's frames per second where its format records none (EasyMocap and ZJU folders).
    pub declared_fps: Option<f64>,
    /// Output frames per second (default: the motion's own).
    pub fps: Option<f64>,
    /// Frames of the resampled motion.
    pub frames: FrameRange,
}

impl Motion {
    /// Reads a motion, detecting its format: an `.npz` file (AMASS), a `.json` fit or a folder of them
    /// (EasyMocap; also a capture folder with `output-smpl-3d/smpl/`), an `.npy` pose file or a folder of
    /// them (ZJU-MoCap `params/`). `person` picks an EasyMocap person by id (default: the lowest).
    pub fn read(path: &Path, person: Option<i64>) -> Result<Self, DataError> {
        let mut opened = readers::open(path, person)?;
        let all = 0..opened.len();
        opened.read(all)
    }

    /// Reads the motion at `path` resampled to `timing.fps` and cut to `timing.frames` — the same frames
    /// as [`Motion::read`], [`Motion::resampled`] and [`Motion::select`] give — reading only the recorded
    /// frames those need: a few frames of a long motion cost the memory of a few frames. The result
    /// records the output rate.
    pub fn read_timed(
        path: &Path,
        person: Option<i64>,
        timing: &Timing,
    ) -> Result<Self, DataError> {
        let mut opened = readers::open(path, person)?;
        let source = opened.source().to_path_buf();
        let from = rate(opened.fps(), timing.declared_fps, &source, opened.format())?;
        let to = timing.fps.unwrap_or(from);
        let count = resampled_count(opened.len(), from, to, &source)?;
        let wanted = timing.frames.bounds(count, &source)?;
        let last = wanted.start + (wanted.len() - 1) / timing.frames.step * timing.frames.step;
        let time = |i: usize| i as f64 * from / to;
        let first_row = time(wanted.start).floor() as usize;
        let rows = first_row..(time(last).floor() as usize + 2).min(opened.len());
        let part = opened.read(rows)?;
        let frames = wanted
            .step_by(timing.frames.step)
            .map(|i| part.frame_at(time(i), first_row))
            .collect();
        Ok(Motion {
            fps: Some(to),
            frames,
            ..part
        })
    }

    /// Frames per second, with `declared` standing in where the file records none; errors when neither
    /// gives a positive finite rate.
    pub fn rate(&self, declared: Option<f64>) -> Result<f64, DataError> {
        rate(self.fps, declared, &self.source, self.format)
    }

    /// The motion resampled from `from` to `to` frames per second: frame `i` at time `i / to`, joint
    /// rotations and the global rotation interpolated by slerp, translations linearly. Frames that fall
    /// on a recorded frame are copied exactly.
    /// At most [`MAX_MOTION_FRAMES`] frames come out: the count is checked before any is made.
    pub fn resampled(&self, from: f64, to: f64) -> Result<Motion, DataError> {
        let count = resampled_count(self.frames.len(), from, to, &self.source)?;
        let frames = (0..count)
            .map(|i| self.frame_at(i as f64 * from / to, 0))
            .collect();
        Ok(Motion {
            fps: Some(to),
            frames,
            ..self.clone()
        })
    }

    /// The frame at time `t` (in recorded frames) of a motion whose recorded frames start at `first`:
    /// a copy where `t` falls on a recorded frame (or past the last), else the two around it blended.
    fn frame_at(&self, t: f64, first: usize) -> MotionFrame {
        let (k, w) = (t.floor() as usize - first, t - t.floor());
        if w < 1e-9 || k + 1 >= self.frames.len() {
            self.frames[k.min(self.frames.len() - 1)].clone()
        } else {
            self.frames[k].lerp(&self.frames[k + 1], w)
        }
    }

    /// The frames of `range`.
    pub fn select(&self, range: FrameRange) -> Result<Motion, DataError> {
        let wanted = range.bounds(self.frames.len(), &self.source)?;
        Ok(Motion {
            frames: self.frames[wanted]
                .iter()
                .step_by(range.step)
                .cloned()
                .collect(),
            ..self.clone()
        })
    }
}

/// A motion's frames per second: `recorded`, else `declared`; an error naming `source` when neither is a
/// positive finite rate.
fn rate(
    recorded: Option<f64>,
    declared: Option<f64>,
    source: &Path,
    format: MotionFormat,
) -> Result<f64, DataError> {
    let rate = recorded.or(declared).ok_or_else(|| {
        DataError::invalid(
            source,
            format!("{format} record no frame rate; give the motion's rate (--motion-fps)"),
        )
    })?;
    check_rate(rate, source, "the frame rate")?;
    Ok(rate)
}

/// Frames a motion of `recorded` frames has resampled from `from` to `to` frames per second (the last
/// recorded frame's time included); at most [`MAX_MOTION_FRAMES`], else an error naming `source`.
fn resampled_count(recorded: usize, from: f64, to: f64, source: &Path) -> Result<usize, DataError> {
    check_rate(from, source, "the frame rate")?;
    check_rate(to, source, "the output frame rate (--fps)")?;
    let last = recorded.saturating_sub(1) as f64;
    let count = (last * to / from + 1e-9).floor() + 1.0;
    if !(count <= MAX_MOTION_FRAMES as f64) {
        return Err(DataError::invalid(
            source,
            format!(
                "resampling its {recorded} frames from {from} to {to} frames per second makes {count:.3e} \
                 frames; at most {MAX_MOTION_FRAMES} are allowed (is its frame rate {from} right? \
                 --motion-fps gives the rate of a file that records none)"
            ),
        ));
    }
    Ok(count as usize)
}

impl MotionFrame {
    /// The frame a fraction `w` of the way to `next` (same model, same root convention).
    fn lerp(&self, next: &MotionFrame, w: f64) -> MotionFrame {
        let slerp = |a: DVec3, b: DVec3| {
            DQuat::from_scaled_axis(a)
                .slerp(DQuat::from_scaled_axis(b), w)
                .to_scaled_axis()
        };
        let root = match (self.root, next.root) {
            (Root::Standard { trans: a }, Root::Standard { trans: b }) => Root::Standard {
                trans: a.lerp(b, w),
            },
            (Root::Placed { rh: ra, th: ta }, Root::Placed { rh: rb, th: tb }) => Root::Placed {
                rh: slerp(ra, rb),
                th: ta.lerp(tb, w),
            },
            _ => unreachable!("a motion's frames share one root convention"),
        };
        MotionFrame {
            joints: self
                .joints
                .iter()
                .zip(&next.joints)
                .map(|(&a, &b)| slerp(a, b))
                .collect(),
            root,
        }
    }
}

/// Most frames a resampled motion may have (over nine hours at 30 frames per second).
pub const MAX_MOTION_FRAMES: usize = 1_000_000;

/// Refuses a rate that is not a positive finite number.
fn check_rate(rate: f64, source: &Path, what: &str) -> Result<(), DataError> {
    if rate.is_finite() && rate > 0.0 {
        Ok(())
    } else {
        Err(DataError::invalid(
            source,
            format!("{what} is {rate}; expected a positive number of frames per second"),
        ))
    }
}

/// Frames `start..end` every `step`-th, written `a:b:step` as in Python (`b` exclusive; `a:b`, `a:` and
/// `:b` also).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameRange {
    pub start: usize,
    /// `None`: to the last frame.
    pub end: Option<usize>,
    pub step: usize,
}

impl FrameRange {
    /// Every frame.
    pub const ALL: FrameRange = FrameRange {
        start: 0,
        end: None,
        step: 1,
    };

    /// The frames `start..end` of a motion of `n` frames (`source`), or an error when the range reaches
    /// outside them or holds none.
    fn bounds(&self, n: usize, source: &Path) -> Result<std::ops::Range<usize>, DataError> {
        let end = self.end.unwrap_or(n);
        if self.start >= n || end > n || self.start >= end {
            return Err(DataError::invalid(
                source,
                format!("frame range {self} is outside the motion's {n} frames (0:{n})"),
            ));
        }
        Ok(self.start..end)
    }
}

impl fmt::Display for FrameRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let end = self.end.map_or(String::new(), |e| e.to_string());
        write!(f, "{}:{end}:{}", self.start, self.step)
    }
}

impl FromStr for FrameRange {
    type Err = InvalidValue;

    fn from_str(s: &str) -> Result<Self, InvalidValue> {
        let bad = || {
            InvalidValue::new(
                "frame range",
                format!("'{s}'"),
                "start:end:step (e.g. 0:300:2)",
            )
        };
        let parts: Vec<&str> = s.split(':').collect();
        if parts.len() > 3 {
            return Err(bad());
        }
        let number = |i: usize| -> Result<Option<usize>, InvalidValue> {
            match parts.get(i).map(|p| p.trim()) {
                None | Some("") => Ok(None),
                Some(p) => p.parse().map(Some).map_err(|_| bad()),
            }
        };
        let range = FrameRange {
            start: number(0)?.unwrap_or(0),
            end: if parts.len() == 1 {
                number(0)?.map(|a| a + 1)
            } else {
                number(1)?
            },
            step: number(2)?.unwrap_or(1),
        };
        if range.step == 0 {
            return Err(InvalidValue::new(
                "frame range",
                format!("'{s}'"),
                "a step of at least 1",
            ));
        }
        Ok(range)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn motion(frames: Vec<MotionFrame>) -> Motion {
        Motion {
            source: "m.npz".into(),
            format: MotionFormat::AmassSmpl,
            fps: Some(4.0),
            model_joints: 1,
            frames,
            up: None,
        }
    }

    fn frame(angle: f64, x: f64) -> MotionFrame {
        MotionFrame {
            joints: vec![DVec3::new(0.0, angle, 0.0)],
            root: Root::Standard {
                trans: DVec3::new(x, 0.0, 0.0),
            },
        }
    }

    #[test]
    fn frame_ranges_parse_as_python_slices() {
        let r = |s: &str| s.parse::<FrameRange>();
        let range = |start, end, step| FrameRange { start, end, step };
        assert_eq!(r("10:20:2"), Ok(range(10, Some(20), 2)));
        assert_eq!(r("5:"), Ok(range(5, None, 1)));
        assert_eq!(r(":7"), Ok(range(0, Some(7), 1)));
        assert_eq!(r("::3"), Ok(range(0, None, 3)));
        assert_eq!(r("4"), Ok(range(4, Some(5), 1)));
        assert!(r("1:2:0").unwrap_err().expected.contains("step"));
        assert!(r("a:b").unwrap_err().to_string().contains("frame range"));
        assert!(r("1:2:3:4").is_err());
    }

    #[test]
    fn ranges_outside_the_motion_are_refused_and_inside_ones_cut_it() {
        let m = motion((0..10).map(|i| frame(0.0, i as f64)).collect());
        let cut = m.select("2:9:3".parse().unwrap()).unwrap();
        let xs: Vec<f64> = cut
            .frames
            .iter()
            .map(|f| match f.root {
                Root::Standard { trans } => trans.x,
                _ => unreachable!(),
            })
            .collect();
        assert_eq!(xs, [2.0, 5.0, 8.0]);
        for bad in ["10:", "0:11", "5:5"] {
            let err = m.select(bad.parse().unwrap()).unwrap_err().to_string();
            assert!(
                err.contains("outside the motion's 10 frames") && err.contains("m.npz"),
                "{err}"
            );
        }
    }

    /// AMASS's `mocap_framerate = 1e-6` resampled to 30 fps would make 9e7 frames (93.6 GB for a real
    /// clip): refused, naming the file and the rates, before any frame is made; the bound itself passes.
    #[test]
    fn a_resampling_that_makes_too_many_frames_is_refused_first() {
        let m = motion((0..313).map(|i| frame(0.0, i as f64)).collect());
        let err = m.resampled(1e-6, 30.0).unwrap_err().to_string();
        assert!(
            err.contains("m.npz") && err.contains("0.000001") && err.contains("1000000"),
            "{err}"
        );
        let two = motion(vec![frame(0.0, 0.0), frame(0.0, 1.0)]);
        let most = two.resampled(1.0, (MAX_MOTION_FRAMES - 1) as f64).unwrap();
        assert_eq!(most.frames.len(), MAX_MOTION_FRAMES);
        assert!(two.resampled(1.0, MAX_MOTION_FRAMES as f64).is_err());
        assert!(two.resampled(0.0, 30.0).is_err());
    }

    #[test]
    fn resampling_interpolates_rotations_by_slerp_and_keeps_recorded_frames() {
        // 4 fps, a joint turning 0.4 rad a frame about y and the root moving 1 m a frame.
        let m = motion((0..5).map(|i| frame(0.4 * i as f64, i as f64)).collect());
        let up = m.resampled(4.0, 8.0).unwrap();
        assert_eq!(up.frames.len(), 9);
        assert_eq!(up.fps, Some(8.0));
        for (i, f) in up.frames.iter().enumerate() {
            assert!(
                (f.joints[0].y - 0.2 * i as f64).abs() < 1e-12,
                "frame {i}: {f:?}"
            );
            match f.root {
                Root::Standard { trans } => assert!((trans.x - 0.5 * i as f64).abs() < 1e-12),
                _ => unreachable!(),
            }
        }
        assert_eq!(up.frames[4], m.frames[2], "recorded frames are copied");
        let down = m.resampled(4.0, 2.0).unwrap();
        assert_eq!(
            down.frames,
            vec![
                m.frames[0].clone(),
                m.frames[2].clone(),
                m.frames[4].clone()
            ]
        );
        for bad in [0.0, -3.0, f64::NAN] {
            let err = m.resampled(4.0, bad).unwrap_err().to_string();
            assert!(err.contains("--fps") && err.contains("positive"), "{err}");
        }
    }
}
