//! The motion file readers behind [`super::Motion::read`]: a motion is first opened (its frame count
//! and rate known, its layout checked), then the frames wanted are read ([`Opened::read`]), so that a
//! cut of a long motion reads only the frames it needs. Every value is checked for its shape and
//! finiteness, and errors name the file and the key.

use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::DVec3;

use super::{Motion, MotionFormat, MotionFrame, Root};
use crate::error::DataError;
use crate::formats::arrays::{check_shape, finite, shape_text};
use crate::formats::npz::{MemberKind, Npz};
use crate::loaders::easymocap::fits::read_fit_file;
use crate::loaders::poses::{numbered_files, read_pose};

/// A motion file or folder opened: its layout checked, its frames not read yet.
pub(super) enum Opened {
    Amass(Amass),
    /// EasyMocap fit files in frame order, and the person asked for.
    EasyMocap {
        source: PathBuf,
        files: Vec<PathBuf>,
        person: Option<i64>,
    },
    /// ZJU-MoCap pose files in numeric order.
    Zju {
        source: PathBuf,
        files: Vec<PathBuf>,
    },
}

/// Detects the format of `path` and opens it.
pub(super) fn open(path: &Path, person: Option<i64>) -> Result<Opened, DataError> {
    let files = |source: &Path, files: Vec<PathBuf>, easymocap: bool| {
        let source = source.to_path_buf();
        if files.is_empty() {
            return Err(DataError::Missing {
                path: source,
                what: "a motion's frames (no numbered files)".into(),
            });
        }
        Ok(if easymocap {
            Opened::EasyMocap {
                source,
                files,
                person,
            }
        } else {
            Opened::Zju { source, files }
        })
    };
    if path.is_dir() {
        for fits in ["output-smpl-3d/smpl", "output/smpl"] {
            let dir = path.join(fits);
            if dir.is_dir() {
                return files(&dir, numbered_files(&dir, "json")?, true);
            }
        }
        let (json, npy) = (numbered_files(path, "json")?, numbered_files(path, "npy")?);
        return match (json.is_empty(), npy.is_empty()) {
            (false, true) => files(path, json, true),
            (true, false) => files(path, npy, false),
            (false, false) => Err(DataError::invalid(
                path,
                "holds both .json and .npy files; expected EasyMocap fits (.json) or ZJU-MoCap pose \
                 files (.npy), not both",
            )),
            (true, true) => Err(DataError::Missing {
                path: path.to_path_buf(),
                what: "a motion: EasyMocap fits (<frame>.json) or ZJU-MoCap pose files (<i>.npy)".into(),
            }),
        };
    }
    if !path.is_file() {
        return Err(DataError::Missing {
            path: path.to_path_buf(),
            what: "a motion file (AMASS .npz, EasyMocap .json, ZJU-MoCap .npy) or a folder of them"
                .into(),
        });
    }
    match path.extension().and_then(|e| e.to_str()).unwrap_or("") {
        "npz" => Ok(Opened::Amass(Amass::open(path)?)),
        "json" => files(path, vec![path.to_path_buf()], true),
        "npy" => files(path, vec![path.to_path_buf()], false),
        other => Err(DataError::invalid(
            path,
            format!(
                "has the extension '{other}'; a motion is an AMASS .npz, an EasyMocap .json or a \
                 ZJU-MoCap .npy (or a folder of them)"
            ),
        )),
    }
}

impl Opened {
    /// Frames the motion records.
    pub(super) fn len(&self) -> usize {
        match self {
            Opened::Amass(a) => a.frames,
            Opened::EasyMocap { files, .. } | Opened::Zju { files, .. } => files.len(),
        }
    }

    /// Frames per second, where the format records it.
    pub(super) fn fps(&self) -> Option<f64> {
        match self {
            Opened::Amass(a) => Some(a.rate),
            Opened::EasyMocap { .. } | Opened::Zju { .. } => None,
        }
    }

    pub(super) fn format(&self) -> MotionFormat {
        match self {
            Opened::Amass(a) => a.format,
            Opened::EasyMocap { .. } => MotionFormat::EasyMocap,
            Opened::Zju { .. } => MotionFormat::ZjuParams,
        }
    }

    pub(super) fn source(&self) -> &Path {
        match self {
            Opened::Amass(a) => &a.path,
            Opened::EasyMocap { source, .. } | Opened::Zju { source, .. } => source,
        }
    }

    /// Reads the recorded frames `rows` (within `0..len()`).
    pub(super) fn read(&mut self, rows: Range<usize>) -> Result<Motion, DataError> {
        match self {
            Opened::Amass(a) => a.read(rows),
            Opened::EasyMocap {
                source,
                files,
                person,
            } => {
                let id = match *person {
                    Some(id) => id,
                    None => lowest_person(&files[0])?,
                };
                read_easymocap_files(source, &files[rows], id)
            }
            Opened::Zju { source, files } => read_zju_files(source, &files[rows]),
        }
    }
}

