//! Writer of the pickled object arrays that `np.save(path, some_dict)` produces (`annots.npy`,
//! `new_params/*.npy`): an `.npy` file of dtype `|O` and shape `()` whose payload is a pickle of a 0-d
//! object ndarray holding the value.
//!
//! The pickle uses protocol 3, as numpy 1.x's `np.save` did when the datasets were made: arrays are
//! rebuilt through `numpy.core.multiarray._reconstruct`, `numpy.dtype` and `BUILD`, their buffers are
//! `BINBYTES`. (Protocol 2 has no bytes opcode; Python would route buffers through `_codecs.encode`, a
//! global that restricted readers rightly refuse.) No memo is written: every object is spelled out.

use std::path::Path;

use super::ndarray::NdArray;
use super::npy_write::npy_header;
use super::FormatWriteError;
use crate::atomic::write_bytes;

/// The Python values the datasets' pickles are made of.
#[derive(Debug, Clone, PartialEq)]
pub enum PyValue {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    List(Vec<PyValue>),
    /// A dict with string keys, in insertion order (as Python keeps it).
    Dict(Vec<(String, PyValue)>),
    Array(NdArray),
}

impl PyValue {
    /// A dict from `(key, value)` pairs.
    pub fn dict<K: Into<String>>(items: impl IntoIterator<Item = (K, PyValue)>) -> Self {
        PyValue::Dict(items.into_iter().map(|(k, v)| (k.into(), v)).collect())
    }
}

mod op {
    pub const PROTO: u8 = 0x80;
    pub const STOP: u8 = b'.';
    pub const GLOBAL: u8 = b'c';
    pub const REDUCE: u8 = b'R';
    pub const BUILD: u8 = b'b';
    pub const MARK: u8 = b'(';
    pub const TUPLE: u8 = b't';
    pub const EMPTY_TUPLE: u8 = b')';
    pub const TUPLE3: u8 = 0x87;
    pub const EMPTY_LIST: u8 = b']';
    pub const APPEND: u8 = b'a';
    pub const APPENDS: u8 = b'e';
    pub const EMPTY_DICT: u8 = b'}';
    pub const SETITEMS: u8 = b'u';
    pub const NONE: u8 = b'N';
    pub const NEWTRUE: u8 = 0x88;
    pub const NEWFALSE: u8 = 0x89;
    pub const BININT1: u8 = b'K';
    pub const BININT: u8 = b'J';
    pub const LONG1: u8 = 0x8a;
    pub const BINFLOAT: u8 = b'G';
    pub const BINUNICODE: u8 = b'X';
    pub const SHORT_BINBYTES: u8 = b'C';
    pub const BINBYTES: u8 = b'B';
}

/// The complete `.npy` file that `np.save(path, value)` writes for a non-array `value`: `np.load(path,
/// allow_pickle=True).item()` gives `value` back.
pub fn object_npy_bytes(value: &PyValue) -> Result<Vec<u8>, FormatWriteError> {
    let mut p = Pickler(vec![op::PROTO, 3]);
    p.ndarray_prefix();
    p.0.push(op::MARK);
    p.int(1);
    p.0.push(op::EMPTY_TUPLE);
    p.dtype("O8", "|", 63);
    p.0.push(op::NEWFALSE);
    p.0.push(op::EMPTY_LIST);
    p.value(value)?;
    p.0.push(op::APPEND);
    p.0.extend([op::TUPLE, op::BUILD, op::STOP]);
    let mut out = npy_header("|O", &[])?;
    out.extend(p.0);
    Ok(out)
}

/// Writes `value` to `path` as `np.save` would (atomically).
pub fn write_object_npy(path: &Path, value: &PyValue) -> Result<(), FormatWriteError> {
    Ok(write_bytes(path, &object_npy_bytes(value)?)?)
}

struct Pickler(Vec<u8>);

