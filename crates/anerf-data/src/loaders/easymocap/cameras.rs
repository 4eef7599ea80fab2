//! EasyMocap's calibration: `intri.yml` (`names`, `K_<cam>`, `dist_<cam>`) and `extri.yml` (`Rot_<cam>` as a
//! 3×3 matrix or `R_<cam>` as a Rodrigues vector (or matrix), `T_<cam>` in metres), OpenCV FileStorage
//! YAML. World → camera is `x_cam = R x_world + T`, OpenCV axes, as in the ZJU-MoCap annotations.

use std::path::Path;

use glam::DVec3;

use super::super::annots::RawCamera;
use super::super::check::Checker;
use crate::error::DataError;
use crate::formats::opencv_yaml::{FileStorage, Matrix};
use crate::paths;
use crate::paths::Folder;
use crate::smpl::rodrigues;

/// Distortion coefficient counts OpenCV uses (k1 k2 p1 p2 [k3 [k4 k5 k6 [s1..s4 [τx τy]]]]).
const DIST_COUNTS: [usize; 5] = [4, 5, 8, 12, 14];

/// The camera names of `intri.yml` and each camera (`None` where its entries were unusable, each
/// problem recorded); `None` when a file or the name list is unusable.
pub(super) fn read_cameras(
    root: &Path,
    ck: &mut Checker,
) -> Result<Option<(Vec<String>, Vec<Option<RawCamera>>)>, DataError> {
    let inside = Folder::new(root, "dataset folder");
    let read = |name: &str| {
        let path = root.join(name);
        inside.check(&path).and_then(|()| FileStorage::read(&path))
    };
    let intri = ck.check(read("intri.yml"))?;
    let extri = ck.check(read("extri.yml"))?;
    let (Some(intri), Some(extri)) = (intri, extri) else {
        return Ok(None);
    };
    let names = intri.strings("names").and_then(|names| {
        names.filter(|n| !n.is_empty()).ok_or_else(|| {
            DataError::invalid(
                intri.path(),
                "has no 'names' list of cameras (EasyMocap writes one in intri.yml)",
            )
        })
    });
    let names = names.and_then(|names| check_names(&names, intri.path()).map(|()| names));
    let Some(names) = ck.check(names)? else {
        return Ok(None);
    };
    if let Some(Ok(Some(extri_names))) = extri.get("names").map(|_| extri.strings("names")) {
        let missing: Vec<&String> = names.iter().filter(|n| !extri_names.contains(n)).collect();
        if !missing.is_empty() {
            ck.check::<()>(Err(DataError::invalid(
                extri.path(),
                format!(
                    "lists no camera {} of intri.yml's names",
                    missing
                        .iter()
                        .map(|n| format!("'{n}'"))
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )))?;
        }
    }
    let cameras = names
        .iter()
        .map(|name| ck.check(camera(&intri, &extri, name)))
        .collect::<Result<_, _>>()?;
    Ok(Some((names, cameras)))
}

/// Each camera name is a folder of `images/` and `mask/`: one plain path component, and listed once (a
/// camera listed twice could be a held-out view and a training view at once).
fn check_names(names: &[String], path: &Path) -> Result<(), DataError> {
    let mut seen = std::collections::HashSet::new();
    for name in names {
        paths::check_component(name).map_err(|why| {
            DataError::invalid(
                path,
                format!(
                    "camera name {name:?} {why}; a camera's name is its folder under images/ and mask/"
                ),
            )
        })?;
        if !seen.insert(name) {
            return Err(DataError::invalid(
                path,
                format!("'names' lists the camera '{name}' twice; each camera must be listed once"),
            ));
        }
    }
    Ok(())
}

/// Camera `name`'s K, distortion, rotation and translation, each of the right shape and finite.
fn camera(intri: &FileStorage, extri: &FileStorage, name: &str) -> Result<RawCamera, DataError> {
    let k = required(intri, &format!("K_{name}"), "the 3×3 intrinsic matrix")?;
    let k = shaped(intri, &format!("K_{name}"), k, &[(3, 3)])?;
    let dist_key = [format!("dist_{name}"), format!("D_{name}")]
        .into_iter()
        .find(|key| intri.get(key).is_some())
        .unwrap_or_else(|| format!("dist_{name}"));
    let dist = required(intri, &dist_key, "the distortion coefficients (1×5)")?;
    let shapes: Vec<(usize, usize)> = DIST_COUNTS.iter().flat_map(|&n| [(1, n), (n, 1)]).collect();
    let dist = shaped(intri, &dist_key, dist, &shapes)?;
    let rotation = match extri.matrix(&format!("Rot_{name}"))? {
        Some(m) => matrix3(&shaped(extri, &format!("Rot_{name}"), m, &[(3, 3)])?),
        None => {
            let key = format!("R_{name}");
            let r = required(
                extri,
                &key,
                "the rotation (Rot_ 3×3, or R_ as a Rodrigues vector)",
            )?;
            let r = shaped(extri, &key, r, &[(3, 1), (1, 3), (3, 3)])?;
            if r.len() == 3 {
                let m = rodrigues(DVec3::new(r[0], r[1], r[2]));
                std::array::from_fn(|i| m.row(i).to_array())
            } else {
                matrix3(&r)
            }
        }
    };
    let key = format!("T_{name}");
    let t = required(extri, &key, "the translation (3×1, metres)")?;
    let t = shaped(extri, &key, t, &[(3, 1), (1, 3)])?;
    let f32s = |m: [[f64; 3]; 3]| m.map(|row| row.map(|x| x as f32));
    Ok(RawCamera {
        k: f32s(matrix3(&k)),
        r: f32s(rotation),
        t: std::array::from_fn(|i| t[i] as f32),
        // OpenCV's first five coefficients (k1, k2, p1, p2, k3), as for the ZJU-MoCap annotations.
        d: std::array::from_fn(|i| dist.get(i).copied().unwrap_or(0.0) as f32),
    })
}

fn required<'a>(fs: &'a FileStorage, key: &str, what: &str) -> Result<&'a Matrix, DataError> {
    fs.matrix(key)?
        .ok_or_else(|| DataError::invalid(fs.path(), format!("has no '{key}'; expected {what}")))
}

/// The matrix's values when its shape is one of `allowed` and every value is finite.
fn shaped(
    fs: &FileStorage,
    key: &str,
    m: &Matrix,
    allowed: &[(usize, usize)],
) -> Result<Vec<f64>, DataError> {
    if !allowed.contains(&(m.rows, m.cols)) {
        let list: Vec<String> = allowed.iter().map(|(r, c)| format!("{r}×{c}")).collect();
        return Err(DataError::invalid(
            fs.path(),
            format!(
                "'{key}' is {}×{}, expected {}",
                m.rows,
                m.cols,
                list.join(" or ")
            ),
        ));
    }
    if m.data.iter().any(|x| !x.is_finite()) {
        return Err(DataError::invalid(
            fs.path(),
            format!("'{key}' holds a non-finite value"),
        ));
    }
    Ok(m.data.clone())
}

fn matrix3(v: &[f64]) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| std::array::from_fn(|j| v[3 * i + j]))
}