/// An AMASS-style `.npz`: `poses` (T × 72, 156, 162 or 165) and `trans` (T × 3) in the standard SMPL root
/// convention, `mocap_framerate` (SMPL+H) or `mocap_frame_rate` (SMPL-X); SMPL-X files' `root_orient`
/// (T × 3) and `pose_body` (T × 63) take the place of the body part of `poses` where present. Opening
/// reads the members' headers and the rate; [`Amass::read`] reads the rows of a range of frames.
pub(super) struct Amass {
    path: PathBuf,
    npz: Npz,
    format: MotionFormat,
    /// Frames (rows of every per-frame member).
    frames: usize,
    rate: f64,
    /// Pose values a frame: `poses`' width, or 66 when only `root_orient` + `pose_body` are given.
    width: usize,
    has_poses: bool,
    /// `root_orient` + `pose_body` override the body part of `poses`.
    split: bool,
}

impl Amass {
    fn open(path: &Path) -> Result<Self, DataError> {
        let mut npz = Npz::open(path)?;
        let listed = listing(&npz);
        let layout = || {
            format!(
                "an AMASS motion has 'poses' (T × 156 for SMPL+H, 162 or 165 for SMPL-X, 72 for SMPL) \
                 or 'root_orient' + 'pose_body' (SMPL-X), 'trans' (T × 3) and 'mocap_framerate' or \
                 'mocap_frame_rate'; this file has {listed}"
            )
        };
        let has = |npz: &Npz, key: &str| npz.kind(key).is_some();
        let split = has(&npz, "root_orient") && has(&npz, "pose_body");
        let has_poses = has(&npz, "poses");
        if !(has(&npz, "trans") && (has_poses || split)) {
            return Err(DataError::invalid(path, layout()));
        }
        let rate_key = ["mocap_framerate", "mocap_frame_rate"]
            .into_iter()
            .find(|k| has(&npz, k))
            .ok_or_else(|| {
                DataError::invalid(path, format!("records no frame rate: {}", layout()))
            })?;
        let trans = shape_of(&npz, path, "trans")?;
        let frames = trans.first().copied().unwrap_or(0);
        check_shape(&trans, path, "trans", &[Some(frames), Some(3)])?;
        if frames == 0 {
            return Err(DataError::invalid(path, "'trans' has no frames"));
        }
        let rate = shape_of(&npz, path, rate_key)?;
        check_shape(&rate, path, rate_key, &vec![Some(1); rate.len()])?;
        let rate = finite(
            &npz.array(rate_key)?,
            path,
            rate_key,
            &vec![Some(1); rate.len()],
        )?[0];
        super::check_rate(rate, path, &format!("'{rate_key}'"))?;
        let width = if has_poses {
            let poses = shape_of(&npz, path, "poses")?;
            let &[_, width] = &poses[..] else {
                return Err(DataError::invalid(
                    path,
                    format!(
                        "'poses' has shape {}; expected (T, 72, 156, 162 or 165) with T = {frames} \
                         frames like 'trans'",
                        shape_text(&poses)
                    ),
                ));
            };
            check_shape(&poses, path, "poses", &[Some(frames), Some(width)])?;
            width
        } else {
            66
        };
        let format = match (width, split || rate_key == "mocap_frame_rate") {
            (72, false) => MotionFormat::AmassSmpl,
            (156, false) => MotionFormat::AmassSmplh,
            (66 | 162 | 165, true) => MotionFormat::AmassSmplx,
            _ => {
                return Err(DataError::invalid(
                    path,
                    format!(
                        "'poses' has {width} values a frame with '{rate_key}', which fits no known body \
                         model (SMPL+H: 156 with mocap_framerate; SMPL-X: 162 or 165 with \
                         mocap_frame_rate; SMPL: 72)"
                    ),
                ))
            }
        };
        if split {
            for (key, values) in [("root_orient", 3), ("pose_body", 63)] {
                check_shape(
                    &shape_of(&npz, path, key)?,
                    path,
                    key,
                    &[Some(frames), Some(values)],
                )?;
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            npz,
            format,
            frames,
            rate,
            width,
            has_poses,
            split,
        })
    }

