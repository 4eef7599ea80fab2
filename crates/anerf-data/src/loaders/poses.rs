//! Pose files of the `params/{i}.npy` format, one per frame: the dataset's own, or a sequence from
//! elsewhere (another subject's motion, a motion-capture retarget) for `anerf render --poses`.

use std::path::{Path, PathBuf};

use anerf_core::geometry::Pose;

use crate::error::DataError;
use crate::formats;
use crate::formats::arrays::{self, field, finite};

/// A pose file of the `params/{i}.npy` format: `poses` (3·K numbers, axis-angle, radians), `Rh`
/// (axis-angle) and `Th` (metres) of the pose → world transform. Other keys (`shapes`) are ignored.
pub fn read_pose_file(path: &Path, num_joints: usize) -> Result<Pose, DataError> {
    read_pose(path, Some(num_joints))
}

/// [`read_pose_file`], or with `num_joints` unknown (`lbs/joints.npy` unreadable) any whole number of joints.
pub(crate) fn read_pose(path: &Path, num_joints: Option<usize>) -> Result<Pose, DataError> {
    let v = formats::read_npy_object(path)?;
    let flat = |key: &str, n: Option<usize>, hint: &str| -> Result<Vec<f64>, DataError> {
        let a = field(&v, key, path)?;
        if let Some(n) = n.filter(|&n| a.len() != n) {
            return Err(DataError::invalid(
                path,
                format!(
                    "'{key}' has shape {} ({} numbers), expected {n}{hint}",
                    arrays::shape_text(a.shape()),
                    a.len()
                ),
            ));
        }
        finite(
            a,
            path,
            key,
            &a.shape().iter().map(|&d| Some(d)).collect::<Vec<_>>(),
        )
    };
    let poses = flat(
        "poses",
        num_joints.map(|k| 3 * k),
        &num_joints.map_or(String::new(), |k| {
            format!(" (3 per joint, {k} joints in lbs/joints.npy)")
        }),
    )?;
    let rh = flat("Rh", Some(3), "")?;
    let th = flat("Th", Some(3), "")?;
    let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    let a3 = |v: &[f64]| std::array::from_fn(|i| v[i] as f32);
    Pose::from_flat(&f32s(&poses), a3(&rh), a3(&th))
        .map_err(|e| DataError::invalid(path, e.to_string()))
}

/// The pose files named by `path`: the file itself, or every `*.npy` file of the folder ordered by the number
/// in its name (`2.npy` before `10.npy`; names without a number after those, by name).
pub fn pose_files(path: &Path) -> Result<Vec<PathBuf>, DataError> {
    if path.is_file() {
        return Ok(vec![path.to_path_buf()]);
    }
    if !path.is_dir() {
        return Err(DataError::Missing {
            path: path.to_path_buf(),
            what: "a pose file (params/{i}.npy format) or a folder of them".into(),
        });
    }
    let files = numbered_files(path, "npy")?;
    if files.is_empty() {
        return Err(DataError::Missing {
            path: path.to_path_buf(),
            what: "at least one pose file (*.npy of the params/{i}.npy format) in this folder"
                .into(),
        });
    }
    Ok(files)
}

/// The `*.<ext>` files of the folder `dir`, ordered by the number in their names (`2.npy` before `10.npy`;
/// names without a number after those, by name).
pub(crate) fn numbered_files(dir: &Path, ext: &str) -> Result<Vec<PathBuf>, DataError> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| DataError::io(dir, e))?
        .map(|entry| entry.map(|e| e.path()).map_err(|e| DataError::io(dir, e)))
        .collect::<Result<Vec<_>, _>>()?
        .into_iter()
        .filter(|p| p.is_file() && p.extension().is_some_and(|e| e == ext))
        .collect();
    let number = |p: &Path| -> Option<u64> { p.file_stem()?.to_str()?.parse().ok() };
    files.sort_by(|a, b| match (number(a), number(b)) {
        (Some(x), Some(y)) => x.cmp(&y),
        (Some(_), None) => std::cmp::Ordering::Less,
        (None, Some(_)) => std::cmp::Ordering::Greater,
        (None, None) => a.cmp(b),
    });
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folders_are_listed_in_numeric_order() {
        let dir = tempfile::tempdir().unwrap();
        for name in ["10.npy", "2.npy", "b.npy", "a.npy", "notes.txt", "1.npy"] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        let names: Vec<String> = pose_files(dir.path())
            .unwrap()
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["1.npy", "2.npy", "10.npy", "a.npy", "b.npy"]);
        let single = dir.path().join("2.npy");
        assert_eq!(pose_files(&single).unwrap(), vec![single]);
    }

    #[test]
    fn a_missing_path_or_an_empty_folder_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let err = pose_files(dir.path()).unwrap_err().to_string();
        assert!(
            err.contains(&dir.path().display().to_string()) && err.contains("at least one"),
            "{err}"
        );
        let gone = dir.path().join("gone");
        let err = pose_files(&gone).unwrap_err().to_string();
        assert!(err.contains("gone") && err.contains("pose file"), "{err}");
    }
}
