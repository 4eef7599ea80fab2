//! Reader for NumPy's `.npy` format (header versions 1–3; C and Fortran order; little- and big-endian
//! `f4 f8 i4 i8 u4 u1 b1`). Object arrays (`np.save` of a dict) hold a pickle, read by
//! [`super::pickle`]. Every size is checked against the bytes actually present before anything is allocated.

use thiserror::Error;

use super::pickle::{self, PickleError, Value};

/// Element types anerf reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DType {
    F32,
    F64,
    I32,
    I64,
    U32,
    U8,
    Bool,
}

impl DType {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            DType::F32 | DType::I32 | DType::U32 => 4,
            DType::F64 | DType::I64 => 8,
            DType::U8 | DType::Bool => 1,
        }
    }

    /// The little-endian numpy type string the writers use (`'<f4'`, `'|u1'`, …).
    pub fn descr(self) -> &'static str {
        match self {
            DType::F32 => "<f4",
            DType::F64 => "<f8",
            DType::I32 => "<i4",
            DType::I64 => "<i8",
            DType::U32 => "<u4",
            DType::U8 => "|u1",
            DType::Bool => "|b1",
        }
    }

    fn from_kind(kind: char, size: usize) -> Option<Self> {
        Some(match (kind, size) {
            ('f', 4) => DType::F32,
            ('f', 8) => DType::F64,
            ('i', 4) => DType::I32,
            ('i', 8) => DType::I64,
            ('u', 4) => DType::U32,
            ('u', 1) => DType::U8,
            ('b', 1) => DType::Bool,
            _ => return None,
        })
    }
}

/// A NumPy type description (`'<f4'`, `'|O'`, `'<U12'`, …) as far as anerf understands it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Descr {
    Numeric {
        dtype: DType,
        big_endian: bool,
    },
    /// Python objects (stored as a pickle).
    Object,
    /// Fixed-width UTF-32 strings of this many characters.
    Unicode {
        chars: usize,
        big_endian: bool,
    },
    /// Fixed-width byte strings of this many bytes.
    Bytes {
        len: usize,
    },
}

impl Descr {
    /// Parses a type string such as `<f8`, `|b1`, `>i4`, `|O`, `<U7`, `|S5` (also without the byte-order
    /// character, as in pickled `dtype('f8')`; `big_endian` then comes from the caller).
    pub fn parse(s: &str) -> Result<Self, String> {
        let unsupported = || {
            format!(
                "unsupported dtype {s:?} (expected one of f4 f8 i4 i8 u4 u1 b1, an object array, or \
                 fixed-width strings)"
            )
        };
        let (big_endian, rest) = match s.chars().next() {
            Some('>') => (true, &s[1..]),
            Some('<' | '|' | '=') => (false, &s[1..]),
            _ => (false, s),
        };
        let mut chars = rest.chars();
        let kind = chars.next().ok_or_else(unsupported)?;
        let digits = chars.as_str();
        let size = if digits.is_empty() {
            None
        } else {
            Some(digits.parse::<usize>().map_err(|_| unsupported())?)
        };
        match (kind, size) {
            ('O', None | Some(8) | Some(4)) => Ok(Descr::Object),
            ('U', Some(n)) => Ok(Descr::Unicode {
                chars: n,
                big_endian,
            }),
            ('S', Some(n)) => Ok(Descr::Bytes { len: n }),
            ('?', None) => Ok(Descr::Numeric {
                dtype: DType::Bool,
                big_endian,
            }),
            (k, Some(n)) => DType::from_kind(k, n)
                .map(|dtype| Descr::Numeric { dtype, big_endian })
                .ok_or_else(unsupported),
            _ => Err(unsupported()),
        }
    }

    /// Bytes per element, when fixed (`None` for objects).
    pub fn item_size(&self) -> Option<usize> {
        match *self {
            Descr::Numeric { dtype, .. } => Some(dtype.size()),
            Descr::Object => None,
            Descr::Unicode { chars, .. } => chars.checked_mul(4),
            Descr::Bytes { len } => Some(len),
        }
    }
}

