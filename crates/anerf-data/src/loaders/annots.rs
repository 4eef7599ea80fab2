//! `annots.npy`: the cameras (`cams`: K, R, T, D lists) and every frame's image paths (`ims`). Each camera,
//! frame and path is checked on its own, so one bad entry hides no other.

use std::path::{Component, Path};

use super::check::Checker;
use crate::error::DataError;
use crate::formats::Value;

/// A camera (K, R, T in metres, D) as stored, before the image size is known.
pub(super) struct RawCamera {
    pub k: [[f32; 3]; 3],
    pub r: [[f32; 3]; 3],
    pub t: [f32; 3],
    pub d: [f32; 5],
}

impl RawCamera {
    /// The principal point `(cx, cy)` in pixels: about half the image size it was calibrated for.
    pub fn principal_point(&self) -> (f32, f32) {
        (self.k[0][2], self.k[1][2])
    }
}

/// One frame's image paths by camera; `None` where a path was refused.
pub(super) type FramePaths = Vec<Option<String>>;

/// The numbers each camera stores per key and the counts allowed.
const CAMERA_KEYS: [(&str, &[usize]); 4] = [
    ("K", &[9]),
    ("R", &[9]),
    ("T", &[3]),
    ("D", &[4, 5, 8, 12, 14]),
];

/// `annots['cams']` (T in millimetres → metres): `None` when the lists themselves are unusable, and a
/// `None` camera where its own numbers are (each recorded).
pub(super) fn read_cameras(
    annots: &Value,
    path: &Path,
    ck: &mut Checker,
) -> Result<Option<Vec<Option<RawCamera>>>, DataError> {
    let Some(lists) = ck.check(camera_lists(annots, path))? else {
        return Ok(None);
    };
    (0..lists[0].len())
        .map(|c| ck.check(camera(path, c, lists.each_ref().map(|l| &l[c][..]))))
        .collect::<Result<_, _>>()
        .map(Some)
}

/// The K, R, T and D lists, one entry per camera each.
fn camera_lists(annots: &Value, path: &Path) -> Result<[Vec<Vec<f64>>; 4], DataError> {
    let cams = annots.get("cams").ok_or_else(|| {
        DataError::invalid(
            path,
            format!("has no 'cams' (keys: {})", annots.keys().join(", ")),
        )
    })?;
    let per_camera = |key: &str| -> Result<Vec<Vec<f64>>, DataError> {
        let v = cams
            .get(key)
            .ok_or_else(|| DataError::invalid(path, format!("cams has no '{key}'")))?;
        match v {
            Value::Array(a) if a.shape().len() >= 2 => {
                let n = a.shape()[0];
                let all = a.to_f64();
                let per = all.len() / n.max(1);
                Ok(all.chunks(per.max(1)).map(<[f64]>::to_vec).collect())
            }
            _ => v
                .as_seq()
                .ok_or_else(|| {
                    DataError::invalid(
                        path,
                        format!("cams['{key}'] is {}, expected a list of arrays", v.kind()),
                    )
                })?
                .iter()
                .map(|x| {
                    x.as_array().map(|a| a.to_f64()).ok_or_else(|| {
                        DataError::invalid(
                            path,
                            format!("cams['{key}'] holds {}, expected arrays", x.kind()),
                        )
                    })
                })
                .collect(),
        }
    };
    let [k, r, t, d] = CAMERA_KEYS.map(|(key, _)| per_camera(key));
    let lists = [k?, r?, t?, d?];
    let counts = lists.each_ref().map(Vec::len);
    if counts.iter().any(|&n| n != counts[0]) || counts[0] == 0 {
        return Err(DataError::invalid(
            path,
            format!(
                "cams lists {} K, {} R, {} T and {} D; expected one of each per camera",
                counts[0], counts[1], counts[2], counts[3]
            ),
        ));
    }
    Ok(lists)
}

