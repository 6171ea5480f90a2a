//! The opcode loop. Mirrors CPython's `_Unpickler` (Lib/pickle.py) opcode by opcode, except
//! that calls are limited to [`Global`]'s allow-list and every length is bounds-checked
//! before it is used.

use std::borrow::Cow;
use std::collections::HashMap;

use super::numpy::{DType, Global, NdArray};
use super::{Id, Obj, Pickle, PickleError};

type R<T> = Result<T, PickleError>;

struct Machine<'a> {
    data: &'a [u8],
    pos: usize,
    /// Offset of the opcode being executed, for error messages.
    op_pos: usize,
    op: u8,
    objs: Vec<Obj<'a>>,
    stack: Vec<Id>,
    /// Stack heights at each MARK (CPython's metastack).
    marks: Vec<usize>,
    memo: HashMap<u64, Id>,
}

pub(super) fn run(data: &[u8]) -> R<Pickle<'_>> {
    sniff(data)?;
    let mut m = Machine {
        data,
        pos: 0,
        op_pos: 0,
        op: 0,
        objs: Vec::new(),
        stack: Vec::new(),
        marks: Vec::new(),
        memo: HashMap::new(),
    };
    loop {
        if m.pos >= data.len() {
            return Err(PickleError {
                offset: data.len(),
                message: "truncated: the stream ends before its STOP opcode".into(),
            });
        }
        m.op_pos = m.pos;
        m.op = data[m.pos];
        m.pos += 1;
        if m.op == b'.' {
            let root = m.pop()?;
            return Ok(Pickle { objs: m.objs, root });
        }
        m.step()?;
    }
}

/// Recognise common non-pickle inputs before running, so the error says what the file is.
fn sniff(data: &[u8]) -> R<()> {
    let fail = |what: &str| Err(PickleError { offset: 0, message: format!("not a pickle: {what}") });
    match data {
        [] => Err(PickleError { offset: 0, message: "empty file".into() }),
        [0x80, ..] => Ok(()),
        [0x1f, 0x8b, ..] => fail("the file is gzip-compressed; decompress it first (gunzip)"),
        [b'P', b'K', 3, 4, ..] => fail("the file is a zip archive (an .npz?); extract it first"),
        [0x93, b'N', b'U', b'M', b'P', b'Y', ..] => fail("the file is a .npy array file"),
        [b'P', b'A', b'R', b'1', ..] => fail("the file is a Parquet file"),
        [b'(' | b']' | b'}' | b')' | b'N' | b'I' | b'L' | b'F' | b'S' | b'V' | b'c' | b'G', ..]
        | [b'J' | b'K' | b'M' | b'T' | b'U' | b'X' | b'B' | b'C' | b'.', ..] => Ok(()),
        [b, ..] => fail(&format!(
            "it starts with byte 0x{b:02x} ({:?}), which no pickle starts with",
            String::from_utf8_lossy(&data[..data.len().min(8)])
        )),
    }
}

fn opcode_name(op: u8) -> &'static str {
    match op {
        b'B' => "BINBYTES",
        b'C' => "SHORT_BINBYTES",
        0x8e => "BINBYTES8",
        b'X' => "BINUNICODE",
        0x8c => "SHORT_BINUNICODE",
        0x8d => "BINUNICODE8",
        0x96 => "BYTEARRAY8",
        b'T' => "BINSTRING",
        b'U' => "SHORT_BINSTRING",
        0x8a => "LONG1",
        0x8b => "LONG4",
        0x95 => "FRAME",
        _ => "opcode",
    }
}

impl<'a> Machine<'a> {
    fn err<T>(&self, message: impl Into<String>) -> R<T> {
        Err(PickleError { offset: self.op_pos, message: message.into() })
    }

    fn malformed<T>(&self, what: &str) -> R<T> {
        self.err(format!("malformed pickle: {what} (opcode 0x{:02x})", self.op))
    }

