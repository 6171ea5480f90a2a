//! numpy's numeric element types: the one model of them in pgser. Each format spells a dtype its
//! own way (a pickle's `dtype('f8')` reduction, an `.npy` header's `descr`, an HDF5 type, an
//! Arrow `DataType`, a passthrough column's record in a table's footer); its reader turns that
//! spelling into a [`Dtype`] at its edge and its writer turns one back, as arrow-rs keeps one
//! `DataType` for all of its formats. So a dtype is parsed, named and mapped to Arrow in one
//! place, and a descr that no format could have written (`<f2` in a footer, a kind character of
//! two bytes) is refused here, in any reader, not panicked on.

use std::fmt;

use arrow_schema::DataType;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// What a value is: numpy's kind.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Kind {
    Bool,
    Int,
    UInt,
    Float,
}

impl Kind {
    /// numpy's kind character: `b`, `i`, `u`, `f`.
    pub fn char(self) -> char {
        match self {
            Kind::Bool => 'b',
            Kind::Int => 'i',
            Kind::UInt => 'u',
            Kind::Float => 'f',
        }
    }
}

/// A numeric element type: its kind, bytes per value, and the byte order it is stored in. Only
/// the types numpy has are made ([`Dtype::new`], [`Dtype::parse`], the constants): bool of one
/// byte, int and uint of 1, 2, 4 or 8, float of 2, 4 or 8; a one-byte type has no byte order.
/// Readers hand values on little-endian whatever the source's order, and `big_endian` records
/// the source's, so that a writer gives the bytes back as they were.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Dtype {
    pub kind: Kind,
    pub size: usize,
    pub big_endian: bool,
}

const fn le(kind: Kind, size: usize) -> Dtype {
    Dtype { kind, size, big_endian: false }
}

impl Dtype {
    pub const BOOL: Dtype = le(Kind::Bool, 1);
    pub const I8: Dtype = le(Kind::Int, 1);
    pub const I16: Dtype = le(Kind::Int, 2);
    pub const I32: Dtype = le(Kind::Int, 4);
    pub const I64: Dtype = le(Kind::Int, 8);
    pub const U8: Dtype = le(Kind::UInt, 1);
    pub const U16: Dtype = le(Kind::UInt, 2);
    pub const U32: Dtype = le(Kind::UInt, 4);
    pub const U64: Dtype = le(Kind::UInt, 8);
    pub const F16: Dtype = le(Kind::Float, 2);
    pub const F32: Dtype = le(Kind::Float, 4);
    pub const F64: Dtype = le(Kind::Float, 8);
    /// Every type there is, little-endian.
    pub const ALL: [Dtype; 12] = [
        Dtype::BOOL,
        Dtype::I8,
        Dtype::I16,
        Dtype::I32,
        Dtype::I64,
        Dtype::U8,
        Dtype::U16,
        Dtype::U32,
        Dtype::U64,
        Dtype::F16,
        Dtype::F32,
        Dtype::F64,
    ];

    /// The little-endian type of `kind` and `size` bytes, if numpy has one.
    pub fn new(kind: Kind, size: usize) -> Option<Dtype> {
        Dtype::ALL.into_iter().find(|d| d.kind == kind && d.size == size)
    }

    /// This type stored in the given byte order (a one-byte type has none: it stays as it is).
    pub fn with_big_endian(self, big_endian: bool) -> Dtype {
        Dtype { big_endian: big_endian && self.size > 1, ..self }
    }

    /// This type little-endian, as readers hand values on and Arrow holds them.
    pub fn little_endian(self) -> Dtype {
        self.with_big_endian(false)
    }