/// Camera `c` from its K, R, T and D numbers, each of an allowed count and finite.
fn camera(path: &Path, c: usize, numbers: [&[f64]; 4]) -> Result<RawCamera, DataError> {
    for ((key, sizes), item) in CAMERA_KEYS.iter().zip(numbers) {
        if !sizes.contains(&item.len()) {
            return Err(DataError::invalid(
                path,
                format!(
                    "cams['{key}'][{c}] has {} numbers, expected {sizes:?}",
                    item.len()
                ),
            ));
        }
        if item.iter().any(|x| !x.is_finite()) {
            return Err(DataError::invalid(
                path,
                format!("cams['{key}'][{c}] is not finite"),
            ));
        }
    }
    let [k, r, t, d] = numbers;
    let m3 = |v: &[f64]| -> [[f32; 3]; 3] {
        std::array::from_fn(|i| std::array::from_fn(|j| v[3 * i + j] as f32))
    };
    Ok(RawCamera {
        k: m3(k),
        r: m3(r),
        t: std::array::from_fn(|i| (t[i] / 1000.0) as f32),
        // OpenCV's first five coefficients (k1, k2, p1, p2, k3); a 4-vector has no k3.
        d: std::array::from_fn(|i| d.get(i).copied().unwrap_or(0.0) as f32),
    })
}

/// `annots['ims'][f]['ims']`: one relative path per camera, checked to stay inside the folder. A frame
/// is `None` when it has no list or (with the camera count known) one of another length.
pub(super) fn read_image_lists(
    annots: &Value,
    path: &Path,
    cameras: Option<usize>,
    ck: &mut Checker,
) -> Result<Option<Vec<Option<FramePaths>>>, DataError> {
    let frames = annots
        .get("ims")
        .and_then(Value::as_seq)
        .ok_or_else(|| DataError::invalid(path, "has no 'ims' list of frames"))
        .and_then(|ims| match ims {
            [] => Err(DataError::invalid(path, "'ims' lists no frame")),
            _ => Ok(ims),
        });
    let Some(frames) = ck.check(frames)? else {
        return Ok(None);
    };
    frames
        .iter()
        .enumerate()
        .map(|(f, frame)| {
            let Some(list) = ck.check(frame_list(path, f, frame, cameras))? else {
                return Ok(None);
            };
            list.iter()
                .enumerate()
                .map(|(c, p)| ck.check(image_path(path, f, c, p)))
                .collect::<Result<_, _>>()
                .map(Some)
        })
        .collect::<Result<_, _>>()
        .map(Some)
}

fn frame_list<'a>(
    path: &Path,
    f: usize,
    frame: &'a Value,
    cameras: Option<usize>,
) -> Result<&'a [Value], DataError> {
    let list = frame.get("ims").and_then(Value::as_seq).ok_or_else(|| {
        DataError::invalid(path, format!("ims[{f}] has no 'ims' list of image paths"))
    })?;
    match cameras {
        Some(n) if list.len() != n => Err(DataError::invalid(
            path,
            format!(
                "frame {f} lists {} images but cams describes {n} cameras",
                list.len()
            ),
        )),
        _ => Ok(list),
    }
}

fn image_path(path: &Path, f: usize, c: usize, p: &Value) -> Result<String, DataError> {
    let s = p.as_str().ok_or_else(|| {
        DataError::invalid(
            path,
            format!("ims[{f}]['ims'][{c}] is {}, expected a path", p.kind()),
        )
    })?;
    check_relative(&s).map_err(|why| {
        DataError::invalid(
            path,
            format!("image path {s:?} (frame {f}, camera {c}) {why}"),
        )
    })?;
    Ok(s)
}

/// Image paths must stay inside the dataset folder: relative, without `..`.
fn check_relative(p: &str) -> Result<(), &'static str> {
    let path = Path::new(p);
    if p.is_empty() {
        return Err("is empty");
    }
    for c in path.components() {
        match c {
            Component::ParentDir => return Err("leaves the dataset folder through '..'"),
            Component::RootDir | Component::Prefix(_) => {
                return Err("is absolute; expected a path relative to the dataset folder")
            }
            _ => {}
        }
    }
    Ok(())
}