/// Typed element storage, C order.
#[derive(Debug, Clone, PartialEq)]
pub enum ArrayData {
    F32(Vec<f32>),
    F64(Vec<f64>),
    I32(Vec<i32>),
    I64(Vec<i64>),
    U32(Vec<u32>),
    U8(Vec<u8>),
    Bool(Vec<bool>),
}

/// Elements that do not fill a shape (`∏ shape` elements, 1 for the 0-d shape `[]`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("array of shape {shape:?} needs {} elements, got {got}", element_count(shape).map_or("more than usize::MAX".to_string(), |n| n.to_string()))]
pub struct ShapeMismatch {
    pub shape: Vec<usize>,
    pub got: usize,
}

/// An n-dimensional numeric array, always in C (row-major) order; what the readers return and the writers
/// take.
#[derive(Debug, Clone, PartialEq)]
pub struct NdArray {
    shape: Vec<usize>,
    data: ArrayData,
}

impl NdArray {
    /// Wraps data of the given shape; fails when the element count does not match.
    pub fn new(shape: Vec<usize>, data: ArrayData) -> Result<Self, ShapeMismatch> {
        let arr = Self { shape, data };
        let got = arr.len();
        if element_count(&arr.shape) != Some(got) {
            return Err(ShapeMismatch {
                shape: arr.shape,
                got,
            });
        }
        Ok(arr)
    }

    /// The shape (empty for a scalar).
    pub fn shape(&self) -> &[usize] {
        &self.shape
    }

    /// The element type.
    pub fn dtype(&self) -> DType {
        match self.data {
            ArrayData::F32(_) => DType::F32,
            ArrayData::F64(_) => DType::F64,
            ArrayData::I32(_) => DType::I32,
            ArrayData::I64(_) => DType::I64,
            ArrayData::U32(_) => DType::U32,
            ArrayData::U8(_) => DType::U8,
            ArrayData::Bool(_) => DType::Bool,
        }
    }

    /// The typed elements.
    pub fn data(&self) -> &ArrayData {
        &self.data
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        match &self.data {
            ArrayData::F32(v) => v.len(),
            ArrayData::F64(v) => v.len(),
            ArrayData::I32(v) => v.len(),
            ArrayData::I64(v) => v.len(),
            ArrayData::U32(v) => v.len(),
            ArrayData::U8(v) => v.len(),
            ArrayData::Bool(v) => v.len(),
        }
    }

