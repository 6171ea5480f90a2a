//! Writing WGCSL buffers as pickles: a dict of C-order numpy arrays (float64, or any dtype a
//! passthrough column gives back), protocol 3, opcode for opcode what numpy 1.x's
//! `pickle.dump(d, f, protocol=3)` writes.
//!
//! Spelled as numpy 1.x spells it (`numpy.core.multiarray._reconstruct`, `numpy.ndarray`,
//! `numpy.dtype`) because that is the one spelling both numpy 1.x and 2.x load (numpy 2 keeps
//! `numpy.core` as an alias; numpy 1 has no `numpy._core`), and protocol 3 because it is what
//! the WGCSL and GoFAR code bases write and read. Matching numpy byte for byte, memo numbering
//! included, makes the writer checkable against files numpy wrote (`tests.rs`).
//!
//! Array bytes are streamed from a callback, so a caller can write buffers larger than memory
//! (`collect` spools its arrays to temporary files and copies them in).

use std::io::{self, Write};

use super::op;
use crate::dtype::Dtype;

/// Writes an array's little-endian C-order values into the pickle when called.
pub type ArraySource<'a> = Box<dyn FnMut(&mut dyn Write) -> io::Result<()> + 'a>;

/// One array of the dict: its key, numpy dtype (the bytes the source gives are in its byte
/// order), shape, and the source of its values (exactly `shape.product() × size` bytes, which is
/// checked).
pub struct ArrayOut<'a> {
    pub key: &'a str,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    pub data: ArraySource<'a>,
}

impl<'a> ArrayOut<'a> {
    /// A float64 array whose bytes are in memory.
    pub fn from_bytes(key: &'a str, shape: Vec<usize>, bytes: &'a [u8]) -> Self {
        ArrayOut { key, dtype: Dtype::F64, shape, data: Box::new(move |w| w.write_all(bytes)) }
    }
}

/// The pickler's state: the output and the memo counter (every PUT numbers the next object).
struct Pickler<'w> {
    out: &'w mut dyn Write,
    memo: u32,
}

impl Pickler<'_> {
    fn raw(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.out.write_all(bytes)
    }

    /// Memoize the object just written; returns its memo index.
    fn put(&mut self) -> io::Result<u32> {
        let id = self.memo;
        self.memo += 1;
        match u8::try_from(id) {
            Ok(b) => self.raw(&[op::BINPUT, b])?,
            Err(_) => {
                self.raw(&[op::LONG_BINPUT])?;
                self.raw(&id.to_le_bytes())?;
            }
        }
        Ok(id)
    }

    fn get(&mut self, id: u32) -> io::Result<()> {
        match u8::try_from(id) {
            Ok(b) => self.raw(&[op::BINGET, b]),
            Err(_) => {
                self.raw(&[op::LONG_BINGET])?;
                self.raw(&id.to_le_bytes())
            }
        }
    }

    fn str(&mut self, s: &str) -> io::Result<u32> {
        self.raw(&[op::BINUNICODE])?;
        self.raw(&(s.len() as u32).to_le_bytes())?;
        self.raw(s.as_bytes())?;
        self.put()
    }

    fn global(&mut self, module: &str, name: &str) -> io::Result<u32> {
        self.raw(&[op::GLOBAL])?;
        self.raw(format!("{module}\n{name}\n").as_bytes())?;
        self.put()
    }

    /// An int as `save_long` writes it for protocols ≥ 2, for the range shapes need.
    fn int(&mut self, v: i64) -> io::Result<()> {
        if (0..=0xff).contains(&v) {
            self.raw(&[op::BININT1, v as u8])
        } else if (0..=0xffff).contains(&v) {
            self.raw(&[op::BININT2])?;
            self.raw(&(v as u16).to_le_bytes())
        } else if let Ok(v) = i32::try_from(v) {
            self.raw(&[op::BININT])?;
            self.raw(&v.to_le_bytes())
        } else {
            Err(io::Error::new(io::ErrorKind::InvalidInput, format!("integer {v} is too large for this writer")))
        }
    }

    /// A tuple of ints (a shape), memoized as Python memoizes every tuple it saves.
    fn int_tuple(&mut self, items: &[usize]) -> io::Result<u32> {
        let big = items.len() > 3;
        if big {
            self.raw(&[op::MARK])?;
        }
        for &v in items {
            let v = i64::try_from(v).map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "shape too large"))?;
            self.int(v)?;
        }
        let close = match items.len() {
            0 => op::EMPTY_TUPLE,
            1 => op::TUPLE1,
            2 => op::TUPLE2,
            3 => op::TUPLE3,
            _ => op::TUPLE,
        };
        self.raw(&[close])?;
        self.put()
    }
}

/// The memo indices numpy's first array leaves behind and later arrays refer back to: the
/// globals, `b'b'`, each dtype written, the `numpy.dtype` class and the byte-order
/// strings (single characters, which Python shares, so pickle memoizes them).
struct Shared {
    reconstruct: u32,
    ndarray: u32,
    b: u32,
    dtypes: Vec<(Dtype, u32)>,
    dtype_class: Option<u32>,
    orders: Vec<(char, u32)>,
}

