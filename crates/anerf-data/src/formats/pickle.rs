//! A restricted unpickler for the pickles inside object `.npy` files (`annots.npy`, `new_params/*.npy`)
//! and for `.pkl` body-model files.
//!
//! It understands pickle protocols 2–5 (and the few protocol-0 opcodes that Python 2 pickles mix in) and
//! builds plain data: `None`, bools, ints, floats, strings, bytes, lists, tuples, dicts, sets (as lists),
//! NumPy arrays and scalars. A global is only ever *recognised*, never looked up or called: the numpy
//! reconstruction helpers below are re-implemented here as data transformations, and any other global is
//! refused with an error naming it. Hostile input gives an error, never a panic: every length is checked
//! against the bytes left, the object graph lives in an arena indexed by the opcodes read (so it grows at
//! most linearly in the input), and turning it into a [`Value`] tree is bounded in depth and total size, so
//! shared or cyclic references cannot blow up. All the memory it allocates (arena, stack, memo, decoded
//! tree) is metered against a cap of [`MEMORY_FACTOR`] times the input plus [`MEMORY_SLACK`]
//! ([`memory_cap`]), so one-byte opcodes that each add an object cannot make it hold gigabytes.

use std::cell::Cell;
use std::collections::HashMap;
use std::mem::size_of;

use thiserror::Error;

use super::ndarray::{element_count, ArrayData, Descr, NdArray};

/// A decoded pickle value.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    None,
    Bool(bool),
    Int(i64),
    Float(f64),
    Str(String),
    /// Python 3 `bytes`, or a Python 2 `str`.
    Bytes(Vec<u8>),
    List(Vec<Value>),
    Tuple(Vec<Value>),
    /// Entries in insertion order.
    Dict(Vec<(Value, Value)>),
    /// A numeric ndarray or numpy scalar (shape `[]`).
    Array(NdArray),
    /// An ndarray of Python objects or fixed-width strings, C order.
    ObjectArray {
        shape: Vec<usize>,
        items: Vec<Value>,
    },
}

impl Value {
    /// What kind of value this is, for error messages.
    pub fn kind(&self) -> String {
        match self {
            Value::None => "None".into(),
            Value::Bool(_) => "a bool".into(),
            Value::Int(_) => "an int".into(),
            Value::Float(_) => "a float".into(),
            Value::Str(_) => "a string".into(),
            Value::Bytes(_) => "bytes".into(),
            Value::List(v) => format!("a list of {}", v.len()),
            Value::Tuple(v) => format!("a tuple of {}", v.len()),
            Value::Dict(_) => "a dict".into(),
            Value::Array(a) => format!("a {:?} array of shape {:?}", a.dtype(), a.shape()),
            Value::ObjectArray { shape, .. } => format!("an object array of shape {shape:?}"),
        }
    }

    /// `.item()` of a 0-d object array (what `np.load(..., allow_pickle=True).item()` does); other values
    /// are returned unchanged.
    pub fn item(self) -> Value {
        match self {
            Value::ObjectArray { shape, mut items } if shape.is_empty() && items.len() == 1 => {
                items.pop().expect("one item")
            }
            other => other,
        }
    }

    /// The value of a dict entry whose key is the string `key` (Python 3 `str` or Python 2 `str`).
    pub fn get(&self, key: &str) -> Option<&Value> {
        match self {
            Value::Dict(entries) => entries
                .iter()
                .find(|(k, _)| k.as_str().as_deref() == Some(key))
                .map(|(_, v)| v),
            _ => None,
        }
    }

    /// Dict keys that are strings.
    pub fn keys(&self) -> Vec<String> {
        match self {
            Value::Dict(entries) => entries.iter().filter_map(|(k, _)| k.as_str()).collect(),
            _ => Vec::new(),
        }
    }

    /// A string, decoding Python 2 byte strings as UTF-8 (falling back to Latin-1).
    pub fn as_str(&self) -> Option<String> {
        match self {
            Value::Str(s) => Some(s.clone()),
            Value::Bytes(b) => Some(match std::str::from_utf8(b) {
                Ok(s) => s.to_string(),
                Err(_) => b.iter().map(|&c| c as char).collect(),
            }),
            Value::Array(_) | Value::ObjectArray { .. } => None,
            _ => None,
        }
    }

    /// The elements of a list, tuple or 1-d object array.
    pub fn as_seq(&self) -> Option<&[Value]> {
        match self {
            Value::List(v) | Value::Tuple(v) => Some(v),
            Value::ObjectArray { shape, items } if shape.len() == 1 => Some(items),
            _ => None,
        }
    }

    /// A numeric array (numpy scalars are 0-d arrays).
    pub fn as_array(&self) -> Option<&NdArray> {
        match self {
            Value::Array(a) => Some(a),
            _ => None,
        }
    }
}

/// Why a pickle was not read.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum PickleError {
    #[error(
        "refused global `{0}`: only numpy array, dtype and scalar reconstruction is allowed (nothing in a \
         data file is ever executed)"
    )]
    Refused(String),
    #[error("truncated at byte {0}")]
    Truncated(usize),
    #[error("unsupported opcode 0x{op:02x} at byte {at}")]
    Opcode { op: u8, at: usize },
    #[error("malformed at byte {at}: {reason}")]
    Malformed { at: usize, reason: String },
    #[error("pickle ended without a STOP opcode")]
    NoStop,
    #[error("nesting deeper than {0} levels (or a reference cycle)")]
    TooDeep(usize),
    #[error("object graph expands beyond {0} bytes (shared references)")]
    TooLarge(usize),
    #[error(
        "unpickling would allocate more than its memory cap of {cap} bytes for a pickle of {input} bytes \
         (real files need a few times their size: this one is hostile or corrupt)"
    )]
    MemoryCap { cap: usize, input: usize },
}

/// Parses one pickle within the memory cap [`memory_cap`] of its size.
pub fn parse(bytes: &[u8]) -> Result<Value, PickleError> {
    parse_within(bytes, memory_cap(bytes.len()))
}

