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

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DTypeKind {
    Float,
    Int,
    UInt,
    Bool,
}

/// A numeric dtype. `big_endian` is only meaningful while assembling; arrays handed out are
/// always native (little-endian) order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DType {
    pub kind: DTypeKind,
    pub size: usize,
    pub big_endian: bool,
    /// numpy's type string as pickled (e.g. "f8", "O8", "U5"); set when `kind` is unusable.
    unsupported: Option<String>,
}

impl DType {
    pub fn float(size: usize) -> Self {
        DType { kind: DTypeKind::Float, size, big_endian: false, unsupported: None }
    }

    /// Parse numpy's type string (`f8`, `<i4`, `b1`, …). Kinds numpy has but we don't read
    /// (object, unicode, void, complex, datetime) parse into an unsupported dtype so that the
    /// error can name the array's dtype when the array is assembled.
    pub fn from_typestr(s: &str) -> Result<Self, String> {
        let (big_endian, rest) = match s.as_bytes().first() {
            Some(b'>') => (true, &s[1..]),
            Some(b'<' | b'=' | b'|') => (false, &s[1..]),
            _ => (false, s),
        };
        let mut chars = rest.chars();
        let kind_char = chars.next().ok_or_else(|| format!("empty dtype string {s:?}"))?;
        let size: usize = chars.as_str().parse().map_err(|_| format!("bad dtype string {s:?}"))?;
        let kind = match (kind_char, size) {
            ('f', 2 | 4 | 8) => Some(DTypeKind::Float),
            ('i', 1 | 2 | 4 | 8) => Some(DTypeKind::Int),
            ('u', 1 | 2 | 4 | 8) => Some(DTypeKind::UInt),
            ('b', 1) => Some(DTypeKind::Bool),
            _ => None,
        };
        Ok(DType {
            kind: kind.unwrap_or(DTypeKind::Bool),
            size,
            big_endian,
            unsupported: kind.is_none().then(|| s.to_string()),
        })
    }

    /// Human name, numpy style: float64, int32, uint8, bool.
    pub fn name(&self) -> String {
        if let Some(s) = &self.unsupported {
            return describe_unsupported(s);
        }
        match self.kind {
            DTypeKind::Float => format!("float{}", self.size * 8),
            DTypeKind::Int => format!("int{}", self.size * 8),
            DTypeKind::UInt => format!("uint{}", self.size * 8),
            DTypeKind::Bool => "bool".to_string(),
        }
    }

    pub fn is_supported(&self) -> bool {
        self.unsupported.is_none()
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

/// A numeric array in native byte order and C (row-major) layout.
#[derive(Debug, Clone)]
pub struct NdArray<'a> {
    pub dtype: DType,
    pub shape: Vec<usize>,
    /// Native-endian, C-order element bytes; borrowed from the file when no conversion was
    /// needed (and therefore not necessarily aligned: read with `from_le_bytes`).
    pub data: Cow<'a, [u8]>,
    /// Whether the pickle stored the values big-endian (`data` is native all the same): what a
    /// passthrough column records, so that an export gives the array back with its dtype.
    pub stored_big_endian: bool,
}

impl<'a> NdArray<'a> {
    /// Check sizes and convert to native C order. `data` is in memory order as pickled.
    pub fn assemble(dtype: DType, shape: Vec<usize>, fortran: bool, data: Cow<'a, [u8]>) -> Result<Self, String> {
        if !dtype.is_supported() {
            return Err(format!(
                "array dtype {} is not supported: only float, int, uint and bool arrays are read",
                dtype.name()
            ));
        }
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
        let needs_swap = dtype.big_endian && dtype.size > 1 && cfg!(target_endian = "little");
        let needs_transpose = fortran && shape.iter().filter(|&&d| d > 1).count() > 1;
        let data = if needs_swap || needs_transpose {
            let mut owned = if needs_transpose { fortran_to_c(&data, &shape, dtype.size) } else { data.into_owned() };
            if needs_swap {
                owned.chunks_exact_mut(dtype.size).for_each(|e| e.reverse());
            }
            Cow::Owned(owned)
        } else {
            data
        };
        let stored_big_endian = dtype.big_endian && dtype.size > 1;
        Ok(NdArray { dtype: DType { big_endian: false, ..dtype }, shape, data, stored_big_endian })
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
        assert_eq!(DType::from_typestr("f8").unwrap(), DType::float(8));
        let be = DType::from_typestr(">i4").unwrap();
        assert!(be.big_endian && be.kind == DTypeKind::Int && be.size == 4);
        assert!(!DType::from_typestr("O8").unwrap().is_supported());
        assert_eq!(DType::from_typestr("U5").unwrap().name(), "unicode string (U5)");
        assert!(DType::from_typestr("f").is_err());
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let e = NdArray::assemble(DType::float(8), vec![2, 3], false, Cow::Owned(vec![0; 40]));
        assert!(e.unwrap_err().contains("needs 48 bytes"));
    }
}
