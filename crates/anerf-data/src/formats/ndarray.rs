//! Numeric n-dimensional arrays as NumPy holds them: element types, the `descr` strings that name them,
//! C-order data with its shape, and decoding from raw bytes. Shared by the `.npy`/`.npz` readers and the
//! unpickler (numpy arrays inside pickles).

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
    pub fn parse(s: &str) -> Result<Self, ArrayError> {
        let unsupported = || ArrayError::UnsupportedDtype(s.to_string());
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

/// Raw bytes that do not decode to an array: an element type anerf does not read, or a byte count that
/// does not fill the shape.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ArrayError {
    #[error(
        "unsupported dtype {0:?} (expected one of f4 f8 i4 i8 u4 u1 b1, an object array, or fixed-width \
         strings)"
    )]
    UnsupportedDtype(String),
    #[error("shape {0:?} overflows")]
    ShapeOverflow(Vec<usize>),
    #[error("data has {got} bytes, shape {shape:?} of {dtype:?} needs {needed}")]
    ByteCount {
        got: usize,
        shape: Vec<usize>,
        dtype: DType,
        needed: usize,
    },
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
    ) -> Result<Self, ArrayError> {
        let needed = element_count(&shape)
            .and_then(|count| count.checked_mul(dtype.size()))
            .ok_or_else(|| ArrayError::ShapeOverflow(shape.clone()))?;
        if bytes.len() != needed {
            return Err(ArrayError::ByteCount {
                got: bytes.len(),
                shape,
                dtype,
                needed,
            });
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