/// The most memory (bytes) the unpickler may allocate for an input of `input_len` bytes.
pub fn memory_cap(input_len: usize) -> usize {
    MEMORY_FACTOR
        .saturating_mul(input_len)
        .saturating_add(MEMORY_SLACK)
}

/// Real files need a few times their size (a buffer, its array, the decoded copy); hostile ones that add an
/// object per opcode would need about 170×.
pub const MEMORY_FACTOR: usize = 16;
pub const MEMORY_SLACK: usize = 64 << 20;

/// Parses one pickle, allocating at most `cap` bytes (as metered: every buffer the machine and the decoded
/// tree allocate); [`parse`] uses [`memory_cap`].
pub fn parse_within(bytes: &[u8], cap: usize) -> Result<Value, PickleError> {
    let limit = OUTPUT_FACTOR
        .saturating_mul(bytes.len())
        .saturating_add(OUTPUT_SLACK);
    let mut m = Machine {
        input: bytes,
        pos: 0,
        arena: Vec::new(),
        stack: Vec::new(),
        memo: HashMap::new(),
        built: Budget { left: limit, limit },
        meter: Meter {
            used: Cell::new(0),
            cap,
            input: bytes.len(),
        },
    };
    let root = m.run()?;
    m.to_value(root, 0, &mut Budget { left: limit, limit })
}

/// The decoded tree may be at most this many times the input (plus [`OUTPUT_SLACK`]): generous for real
/// files (arrays convert 1:1, small objects by a constant), small enough to stop exponential sharing.
const OUTPUT_FACTOR: usize = 16;
const OUTPUT_SLACK: usize = 1 << 16;
const MAX_DEPTH: usize = 100;

type Id = usize;

/// The numpy (and codec) callables this reader re-implements. Anything else is refused.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Global {
    Reconstruct,
    NdarrayClass,
    DtypeClass,
    Scalar,
    FromBuffer,
    CodecsEncode,
    /// A class whose instances are rebuilt as data from their `__dict__` (never by calling the class).
    Data(DataClass),
}

/// The classes of the original SMPL `.pkl` releases, read as the arrays they hold.
#[derive(Debug, Clone, Copy, PartialEq)]
enum DataClass {
    /// `chumpy.ch.Ch`: its array is the `x` of its state.
    Chumpy,
    /// `scipy.sparse` CSC or CSR matrices (`data`, `indices`, `indptr`, `_shape`), read as dense f64.
    Sparse { by_columns: bool },
}

impl Global {
    fn resolve(module: &str, name: &str) -> Result<Self, PickleError> {
        Ok(match (module, name) {
            ("numpy.core.multiarray" | "numpy._core.multiarray", "_reconstruct") => {
                Global::Reconstruct
            }
            ("numpy", "ndarray") => Global::NdarrayClass,
            ("numpy", "dtype") => Global::DtypeClass,
            ("numpy.core.multiarray" | "numpy._core.multiarray", "scalar") => Global::Scalar,
            // Protocol 5 pickles arrays as `_frombuffer(buffer, dtype, shape, order)`.
            ("numpy.core.numeric" | "numpy._core.numeric", "_frombuffer") => Global::FromBuffer,
            // Protocol 2 pickles from Python 3 store bytes as `_codecs.encode(text, 'latin1')`.
            ("_codecs", "encode") => Global::CodecsEncode,
            ("chumpy.ch", "Ch") => Global::Data(DataClass::Chumpy),
            ("scipy.sparse._csc" | "scipy.sparse.csc", "csc_matrix") => {
                Global::Data(DataClass::Sparse { by_columns: true })
            }
            ("scipy.sparse._csr" | "scipy.sparse.csr", "csr_matrix") => {
                Global::Data(DataClass::Sparse { by_columns: false })
            }
            _ => return Err(PickleError::Refused(format!("{module}.{name}"))),
        })
    }
}

/// Objects of the pickle machine; containers refer to others by arena index, so memo sharing and
/// mutation after memoisation behave as in Python without reference counting.
#[derive(Debug, Clone)]
enum Obj {
    Leaf(Value),
    List(Vec<Id>),
    Tuple(Vec<Id>),
    Dict(Vec<(Id, Id)>),
    Global(Global),
    /// `dtype(typestr)` awaiting its BUILD state (which carries the byte order).
    Dtype {
        typestr: String,
        big_endian: bool,
        elsize: Option<usize>,
    },
    /// `_reconstruct(ndarray, …)` awaiting its BUILD state.
    PendingArray,
    /// `NEWOBJ` of a [`DataClass`]; `state` is the dict its BUILD gave.
    Instance {
        class: DataClass,
        state: Option<Id>,
    },
    Objects {
        shape: Vec<usize>,
        items: Vec<Id>,
    },
}

#[derive(Debug, Clone, Copy)]
enum Slot {
    Mark,
    Obj(Id),
}

struct Machine<'a> {
    input: &'a [u8],
    pos: usize,
    arena: Vec<Obj>,
    stack: Vec<Slot>,
    memo: HashMap<u64, Id>,
    /// What REDUCE and BUILD may materialise in total (decoded arrays, copied strings and item lists),
    /// so that many references to one large object cannot multiply it.
    built: Budget,
    meter: Meter,
}

/// The memory allocated so far against the cap. Charges are never refunded: a growing buffer is charged in
/// full each time, which also covers the moment its old and new copies coexist.
struct Meter {
    used: Cell<usize>,
    cap: usize,
    input: usize,
}

impl Meter {
    fn charge(&self, bytes: usize) -> Result<(), PickleError> {
        let used = self.used.get().saturating_add(bytes);
        if used > self.cap {
            return Err(PickleError::MemoryCap {
                cap: self.cap,
                input: self.input,
            });
        }
        self.used.set(used);
        Ok(())
    }

    /// Room in `v` for `extra` more items, doubling its buffer as `Vec` would, charged before allocating.
    fn grow<T>(&self, v: &mut Vec<T>, extra: usize) -> Result<(), PickleError> {
        let need = v.len().saturating_add(extra);
        if need > v.capacity() {
            let cap = need.max(2 * v.capacity()).max(4);
            self.charge(cap.saturating_mul(size_of::<T>()))?;
            v.reserve_exact(cap - v.len());
        }
        Ok(())
    }

