//! Reader for NumPy's `.npy` format (header versions 1–3; C and Fortran order; little- and big-endian
//! `f4 f8 i4 i8 u4 u1 b1`). Object arrays (`np.save` of a dict) hold a pickle, read by
//! [`super::pickle`]. Every size is checked against the bytes actually present before anything is allocated.

use thiserror::Error;

use super::ndarray::{ArrayError, Descr, NdArray};
use super::pickle::{self, PickleError, Value};

/// Why a `.npy` file could not be read.
#[derive(Debug, Error)]
pub enum NpyError {
    #[error("not a .npy file (expected the magic bytes \\x93NUMPY)")]
    Magic,
    #[error("file is truncated: {0}")]
    Truncated(String),
    #[error("unsupported .npy format version {0}.{1} (expected 1.0, 2.0 or 3.0)")]
    Version(u8, u8),
    #[error("header {header:?} is malformed: {reason}")]
    Header { header: String, reason: String },
    #[error(transparent)]
    Array(#[from] ArrayError),
    #[error("holds {0}, expected a numeric array")]
    NotNumeric(String),
    #[error("holds a numeric array, expected a pickled object (np.save of a dict)")]
    NotObject,
    #[error("pickled object: {0}")]
    Pickle(#[from] PickleError),
}

/// The contents of a `.npy` file.
#[derive(Debug, Clone, PartialEq)]
pub enum Npy {
    Array(NdArray),
    /// An object array (`np.save(dict)` gives a 0-d one; `.item()` of it is the dict).
    Object(Value),
}

/// A `.npy` header: the element type, whether the data is in Fortran order, and the shape.
#[derive(Debug, Clone, PartialEq)]
pub struct Header {
    pub descr: Descr,
    pub fortran: bool,
    pub shape: Vec<usize>,
}

/// The header of a `.npy` file (element type, order, shape) from its first bytes alone (the data is not
/// needed), and the offset in bytes at which its data starts.
pub fn peek_header(bytes: &[u8]) -> Result<(Header, usize), NpyError> {
    let (header, body) = split_header(bytes)?;
    Ok((header, bytes.len() - body.len()))
}

/// The parsed header of a `.npy` file and the data after it.
fn split_header(bytes: &[u8]) -> Result<(Header, &[u8]), NpyError> {
    if bytes.len() < 8 || &bytes[..6] != b"\x93NUMPY" {
        return Err(NpyError::Magic);
    }
    let (major, minor) = (bytes[6], bytes[7]);
    let (len_bytes, utf8) = match major {
        1 => (2, false),
        2 => (4, false),
        3 => (4, true),
        _ => return Err(NpyError::Version(major, minor)),
    };
    let start = 8 + len_bytes;
    if bytes.len() < start {
        return Err(NpyError::Truncated("header length missing".into()));
    }
    let header_len = if len_bytes == 2 {
        u16::from_le_bytes([bytes[8], bytes[9]]) as usize
    } else {
        u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize
    };
    let end = start
        .checked_add(header_len)
        .filter(|&e| e <= bytes.len())
        .ok_or_else(|| {
            NpyError::Truncated(format!(
                "header of {header_len} bytes, only {} present",
                bytes.len() - start
            ))
        })?;
    let raw = &bytes[start..end];
    let text = if utf8 {
        std::str::from_utf8(raw).map_err(|e| NpyError::Header {
            header: String::from_utf8_lossy(raw).into_owned(),
            reason: e.to_string(),
        })?
    } else {
        if !raw.is_ascii() {
            return Err(NpyError::Header {
                header: String::from_utf8_lossy(raw).into_owned(),
                reason: "not ASCII".into(),
            });
        }
        std::str::from_utf8(raw).expect("ASCII is UTF-8")
    };
    let header = parse_header(text).map_err(|reason| NpyError::Header {
        header: text.trim_end().to_string(),
        reason,
    })?;
    Ok((header, &bytes[end..]))
}

/// Parses a whole `.npy` file.
pub fn parse(bytes: &[u8]) -> Result<Npy, NpyError> {
    let (header, body) = split_header(bytes)?;
    match header.descr {
        Descr::Numeric { dtype, big_endian } => {
            let arr = NdArray::from_bytes(dtype, big_endian, header.shape, header.fortran, body)?;
            Ok(Npy::Array(arr))
        }
        Descr::Object => Ok(Npy::Object(pickle::parse(body)?)),
        other => Err(NpyError::NotNumeric(format!("{other:?}"))),
    }
}

/// Parses a numeric `.npy` file.
pub fn parse_array(bytes: &[u8]) -> Result<NdArray, NpyError> {
    match parse(bytes)? {
        Npy::Array(a) => Ok(a),
        Npy::Object(_) => Err(NpyError::NotNumeric("a pickled object".into())),
    }
}

/// Parses an object `.npy` file (`np.save(dict)`) and returns the object, unwrapping a 0-d object array
/// the way `.item()` does.
pub fn parse_object(bytes: &[u8]) -> Result<Value, NpyError> {
    match parse(bytes)? {
        Npy::Object(v) => Ok(v.item()),
        Npy::Array(_) => Err(NpyError::NotObject),
    }
}

/// Parses the header dict `{'descr': '<f4', 'fortran_order': False, 'shape': (3, 4), }`.
fn parse_header(text: &str) -> Result<Header, String> {
    let mut p = Lit {
        s: text.trim().as_bytes(),
        i: 0,
    };
    p.expect(b'{')?;
    let (mut descr, mut fortran, mut shape) = (None, None, None);
    loop {
        p.skip_ws();
        if p.eat(b'}') {
            break;
        }
        let key = p.string()?;
        p.skip_ws();
        p.expect(b':')?;
        p.skip_ws();
        match key.as_str() {
            "descr" => {
                if p.peek() == Some(b'[') {
                    return Err("structured dtypes are not supported".into());
                }
                descr = Some(Descr::parse(&p.string()?).map_err(|e| e.to_string())?);
            }
            "fortran_order" => fortran = Some(p.boolean()?),
            "shape" => shape = Some(p.shape()?),
            other => return Err(format!("unexpected key {other:?}")),
        }
        p.skip_ws();
        if !p.eat(b',') {
            p.skip_ws();
            p.expect(b'}')?;
            break;
        }
    }
    Ok(Header {
        descr: descr.ok_or("no 'descr'")?,
        fortran: fortran.ok_or("no 'fortran_order'")?,
        shape: shape.ok_or("no 'shape'")?,
    })
}

/// A cursor over the Python literal of a `.npy` header.
struct Lit<'a> {
    s: &'a [u8],
    i: usize,
}

impl Lit<'_> {
    fn peek(&self) -> Option<u8> {
        self.s.get(self.i).copied()
    }
    fn skip_ws(&mut self) {
        while matches!(self.peek(), Some(b' ' | b'\t' | b'\n' | b'\r')) {
            self.i += 1;
        }
    }
    fn eat(&mut self, c: u8) -> bool {
        if self.peek() == Some(c) {
            self.i += 1;
            true
        } else {
            false
        }
    }
    fn expect(&mut self, c: u8) -> Result<(), String> {
        if self.eat(c) {
            Ok(())
        } else {
            Err(format!("expected {:?} at byte {}", c as char, self.i))
        }
    }
    fn string(&mut self) -> Result<String, String> {
        let q = self.peek().filter(|c| *c == b'\'' || *c == b'"');
        let q = q.ok_or_else(|| format!("expected a string at byte {}", self.i))?;
        self.i += 1;
        let start = self.i;
        while self.peek().is_some_and(|c| c != q) {
            self.i += 1;
        }
        let s = String::from_utf8_lossy(&self.s[start..self.i]).into_owned();
        self.expect(q)?;
        Ok(s)
    }
    fn boolean(&mut self) -> Result<bool, String> {
        for (word, v) in [(&b"True"[..], true), (&b"False"[..], false)] {
            if self.s[self.i..].starts_with(word) {
                self.i += word.len();
                return Ok(v);
            }
        }
        Err(format!("expected True or False at byte {}", self.i))
    }
    fn shape(&mut self) -> Result<Vec<usize>, String> {
        self.expect(b'(')?;
        let mut dims = Vec::new();
        loop {
            self.skip_ws();
            if self.eat(b')') {
                return Ok(dims);
            }
            let start = self.i;
            while self.peek().is_some_and(|c| c.is_ascii_digit()) {
                self.i += 1;
            }
            let digits = std::str::from_utf8(&self.s[start..self.i]).expect("ASCII digits");
            let d = digits
                .parse::<usize>()
                .map_err(|_| format!("expected a dimension at byte {start}"))?;
            dims.push(d);
            self.skip_ws();
            if !self.eat(b',') {
                self.skip_ws();
                self.expect(b')')?;
                return Ok(dims);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(version: u8, header: &str, body: &[u8]) -> Vec<u8> {
        let mut out = b"\x93NUMPY".to_vec();
        out.extend([version, 0]);
        if version == 1 {
            out.extend((header.len() as u16).to_le_bytes());
        } else {
            out.extend((header.len() as u32).to_le_bytes());
        }
        out.extend(header.as_bytes());
        out.extend(body);
        out
    }

    #[test]
    fn fortran_order_is_transposed_to_c_order() {
        // np.asfortranarray(np.arange(6, dtype='<i4').reshape(2, 3)) stores 0 3 1 4 2 5.
        let body: Vec<u8> = [0i32, 3, 1, 4, 2, 5]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let bytes = npy(
            1,
            "{'descr': '<i4', 'fortran_order': True, 'shape': (2, 3), }\n",
            &body,
        );
        let a = parse_array(&bytes).unwrap();
        assert_eq!(a.shape(), &[2, 3]);
        assert_eq!(a.to_i64().unwrap(), vec![0, 1, 2, 3, 4, 5]);
    }

    #[test]
    fn malformed_headers_and_bodies_are_errors() {
        let body = [0u8; 8];
        for (header, needle) in [
            ("{'descr': '<c8', 'fortran_order': False, 'shape': (1,), }", "dtype"),
            ("{'descr': '<f4', 'shape': (2,), }", "fortran_order"),
            ("{'descr': '<f4', 'fortran_order': False, 'shape': (3,), }", "needs 12"),
            ("{'descr': [('a', '<f4')], 'fortran_order': False, 'shape': (2,), }", "structured"),
            (
                "{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999999, 99999999999999, 9999), }",
                "overflow",
            ),
        ] {
            let err = parse(&npy(1, header, &body)).unwrap_err().to_string();
            assert!(err.contains(needle), "{header}: {err}");
        }
        assert!(matches!(
            parse(b"\x93NUMPY\x09\x00"),
            Err(NpyError::Version(9, 0))
        ));
        assert!(matches!(parse(b"PK\x03\x04"), Err(NpyError::Magic)));
        let truncated = &npy(
            2,
            "{'descr': '<f4', 'fortran_order': False, 'shape': (), }",
            &[],
        )[..14];
        assert!(matches!(parse(truncated), Err(NpyError::Truncated(_))));
    }
}
