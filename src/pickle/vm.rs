//! The opcode loop. Mirrors CPython's `_Unpickler` (Lib/pickle.py) opcode by opcode, except
//! that calls are limited to [`Global`]'s allow-list and every length is bounds-checked
//! before it is used.

use std::borrow::Cow;
use std::collections::HashMap;

use super::numpy::Global;
use super::op;
use super::text::{decode_raw_unicode_escape, decode_repr_string};
use super::{Id, Obj, Pickle, PickleError};

type R<T> = Result<T, PickleError>;

pub(super) struct Machine<'a> {
    pub(super) data: &'a [u8],
    pub(super) pos: usize,
    /// Offset of the opcode being executed, for error messages.
    pub(super) op_pos: usize,
    pub(super) op: u8,
    pub(super) objs: Vec<Obj<'a>>,
    pub(super) stack: Vec<Id>,
    /// Stack heights at each MARK (CPython's metastack).
    pub(super) marks: Vec<usize>,
    pub(super) memo: HashMap<u64, Id>,
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
        if m.op == op::STOP {
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
        [op::PROTO, ..] => Ok(()),
        [0x1f, 0x8b, ..] => fail("the file is gzip-compressed; decompress it first (gunzip)"),
        [b'P', b'K', 3, 4, ..] => fail("the file is a zip archive (an .npz?); extract it first"),
        [0x93, b'N', b'U', b'M', b'P', b'Y', ..] => fail("the file is a .npy array file"),
        [b'P', b'A', b'R', b'1', ..] => fail("the file is a Parquet file"),
        [
            op::MARK
            | op::EMPTY_LIST
            | op::EMPTY_DICT
            | op::EMPTY_TUPLE
            | op::NONE
            | op::INT
            | op::LONG
            | op::FLOAT
            | op::STRING
            | op::UNICODE
            | op::GLOBAL
            | op::BINFLOAT,
            ..,
        ]
        | [
            op::BININT
            | op::BININT1
            | op::BININT2
            | op::BINSTRING
            | op::SHORT_BINSTRING
            | op::BINUNICODE
            | op::BINBYTES
            | op::SHORT_BINBYTES
            | op::STOP,
            ..,
        ] => Ok(()),
        [b, ..] => fail(&format!(
            "it starts with byte 0x{b:02x} ({:?}), which no pickle starts with",
            String::from_utf8_lossy(&data[..data.len().min(8)])
        )),
    }
}

fn opcode_name(op: u8) -> &'static str {
    op::name(op)
}

impl<'a> Machine<'a> {
    pub(super) fn err<T>(&self, message: impl Into<String>) -> R<T> {
        Err(PickleError { offset: self.op_pos, message: message.into() })
    }

