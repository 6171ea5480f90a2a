//! numpy arrays and dtypes as pickles spell them, and the closed list of globals we resolve.
//!
//! numpy pickles an array in one of two ways:
//! * protocols 0–4 (and non-contiguous arrays in 5): `_reconstruct(ndarray, (0,), b'b')`, then
//!   BUILD with state `(version, shape, dtype, is_fortran, raw_bytes)`;
//! * protocol 5: `_frombuffer(buffer, dtype, shape, order)` with the bytes in-band
//!   (BYTEARRAY8/BINBYTES8) or out-of-band (NEXT_BUFFER, which a file cannot carry).
//!
//! A dtype is `dtype('f8', False, True)` then BUILD with `(3, '<', None, …)`: the byte order
//! only arrives with BUILD. numpy 1.x names live in `numpy.core.*`, numpy 2.x in `numpy._core.*`.

use std::borrow::Cow;

use crate::dtype::Dtype;

/// Every global the machine will resolve. Anything else is refused by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Global {
    Reconstruct,
    NdArrayType,
    DTypeCtor,
    FromBuffer,
    Scalar,
    CodecsEncode,
    ByteArray,
    Set,
    FrozenSet,
    OrderedDict,
}

impl Global {
    pub fn resolve(module: &str, name: &str) -> Option<Global> {
        let core = |m: &str, sub: &str| m == format!("numpy.core.{sub}") || m == format!("numpy._core.{sub}");
        Some(match (module, name) {
            (m, "_reconstruct") if core(m, "multiarray") => Global::Reconstruct,
            (m, "_frombuffer") if core(m, "numeric") => Global::FromBuffer,
            (m, "scalar") if core(m, "multiarray") => Global::Scalar,
            ("numpy", "ndarray") => Global::NdArrayType,
            (m, "ndarray") if core(m, "multiarray") => Global::NdArrayType,
            ("numpy", "dtype") => Global::DTypeCtor,
            (m, "dtype") if core(m, "multiarray") => Global::DTypeCtor,
            ("_codecs", "encode") => Global::CodecsEncode,
            ("builtins" | "__builtin__", "bytearray") => Global::ByteArray,
            ("builtins" | "__builtin__", "set") => Global::Set,
            ("builtins" | "__builtin__", "frozenset") => Global::FrozenSet,
            ("collections", "OrderedDict") => Global::OrderedDict,
            _ => return None,
        })
    }
}

/// A dtype as a pickle rebuilds it: a numeric one ([`Dtype`]), or another of numpy's (object,
/// unicode, void, complex, datetime), kept by its type string so that an array of it is refused
/// by name when it is assembled, not where the dtype appears.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PickledDtype {
    Numeric(Dtype),
    Other(String),
}

impl PickledDtype {
    /// numpy's type string as `dtype(...)` takes it (`f8`, `<i4`, `b1`, `U5`). A string with no
    /// kind character, or no size after it, is malformed.
    pub fn from_typestr(s: &str) -> Result<Self, String> {
        let rest = s.strip_prefix(['<', '>', '=', '|']).unwrap_or(s);
        let mut chars = rest.chars();
        if chars.next().is_none() {
            return Err(format!("empty dtype string {s:?}"));
        }
        if chars.as_str().parse::<usize>().is_err() {
            return Err(format!("bad dtype string {s:?}"));
        }
        Ok(match Dtype::parse(s) {
            Some(d) => PickledDtype::Numeric(d),
            None => PickledDtype::Other(s.to_string()),
        })
    }

    /// The byte order a dtype's BUILD state gives it (`>` big-endian; `<`, `=`, `|` not).
    pub fn set_big_endian(&mut self, big_endian: bool) {
        if let PickledDtype::Numeric(d) = self {
            *d = d.with_big_endian(big_endian);
        }
    }

    /// Human name, numpy style: float64, int32, uint8, bool; `unicode string (U5)`.
    pub fn name(&self) -> String {
        match self {
            PickledDtype::Numeric(d) => d.name(),
            PickledDtype::Other(s) => describe_unsupported(s),
        }
    }
}

fn describe_unsupported(s: &str) -> String {
    let kind = match s.trim_start_matches(['<', '>', '=', '|']).chars().next() {
        Some('O') => "object",
        Some('U') => "unicode string",
        Some('S') => "byte string",
        Some('V') => "void/structured",
        Some('c') => "complex",
        Some('M' | 'm') => "datetime",
        _ => "unknown",
    };
    format!("{kind} ({s})")
}

/// A numeric array in native (little-endian) byte order and C (row-major) layout.
#[derive(Debug, Clone)]
pub struct NdArray<'a> {
    /// The dtype as the pickle stored it, byte order included (`data` is little-endian all the
    /// same): what a passthrough column records, so that an export gives the array back as it was.
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    /// Little-endian, C-order element bytes; borrowed from the file when no conversion was
    /// needed (and therefore not necessarily aligned: read with `from_le_bytes`).
    pub data: Cow<'a, [u8]>,
}