    /// numpy's `descr` (`<f8`, `>i4`, `|b1`, `f4`, `=u2`, `?`), or None for anything else: other
    /// kinds (complex, strings, objects, datetimes), sizes numpy does not have, and any text at
    /// all that is not a descr (this never panics, whatever it is given). `=` and `|` are the
    /// machine's order, which pgser only runs little-endian.
    pub fn parse(descr: &str) -> Option<Dtype> {
        let (big_endian, rest) = match descr.strip_prefix('>') {
            Some(rest) => (true, rest),
            None => (false, descr.strip_prefix(['<', '=', '|']).unwrap_or(descr)),
        };
        if rest == "?" {
            return Some(Dtype::BOOL);
        }
        let mut chars = rest.chars();
        let kind = match chars.next()? {
            'b' => Kind::Bool,
            'i' => Kind::Int,
            'u' => Kind::UInt,
            'f' => Kind::Float,
            _ => return None,
        };
        let digits = chars.as_str();
        if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
            return None;
        }
        Dtype::new(kind, digits.parse().ok()?).map(|d| d.with_big_endian(big_endian))
    }

    /// numpy's `descr`, as `np.save` writes it: `<f4`, `>f8`, `|b1`.
    pub fn descr(self) -> String {
        let order = match (self.size, self.big_endian) {
            (1, _) => '|',
            (_, true) => '>',
            (_, false) => '<',
        };
        format!("{order}{}{}", self.kind.char(), self.size)
    }

    /// numpy's name of the type: `float32`, `int64`, `uint8`, `bool`.
    pub fn name(self) -> String {
        match self.kind {
            Kind::Bool => "bool".to_string(),
            Kind::Int => format!("int{}", self.size * 8),
            Kind::UInt => format!("uint{}", self.size * 8),
            Kind::Float => format!("float{}", self.size * 8),
        }
    }

    /// The Arrow type of its values; None for float16, which a table column does not hold.
    pub fn arrow(self) -> Option<DataType> {
        let t = match self.little_endian() {
            Dtype::BOOL => DataType::Boolean,
            Dtype::I8 => DataType::Int8,
            Dtype::I16 => DataType::Int16,
            Dtype::I32 => DataType::Int32,
            Dtype::I64 => DataType::Int64,
            Dtype::U8 => DataType::UInt8,
            Dtype::U16 => DataType::UInt16,
            Dtype::U32 => DataType::UInt32,
            Dtype::U64 => DataType::UInt64,
            Dtype::F32 => DataType::Float32,
            Dtype::F64 => DataType::Float64,
            _ => return None,
        };
        Some(t)
    }

    /// The (little-endian) type of an Arrow value type, where [`arrow`](Self::arrow) gives it.
    pub fn from_arrow(t: &DataType) -> Option<Dtype> {
        Dtype::ALL.into_iter().find(|d| d.arrow().as_ref() == Some(t))
    }

    /// Turns `bytes` (values of this type) between its byte order and little-endian: the same
    /// swap both ways, and nothing for a little-endian or one-byte type.
    pub fn reorder(self, bytes: &mut [u8]) {
        if self.big_endian {
            bytes.chunks_exact_mut(self.size).for_each(<[u8]>::reverse);
        }
    }
}

impl fmt::Display for Dtype {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.descr())
    }
}

/// As numpy's `descr`, which is how a footer records it.
impl Serialize for Dtype {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.descr())
    }
}

impl<'de> Deserialize<'de> for Dtype {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Dtype, D::Error> {
        let s = String::deserialize(d)?;
        Dtype::parse(&s).ok_or_else(|| serde::de::Error::custom(format!("{s:?} is not a numeric numpy dtype")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numpy_dtypes_read_and_print_as_numpy_does() {
        for d in ["<f8", ">f4", "|b1", "|u1", "|i1", "<i8", ">u2", "<u4", "<f2", ">f2"] {
            assert_eq!(Dtype::parse(d).unwrap().descr(), d);
        }
        assert_eq!(Dtype::parse("f4").unwrap().descr(), "<f4");
        assert_eq!(Dtype::parse("=i4").unwrap().descr(), "<i4");
        assert_eq!(Dtype::parse(">b1").unwrap().descr(), "|b1");
        assert_eq!(Dtype::parse("?"), Some(Dtype::BOOL));
        assert_eq!(Dtype::parse(">f8").unwrap().name(), "float64");
        for d in ["<c16", "|O", "<U5", "|S3", "<M8[ns]", "", "<", "f", "<f3", "<b2", "<i16", "<f+4", "<f 4"] {
            assert_eq!(Dtype::parse(d), None, "{d}");
        }
    }

    /// Any text at all: a kind or order character of several bytes is not cut through.
    #[test]
    fn parsing_never_panics() {
        for d in ["<é4", "é4", "é", ">é", "f\u{1F600}", "<f4\u{301}", "\u{0}", "<f99999999999999999999999"] {
            assert_eq!(Dtype::parse(d), None, "{d:?}");
        }
    }

    #[test]
    fn arrow_types_map_both_ways() {
        for d in Dtype::ALL {
            match d.arrow() {
                Some(t) => assert_eq!(Dtype::from_arrow(&t), Some(d)),
                None => assert_eq!(d, Dtype::F16),
            }
            assert_eq!(d.with_big_endian(true).arrow(), d.arrow());
        }
        assert_eq!(Dtype::from_arrow(&DataType::Utf8), None);
    }

    #[test]
    fn a_footer_records_the_descr() {
        let d = Dtype::parse(">i2").unwrap();
        assert_eq!(serde_json::to_string(&d).unwrap(), "\">i2\"");
        assert_eq!(serde_json::from_str::<Dtype>("\">i2\"").unwrap(), d);
        let e = serde_json::from_str::<Dtype>("\"<é4\"").unwrap_err().to_string();
        assert!(e.contains("\"<é4\" is not a numeric numpy dtype"), "{e}");
    }

    #[test]
    fn big_endian_values_turn_around_one_value_at_a_time() {
        let mut b = vec![1, 2, 3, 4, 5, 6, 7, 8];
        Dtype::I32.reorder(&mut b);
        assert_eq!(b, [1, 2, 3, 4, 5, 6, 7, 8]);
        Dtype::I32.with_big_endian(true).reorder(&mut b);
        assert_eq!(b, [4, 3, 2, 1, 8, 7, 6, 5]);
    }
}