    /// Borrow `n` bytes, refusing before any allocation if the file does not have them.
    fn take(&mut self, n: u64) -> R<&'a [u8]> {
        let left = self.data.len() - self.pos;
        if n > left as u64 {
            return self.err(format!(
                "{} declares {n} bytes, past the end of the file ({left} bytes left): \
                 the file is truncated or corrupt",
                opcode_name(self.op)
            ));
        }
        let s = &self.data[self.pos..self.pos + n as usize];
        self.pos += n as usize;
        Ok(s)
    }

    fn fixed<const N: usize>(&mut self) -> R<[u8; N]> {
        let left = self.data.len() - self.pos;
        if N > left {
            return self.err("truncated: the stream ends inside an opcode's argument");
        }
        let mut a = [0u8; N];
        a.copy_from_slice(&self.data[self.pos..self.pos + N]);
        self.pos += N;
        Ok(a)
    }

    fn u8(&mut self) -> R<u64> {
        Ok(self.fixed::<1>()?[0] as u64)
    }
    fn u32(&mut self) -> R<u64> {
        Ok(u32::from_le_bytes(self.fixed()?) as u64)
    }
    fn u64(&mut self) -> R<u64> {
        Ok(u64::from_le_bytes(self.fixed()?))
    }

    /// A protocol-0 text argument: the bytes up to the next newline.
    fn line(&mut self) -> R<&'a [u8]> {
        let rest = &self.data[self.pos..];
        match rest.iter().position(|&b| b == b'\n') {
            Some(n) => {
                self.pos += n + 1;
                Ok(&rest[..n])
            }
            None => self.err("truncated: the stream ends inside a text argument"),
        }
    }

    fn line_str(&mut self) -> R<&'a str> {
        let l = self.line()?;
        std::str::from_utf8(l).or_else(|_| self.malformed("text argument is not UTF-8"))
    }

    fn utf8(&self, b: &'a [u8]) -> R<Obj<'a>> {
        match std::str::from_utf8(b) {
            Ok(s) => Ok(Obj::Str(Cow::Borrowed(s))),
            Err(_) => self.malformed("string is not valid UTF-8"),
        }
    }

    fn push(&mut self, o: Obj<'a>) {
        self.objs.push(o);
        self.stack.push(self.objs.len() - 1);
    }

    fn floor(&self) -> usize {
        self.marks.last().copied().unwrap_or(0)
    }

    fn pop(&mut self) -> R<Id> {
        if self.stack.len() <= self.floor() {
            return self.malformed("stack underflow");
        }
        Ok(self.stack.pop().expect("checked above"))
    }

    fn top(&self) -> R<Id> {
        if self.stack.len() <= self.floor() {
            return self.malformed("stack underflow");
        }
        Ok(*self.stack.last().expect("checked above"))
    }

    fn pop_mark(&mut self) -> R<Vec<Id>> {
        match self.marks.pop() {
            Some(h) => Ok(self.stack.split_off(h)),
            None => self.malformed("MARK expected but none is open"),
        }
    }

    fn get(&mut self, key: u64) -> R<()> {
        match self.memo.get(&key) {
            Some(&id) => {
                self.stack.push(id);
                Ok(())
            }
            None => self.err(format!("malformed pickle: memo key {key} read before it was set")),
        }
    }

    fn put(&mut self, key: u64) -> R<()> {
        let id = self.top()?;
        self.memo.insert(key, id);
        Ok(())
    }

    fn text_int(&mut self) -> R<u64> {
        let l = self.line_str()?;
        l.trim().parse().or_else(|_| self.malformed("memo index is not a number"))
    }

    fn int_obj(v: i128) -> Obj<'a> {
        match i64::try_from(v) {
            Ok(i) => Obj::Int(i),
            Err(_) => Obj::BigInt(v.to_le_bytes().to_vec()),
        }
    }

    /// LONG1/LONG4 payload: little-endian two's complement of any length.
    fn long_bytes(b: &[u8]) -> Obj<'a> {
        if b.len() <= 8 {
            let mut buf = [if b.last().is_some_and(|&x| x & 0x80 != 0) { 0xff } else { 0 }; 8];
            buf[..b.len()].copy_from_slice(b);
            Obj::Int(i64::from_le_bytes(buf))
        } else {
            Obj::BigInt(b.to_vec())
        }
    }

    fn container_mut(&mut self, id: Id) -> &mut Obj<'a> {
        &mut self.objs[id]
    }

    fn set_items(&mut self, dict: Id, items: Vec<Id>) -> R<()> {
        if items.len() % 2 != 0 {
            return self.malformed("odd number of items for a dict");
        }
        let keys: Vec<Option<Vec<u8>>> = items.chunks(2).map(|kv| self.key_bytes(kv[0])).collect();
        let Obj::Dict(_) = &self.objs[dict] else {
            let t = self.objs[dict].type_name();
            return self.err(format!("malformed pickle: SETITEM on a {t}, not a dict"));
        };
        for (kv, key) in items.chunks(2).zip(keys) {
            // Python dict semantics: a repeated key replaces the earlier value.
            let existing = key.as_ref().and_then(|k| {
                let Obj::Dict(entries) = &self.objs[dict] else { unreachable!() };
                entries.iter().position(|(ek, _)| self.key_bytes(*ek).as_ref() == Some(k))
            });
            let Obj::Dict(entries) = self.container_mut(dict) else { unreachable!() };
            match existing {
                Some(i) => entries[i] = (kv[0], kv[1]),
                None => entries.push((kv[0], kv[1])),
            }
        }
        Ok(())
    }

    /// A comparable form of simple keys (str, bytes, int); None for the rest.
    fn key_bytes(&self, id: Id) -> Option<Vec<u8>> {
        match &self.objs[id] {
            Obj::Str(s) => Some([b"s", s.as_bytes()].concat()),
            Obj::Bytes(b) => Some([b"b", b.as_ref()].concat()),
            Obj::Int(i) => Some([b"i".as_slice(), &i.to_le_bytes()].concat()),
            _ => None,
        }
    }

    fn refuse_global(&self, how: &str, module: &str, name: &str) -> R<()> {
        self.err(format!(
            "refused global `{module}.{name}` ({how}): pgser only rebuilds numpy arrays and \
             plain values and never calls code named by a pickle"
        ))
    }

    fn step(&mut self) -> R<()> {
        match self.op {
            // --- framing and protocol ---
            0x80 => {
                let v = self.u8()?;
                if v > 5 {
                    return self.err(format!("unsupported pickle protocol {v} (this reader knows 0-5)"));
                }
            }
            0x95 => {
                // FRAME: only a hint for buffered readers; just check it is inside the file.
                let n = self.u64()?;
                let left = (self.data.len() - self.pos) as u64;
                if n > left {
                    self.take(n)?;
                }
            }
            // --- constants and numbers ---
            b'N' => self.push(Obj::None),
            0x88 => self.push(Obj::Bool(true)),
            0x89 => self.push(Obj::Bool(false)),
            b'I' => {
                let l = self.line_str()?.trim();
                let o = match l {
                    "00" => Obj::Bool(false),
                    "01" => Obj::Bool(true),
                    _ => match l.parse::<i128>() {
                        Ok(v) => Self::int_obj(v),
                        Err(_) => return self.malformed("INT argument is not a number"),
                    },
                };
                self.push(o);
            }
            b'L' => {
                let l = self.line_str()?.trim().trim_end_matches('L');
                match l.parse::<i128>() {
                    Ok(v) => self.push(Self::int_obj(v)),
                    Err(_) => self.push(Obj::BigInt(l.as_bytes().to_vec())),
                }
            }
            b'J' => {
                let v = i32::from_le_bytes(self.fixed()?);
                self.push(Obj::Int(v as i64));
            }
            b'K' => {
                let v = self.u8()?;
                self.push(Obj::Int(v as i64));
            }
            b'M' => {
                let v = u16::from_le_bytes(self.fixed()?);
                self.push(Obj::Int(v as i64));
            }
            0x8a => {
                let n = self.u8()?;
                let b = self.take(n)?;
                self.push(Self::long_bytes(b));
            }
            0x8b => {
                let n = i32::from_le_bytes(self.fixed()?);
                if n < 0 {
                    return self.malformed("LONG4 with a negative length");
                }
                let b = self.take(n as u64)?;
                self.push(Self::long_bytes(b));
            }
            b'F' => {
                let l = self.line_str()?.trim();
                match l.parse::<f64>() {
                    Ok(v) => self.push(Obj::Float(v)),
                    Err(_) => return self.malformed("FLOAT argument is not a number"),
                }
            }
            b'G' => {
                let v = f64::from_be_bytes(self.fixed()?);
                self.push(Obj::Float(v));
            }
            // --- strings and bytes ---
            b'S' => {
                let l = self.line()?;
                let b = decode_repr_string(l).or_else(|e| self.malformed(&e))?;
                self.push(Obj::Bytes(Cow::Owned(b)));
            }
            b'T' | b'U' | b'B' | b'C' | 0x8e | 0x96 => {
                let n = match self.op {
                    b'U' | b'C' => self.u8()?,
                    b'T' => {
                        let n = i32::from_le_bytes(self.fixed()?);
                        if n < 0 {
                            return self.malformed("BINSTRING with a negative length");
                        }
                        n as u64
                    }
                    b'B' => self.u32()?,
                    _ => self.u64()?,
                };
                let b = self.take(n)?;
                self.push(Obj::Bytes(Cow::Borrowed(b)));
            }
            b'V' => {
                let l = self.line()?;
                let s = decode_raw_unicode_escape(l).or_else(|e| self.malformed(&e))?;
                self.push(Obj::Str(Cow::Owned(s)));
            }
            b'X' | 0x8c | 0x8d => {
                let n = match self.op {
                    0x8c => self.u8()?,
                    b'X' => self.u32()?,
                    _ => self.u64()?,
                };
                let b = self.take(n)?;
                let s = self.utf8(b)?;
                self.push(s);
            }
            0x97 => {
                return self.err(
                    "NEXT_BUFFER: the pickle refers to an out-of-band buffer (protocol 5 with \
                     buffer_callback), whose bytes are not in the file",
                );
            }
            0x98 => {
                self.top()?;
            }
            // --- containers ---
            b']' => self.push(Obj::List(Vec::new())),
            b'}' => self.push(Obj::Dict(Vec::new())),
            b')' => self.push(Obj::Tuple(Vec::new())),
            0x8f => self.push(Obj::Set(Vec::new())),
            b'(' => self.marks.push(self.stack.len()),
            b'l' => {
                let items = self.pop_mark()?;
                self.push(Obj::List(items));
            }
            b't' => {
                let items = self.pop_mark()?;
                self.push(Obj::Tuple(items));
            }
            0x91 => {
                let items = self.pop_mark()?;
                self.push(Obj::Set(items));
            }
            0x85..=0x87 => {
                let n = (self.op - 0x84) as usize;
                let mut items = Vec::with_capacity(n);
                for _ in 0..n {
                    items.push(self.pop()?);
                }
                items.reverse();
                self.push(Obj::Tuple(items));
            }
            b'd' => {
                let items = self.pop_mark()?;
                self.push(Obj::Dict(Vec::new()));
                let d = self.top()?;
                self.set_items(d, items)?;
            }
            b'a' | b'e' | 0x90 => {
                let items = if self.op == b'a' { vec![self.pop()?] } else { self.pop_mark()? };
                let target = self.top()?;
                let want_set = self.op == 0x90;
                match self.container_mut(target) {
                    Obj::List(v) if !want_set => v.extend(items),
                    Obj::Set(v) if want_set => v.extend(items),
                    other => {
                        let t = other.type_name();
                        return self.malformed(&format!("cannot append to a {t}"));
                    }
                }
            }
            b's' => {
                let v = self.pop()?;
                let k = self.pop()?;
                let d = self.top()?;
                self.set_items(d, vec![k, v])?;
            }
            b'u' => {
                let items = self.pop_mark()?;
                let d = self.top()?;
                self.set_items(d, items)?;
            }
            // --- stack and memo ---
            b'0' => {
                if self.stack.len() > self.floor() {
                    self.stack.pop();
                } else {
                    self.pop_mark()?;
                }
            }
            b'1' => {
                self.pop_mark()?;
            }
            b'2' => {
                let t = self.top()?;
                self.stack.push(t);
            }
            b'g' => {
                let k = self.text_int()?;
                self.get(k)?;
            }
            b'h' => {
                let k = self.u8()?;
                self.get(k)?;
            }
            b'j' => {
                let k = self.u32()?;
                self.get(k)?;
            }
            b'p' => {
                let k = self.text_int()?;
                self.put(k)?;
            }
            b'q' => {
                let k = self.u8()?;
                self.put(k)?;
            }
            b'r' => {
                let k = self.u32()?;
                self.put(k)?;
            }
            0x94 => {
                let k = self.memo.len() as u64;
                self.put(k)?;
            }
            // --- globals and calls: the allow-list lives here ---
            b'c' => {
                let module = self.line_str()?;
                let name = self.line_str()?;
                match Global::resolve(module, name) {
                    Some(g) => self.push(Obj::Global(g)),
                    None => return self.refuse_global("GLOBAL", module, name),
                }
            }
            0x93 => {
                let name = self.pop()?;
                let module = self.pop()?;
                let (Obj::Str(m), Obj::Str(n)) = (&self.objs[module], &self.objs[name]) else {
                    return self.malformed("STACK_GLOBAL needs two strings");
                };
                let (m, n) = (m.to_string(), n.to_string());
                match Global::resolve(&m, &n) {
                    Some(g) => self.push(Obj::Global(g)),
                    None => return self.refuse_global("STACK_GLOBAL", &m, &n),
                }
            }
            b'i' => {
                let module = self.line_str()?;
                let name = self.line_str()?;
                return self.refuse_global("INST", module, name);
            }
            b'o' => {
                let items = self.pop_mark()?;
                let what = items.first().map(|&c| self.describe_callable(c));
                return self.err(format!(
                    "refused global {} (OBJ): pgser never instantiates classes named by a pickle",
                    what.unwrap_or_else(|| "<none>".into())
                ));
            }
            0x81 | 0x92 => {
                if self.op == 0x92 {
                    self.pop()?; // kwargs
                }
                self.pop()?; // args
                let cls = self.pop()?;
                let what = self.describe_callable(cls);
                return self.err(format!(
                    "refused global {what} (NEWOBJ): pgser never instantiates classes named by a pickle"
                ));
            }
            0x82..=0x84 => {
                return self.err("refused global from the copyreg extension registry (EXT opcode)");
            }
            b'P' | b'Q' => {
                return self.err("refused persistent id: the pickle refers to objects outside the file");
            }
            b'R' => {
                let args = self.pop()?;
                let func = self.pop()?;
                let Obj::Global(g) = self.objs[func] else {
                    return self.malformed("REDUCE on something that is not a global");
                };
                let Obj::Tuple(args) = self.objs[args].clone() else {
                    return self.malformed("REDUCE arguments are not a tuple");
                };
                let o = self.call(g, &args)?;
                self.push(o);
            }
            b'b' => {
                let state = self.pop()?;
                let target = self.top()?;
                self.build(target, state)?;
            }
            op => {
                return self.err(format!("unknown opcode 0x{op:02x}: corrupt pickle or not a pickle"));
            }
        }
        Ok(())
    }

    fn describe_callable(&self, id: Id) -> String {
        match &self.objs[id] {
            Obj::Global(g) => format!("`{g:?}`"),
            o => format!("<{}>", o.type_name()),
        }
    }

    // --- the allow-listed calls ---

    fn call(&mut self, g: Global, args: &[Id]) -> R<Obj<'a>> {
        let bad = |m: &Self, what: &str| m.err(format!("bad arguments to {g:?}: {what}"));
        match g {
            Global::Reconstruct => match args.first().map(|&a| &self.objs[a]) {
                Some(Obj::Global(Global::NdArrayType)) => Ok(Obj::PendingArray),
                _ => bad(self, "only numpy.ndarray can be reconstructed"),
            },
            Global::DTypeCtor => match args.first().map(|&a| &self.objs[a]) {
                Some(Obj::Str(s)) => {
                    let s = s.to_string();
                    DType::from_typestr(&s).map(Obj::DType).or_else(|e| self.malformed(&e))
                }
                _ => bad(self, "dtype needs a type string"),
            },
            Global::FromBuffer => {
                let [buf, dtype, shape, order] = args else {
                    return bad(self, "expected (buffer, dtype, shape, order)");
                };
                let data = self.bytes_of(*buf)?;
                let dtype = self.dtype_of(*dtype)?;
                let shape = self.shape_of(*shape)?;
                let fortran = matches!(&self.objs[*order], Obj::Str(s) if s == "F");
                self.array(dtype, shape, fortran, data)
            }
            Global::Scalar => {
                let [dtype, data] = args else {
                    return bad(self, "expected (dtype, bytes)");
                };
                let dtype = self.dtype_of(*dtype)?;
                let data = self.bytes_of(*data)?;
                self.array(dtype, Vec::new(), false, data)
            }
            Global::CodecsEncode => match args {
                [s, enc] if matches!(&self.objs[*enc], Obj::Str(e) if e == "latin1" || e == "latin-1") => {
                    let Obj::Str(s) = &self.objs[*s] else {
                        return bad(self, "encode needs a str");
                    };
                    latin1(s).map(|b| Obj::Bytes(Cow::Owned(b))).or_else(|e| self.malformed(&e))
                }
                _ => bad(self, "only str.encode('latin1') is allowed"),
            },
            Global::ByteArray => match args {
                [] => Ok(Obj::Bytes(Cow::Owned(Vec::new()))),
                // bytearray(int) would allocate an attacker-chosen size: refused.
                [b] | [b, _] => self.bytes_of(*b).map(Obj::Bytes),
                _ => bad(self, "expected bytes"),
            },
            Global::Set | Global::FrozenSet => match args.first().map(|&a| &self.objs[a]) {
                None => Ok(Obj::Set(Vec::new())),
                Some(Obj::List(v) | Obj::Tuple(v) | Obj::Set(v)) => Ok(Obj::Set(v.clone())),
                _ => bad(self, "expected a list"),
            },
            Global::OrderedDict => match args {
                [] => Ok(Obj::Dict(Vec::new())),
                _ => bad(self, "OrderedDict is only rebuilt from ()"),
            },
            Global::NdArrayType => self.err("refused call of numpy.ndarray: not a reconstruction path"),
        }
    }

    /// BUILD: the second half of numpy's array and dtype reconstruction. BUILD on anything
    /// else would mean calling `__setstate__` of an arbitrary object, so it is refused.
    fn build(&mut self, target: Id, state: Id) -> R<()> {
        match &self.objs[target] {
            Obj::PendingArray => {
                let Obj::Tuple(st) = self.objs[state].clone() else {
                    return self.malformed("array state is not a tuple");
                };
                // (version, shape, dtype, is_fortran, data) or, from old numpy, without version.
                let st = match st.len() {
                    5 => &st[1..],
                    4 => &st[..],
                    _ => return self.malformed("array state has the wrong length"),
                };
                let shape = self.shape_of(st[0])?;
                let dtype = self.dtype_of(st[1])?;
                let fortran = match self.objs[st[2]] {
                    Obj::Bool(b) => b,
                    Obj::Int(i) => i != 0,
                    _ => return self.malformed("array is_fortran flag is not a bool"),
                };
                if let Obj::List(_) = self.objs[st[3]] {
                    return self.err(format!(
                        "array dtype {} is not supported: object arrays hold Python objects",
                        dtype.name()
                    ));
                }
                let data = self.bytes_of(st[3])?;
                self.objs[target] = self.array(dtype, shape, fortran, data)?;
                Ok(())
            }
            Obj::DType(_) => {
                let endian = match &self.objs[state] {
                    Obj::Tuple(st) if st.len() >= 2 => match &self.objs[st[1]] {
                        Obj::Str(e) => e.to_string(),
                        _ => return self.malformed("dtype byte order is not a str"),
                    },
                    _ => return self.malformed("dtype state is not a tuple"),
                };
                let Obj::DType(d) = &mut self.objs[target] else { unreachable!() };
                d.big_endian = endian == ">";
                Ok(())
            }
            other => {
                let t = other.type_name();
                self.err(format!("refused BUILD on a {t}: only numpy arrays and dtypes are rebuilt"))
            }
        }
    }

    fn array(&self, dtype: DType, shape: Vec<usize>, fortran: bool, data: Cow<'a, [u8]>) -> R<Obj<'a>> {
        NdArray::assemble(dtype, shape, fortran, data).map(Obj::Array).or_else(|e| self.err(e))
    }

    fn bytes_of(&self, id: Id) -> R<Cow<'a, [u8]>> {
        match &self.objs[id] {
            Obj::Bytes(b) => Ok(b.clone()),
            // Python 2 pickles loaded with encoding='latin1' carry array data as str.
            Obj::Str(s) => latin1(s).map(Cow::Owned).or_else(|e| self.malformed(&e)),
            o => self.malformed(&format!("expected bytes, found a {}", o.type_name())),
        }
    }

    fn dtype_of(&self, id: Id) -> R<DType> {
        match &self.objs[id] {
            Obj::DType(d) => Ok(d.clone()),
            o => self.malformed(&format!("expected a numpy dtype, found a {}", o.type_name())),
        }
    }

    fn shape_of(&self, id: Id) -> R<Vec<usize>> {
        let Obj::Tuple(dims) = &self.objs[id] else {
            return self.malformed("array shape is not a tuple");
        };
        dims.iter()
            .map(|&d| match self.objs[d] {
                Obj::Int(i) if i >= 0 => Ok(i as usize),
                _ => self.malformed("array shape holds something other than a non-negative int"),
            })
            .collect()
    }
}

