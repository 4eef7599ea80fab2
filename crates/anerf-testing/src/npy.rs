//! Hand-written `.npy` headers, for tests that build archives byte by byte (a member streamed from zeros,
//! a Fortran-order member, a header that claims more than its data holds).

/// A version-1 `.npy` header for little-endian float64 of `shape`, declaring `fortran` order, padded as
/// numpy pads it (header length a multiple of 64, ending in a newline).
pub fn npy_f64_header(shape: &[usize], fortran: bool) -> Vec<u8> {
    let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
    let shape = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let order = if fortran { "True" } else { "False" };
    let mut dict = format!("{{'descr': '<f8', 'fortran_order': {order}, 'shape': {shape}, }}");
    while (10 + dict.len() + 1) % 64 != 0 {
        dict.push(' ');
    }
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((dict.len() as u16).to_le_bytes());
    out.extend(dict.as_bytes());
    out
}