/// Write `{key: array, …}` (keys in the given order) as a protocol-3 pickle.
pub fn write_dict(out: &mut dyn Write, arrays: &mut [ArrayOut]) -> io::Result<()> {
    let mut p = Pickler { out, memo: 0 };
    p.raw(&[op::PROTO, 3, op::EMPTY_DICT])?;
    p.put()?;
    // `_batch_setitems`: MARK … SETITEMS for more than one item, plain SETITEM for one.
    let batched = arrays.len() > 1;
    if batched {
        p.raw(&[op::MARK])?;
    }
    let mut shared: Option<Shared> = None;
    for a in arrays.iter_mut() {
        p.str(a.key)?;
        write_array(&mut p, a, &mut shared)?;
        if !batched {
            p.raw(&[op::SETITEM])?;
        }
    }
    if batched {
        p.raw(&[op::SETITEMS])?;
    }
    p.raw(&[op::STOP])
}

/// `ndarray.__reduce__`: `_reconstruct(ndarray, (0,), b'b')`, then BUILD with
/// `(1, shape, dtype, False, raw bytes)`.
fn write_array(p: &mut Pickler, a: &mut ArrayOut, shared: &mut Option<Shared>) -> io::Result<()> {
    let len = a
        .shape
        .iter()
        .try_fold(a.dtype.size as u64, |n, &d| n.checked_mul(d as u64))
        .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "array size overflows"))?;
    let Ok(len32) = u32::try_from(len) else {
        return Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("array '{}' has {len} bytes; a protocol-3 pickle holds at most 4 GiB per array", a.key),
        ));
    };
    // numpy's first array defines the globals, b'b' and the dtype; later ones refer back.
    let ids = match shared {
        Some(s) => {
            p.get(s.reconstruct)?;
            p.get(s.ndarray)?;
            p.int_tuple(&[0])?;
            p.get(s.b)?;
            None
        }
        None => {
            let reconstruct = p.global("numpy.core.multiarray", "_reconstruct")?;
            let ndarray = p.global("numpy", "ndarray")?;
            p.int_tuple(&[0])?;
            p.raw(&[op::SHORT_BINBYTES, 1, b'b'])?;
            Some((reconstruct, ndarray, p.put()?))
        }
    };
    p.raw(&[op::TUPLE3])?;
    p.put()?;
    p.raw(&[op::REDUCE])?;
    p.put()?;
    p.raw(&[op::MARK])?;
    p.int(1)?;
    p.int_tuple(&a.shape)?;
    if let Some((reconstruct, ndarray, b)) = ids {
        *shared = Some(Shared { reconstruct, ndarray, b, dtypes: Vec::new(), dtype_class: None, orders: Vec::new() });
    }
    let s = shared.as_mut().expect("set by the first array");
    match s.dtypes.iter().find(|(d, _)| *d == a.dtype) {
        Some(&(_, id)) => p.get(id)?,
        None => {
            let id = write_dtype(p, a.dtype, s)?;
            s.dtypes.push((a.dtype, id));
        }
    }
    p.raw(&[op::NEWFALSE])?;
    if len32 < 256 {
        p.raw(&[op::SHORT_BINBYTES, len32 as u8])?;
    } else {
        p.raw(&[op::BINBYTES])?;
        p.raw(&len32.to_le_bytes())?;
    }
    let mut counted = Counted { inner: &mut *p.out, n: 0 };
    (a.data)(&mut counted)?;
    if counted.n != len {
        return Err(io::Error::other(format!(
            "array '{}' of shape {:?} needs {len} bytes but its source gave {}",
            a.key, a.shape, counted.n
        )));
    }
    p.put()?;
    p.raw(&[op::TUPLE])?;
    p.put()?;
    p.raw(&[op::BUILD])
}

/// `dtype('f8', False, True)` then BUILD with `(3, '<', None, None, None, -1, -1, 0)`: numpy's
/// reduction of a dtype, its type string without the byte order, which the state carries
/// (`|` for one-byte types).
fn write_dtype(p: &mut Pickler, dtype: Dtype, s: &mut Shared) -> io::Result<u32> {
    let descr = dtype.descr();
    let (order, typestr) = descr.split_at(1);
    let order = order.chars().next().expect("a descr starts with its byte order");
    match s.dtype_class {
        Some(id) => p.get(id)?,
        None => s.dtype_class = Some(p.global("numpy", "dtype")?),
    }
    p.str(typestr)?;
    p.raw(&[op::NEWFALSE, op::NEWTRUE, op::TUPLE3])?;
    p.put()?;
    p.raw(&[op::REDUCE])?;
    let dtype = p.put()?;
    p.raw(&[op::MARK])?;
    p.int(3)?;
    match s.orders.iter().find(|(c, _)| *c == order) {
        Some(&(_, id)) => p.get(id)?,
        None => {
            let id = p.str(&order.to_string())?;
            s.orders.push((order, id));
        }
    }
    p.raw(&[op::NONE, op::NONE, op::NONE])?;
    p.int(-1)?;
    p.int(-1)?;
    p.int(0)?;
    p.raw(&[op::TUPLE])?;
    p.put()?;
    p.raw(&[op::BUILD])?;
    Ok(dtype)
}

/// Counts what passes through, to hold array sources to their declared length.
struct Counted<'a> {
    inner: &'a mut dyn Write,
    n: u64,
}

impl Write for Counted<'_> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let k = self.inner.write(buf)?;
        self.n += k as u64;
        Ok(k)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}