impl Pickler {
    fn value(&mut self, value: &PyValue) -> Result<(), FormatWriteError> {
        match value {
            PyValue::None => self.0.push(op::NONE),
            PyValue::Bool(b) => self.0.push(if *b { op::NEWTRUE } else { op::NEWFALSE }),
            PyValue::Int(i) => self.int(*i),
            PyValue::Float(f) => {
                self.0.push(op::BINFLOAT);
                self.0.extend(f.to_be_bytes());
            }
            PyValue::Str(s) => self.str(s),
            PyValue::List(items) => {
                self.0.push(op::EMPTY_LIST);
                if !items.is_empty() {
                    self.0.push(op::MARK);
                    for v in items {
                        self.value(v)?;
                    }
                    self.0.push(op::APPENDS);
                }
            }
            PyValue::Dict(items) => {
                self.0.push(op::EMPTY_DICT);
                if !items.is_empty() {
                    self.0.push(op::MARK);
                    for (k, v) in items {
                        self.str(k);
                        self.value(v)?;
                    }
                    self.0.push(op::SETITEMS);
                }
            }
            PyValue::Array(a) => self.array(a)?,
        }
        Ok(())
    }

    fn int(&mut self, i: i64) {
        if let Ok(small) = u8::try_from(i) {
            self.0.extend([op::BININT1, small]);
        } else if let Ok(word) = i32::try_from(i) {
            self.0.push(op::BININT);
            self.0.extend(word.to_le_bytes());
        } else {
            // Two's complement, little-endian, as Python's encode_long.
            self.0.extend([op::LONG1, 8]);
            self.0.extend(i.to_le_bytes());
        }
    }

    fn str(&mut self, s: &str) {
        self.0.push(op::BINUNICODE);
        self.0.extend((s.len() as u32).to_le_bytes());
        self.0.extend(s.as_bytes());
    }

    fn global(&mut self, module: &str, name: &str) {
        self.0.push(op::GLOBAL);
        self.0.extend(format!("{module}\n{name}\n").as_bytes());
    }

    /// `_reconstruct(ndarray, (0,), b'b')`: the empty array that `BUILD` then fills.
    fn ndarray_prefix(&mut self) {
        self.global("numpy.core.multiarray", "_reconstruct");
        self.global("numpy", "ndarray");
        self.0.push(op::MARK);
        self.int(0);
        self.0.push(op::TUPLE);
        self.0.extend([op::SHORT_BINBYTES, 1, b'b']);
        self.0.extend([op::TUPLE3, op::REDUCE]);
    }

    /// `dtype(code, False, True)` with its `__setstate__` tuple `(3, order, None, None, None, -1, -1, flags)`.
    fn dtype(&mut self, code: &str, byte_order: &str, flags: i64) {
        self.global("numpy", "dtype");
        self.0.push(op::MARK);
        self.str(code);
        self.0
            .extend([op::NEWFALSE, op::NEWTRUE, op::TUPLE, op::REDUCE, op::MARK]);
        self.int(3);
        self.str(byte_order);
        self.0.extend([op::NONE, op::NONE, op::NONE]);
        self.int(-1);
        self.int(-1);
        self.int(flags);
        self.0.extend([op::TUPLE, op::BUILD]);
    }

    /// An ndarray: `_reconstruct(...)` then `BUILD` with `(1, shape, dtype, is_fortran, raw bytes)`.
    fn array(&mut self, a: &NdArray) -> Result<(), FormatWriteError> {
        self.ndarray_prefix();
        self.0.push(op::MARK);
        self.int(1);
        self.0.push(op::MARK);
        a.shape().iter().for_each(|&d| self.int(d as i64));
        self.0.push(op::TUPLE);
        let (byte_order, code) = a.dtype().descr().split_at(1);
        self.dtype(code, byte_order, 0);
        self.0.push(op::NEWFALSE);
        let bytes = a.le_bytes();
        match u8::try_from(bytes.len()) {
            Ok(n) => self.0.extend([op::SHORT_BINBYTES, n]),
            Err(_) => {
                let len = u32::try_from(bytes.len()).map_err(|_| {
                    FormatWriteError::PickledArrayTooLarge {
                        shape: a.shape().to_vec(),
                        bytes: bytes.len(),
                    }
                })?;
                self.0.push(op::BINBYTES);
                self.0.extend(len.to_le_bytes());
            }
        }
        self.0.extend(bytes);
        self.0.extend([op::TUPLE, op::BUILD]);
        Ok(())
    }
}