    pub(super) fn malformed<T>(&self, what: &str) -> R<T> {
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
        if !items.len().is_multiple_of(2) {
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
            op::PROTO => {
                let v = self.u8()?;
                if v > 5 {
                    return self.err(format!("unsupported pickle protocol {v} (this reader knows 0-5)"));
                }
            }
            op::FRAME => {
                // FRAME: only a hint for buffered readers; just check it is inside the file.
                let n = self.u64()?;
                let left = (self.data.len() - self.pos) as u64;
                if n > left {
                    self.take(n)?;
                }
            }
            // --- constants and numbers ---
            op::NONE => self.push(Obj::None),
            op::NEWTRUE => self.push(Obj::Bool(true)),
            op::NEWFALSE => self.push(Obj::Bool(false)),
            op::INT => {
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
            op::LONG => {
                let l = self.line_str()?.trim().trim_end_matches('L');
                match l.parse::<i128>() {
                    Ok(v) => self.push(Self::int_obj(v)),
                    Err(_) => self.push(Obj::BigInt(l.as_bytes().to_vec())),
                }
            }
            op::BININT => {
                let v = i32::from_le_bytes(self.fixed()?);
                self.push(Obj::Int(v as i64));
            }
            op::BININT1 => {
                let v = self.u8()?;
                self.push(Obj::Int(v as i64));
            }
            op::BININT2 => {
                let v = u16::from_le_bytes(self.fixed()?);
                self.push(Obj::Int(v as i64));
            }
            op::LONG1 => {
                let n = self.u8()?;
                let b = self.take(n)?;
                self.push(Self::long_bytes(b));
            }
            op::LONG4 => {
                let n = i32::from_le_bytes(self.fixed()?);
                if n < 0 {
                    return self.malformed("LONG4 with a negative length");
                }
                let b = self.take(n as u64)?;
                self.push(Self::long_bytes(b));
            }
            op::FLOAT => {
                let l = self.line_str()?.trim();
                match l.parse::<f64>() {
                    Ok(v) => self.push(Obj::Float(v)),
                    Err(_) => return self.malformed("FLOAT argument is not a number"),
                }
            }
            op::BINFLOAT => {
                let v = f64::from_be_bytes(self.fixed()?);
                self.push(Obj::Float(v));
            }
            // --- strings and bytes ---
            op::STRING => {
                let l = self.line()?;
                let b = decode_repr_string(l).or_else(|e| self.malformed(&e))?;
                self.push(Obj::Bytes(Cow::Owned(b)));
            }
            op::BINSTRING
            | op::SHORT_BINSTRING
            | op::BINBYTES
            | op::SHORT_BINBYTES
            | op::BINBYTES8
            | op::BYTEARRAY8 => {
                let n = match self.op {
                    op::SHORT_BINSTRING | op::SHORT_BINBYTES => self.u8()?,
                    op::BINSTRING => {
                        let n = i32::from_le_bytes(self.fixed()?);
                        if n < 0 {
                            return self.malformed("BINSTRING with a negative length");
                        }
                        n as u64
                    }
                    op::BINBYTES => self.u32()?,
                    _ => self.u64()?,
                };
                let b = self.take(n)?;
                self.push(Obj::Bytes(Cow::Borrowed(b)));
            }
            op::UNICODE => {
                let l = self.line()?;
                let s = decode_raw_unicode_escape(l).or_else(|e| self.malformed(&e))?;
                self.push(Obj::Str(Cow::Owned(s)));
            }
            op::BINUNICODE | op::SHORT_BINUNICODE | op::BINUNICODE8 => {
                let n = match self.op {
                    op::SHORT_BINUNICODE => self.u8()?,
                    op::BINUNICODE => self.u32()?,
                    _ => self.u64()?,
                };
                let b = self.take(n)?;
                let s = self.utf8(b)?;
                self.push(s);
            }
            op::NEXT_BUFFER => {
                return self.err(
                    "NEXT_BUFFER: the pickle refers to an out-of-band buffer (protocol 5 with \
                     buffer_callback), whose bytes are not in the file",
                );
            }
            op::READONLY_BUFFER => {
                self.top()?;
            }
            // --- containers ---
            op::EMPTY_LIST => self.push(Obj::List(Vec::new())),
            op::EMPTY_DICT => self.push(Obj::Dict(Vec::new())),
            op::EMPTY_TUPLE => self.push(Obj::Tuple(Vec::new())),
            op::EMPTY_SET => self.push(Obj::Set(Vec::new())),
            op::MARK => self.marks.push(self.stack.len()),
            op::LIST => {
                let items = self.pop_mark()?;
                self.push(Obj::List(items));
            }
            op::TUPLE => {
                let items = self.pop_mark()?;
                self.push(Obj::Tuple(items));
            }
            op::FROZENSET => {
                let items = self.pop_mark()?;
                self.push(Obj::Set(items));
            }
            op::TUPLE1..=op::TUPLE3 => {
                let n = (self.op - op::TUPLE1 + 1) as usize;
                let mut items = Vec::with_capacity(n);
                for _ in 0..n {
                    items.push(self.pop()?);
                }
                items.reverse();
                self.push(Obj::Tuple(items));
            }
            op::DICT => {
                let items = self.pop_mark()?;
                self.push(Obj::Dict(Vec::new()));
                let d = self.top()?;
                self.set_items(d, items)?;
            }
            op::APPEND | op::APPENDS | op::ADDITEMS => {
                let items = if self.op == op::APPEND { vec![self.pop()?] } else { self.pop_mark()? };
                let target = self.top()?;
                let want_set = self.op == op::ADDITEMS;
                match self.container_mut(target) {
                    Obj::List(v) if !want_set => v.extend(items),
                    Obj::Set(v) if want_set => v.extend(items),
                    other => {
                        let t = other.type_name();
                        return self.malformed(&format!("cannot append to a {t}"));
                    }
                }
            }
            op::SETITEM => {
                let v = self.pop()?;
                let k = self.pop()?;
                let d = self.top()?;
                self.set_items(d, vec![k, v])?;
            }
            op::SETITEMS => {
                let items = self.pop_mark()?;
                let d = self.top()?;
                self.set_items(d, items)?;
            }
            // --- stack and memo ---
            op::POP => {
                if self.stack.len() > self.floor() {
                    self.stack.pop();
                } else {
                    self.pop_mark()?;
                }
            }
            op::POP_MARK => {
                self.pop_mark()?;
            }
            op::DUP => {
                let t = self.top()?;
                self.stack.push(t);
            }
            op::GET => {
                let k = self.text_int()?;
                self.get(k)?;
            }
            op::BINGET => {
                let k = self.u8()?;
                self.get(k)?;
            }
            op::LONG_BINGET => {
                let k = self.u32()?;
                self.get(k)?;
            }
            op::PUT => {
                let k = self.text_int()?;
                self.put(k)?;
            }
            op::BINPUT => {
                let k = self.u8()?;
                self.put(k)?;
            }
            op::LONG_BINPUT => {
                let k = self.u32()?;
                self.put(k)?;
            }
            op::MEMOIZE => {
                let k = self.memo.len() as u64;
                self.put(k)?;
            }
            // --- globals and calls: the allow-list lives here ---
            op::GLOBAL => {
                let module = self.line_str()?;
                let name = self.line_str()?;
                match Global::resolve(module, name) {
                    Some(g) => self.push(Obj::Global(g)),
                    None => return self.refuse_global("GLOBAL", module, name),
                }
            }
            op::STACK_GLOBAL => {
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
            op::INST => {
                let module = self.line_str()?;
                let name = self.line_str()?;
                return self.refuse_global("INST", module, name);
            }
            op::OBJ => {
                let items = self.pop_mark()?;
                let what = items.first().map(|&c| self.describe_callable(c));
                return self.err(format!(
                    "refused global {} (OBJ): pgser never instantiates classes named by a pickle",
                    what.unwrap_or_else(|| "<none>".into())
                ));
            }
            op::NEWOBJ | op::NEWOBJ_EX => {
                if self.op == op::NEWOBJ_EX {
                    self.pop()?; // kwargs
                }
                self.pop()?; // args
                let cls = self.pop()?;
                let what = self.describe_callable(cls);
                return self.err(format!(
                    "refused global {what} (NEWOBJ): pgser never instantiates classes named by a pickle"
                ));
            }
            op::EXT1..=op::EXT4 => {
                return self.err("refused global from the copyreg extension registry (EXT opcode)");
            }
            op::PERSID | op::BINPERSID => {
                return self.err("refused persistent id: the pickle refers to objects outside the file");
            }
            op::REDUCE => {
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
            op::BUILD => {
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
}