/// `str.encode('latin1')`: every char must be below 256.
fn latin1(s: &str) -> Result<Vec<u8>, String> {
    s.chars().map(|c| u8::try_from(c as u32).map_err(|_| format!("char U+{:04X} is not latin-1", c as u32))).collect()
}

/// Protocol 0 UNICODE: raw-unicode-escape (latin-1 bytes plus `\uXXXX` / `\UXXXXXXXX`).
fn decode_raw_unicode_escape(b: &[u8]) -> Result<String, String> {
    let mut out = String::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        let width = match (b[i], b.get(i + 1)) {
            (b'\\', Some(b'u')) => 4,
            (b'\\', Some(b'U')) => 8,
            _ => {
                out.push(b[i] as char);
                i += 1;
                continue;
            }
        };
        let hex = b.get(i + 2..i + 2 + width).ok_or("truncated \\u escape")?;
        let hex = std::str::from_utf8(hex).map_err(|_| "bad \\u escape")?;
        let cp = u32::from_str_radix(hex, 16).map_err(|_| "bad \\u escape")?;
        out.push(char::from_u32(cp).ok_or("\\u escape is not a valid char")?);
        i += 2 + width;
    }
    Ok(out)
}

/// Protocol 0 STRING: a Python 2 `repr` of a byte string, quotes included.
fn decode_repr_string(line: &[u8]) -> Result<Vec<u8>, String> {
    let q = *line.first().ok_or("empty STRING")?;
    if line.len() < 2 || (q != b'\'' && q != b'"') || line[line.len() - 1] != q {
        return Err("STRING argument is not quoted".into());
    }
    let body = &line[1..line.len() - 1];
    let mut out = Vec::with_capacity(body.len());
    let mut i = 0;
    while i < body.len() {
        if body[i] != b'\\' {
            out.push(body[i]);
            i += 1;
            continue;
        }
        let e = *body.get(i + 1).ok_or("dangling backslash in STRING")?;
        i += 2;
        match e {
            b'n' => out.push(b'\n'),
            b'r' => out.push(b'\r'),
            b't' => out.push(b'\t'),
            b'a' => out.push(7),
            b'b' => out.push(8),
            b'f' => out.push(12),
            b'v' => out.push(11),
            b'x' => {
                let h = body.get(i..i + 2).ok_or("truncated \\x escape")?;
                let h = std::str::from_utf8(h).map_err(|_| "bad \\x escape")?;
                out.push(u8::from_str_radix(h, 16).map_err(|_| "bad \\x escape")?);
                i += 2;
            }
            b'0'..=b'7' => {
                let mut v = (e - b'0') as u32;
                for _ in 0..2 {
                    match body.get(i) {
                        Some(&d @ b'0'..=b'7') => {
                            v = v * 8 + (d - b'0') as u32;
                            i += 1;
                        }
                        _ => break,
                    }
                }
                out.push(v as u8);
            }
            other => out.push(other),
        }
    }
    Ok(out)
}