    /// Charges `n` items of `T` about to be allocated in one buffer.
    fn items<T>(&self, n: usize) -> Result<(), PickleError> {
        self.charge(n.saturating_mul(size_of::<T>()))
    }
}

/// Metered bytes of one memo entry: hashbrown keeps at most 7/8 of its power-of-two buckets full, each a
/// `(u64, Id)` and a control byte.
const MEMO_ENTRY_BYTES: usize = 40;

struct Budget {
    left: usize,
    limit: usize,
}

impl Budget {
    fn take(&mut self, n: usize) -> Result<(), PickleError> {
        self.left = self
            .left
            .checked_sub(n)
            .ok_or(PickleError::TooLarge(self.limit))?;
        Ok(())
    }
}

impl<'a> Machine<'a> {
    fn malformed(&self, reason: impl Into<String>) -> PickleError {
        PickleError::Malformed {
            at: self.pos,
            reason: reason.into(),
        }
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], PickleError> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.input.len())
            .ok_or(PickleError::Truncated(self.pos))?;
        let s = &self.input[self.pos..end];
        self.pos = end;
        Ok(s)
    }

    fn u8(&mut self) -> Result<u8, PickleError> {
        Ok(self.take(1)?[0])
    }

    fn le(&mut self, n: usize) -> Result<u64, PickleError> {
        let b = self.take(n)?;
        Ok(b.iter().rev().fold(0u64, |acc, &x| (acc << 8) | x as u64))
    }

    /// A length prefix of `n` bytes, checked against the input left so no huge allocation follows.
    fn len_prefix(&mut self, n: usize) -> Result<usize, PickleError> {
        let len = self.le(n)?;
        let left = (self.input.len() - self.pos) as u64;
        if len > left {
            return Err(PickleError::Truncated(self.pos));
        }
        Ok(len as usize)
    }

    fn line(&mut self) -> Result<&'a str, PickleError> {
        let rest = &self.input[self.pos..];
        let n = rest
            .iter()
            .position(|&c| c == b'\n')
            .ok_or(PickleError::Truncated(self.input.len()))?;
        let s = std::str::from_utf8(&rest[..n]).map_err(|_| self.malformed("non-UTF-8 text"))?;
        self.pos += n + 1;
        Ok(s)
    }

    fn alloc(&mut self, o: Obj) -> Result<Id, PickleError> {
        self.meter.grow(&mut self.arena, 1)?;
        self.arena.push(o);
        Ok(self.arena.len() - 1)
    }

    fn push_slot(&mut self, slot: Slot) -> Result<(), PickleError> {
        self.meter.grow(&mut self.stack, 1)?;
        self.stack.push(slot);
        Ok(())
    }

    fn push(&mut self, o: Obj) -> Result<(), PickleError> {
        let id = self.alloc(o)?;
        self.push_slot(Slot::Obj(id))
    }

    fn push_leaf(&mut self, v: Value) -> Result<(), PickleError> {
        self.push(Obj::Leaf(v))
    }

    /// The next `n` input bytes as an owned buffer, charged first.
    fn take_owned(&mut self, n: usize) -> Result<Vec<u8>, PickleError> {
        self.meter.charge(n)?;
        Ok(self.take(n)?.to_vec())
    }

    fn pop(&mut self) -> Result<Id, PickleError> {
        match self.stack.pop() {
            Some(Slot::Obj(id)) => Ok(id),
            Some(Slot::Mark) => Err(self.malformed("unexpected MARK")),
            None => Err(self.malformed("stack underflow")),
        }
    }

    fn top(&self) -> Result<Id, PickleError> {
        match self.stack.last() {
            Some(Slot::Obj(id)) => Ok(*id),
            _ => Err(self.malformed("stack underflow")),
        }
    }

    /// Pops everything above the topmost MARK (and the MARK).
    fn pop_mark(&mut self) -> Result<Vec<Id>, PickleError> {
        let m = self
            .stack
            .iter()
            .rposition(|s| matches!(s, Slot::Mark))
            .ok_or_else(|| self.malformed("no MARK on the stack"))?;
        self.meter.items::<Id>(self.stack.len() - m - 1)?;
        let items = self.stack[m + 1..]
            .iter()
            .map(|s| match s {
                Slot::Obj(id) => *id,
                Slot::Mark => unreachable!("rposition found the last MARK"),
            })
            .collect();
        self.stack.truncate(m);
        Ok(items)
    }

    /// The memo index of a PUT/GET opcode (MEMOIZE uses the next free index).
    fn memo_key(&mut self, op: u8) -> Result<u64, PickleError> {
        match op {
            b'p' | b'g' => {
                let line = self.line()?;
                line.trim()
                    .parse()
                    .map_err(|_| self.malformed("bad memo key"))
            }
            b'q' | b'h' => Ok(self.u8()? as u64),
            b'r' | b'j' => self.le(4),
            _ => Ok(self.memo.len() as u64),
        }
    }

    fn memo_get(&mut self, key: u64) -> Result<(), PickleError> {
        let id = *self
            .memo
            .get(&key)
            .ok_or_else(|| self.malformed(format!("memo key {key} not set")))?;
        self.push_slot(Slot::Obj(id))
    }

    fn memo_put(&mut self, key: u64) -> Result<(), PickleError> {
        let id = self.top()?;
        if self.memo.len() == self.memo.capacity() && !self.memo.contains_key(&key) {
            let cap = (2 * self.memo.capacity()).max(16);
            self.meter.charge(cap.saturating_mul(MEMO_ENTRY_BYTES))?;
            self.memo.reserve(cap - self.memo.len());
        }
        self.memo.insert(key, id);
        Ok(())
    }

    fn string(&self, bytes: &[u8]) -> Result<String, PickleError> {
        std::str::from_utf8(bytes)
            .map(str::to_string)
            .map_err(|_| self.malformed("string is not UTF-8"))
    }

    fn append(&mut self, target: Id, items: Vec<Id>) -> Result<(), PickleError> {
        match &mut self.arena[target] {
            Obj::List(v) => {
                self.meter.grow(v, items.len())?;
                v.extend(items);
                Ok(())
            }
            _ => Err(self.malformed("APPEND to something that is not a list")),
        }
    }

    fn set_items(&mut self, target: Id, items: Vec<Id>) -> Result<(), PickleError> {
        if !items.len().is_multiple_of(2) {
            return Err(self.malformed("SETITEMS with an odd number of items"));
        }
        match &mut self.arena[target] {
            Obj::Dict(d) => {
                self.meter.grow(d, items.len() / 2)?;
                d.extend(items.chunks_exact(2).map(|kv| (kv[0], kv[1])));
                Ok(())
            }
            _ => Err(self.malformed("SETITEM on something that is not a dict")),
        }
    }

    fn int(&self, bytes: &[u8]) -> Result<i64, PickleError> {
        if bytes.is_empty() {
            return Ok(0);
        }
        if bytes.len() > 8 {
            return Err(self.malformed(format!("integer of {} bytes", bytes.len())));
        }
        let neg = bytes[bytes.len() - 1] & 0x80 != 0;
        let mut buf = [if neg { 0xff } else { 0 }; 8];
        buf[..bytes.len()].copy_from_slice(bytes);
        Ok(i64::from_le_bytes(buf))
    }

    fn run(&mut self) -> Result<Id, PickleError> {
        loop {
            let at = self.pos;
            let op = match self.u8() {
                Ok(op) => op,
                Err(_) => return Err(PickleError::NoStop),
            };
            match op {
                0x80 => {
                    let proto = self.u8()?;
                    if proto > 5 {
                        return Err(self.malformed(format!("protocol {proto}")));
                    }
                }
                0x95 => {
                    self.le(8)?; // FRAME: a size hint only
                }
                b'.' => return self.pop(),
                b'(' => self.push_slot(Slot::Mark)?,
                b'0' => {
                    if matches!(self.stack.last(), Some(Slot::Mark)) {
                        self.stack.pop();
                    } else {
                        self.pop()?;
                    }
                }
                b'1' => {
                    self.pop_mark()?;
                }
                b'2' => {
                    let id = self.top()?;
                    self.push_slot(Slot::Obj(id))?;
                }
                b'N' => self.push_leaf(Value::None)?,
                0x88 => self.push_leaf(Value::Bool(true))?,
                0x89 => self.push_leaf(Value::Bool(false))?,
                b'I' => {
                    let line = self.line()?.trim();
                    let v = match line {
                        "01" => Value::Bool(true),
                        "00" => Value::Bool(false),
                        s => Value::Int(s.parse().map_err(|_| self.malformed("bad INT"))?),
                    };
                    self.push_leaf(v)?;
                }
                b'L' => {
                    let line = self.line()?.trim().trim_end_matches('L');
                    let v = line.parse().map_err(|_| self.malformed("bad LONG"))?;
                    self.push_leaf(Value::Int(v))?;
                }
                b'J' => {
                    let v = self.le(4)? as u32 as i32 as i64;
                    self.push_leaf(Value::Int(v))?;
                }
                b'K' => {
                    let v = self.u8()? as i64;
                    self.push_leaf(Value::Int(v))?;
                }
                b'M' => {
                    let v = self.le(2)? as i64;
                    self.push_leaf(Value::Int(v))?;
                }
                0x8a | 0x8b => {
                    let n = if op == 0x8a {
                        self.u8()? as usize
                    } else {
                        self.len_prefix(4)?
                    };
                    let bytes = self.take(n)?;
                    let v = self.int(bytes)?;
                    self.push_leaf(Value::Int(v))?;
                }
                b'G' => {
                    let b = self.take(8)?;
                    let v = f64::from_be_bytes(b.try_into().expect("8 bytes"));
                    self.push_leaf(Value::Float(v))?;
                }
                b'F' => {
                    let line = self.line()?.trim();
                    let v = line.parse().map_err(|_| self.malformed("bad FLOAT"))?;
                    self.push_leaf(Value::Float(v))?;
                }
                b'X' | 0x8c | 0x8d => {
                    let n = match op {
                        b'X' => self.len_prefix(4)?,
                        0x8c => self.len_prefix(1)?,
                        _ => self.len_prefix(8)?,
                    };
                    self.meter.charge(n)?;
                    let bytes = self.take(n)?;
                    let s = self.string(bytes)?;
                    self.push_leaf(Value::Str(s))?;
                }
                b'T' | b'U' | b'B' | b'C' | 0x8e | 0x96 => {
                    let n = match op {
                        b'T' | b'B' => self.len_prefix(4)?,
                        b'U' | b'C' => self.len_prefix(1)?,
                        _ => self.len_prefix(8)?,
                    };
                    let bytes = self.take_owned(n)?;
                    self.push_leaf(Value::Bytes(bytes))?;
                }
                b'}' => self.push(Obj::Dict(Vec::new()))?,
                b']' => self.push(Obj::List(Vec::new()))?,
                b')' => self.push(Obj::Tuple(Vec::new()))?,
                0x8f => self.push(Obj::List(Vec::new()))?, // EMPTY_SET, read as a list
                b'd' => {
                    let items = self.pop_mark()?;
                    let id = self.alloc(Obj::Dict(Vec::new()))?;
                    self.set_items(id, items)?;
                    self.push_slot(Slot::Obj(id))?;
                }
                b'l' | 0x91 => {
                    let items = self.pop_mark()?;
                    self.push(Obj::List(items))?;
                }
                b't' => {
                    let items = self.pop_mark()?;
                    self.push(Obj::Tuple(items))?;
                }
                0x85..=0x87 => {
                    let n = (op - 0x84) as usize;
                    if self.stack.len() < n {
                        return Err(self.malformed("stack underflow"));
                    }
                    let mut items = Vec::with_capacity(n);
                    for _ in 0..n {
                        items.push(self.pop()?);
                    }
                    items.reverse();
                    self.push(Obj::Tuple(items))?;
                }
                b'a' => {
                    let v = self.pop()?;
                    let target = self.top()?;
                    self.append(target, vec![v])?;
                }
                b'e' | 0x90 => {
                    let items = self.pop_mark()?;
                    let target = self.top()?;
                    self.append(target, items)?;
                }
                b's' => {
                    let v = self.pop()?;
                    let k = self.pop()?;
                    let target = self.top()?;
                    self.set_items(target, vec![k, v])?;
                }
                b'u' => {
                    let items = self.pop_mark()?;
                    let target = self.top()?;
                    self.set_items(target, items)?;
                }
                b'p' | b'q' | b'r' | 0x94 => {
                    let key = self.memo_key(op)?;
                    self.memo_put(key)?;
                }
                b'g' | b'h' | b'j' => {
                    let key = self.memo_key(op)?;
                    self.memo_get(key)?;
                }
                b'c' => {
                    let module = self.line()?.to_string();
                    let name = self.line()?.to_string();
                    let g = Global::resolve(&module, &name)?;
                    self.push(Obj::Global(g))?;
                }
                0x93 => {
                    let name = self.pop()?;
                    let module = self.pop()?;
                    let (Obj::Leaf(Value::Str(module)), Obj::Leaf(Value::Str(name))) =
                        (&self.arena[module], &self.arena[name])
                    else {
                        return Err(self.malformed("STACK_GLOBAL needs two strings"));
                    };
                    let g = Global::resolve(module, name)?;
                    self.push(Obj::Global(g))?;
                }
                b'R' => {
                    let args = self.pop()?;
                    let callable = self.pop()?;
                    let obj = self.reduce(callable, args)?;
                    self.built.take(obj_size(&obj))?;
                    self.meter.charge(obj_size(&obj))?;
                    self.push(obj)?;
                }
                b'b' => {
                    let state = self.pop()?;
                    let target = self.top()?;
                    self.build(target, state)?;
                }
                0x81 => {
                    let args = self.pop()?;
                    let cls = self.pop()?;
                    let class = match (self.global_of(cls), &self.arena[args]) {
                        (Some(Global::Data(class)), Obj::Tuple(a)) if a.is_empty() => class,
                        _ => {
                            return Err(self.malformed(
                                "NEWOBJ: only chumpy arrays and scipy sparse matrices are rebuilt, as data",
                            ))
                        }
                    };
                    self.push(Obj::Instance { class, state: None })?;
                }
                0x92 => {
                    return Err(
                        self.malformed("NEWOBJ_EX: constructing class instances is not allowed")
                    )
                }
                _ => return Err(PickleError::Opcode { op, at }),
            }
        }
    }

    fn global_of(&self, id: Id) -> Option<Global> {
        match self.arena[id] {
            Obj::Global(g) => Some(g),
            _ => None,
        }
    }

    fn tuple(&self, id: Id, what: &str) -> Result<&[Id], PickleError> {
        match &self.arena[id] {
            Obj::Tuple(v) => Ok(v),
            _ => Err(self.malformed(format!("{what}: expected a tuple"))),
        }
    }

    fn leaf(&self, id: Id) -> Option<&Value> {
        match &self.arena[id] {
            Obj::Leaf(v) => Some(v),
            _ => None,
        }
    }

    fn text(&self, id: Id, what: &str) -> Result<String, PickleError> {
        self.leaf(id)
            .and_then(Value::as_str)
            .ok_or_else(|| self.malformed(format!("{what}: expected a string")))
    }

    fn bytes(&self, id: Id, what: &str) -> Result<&[u8], PickleError> {
        match self.leaf(id) {
            Some(Value::Bytes(b)) => Ok(b),
            _ => Err(self.malformed(format!("{what}: expected bytes"))),
        }
    }

    fn shape(&self, id: Id) -> Result<Vec<usize>, PickleError> {
        let dims = match &self.arena[id] {
            Obj::Tuple(v) | Obj::List(v) => {
                self.meter.items::<usize>(2 * v.len())?;
                v.clone()
            }
            _ => return Err(self.malformed("array shape: expected a tuple")),
        };
        let shape = dims
            .iter()
            .map(|&d| match self.leaf(d) {
                Some(Value::Int(n)) if *n >= 0 => Ok(*n as usize),
                _ => Err(self.malformed("array shape: expected non-negative ints")),
            })
            .collect::<Result<Vec<_>, _>>()?;
        element_count(&shape).ok_or_else(|| self.malformed("array shape overflows"))?;
        Ok(shape)
    }

    fn descr(&self, id: Id) -> Result<Descr, PickleError> {
        match &self.arena[id] {
            Obj::Dtype {
                typestr,
                big_endian,
                elsize,
            } => {
                let d = Descr::parse(typestr).map_err(|e| self.malformed(e.to_string()))?;
                Ok(match d {
                    Descr::Numeric { dtype, .. } => Descr::Numeric {
                        dtype,
                        big_endian: *big_endian,
                    },
                    Descr::Unicode { chars, .. } => Descr::Unicode {
                        chars: elsize.map_or(chars, |e| e / 4),
                        big_endian: *big_endian,
                    },
                    Descr::Bytes { len } => Descr::Bytes {
                        len: elsize.unwrap_or(len),
                    },
                    Descr::Object => Descr::Object,
                })
            }
            _ => Err(self.malformed("expected a numpy dtype")),
        }
    }

    fn reduce(&self, callable: Id, args: Id) -> Result<Obj, PickleError> {
        let g = self
            .global_of(callable)
            .ok_or_else(|| self.malformed("REDUCE on something that is not a global"))?;
        let a = self.tuple(args, "call arguments")?;
        let arg = |i: usize| {
            a.get(i)
                .copied()
                .ok_or_else(|| self.malformed(format!("{g:?}: missing argument {i}")))
        };
        match g {
            Global::Reconstruct => {
                if self.global_of(arg(0)?) != Some(Global::NdarrayClass) {
                    return Err(self.malformed("_reconstruct of something other than ndarray"));
                }
                Ok(Obj::PendingArray)
            }
            Global::DtypeClass => Ok(Obj::Dtype {
                typestr: self.text(arg(0)?, "dtype")?,
                big_endian: false,
                elsize: None,
            }),
            Global::Scalar => {
                let descr = self.descr(arg(0)?)?;
                match descr {
                    Descr::Numeric { dtype, big_endian } => {
                        let bytes = self.bytes(arg(1)?, "numpy scalar")?;
                        let a = NdArray::from_bytes(dtype, big_endian, vec![], false, bytes)
                            .map_err(|e| self.malformed(e.to_string()))?;
                        Ok(Obj::Leaf(Value::Array(a)))
                    }
                    Descr::Object => {
                        let object = &self.arena[arg(1)?];
                        self.meter.charge(obj_size(object))?;
                        Ok(object.clone())
                    }
                    // A numpy string scalar (`np.str_`, `np.bytes_`) is just its string.
                    _ => {
                        let chunk = self.bytes(arg(1)?, "numpy scalar")?;
                        Ok(Obj::Leaf(self.string_item(descr, chunk)?))
                    }
                }
            }
            Global::FromBuffer => {
                let descr = self.descr(arg(1)?)?;
                let shape = self.shape(arg(2)?)?;
                let fortran = self.text(arg(3)?, "array order")? == "F";
                let bytes = self.bytes(arg(0)?, "array buffer")?;
                self.array(descr, shape, fortran, bytes)
            }
            Global::CodecsEncode => {
                let text = match self.leaf(arg(0)?) {
                    Some(Value::Str(s)) => s.clone(),
                    _ => return Err(self.malformed("_codecs.encode: expected a string")),
                };
                let enc = self.text(arg(1)?, "encoding")?.to_ascii_lowercase();
                if enc != "latin1" && enc != "latin-1" {
                    return Err(self.malformed(format!("_codecs.encode with encoding {enc:?}")));
                }
                let bytes = latin1(&text)
                    .ok_or_else(|| self.malformed("_codecs.encode: character beyond Latin-1"))?;
                Ok(Obj::Leaf(Value::Bytes(bytes)))
            }
            Global::NdarrayClass => Err(self.malformed("calling numpy.ndarray directly")),
            Global::Data(class) => Err(self.malformed(format!(
                "calling {class:?}: its objects are only rebuilt from their state (NEWOBJ, BUILD)"
            ))),
        }
    }

    fn array(
        &self,
        descr: Descr,
        shape: Vec<usize>,
        fortran: bool,
        bytes: &[u8],
    ) -> Result<Obj, PickleError> {
        match descr {
            Descr::Numeric { dtype, big_endian } => {
                let a = NdArray::from_bytes(dtype, big_endian, shape, fortran, bytes)
                    .map_err(|e| self.malformed(e.to_string()))?;
                Ok(Obj::Leaf(Value::Array(a)))
            }
            Descr::Object => Err(self.malformed("object array given as raw bytes")),
            _ if fortran && shape.len() > 1 => {
                Err(self.malformed("Fortran-order string arrays are not supported"))
            }
            _ => self.strings(descr, shape, bytes),
        }
    }

    /// Fixed-width string arrays (`<U…`, `|S…`) become object arrays of strings / bytes.
    fn strings(&self, descr: Descr, shape: Vec<usize>, bytes: &[u8]) -> Result<Obj, PickleError> {
        let size = descr
            .item_size()
            .filter(|&s| s > 0)
            .ok_or_else(|| self.malformed("string dtype of zero or unknown size"))?;
        let count = element_count(&shape).ok_or_else(|| self.malformed("shape overflows"))?;
        if count.checked_mul(size) != Some(bytes.len()) {
            return Err(self.malformed(format!(
                "{} bytes do not hold {count} strings of {size} bytes",
                bytes.len()
            )));
        }
        // Strings are leaves; store them inline as a finished object array value.
        self.meter.items::<Value>(count)?;
        let values = bytes
            .chunks(size)
            .take(count)
            .map(|chunk| self.string_item(descr, chunk))
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Obj::Leaf(Value::ObjectArray {
            shape,
            items: values,
        }))
    }

    fn string_item(&self, descr: Descr, chunk: &[u8]) -> Result<Value, PickleError> {
        Ok(match descr {
            Descr::Unicode { big_endian, .. } => {
                let mut s = String::new();
                for c in chunk.chunks_exact(4) {
                    let a: [u8; 4] = c.try_into().expect("4 bytes");
                    let code = if big_endian {
                        u32::from_be_bytes(a)
                    } else {
                        u32::from_le_bytes(a)
                    };
                    if code == 0 {
                        break;
                    }
                    s.push(
                        char::from_u32(code).ok_or_else(|| self.malformed("invalid character"))?,
                    );
                }
                Value::Str(s)
            }
            _ => {
                let end = chunk.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
                Value::Bytes(chunk[..end].to_vec())
            }
        })
    }

    fn build(&mut self, target: Id, state: Id) -> Result<(), PickleError> {
        match self.arena[target] {
            Obj::PendingArray => {
                let s = self.tuple(state, "ndarray state")?;
                // An optional leading version field.
                let s = if s.len() == 5 { &s[1..] } else { s };
                let [shape, dtype, fortran, data] = *s else {
                    return Err(self.malformed("ndarray state: expected 4 or 5 fields"));
                };
                let shape = self.shape(shape)?;
                let descr = self.descr(dtype)?;
                let fortran = matches!(self.leaf(fortran), Some(Value::Bool(true)));
                let obj = if descr == Descr::Object {
                    let items = match &self.arena[data] {
                        Obj::List(v) => {
                            self.meter.items::<Id>(v.len())?;
                            v.clone()
                        }
                        _ => return Err(self.malformed("object array state: expected a list")),
                    };
                    let count = element_count(&shape).unwrap_or(usize::MAX);
                    if items.len() != count {
                        return Err(self.malformed(format!(
                            "object array of shape {shape:?} has {} items",
                            items.len()
                        )));
                    }
                    if fortran && shape.len() > 1 {
                        return Err(self.malformed("Fortran-order object arrays are not supported"));
                    }
                    Obj::Objects { shape, items }
                } else {
                    let bytes = match self.leaf(data) {
                        Some(Value::Bytes(b)) => {
                            self.meter.charge(b.len())?;
                            b.clone()
                        }
                        Some(Value::Str(s)) => {
                            latin1(s).ok_or_else(|| self.malformed("array data beyond Latin-1"))?
                        }
                        _ => return Err(self.malformed("array data: expected bytes")),
                    };
                    self.array(descr, shape, fortran, &bytes)?
                };
                self.built.take(obj_size(&obj))?;
                self.meter.charge(obj_size(&obj))?;
                self.arena[target] = obj;
                Ok(())
            }
            Obj::Dtype { .. } => {
                let s = self.tuple(state, "dtype state")?;
                if s.len() < 8 {
                    return Err(self.malformed("dtype state: expected at least 8 fields"));
                }
                let s = s[..8].to_vec();
                let endian = self.text(s[1], "dtype byte order")?;
                for (i, what) in [(2, "sub-arrays"), (3, "field names"), (4, "fields")] {
                    if !matches!(self.leaf(s[i]), Some(Value::None)) {
                        return Err(self.malformed(format!("dtype with {what} is not supported")));
                    }
                }
                let elsize = match self.leaf(s[5]) {
                    Some(Value::Int(n)) if *n > 0 => Some(*n as usize),
                    _ => None,
                };
                if let Obj::Dtype {
                    big_endian,
                    elsize: e,
                    ..
                } = &mut self.arena[target]
                {
                    *big_endian = endian == ">";
                    *e = elsize;
                }
                Ok(())
            }
            Obj::Instance { class, state: None } => {
                if !matches!(self.arena[state], Obj::Dict(_)) {
                    return Err(self.malformed(format!("{class:?} state: expected a dict")));
                }
                self.arena[target] = Obj::Instance {
                    class,
                    state: Some(state),
                };
                Ok(())
            }
            _ => Err(self.malformed(
                "BUILD on an object that is not a numpy array, dtype, chumpy array or sparse matrix",
            )),
        }
    }

    fn to_value(&self, id: Id, depth: usize, budget: &mut Budget) -> Result<Value, PickleError> {
        if depth > MAX_DEPTH {
            return Err(PickleError::TooDeep(MAX_DEPTH));
        }
        budget.take(16)?;
        let seq = |ids: &[Id], budget: &mut Budget| {
            self.meter.items::<Value>(ids.len())?;
            let mut out = Vec::with_capacity(ids.len());
            for &i in ids {
                out.push(self.to_value(i, depth + 1, budget)?);
            }
            Ok::<_, PickleError>(out)
        };
        Ok(match &self.arena[id] {
            Obj::Leaf(v) => {
                budget.take(leaf_size(v))?;
                self.meter.charge(leaf_size(v))?;
                v.clone()
            }
            Obj::List(v) => Value::List(seq(v, budget)?),
            Obj::Tuple(v) => Value::Tuple(seq(v, budget)?),
            Obj::Dict(d) => {
                self.meter.items::<(Value, Value)>(d.len())?;
                let mut entries = Vec::with_capacity(d.len());
                for &(k, v) in d {
                    entries.push((
                        self.to_value(k, depth + 1, budget)?,
                        self.to_value(v, depth + 1, budget)?,
                    ));
                }
                Value::Dict(entries)
            }
            Obj::Objects { shape, items } => Value::ObjectArray {
                shape: shape.clone(),
                items: seq(items, budget)?,
            },
            Obj::Global(g) => return Err(self.malformed(format!("bare global {g:?} in the data"))),
            Obj::Dtype { typestr, .. } => Value::Str(typestr.clone()),
            Obj::PendingArray => return Err(self.malformed("ndarray without its state")),
            Obj::Instance { class, state } => {
                let state =
                    state.ok_or_else(|| self.malformed(format!("{class:?} without its state")))?;
                let state = self.to_value(state, depth + 1, budget)?;
                self.data_instance(*class, &state, budget)?
            }
        })
    }

    /// The array a chumpy object or sparse matrix holds, from its state dict.
    fn data_instance(
        &self,
        class: DataClass,
        state: &Value,
        budget: &mut Budget,
    ) -> Result<Value, PickleError> {
        let array = |key: &str| match state.get(key) {
            Some(Value::Array(a)) => Ok(a),
            _ => Err(self.malformed(format!("{class:?} state has no '{key}' array"))),
        };
        match class {
            DataClass::Chumpy => Ok(Value::Array(array("x")?.clone())),
            DataClass::Sparse { by_columns } => {
                let [rows, cols] = match state.get("_shape") {
                    Some(Value::Tuple(t)) => match t.as_slice() {
                        [Value::Int(r), Value::Int(c)] if *r >= 0 && *c >= 0 => {
                            [*r as usize, *c as usize]
                        }
                        _ => return Err(self.malformed("sparse matrix _shape: expected two sizes")),
                    },
                    _ => return Err(self.malformed("sparse matrix state has no '_shape'")),
                };
                let (data, indices, indptr) = (
                    array("data")?.to_f64(),
                    array("indices")?.to_i64(),
                    array("indptr")?.to_i64(),
                );
                let (Some(indices), Some(indptr)) = (indices, indptr) else {
                    return Err(self.malformed("sparse matrix indices are not integers"));
                };
                let (outer, inner) = if by_columns {
                    (cols, rows)
                } else {
                    (rows, cols)
                };
                let cells = rows.saturating_mul(cols);
                budget.take(cells.saturating_mul(8))?;
                self.meter.items::<f64>(cells)?;
                let bad = || self.malformed("sparse matrix: indptr, indices and data disagree");
                if indptr.len() != outer + 1 || indices.len() != data.len() {
                    return Err(bad());
                }
                let mut dense = vec![0.0; cells];
                for o in 0..outer {
                    let (a, b) = (indptr[o], indptr[o + 1]);
                    if a < 0 || b < a || b as usize > data.len() {
                        return Err(bad());
                    }
                    for n in a as usize..b as usize {
                        let i = usize::try_from(indices[n])
                            .ok()
                            .filter(|&i| i < inner)
                            .ok_or_else(bad)?;
                        let (r, c) = if by_columns { (i, o) } else { (o, i) };
                        dense[r * cols + c] += data[n];
                    }
                }
                NdArray::new(vec![rows, cols], ArrayData::F64(dense))
                    .map(Value::Array)
                    .map_err(|e| self.malformed(e.to_string()))
            }
        }
    }
}