impl<'a> NdArray<'a> {
    /// Check sizes and convert to native C order. `data` is in memory order as pickled.
    pub fn assemble(
        dtype: PickledDtype,
        shape: Vec<usize>,
        fortran: bool,
        data: Cow<'a, [u8]>,
    ) -> Result<Self, String> {
        let dtype = match dtype {
            PickledDtype::Numeric(d) => d,
            other => {
                return Err(format!(
                    "array dtype {} is not supported: only float, int, uint and bool arrays are read",
                    other.name()
                ));
            }
        };
        let count = shape
            .iter()
            .try_fold(1usize, |acc, &d| acc.checked_mul(d))
            .and_then(|n| n.checked_mul(dtype.size))
            .ok_or_else(|| format!("array shape {shape:?} overflows"))?;
        if count != data.len() {
            return Err(format!(
                "array of shape {shape:?} and dtype {} needs {count} bytes but {} were pickled",
                dtype.name(),
                data.len()
            ));
        }
        let needs_transpose = fortran && shape.iter().filter(|&&d| d > 1).count() > 1;
        let data = if dtype.big_endian || needs_transpose {
            let mut owned = if needs_transpose { fortran_to_c(&data, &shape, dtype.size) } else { data.into_owned() };
            dtype.reorder(&mut owned);
            Cow::Owned(owned)
        } else {
            data
        };
        Ok(NdArray { dtype, shape, data })
    }

    pub fn len(&self) -> usize {
        self.shape.iter().product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// numpy-style shape text, e.g. `(200, 50, 10)`.
    pub fn shape_text(&self) -> String {
        shape_text(&self.shape)
    }
}

pub fn shape_text(shape: &[usize]) -> String {
    match shape {
        [one] => format!("({one},)"),
        _ => format!("({})", shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")),
    }
}

/// Reorder elements from column-major to row-major: walk the C-order output with an odometer
/// over the multi-index, keeping the Fortran offset of that index up to date.
pub(crate) fn fortran_to_c(src: &[u8], shape: &[usize], size: usize) -> Vec<u8> {
    let n: usize = shape.iter().product();
    let mut out = vec![0u8; src.len()];
    let ndim = shape.len();
    let mut fstride = vec![1usize; ndim];
    for k in 1..ndim {
        fstride[k] = fstride[k - 1] * shape[k - 1];
    }
    let mut idx = vec![0usize; ndim];
    let mut off = 0usize;
    for i in 0..n {
        out[i * size..(i + 1) * size].copy_from_slice(&src[off * size..(off + 1) * size]);
        for k in (0..ndim).rev() {
            idx[k] += 1;
            off += fstride[k];
            if idx[k] < shape[k] {
                break;
            }
            off -= fstride[k] * shape[k];
            idx[k] = 0;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fortran_transpose_matches_index_formula() {
        let shape = [2usize, 3, 4];
        // Fortran buffer holding value = C index of (i,j,k).
        let mut f = vec![0u8; 24 * 2];
        for i in 0..2 {
            for j in 0..3 {
                for k in 0..4 {
                    let c = (i * 3 + j) * 4 + k;
                    let foff = i + 2 * (j + 3 * k);
                    f[foff * 2..foff * 2 + 2].copy_from_slice(&(c as u16).to_le_bytes());
                }
            }
        }
        let out = fortran_to_c(&f, &shape, 2);
        for c in 0..24 {
            assert_eq!(u16::from_le_bytes([out[c * 2], out[c * 2 + 1]]), c as u16);
        }
    }

    #[test]
    fn typestr_parsing() {
        assert_eq!(PickledDtype::from_typestr("f8").unwrap(), PickledDtype::Numeric(Dtype::F64));
        let be = PickledDtype::from_typestr(">i4").unwrap();
        assert_eq!(be, PickledDtype::Numeric(Dtype::I32.with_big_endian(true)));
        assert_eq!(PickledDtype::from_typestr("O8").unwrap(), PickledDtype::Other("O8".into()));
        assert_eq!(PickledDtype::from_typestr("U5").unwrap().name(), "unicode string (U5)");
        assert!(PickledDtype::from_typestr("f").is_err());
        assert!(PickledDtype::from_typestr("é").is_err());
        assert_eq!(PickledDtype::from_typestr("é4").unwrap().name(), "unknown (é4)");
    }

    /// A big-endian array comes out little-endian, its dtype still saying how it was stored.
    #[test]
    fn a_big_endian_array_is_turned_around() {
        let be = PickledDtype::Numeric(Dtype::I16.with_big_endian(true));
        let a = NdArray::assemble(be, vec![2], false, Cow::Owned(vec![0, 1, 0, 2])).unwrap();
        assert_eq!((a.dtype.big_endian, &a.data[..]), (true, &[1, 0, 2, 0][..]));
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let e = NdArray::assemble(PickledDtype::Numeric(Dtype::F64), vec![2, 3], false, Cow::Owned(vec![0; 40]));
        assert!(e.unwrap_err().contains("needs 48 bytes"));
    }
}
