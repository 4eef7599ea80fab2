//! Writer of numpy `.npy` files, format version 1.0 (little-endian, C order), as `np.save` writes them.

use std::path::Path;

use super::ndarray::NdArray;
use super::FormatWriteError;
use crate::atomic::write_bytes;

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
pub fn npy_bytes(array: &NdArray) -> Result<Vec<u8>, FormatWriteError> {
    let mut out = npy_header(array.dtype().descr(), array.shape())?;
    out.extend(array.le_bytes());
    Ok(out)
}

/// Writes `array` to `path` as a `.npy` file (atomically).
pub fn write_npy(path: &Path, array: &NdArray) -> Result<(), FormatWriteError> {
    Ok(write_bytes(path, &npy_bytes(array)?)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::ArrayData;

    #[test]
    fn header_is_numpy_byte_for_byte() {
        // `np.save` of a float32 (2, 3) array starts with exactly these 128 bytes.
        let a = NdArray::new(vec![2, 3], ArrayData::F32(vec![0.0; 6])).unwrap();
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
        let err = NdArray::new(vec![4, 3], ArrayData::U8(vec![0; 11])).unwrap_err();
        assert!(
            err.to_string().contains("needs 12 elements, got 11"),
            "{err}"
        );
    }
}
