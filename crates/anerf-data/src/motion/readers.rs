//! The motion file readers behind [`super::Motion::read`]; every value is checked for its shape and
//! finiteness, and errors name the file and the key.

use std::path::{Path, PathBuf};

use glam::DVec3;

use super::{Motion, MotionFormat, MotionFrame, Root};
use crate::error::DataError;
use crate::formats::npz::{MemberKind, Npz};
use crate::loaders::arrays::{finite, shape_text};
use crate::loaders::easymocap::fits::read_fit_file;
use crate::loaders::poses::{numbered_files, read_pose};

/// Detects the format of `path` and reads it.
pub(super) fn read(path: &Path, person: Option<i64>) -> Result<Motion, DataError> {
    if path.is_dir() {
        for fits in ["output-smpl-3d/smpl", "output/smpl"] {
            if path.join(fits).is_dir() {
                return read_easymocap(&path.join(fits), person);
            }
        }
        let has =
            |ext: &str| -> Result<bool, DataError> { Ok(!numbered_files(path, ext)?.is_empty()) };
        return match (has("json")?, has("npy")?) {
            (true, false) => read_easymocap(path, person),
            (false, true) => read_zju(path),
            (true, true) => Err(DataError::invalid(
                path,
                "holds both .json and .npy files; expected EasyMocap fits (.json) or ZJU-MoCap pose \
                 files (.npy), not both",
            )),
            (false, false) => Err(DataError::Missing {
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
        "npz" => read_amass(path),
        "json" => read_easymocap_files(path, &[path.to_path_buf()], person),
        "npy" => read_zju_files(path, &[path.to_path_buf()]),
        other => Err(DataError::invalid(
            path,
            format!(
                "has the extension '{other}'; a motion is an AMASS .npz, an EasyMocap .json or a \
                 ZJU-MoCap .npy (or a folder of them)"
            ),
        )),
    }
}

/// An AMASS-style `.npz`: `poses` (T × 72, 156, 162 or 165) and `trans` (T × 3) in the standard SMPL root
/// convention, `mocap_framerate` (SMPL+H) or `mocap_frame_rate` (SMPL-X); SMPL-X files' `root_orient`
/// (T × 3) and `pose_body` (T × 63) take the place of the body part of `poses` where present.
fn read_amass(path: &Path) -> Result<Motion, DataError> {
    let mut npz = Npz::open(path)?;
    let listed = listing(&npz);
    let layout = || {
        format!(
            "an AMASS motion has 'poses' (T × 156 for SMPL+H, 162 or 165 for SMPL-X, 72 for SMPL) or \
             'root_orient' + 'pose_body' (SMPL-X), 'trans' (T × 3) and 'mocap_framerate' or \
             'mocap_frame_rate'; this file has {listed}"
        )
    };
    let has = |npz: &Npz, key: &str| npz.kind(key).is_some();
    let split = has(&npz, "root_orient") && has(&npz, "pose_body");
    if !(has(&npz, "trans") && (has(&npz, "poses") || split)) {
        return Err(DataError::invalid(path, layout()));
    }
    let rate_key = ["mocap_framerate", "mocap_frame_rate"]
        .into_iter()
        .find(|k| has(&npz, k))
        .ok_or_else(|| DataError::invalid(path, format!("records no frame rate: {}", layout())))?;
    let trans = numeric(&mut npz, path, "trans")?;
    let t = trans.shape().first().copied().unwrap_or(0);
    let trans = finite(&trans, path, "trans", &[Some(t), Some(3)])?;
    if t == 0 {
        return Err(DataError::invalid(path, "'trans' has no frames"));
    }
    let rate = numeric(&mut npz, path, rate_key)?;
    let rate = match finite(&rate, path, rate_key, &vec![Some(1); rate.shape().len()])?[..] {
        [r] => r,
        _ => unreachable!("a shape of ones holds one value"),
    };
    super::check_rate(rate, path, &format!("'{rate_key}'"))?;
    let poses = if has(&npz, "poses") {
        let p = numeric(&mut npz, path, "poses")?;
        let &[_, width] = p.shape() else {
            return Err(DataError::invalid(
                path,
                format!(
                    "'poses' has shape {}; expected (T, 72, 156, 162 or 165) with T = {t} frames like \
                     'trans'",
                    shape_text(p.shape())
                ),
            ));
        };
        Some((finite(&p, path, "poses", &[Some(t), Some(width)])?, width))
    } else {
        None
    };
    let (mut values, width) = match &poses {
        Some((v, w)) => (v.clone(), *w),
        None => (vec![0.0; t * 66], 66),
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
        let root = finite(
            &numeric(&mut npz, path, "root_orient")?,
            path,
            "root_orient",
            &[Some(t), Some(3)],
        )?;
        let body = finite(
            &numeric(&mut npz, path, "pose_body")?,
            path,
            "pose_body",
            &[Some(t), Some(63)],
        )?;
        for f in 0..t {
            values[f * width..f * width + 3].copy_from_slice(&root[f * 3..f * 3 + 3]);
            values[f * width + 3..f * width + 66].copy_from_slice(&body[f * 63..f * 63 + 63]);
        }
    }
    let frames = (0..t)
        .map(|f| MotionFrame {
            joints: vectors(&values[f * width..(f + 1) * width]),
            root: Root::Standard {
                trans: DVec3::from_slice(&trans[f * 3..f * 3 + 3]),
            },
        })
        .collect();
    Ok(Motion {
        source: path.to_path_buf(),
        format,
        fps: Some(rate),
        model_joints: width / 3,
        frames,
        up: Some(DVec3::Z),
    })
}

/// A numeric member of an archive, or an error saying what it holds instead.
fn numeric(npz: &mut Npz, path: &Path, key: &str) -> Result<crate::formats::NdArray, DataError> {
    match npz.kind(key) {
        Some(MemberKind::Numeric { .. }) => npz.array(key),
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

/// A folder of EasyMocap fits, in frame order.
fn read_easymocap(dir: &Path, person: Option<i64>) -> Result<Motion, DataError> {
    read_easymocap_files(dir, &numbered_files(dir, "json")?, person)
}

/// EasyMocap fit files: each frame's person `person` (default: the lowest id of the first file).
fn read_easymocap_files(
    source: &Path,
    files: &[PathBuf],
    person: Option<i64>,
) -> Result<Motion, DataError> {
    let mut chosen = person;
    let mut frames = Vec::with_capacity(files.len());
    for file in files {
        let people = read_fit_file(file)?;
        let id = *chosen.get_or_insert_with(|| people.iter().map(|p| p.id).min().unwrap_or(0));
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

/// A folder of ZJU-MoCap pose files, in numeric order.
fn read_zju(dir: &Path) -> Result<Motion, DataError> {
    read_zju_files(dir, &numbered_files(dir, "npy")?)
}

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