    /// True when the array holds no element.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// All elements converted to `f64` (exact for every supported type but 64-bit integers beyond 2⁵³).
    pub fn to_f64(&self) -> Vec<f64> {
        match &self.data {
            ArrayData::F32(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::F64(v) => v.clone(),
            ArrayData::I32(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::I64(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::U32(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::U8(v) => v.iter().map(|&x| x as f64).collect(),
            ArrayData::Bool(v) => v.iter().map(|&x| x as u8 as f64).collect(),
        }
    }

    /// All elements converted to `f32`.
    pub fn to_f32(&self) -> Vec<f32> {
        match &self.data {
            ArrayData::F32(v) => v.clone(),
            _ => self.to_f64().into_iter().map(|x| x as f32).collect(),
        }
    }

    /// All elements as `i64`; `None` for floating-point arrays.
    pub fn to_i64(&self) -> Option<Vec<i64>> {
        Some(match &self.data {
            ArrayData::F32(_) | ArrayData::F64(_) => return None,
            ArrayData::I32(v) => v.iter().map(|&x| x as i64).collect(),
            ArrayData::I64(v) => v.clone(),
            ArrayData::U32(v) => v.iter().map(|&x| x as i64).collect(),
            ArrayData::U8(v) => v.iter().map(|&x| x as i64).collect(),
            ArrayData::Bool(v) => v.iter().map(|&x| x as i64).collect(),
        })
    }

    /// The elements as little-endian bytes in C order, the layout of `.npy` files and pickled arrays.
    pub fn le_bytes(&self) -> Vec<u8> {
        fn flat<const N: usize, T: Copy>(v: &[T], f: impl Fn(T) -> [u8; N]) -> Vec<u8> {
            v.iter().flat_map(|&x| f(x)).collect()
        }
        match &self.data {
            ArrayData::F32(v) => flat(v, f32::to_le_bytes),
            ArrayData::F64(v) => flat(v, f64::to_le_bytes),
            ArrayData::I32(v) => flat(v, i32::to_le_bytes),
            ArrayData::I64(v) => flat(v, i64::to_le_bytes),
            ArrayData::U32(v) => flat(v, u32::to_le_bytes),
            ArrayData::U8(v) => v.clone(),
            ArrayData::Bool(v) => v.iter().map(|&b| b as u8).collect(),
        }
    }

    /// Decodes `count = Π shape` elements from raw bytes in NumPy's layout (C or Fortran order).
    pub fn from_bytes(
        dtype: DType,
        big_endian: bool,
        shape: Vec<usize>,
        fortran: bool,
        bytes: &[u8],
    ) -> Result<Self, String> {
        let count = element_count(&shape).ok_or_else(|| format!("shape {shape:?} overflows"))?;
        let needed = count
            .checked_mul(dtype.size())
            .ok_or_else(|| format!("shape {shape:?} overflows"))?;
        if bytes.len() != needed {
            return Err(format!(
                "data has {} bytes, shape {shape:?} of {dtype:?} needs {needed}",
                bytes.len()
            ));
        }
        macro_rules! decode {
            ($t:ty, $n:expr) => {
                bytes
                    .chunks_exact($n)
                    .map(|c| {
                        let a: [u8; $n] = c.try_into().expect("chunk of element size");
                        if big_endian {
                            <$t>::from_be_bytes(a)
                        } else {
                            <$t>::from_le_bytes(a)
                        }
                    })
                    .collect::<Vec<$t>>()
            };
        }
        let mut data = match dtype {
            DType::F32 => ArrayData::F32(decode!(f32, 4)),
            DType::F64 => ArrayData::F64(decode!(f64, 8)),
            DType::I32 => ArrayData::I32(decode!(i32, 4)),
            DType::I64 => ArrayData::I64(decode!(i64, 8)),
            DType::U32 => ArrayData::U32(decode!(u32, 4)),
            DType::U8 => ArrayData::U8(bytes.to_vec()),
            DType::Bool => ArrayData::Bool(bytes.iter().map(|&b| b != 0).collect()),
        };
        if fortran && shape.len() > 1 {
            data = fortran_to_c(&data, &shape);
        }
        Ok(Self { shape, data })
    }
}

/// `Π shape`, `None` on overflow.
pub(crate) fn element_count(shape: &[usize]) -> Option<usize> {
    shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

/// Reorders Fortran-order (first index fastest) elements into C order.
fn fortran_to_c(data: &ArrayData, shape: &[usize]) -> ArrayData {
    fn permute<T: Copy>(v: &[T], shape: &[usize]) -> Vec<T> {
        let n = v.len();
        let mut out = Vec::with_capacity(n);
        let mut idx = vec![0usize; shape.len()];
        // Fortran strides: stride[0] = 1, stride[k] = stride[k-1] * shape[k-1].
        let mut strides = vec![1usize; shape.len()];
        for k in 1..shape.len() {
            strides[k] = strides[k - 1] * shape[k - 1];
        }
        for _ in 0..n {
            let f: usize = idx.iter().zip(&strides).map(|(i, s)| i * s).sum();
            out.push(v[f]);
            for k in (0..shape.len()).rev() {
                idx[k] += 1;
                if idx[k] < shape[k] {
                    break;
                }
                idx[k] = 0;
            }
        }
        out
    }
    match data {
        ArrayData::F32(v) => ArrayData::F32(permute(v, shape)),
        ArrayData::F64(v) => ArrayData::F64(permute(v, shape)),
        ArrayData::I32(v) => ArrayData::I32(permute(v, shape)),
        ArrayData::I64(v) => ArrayData::I64(permute(v, shape)),
        ArrayData::U32(v) => ArrayData::U32(permute(v, shape)),
        ArrayData::U8(v) => ArrayData::U8(permute(v, shape)),
        ArrayData::Bool(v) => ArrayData::Bool(permute(v, shape)),
    }
}

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
    #[error("{0}")]
    Data(String),
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
            let arr = NdArray::from_bytes(dtype, big_endian, header.shape, header.fortran, body)
                .map_err(NpyError::Data)?;
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
                descr = Some(Descr::parse(&p.string()?)?);
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
