//! Writer of numpy `.npy` files, format version 1.0 (little-endian, C order), as `np.save` writes them.

use std::path::Path;

use super::FormatWriteError;
use crate::atomic::write_bytes;

/// The element buffer of an array; each variant maps to one numpy dtype.
#[derive(Debug, Clone, PartialEq)]
pub enum NpyData {
    /// `<f4`
    F32(Vec<f32>),
    /// `<f8`
    F64(Vec<f64>),
    /// `<i4`
    I32(Vec<i32>),
    /// `<i8`
    I64(Vec<i64>),
    /// `<u4`
    U32(Vec<u32>),
    /// `|u1`
    U8(Vec<u8>),
}

impl NpyData {
    fn len(&self) -> usize {
        match self {
            NpyData::F32(v) => v.len(),
            NpyData::F64(v) => v.len(),
            NpyData::I32(v) => v.len(),
            NpyData::I64(v) => v.len(),
            NpyData::U32(v) => v.len(),
            NpyData::U8(v) => v.len(),
        }
    }
}

/// A C-ordered n-dimensional array: a shape and a flat element buffer of matching length.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    shape: Vec<usize>,
    data: NpyData,
}

impl NpyArray {
    /// Checks that `data` holds `∏ shape` elements (1 for the 0-d shape `[]`).
    pub fn new(shape: Vec<usize>, data: NpyData) -> Result<Self, FormatWriteError> {
        let expected = shape.iter().product::<usize>();
        if data.len() != expected {
            return Err(FormatWriteError::ShapeMismatch {
                shape,
                expected,
                got: data.len(),
            });
        }
        Ok(Self { shape, data })
    }

    /// The array's shape.
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// The array's elements in C order.
    pub fn data(&self) -> &NpyData {
        &self.data
    }

    /// The numpy type string of the elements (`'<f4'`, …).
    pub fn descr(&self) -> &'static str {
        match self.data {
            NpyData::F32(_) => "<f4",
            NpyData::F64(_) => "<f8",
            NpyData::I32(_) => "<i4",
            NpyData::I64(_) => "<i8",
            NpyData::U32(_) => "<u4",
            NpyData::U8(_) => "|u1",
        }
    }

    /// The elements as little-endian bytes, the layout of both `.npy` files and pickled arrays.
    pub fn le_bytes(&self) -> Vec<u8> {
        fn flat<const N: usize, T: Copy>(v: &[T], f: impl Fn(T) -> [u8; N]) -> Vec<u8> {
            v.iter().flat_map(|&x| f(x)).collect()
        }
        match &self.data {
            NpyData::F32(v) => flat(v, f32::to_le_bytes),
            NpyData::F64(v) => flat(v, f64::to_le_bytes),
            NpyData::I32(v) => flat(v, i32::to_le_bytes),
            NpyData::I64(v) => flat(v, i64::to_le_bytes),
            NpyData::U32(v) => flat(v, u32::to_le_bytes),
            NpyData::U8(v) => v.clone(),
        }
    }
}

/// The version-1.0 header of an array of `descr` and `shape`: magic, version, length, and the header dict
/// padded with spaces to a multiple of 64 bytes and ended by a newline, exactly as numpy writes it.
pub(crate) fn npy_header(descr: &str, shape: &[usize]) -> Result<Vec<u8>, FormatWriteError> {
    let dims = match shape {
        [] => "()".to_string(),
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(|d| d.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    };
    let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {dims}, }}");
    const PREAMBLE: usize = 10; // magic (6) + version (2) + header length (2)
    let unpadded = PREAMBLE + dict.len() + 1;
    dict.extend(std::iter::repeat_n(
        ' ',
        unpadded.next_multiple_of(64) - unpadded,
    ));
    dict.push('\n');
    let len = u16::try_from(dict.len()).map_err(|_| FormatWriteError::HeaderTooLong {
        shape: shape.to_vec(),
        len: dict.len(),
    })?;
    let mut out = Vec::with_capacity(PREAMBLE + dict.len());
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(dict.as_bytes());
    Ok(out)
}

/// The complete `.npy` file of `array`.
pub fn npy_bytes(array: &NpyArray) -> Result<Vec<u8>, FormatWriteError> {
    let mut out = npy_header(array.descr(), &array.shape)?;
    out.extend(array.le_bytes());
    Ok(out)
}

/// Writes `array` to `path` as a `.npy` file (atomically).
pub fn write_npy(path: &Path, array: &NpyArray) -> Result<(), FormatWriteError> {
    Ok(write_bytes(path, &npy_bytes(array)?)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_is_numpy_byte_for_byte() {
        // `np.save` of a float32 (2, 3) array starts with exactly these 128 bytes.
        let a = NpyArray::new(vec![2, 3], NpyData::F32(vec![0.0; 6])).unwrap();
        let bytes = npy_bytes(&a).unwrap();
        let dict = "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 3), }";
        assert_eq!(&bytes[..8], b"\x93NUMPY\x01\x00");
        assert_eq!(u16::from_le_bytes([bytes[8], bytes[9]]), 118);
        assert_eq!(&bytes[10..10 + dict.len()], dict.as_bytes());
        assert_eq!(bytes[127], b'\n');
        assert!(bytes[10 + dict.len()..127].iter().all(|&b| b == b' '));
        assert_eq!(bytes.len(), 128 + 24);
    }

    #[test]
    fn mismatched_shapes_are_rejected() {
        let err = NpyArray::new(vec![4, 3], NpyData::U8(vec![0; 11])).unwrap_err();
        assert!(
            err.to_string().contains("needs 12 elements, got 11"),
            "{err}"
        );
    }
}