/// Latin-1 bytes of a string (how Python 3 pickles `bytes` for protocol 2).
fn latin1(text: &str) -> Option<Vec<u8>> {
    text.chars().map(|c| u8::try_from(c as u32).ok()).collect()
}

/// Approximate heap bytes of an object made by REDUCE or BUILD.
fn obj_size(o: &Obj) -> usize {
    match o {
        Obj::Leaf(v) => leaf_size(v),
        Obj::List(ids) | Obj::Tuple(ids) => size_of::<Id>() * ids.len(),
        Obj::Dict(d) => size_of::<(Id, Id)>() * d.len(),
        Obj::Objects { items, .. } => size_of::<Id>() * items.len(),
        Obj::Dtype { typestr, .. } => typestr.len(),
        _ => 0,
    }
}

/// Approximate heap bytes of a leaf, for the output budget.
fn leaf_size(v: &Value) -> usize {
    match v {
        Value::Str(s) => s.len(),
        Value::Bytes(b) => b.len(),
        Value::Array(a) => a.len().saturating_mul(a.dtype().size()),
        Value::ObjectArray { items, .. } => items.iter().map(|i| 16 + leaf_size(i)).sum(),
        _ => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_written_protocol_2_pickle() {
        // pickle.dumps({'a': [1, -2, 3.5], 'b': (True, None)}, protocol=2) restated opcode by opcode.
        let mut p = vec![0x80, 2, b'}', b'q', 0, b'('];
        p.extend([b'X', 1, 0, 0, 0, b'a', b']', b'q', 1, b'(']);
        p.extend([b'K', 1, b'J']);
        p.extend((-2i32).to_le_bytes());
        p.push(b'G');
        p.extend(3.5f64.to_be_bytes());
        p.extend([b'e', b'X', 1, 0, 0, 0, b'b', 0x88, b'N', 0x86, b'u', b'.']);
        let v = parse(&p).unwrap();
        assert_eq!(
            v.get("a"),
            Some(&Value::List(vec![
                Value::Int(1),
                Value::Int(-2),
                Value::Float(3.5)
            ]))
        );
        assert_eq!(
            v.get("b"),
            Some(&Value::Tuple(vec![Value::Bool(true), Value::None]))
        );
    }

    #[test]
    fn cycles_and_exponential_sharing_are_bounded() {
        // l = []; l.append(l)
        let cyclic = [0x80, 2, b']', b'q', 0, b'h', 0, b'a', b'.'];
        assert_eq!(parse(&cyclic), Err(PickleError::TooDeep(MAX_DEPTH)));
        // Each level is a list holding the previous level twice: 2^60 leaves from ~300 bytes.
        let mut p = vec![0x80, 2, b'X', 4, 0, 0, 0, b'a', b'b', b'c', b'd'];
        for _ in 0..60 {
            p.extend([b'2', 0x86]);
        }
        p.push(b'.');
        assert!(matches!(parse(&p), Err(PickleError::TooLarge(_))));
    }

    #[test]
    fn many_arrays_sharing_one_buffer_cannot_multiply_it() {
        // One 65535-byte buffer (memo 0), a uint8 dtype (memo 1), then 600 arrays each rebuilt from that
        // buffer: 39 MB of arrays from ~110 KB of pickle.
        let n = 0xffffusize;
        let mut p = vec![0x80, 2, b'B'];
        p.extend((n as u32).to_le_bytes());
        p.extend(std::iter::repeat_n(7u8, n));
        p.extend(b"q\x00cnumpy\ndtype\nX\x02\x00\x00\x00u1\x89\x88\x87R");
        p.extend(b"(K\x03X\x01\x00\x00\x00|NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tbq\x01(");
        for _ in 0..600 {
            p.extend(
                b"cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\nK\x00\x85C\x01b\x87R",
            );
            p.extend(b"(K\x01M\xff\xff\x85h\x01\x89h\x00tb");
        }
        p.extend(b"l.");
        assert!(matches!(parse(&p), Err(PickleError::TooLarge(_))));
        // The same pickle with only 3 arrays is fine: the limit is proportional, not a fixed cap.
        let three = [&p[..p.len() - 2 - 597 * 73], b"l."].concat();
        let v = parse(&three).unwrap();
        assert_eq!(v.as_seq().map(<[Value]>::len), Some(3));
        assert_eq!(v.as_seq().unwrap()[2].as_array().unwrap().shape(), &[n]);
    }

    #[test]
    fn the_memory_cap_stops_an_object_per_opcode() {
        // 100 000 empty lists left on the stack (STOP returns the last), or each memoised as well.
        let n = 100_000;
        for unit in [&b"]"[..], b"]\x94"] {
            let p = [&b"\x80\x02"[..], &unit.repeat(n), b"."].concat();
            assert_eq!(parse(&p), Ok(Value::List(vec![])), "within the default cap");
            let cap = 1 << 20;
            assert_eq!(
                parse_within(&p, cap),
                Err(PickleError::MemoryCap {
                    cap,
                    input: p.len()
                })
            );
        }
        // A list of those lists decodes within the default cap.
        let p = [&b"\x80\x02("[..], &b"]".repeat(n), b"l."].concat();
        assert_eq!(parse(&p).unwrap().as_seq().map(<[Value]>::len), Some(n));
    }

    #[test]
    fn unknown_globals_are_refused_by_name() {
        let p = b"\x80\x02cos\nsystem\nq\x00X\x02\x00\x00\x00lsq\x01\x85q\x02Rq\x03.";
        assert_eq!(parse(p), Err(PickleError::Refused("os.system".into())));
    }
}
