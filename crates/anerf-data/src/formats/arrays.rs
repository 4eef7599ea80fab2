//! Shape-checked views of arrays read from dataset files.

use std::path::Path;

use glam::Vec3;

use crate::error::DataError;
use crate::formats::{NdArray, Value};

/// Checks `arr`'s shape against `expected` (`None` = any size) and returns its elements as `f64`,
/// refusing NaN and infinities.
pub(crate) fn finite(
    arr: &NdArray,
    path: &Path,
    field: &str,
    expected: &[Option<usize>],
) -> Result<Vec<f64>, DataError> {
    check_shape(arr.shape(), path, field, expected)?;
    let v = arr.to_f64();
    if let Some(i) = v.iter().position(|x| !x.is_finite()) {
        return Err(DataError::invalid(
            path,
            format!("{field} holds a non-finite value ({}) at element {i}", v[i]),
        ));
    }
    Ok(v)
}

/// Refuses a `shape` of `field` that does not match `expected` (`None` = any size), naming both.
pub(crate) fn check_shape(
    shape: &[usize],
    path: &Path,
    field: &str,
    expected: &[Option<usize>],
) -> Result<(), DataError> {
    let fits = shape.len() == expected.len()
        && shape
            .iter()
            .zip(expected)
            .all(|(d, e)| e.is_none_or(|e| e == *d));
    if fits {
        return Ok(());
    }
    let want: Vec<String> = expected
        .iter()
        .map(|e| e.map_or("any".to_string(), |n| n.to_string()))
        .collect();
    Err(DataError::invalid(
        path,
        format!(
            "{field} has shape {}, expected ({})",
            shape_text(shape),
            want.join(", ")
        ),
    ))
}

/// A shape as NumPy prints it: `(7, 5)`, `(3,)`, `()`.
pub(crate) fn shape_text(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// `N × 3` points (metres).
pub(crate) fn points(arr: &NdArray, path: &Path, field: &str) -> Result<Vec<Vec3>, DataError> {
    let v = finite(arr, path, field, &[None, Some(3)])?;
    Ok(v.chunks_exact(3)
        .map(|c| Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32))
        .collect())
}

/// The array stored under `key` of a dict.
pub(crate) fn field<'a>(dict: &'a Value, key: &str, path: &Path) -> Result<&'a NdArray, DataError> {
    let v = dict.get(key).ok_or_else(|| {
        DataError::invalid(
            path,
            format!("has no '{key}' entry (keys: {})", dict.keys().join(", ")),
        )
    })?;
    v.as_array().ok_or_else(|| {
        DataError::invalid(
            path,
            format!("'{key}' is {}, expected a numeric array", v.kind()),
        )
    })
}

/// Integer triangles `F × 3` with every index below `num_vertices` (when known).
pub(crate) fn faces(
    arr: &NdArray,
    path: &Path,
    num_vertices: Option<usize>,
) -> Result<Vec<[u32; 3]>, DataError> {
    let ints = arr
        .to_i64()
        .ok_or_else(|| DataError::invalid(path, "faces are not integers"))?;
    if arr.shape().len() != 2 || arr.shape()[1] != 3 {
        return Err(DataError::invalid(
            path,
            format!(
                "faces have shape {}, expected (F, 3)",
                shape_text(arr.shape())
            ),
        ));
    }
    let limit = num_vertices.unwrap_or(u32::MAX as usize);
    if let Some(bad) = ints.iter().find(|&&i| i < 0 || i as usize >= limit) {
        return Err(DataError::invalid(
            path,
            match num_vertices {
                Some(n) => format!("face index {bad} is outside the {n} vertices"),
                None => format!("face index {bad} is not a vertex index"),
            },
        ));
    }
    Ok(ints
        .chunks_exact(3)
        .map(|c| [c[0] as u32, c[1] as u32, c[2] as u32])
        .collect())
}
