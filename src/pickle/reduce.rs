//! REDUCE and BUILD for the allow-listed globals: the only "calls" a pickle can make here.
//! Each rebuilds a value from plain arguments; none runs code named by the file.

use std::borrow::Cow;

use super::numpy::{Global, NdArray, PickledDtype};
use super::text::latin1;
use super::vm::Machine;
use super::{Id, Obj};

type R<T> = Result<T, super::PickleError>;

impl<'a> Machine<'a> {
    pub(super) fn call(&mut self, g: Global, args: &[Id]) -> R<Obj<'a>> {
        let bad = |m: &Self, what: &str| m.err(format!("bad arguments to {g:?}: {what}"));
        match g {
            Global::Reconstruct => match args.first().map(|&a| &self.objs[a]) {
                Some(Obj::Global(Global::NdArrayType)) => Ok(Obj::PendingArray),
                _ => bad(self, "only numpy.ndarray can be reconstructed"),
            },
            Global::DTypeCtor => match args.first().map(|&a| &self.objs[a]) {
                Some(Obj::Str(s)) => {
                    let s = s.to_string();
                    PickledDtype::from_typestr(&s).map(Obj::DType).or_else(|e| self.malformed(&e))
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
    pub(super) fn build(&mut self, target: Id, state: Id) -> R<()> {
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
                    // An object array: its elements are Python objects, never a column's values.
                    self.objs[target] = Obj::Unreadable(dtype.name());
                    return Ok(());
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
                d.set_big_endian(endian == ">");
                Ok(())
            }
            other => {
                let t = other.type_name();
                self.err(format!("refused BUILD on a {t}: only numpy arrays and dtypes are rebuilt"))
            }
        }
    }

    fn array(&self, dtype: PickledDtype, shape: Vec<usize>, fortran: bool, data: Cow<'a, [u8]>) -> R<Obj<'a>> {
        if let PickledDtype::Other(_) = dtype {
            return Ok(Obj::Unreadable(dtype.name()));
        }
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

    fn dtype_of(&self, id: Id) -> R<PickledDtype> {
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