    /// Frames `rows`, reading only those rows of each member.
    fn read(&mut self, rows: Range<usize>) -> Result<Motion, DataError> {
        let (path, n, width) = (self.path.clone(), rows.len(), self.width);
        let mut member = |key: &str, values: usize| -> Result<Vec<f64>, DataError> {
            finite(
                &self.npz.rows(key, rows.clone())?,
                &path,
                key,
                &[Some(n), Some(values)],
            )
        };
        let trans = member("trans", 3)?;
        let mut values = if self.has_poses {
            member("poses", width)?
        } else {
            vec![0.0; n * width]
        };
        if self.split {
            let root = member("root_orient", 3)?;
            let body = member("pose_body", 63)?;
            for f in 0..n {
                values[f * width..f * width + 3].copy_from_slice(&root[f * 3..f * 3 + 3]);
                values[f * width + 3..f * width + 66].copy_from_slice(&body[f * 63..f * 63 + 63]);
            }
        }
        let frames = (0..n)
            .map(|f| MotionFrame {
                joints: vectors(&values[f * width..(f + 1) * width]),
                root: Root::Standard {
                    trans: DVec3::from_slice(&trans[f * 3..f * 3 + 3]),
                },
            })
            .collect();
        Ok(Motion {
            source: path,
            format: self.format,
            fps: Some(self.rate),
            model_joints: width / 3,
            frames,
            up: Some(DVec3::Z),
        })
    }
}

/// The shape of the numeric member `key`, or an error saying what it holds instead.
fn shape_of(npz: &Npz, path: &Path, key: &str) -> Result<Vec<usize>, DataError> {
    match npz.kind(key) {
        Some(MemberKind::Numeric { shape, .. }) => Ok(shape.clone()),
        Some(MemberKind::Other(kind)) => Err(DataError::invalid(
            path,
            format!("'{key}' holds {kind}; expected a numeric array (object arrays are never unpickled)"),
        )),
        None => Err(DataError::invalid(
            path,
            format!("has no '{key}' ({})", listing(npz)),
        )),
    }
}

/// The members of `npz` with their shapes or kinds, for error messages.
fn listing(npz: &Npz) -> String {
    npz.names()
        .into_iter()
        .map(|name| match npz.kind(name) {
            Some(MemberKind::Numeric { shape, .. }) => format!("{name} {}", shape_text(shape)),
            Some(MemberKind::Other(kind)) => format!("{name} ({kind})"),
            None => name.to_string(),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Axis-angle vectors of a flat `3·K` array.
fn vectors(values: &[f64]) -> Vec<DVec3> {
    values.chunks_exact(3).map(DVec3::from_slice).collect()
}

/// The lowest person id in the EasyMocap fit `file` (the person a motion follows by default).
fn lowest_person(file: &Path) -> Result<i64, DataError> {
    Ok(read_fit_file(file)?.iter().map(|p| p.id).min().unwrap_or(0))
}

/// EasyMocap fit files: each frame's person `id`.
fn read_easymocap_files(source: &Path, files: &[PathBuf], id: i64) -> Result<Motion, DataError> {
    let mut frames = Vec::with_capacity(files.len());
    for file in files {
        let people = read_fit_file(file)?;
        let fit = people.iter().find(|p| p.id == id).ok_or_else(|| {
            DataError::invalid(
                file,
                format!(
                    "has no person {id} (ids: {:?}); choose one with --person",
                    people.iter().map(|p| p.id).collect::<Vec<_>>()
                ),
            )
        })?;
        frames.push((
            file,
            MotionFrame {
                joints: vectors(&fit.poses),
                root: Root::Placed {
                    rh: fit.rh,
                    th: fit.th,
                },
            },
        ));
    }
    same_joints(frames, source, MotionFormat::EasyMocap)
}

/// ZJU-MoCap pose files, in the order given.
fn read_zju_files(source: &Path, files: &[PathBuf]) -> Result<Motion, DataError> {
    let frames = files
        .iter()
        .map(|file| {
            let pose = read_pose(file, None)?;
            let v = |x: glam::Vec3| x.as_dvec3();
            Ok((
                file,
                MotionFrame {
                    joints: pose.joint_rotations.iter().map(|&r| v(r)).collect(),
                    root: Root::Placed {
                        rh: v(pose.global.rh),
                        th: v(pose.global.th),
                    },
                },
            ))
        })
        .collect::<Result<Vec<_>, DataError>>()?;
    same_joints(frames, source, MotionFormat::ZjuParams)
}

/// A motion of frames that must all have one joint count (the first file's).
fn same_joints(
    frames: Vec<(&PathBuf, MotionFrame)>,
    source: &Path,
    format: MotionFormat,
) -> Result<Motion, DataError> {
    let model_joints = frames.first().map_or(0, |(_, f)| f.joints.len());
    if let Some((file, f)) = frames.iter().find(|(_, f)| f.joints.len() != model_joints) {
        return Err(DataError::invalid(
            file,
            format!(
                "has poses of {} joints, the first frame of {} has {model_joints}",
                f.joints.len(),
                source.display()
            ),
        ));
    }
    Ok(Motion {
        source: source.to_path_buf(),
        format,
        fps: None,
        model_joints,
        frames: frames.into_iter().map(|(_, f)| f).collect(),
        up: None,
    })
}
