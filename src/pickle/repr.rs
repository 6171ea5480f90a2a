//! A value as Python's `repr` writes it: how a dict key that is not a string is named in messages
//! and on the command line (`convert --drop 1`, `--drop '(1, 2)'`, `--drop "b'\\xff'"`, quoted by
//! [`shell_word`]), so that the name a user passes is the one Python shows them for that key.
//!
//! Exact for None, bools, ints of any size, floats (the shortest digits that read back, in
//! Python's fixed or exponent form), bytes, and tuples and frozensets of those. In a str, Python
//! escapes every character Unicode does not call printable; this escapes the control and
//! whitespace characters (but the space) among them, and writes format characters and unassigned
//! code points as they are. A repr longer than [`LIMIT`] characters or nested deeper than
//! [`DEPTH`] ends in `...`: a pickle may nest a key without end, and a message stays one line.

use std::fmt::Write;

use super::{Id, Obj, Pickle};

/// Characters after which a repr is cut (and ends in `...`).
pub const LIMIT: usize = 200;
/// Containers inside containers beyond which a repr writes `...`.
pub const DEPTH: usize = 16;

impl Pickle<'_> {
    /// The object `id` as Python's `repr` writes it (see the module's notes for where it differs).
    pub fn repr(&self, id: Id) -> String {
        let mut out = String::new();
        self.write_repr(id, 0, &mut out);
        if out.chars().count() > LIMIT {
            out = out.chars().take(LIMIT).collect::<String>() + "...";
        }
        out
    }

    fn write_repr(&self, id: Id, depth: usize, out: &mut String) {
        if out.len() > 4 * LIMIT {
            return;
        }
        let items = |open: &str, ids: &[Id], close: &str, out: &mut String| {
            out.push_str(open);
            if depth >= DEPTH {
                out.push_str("...");
            } else {
                for (i, &item) in ids.iter().enumerate() {
                    if i > 0 {
                        out.push_str(", ");
                    }
                    self.write_repr(item, depth + 1, out);
                    if out.len() > 4 * LIMIT {
                        break;
                    }
                }
            }
            out.push_str(close);
        };
        match self.get(id) {
            Obj::None => out.push_str("None"),
            Obj::Bool(b) => out.push_str(if *b { "True" } else { "False" }),
            Obj::Int(i) => write!(out, "{i}").expect("a String takes any write"),
            Obj::BigInt(le) => out.push_str(&bigint_decimal(le)),
            Obj::Float(f) => out.push_str(&float_repr(*f)),
            Obj::Str(s) => str_repr(s, out),
            Obj::Bytes(b) => bytes_repr(b, out),
            Obj::Tuple(t) if t.len() == 1 => items("(", t, ",)", out),
            Obj::Tuple(t) => items("(", t, ")", out),
            Obj::List(l) => items("[", l, "]", out),
            // A dict key can only be a frozenset; a set is never a key.
            Obj::Set(s) if s.is_empty() => out.push_str("frozenset()"),
            Obj::Set(s) => items("frozenset({", s, "})", out),
            Obj::Dict(_) if depth >= DEPTH => out.push_str("{...}"),
            Obj::Dict(d) => {
                out.push('{');
                for (i, (k, v)) in d.iter().enumerate() {
                    if i > 0 {
                        out.push_str(", ");
                    }
                    self.write_repr(*k, depth + 1, out);
                    out.push_str(": ");
                    self.write_repr(*v, depth + 1, out);
                    if out.len() > 4 * LIMIT {
                        break;
                    }
                }
                out.push('}');
            }
            other => write!(out, "<{}>", other.type_name()).expect("a String takes any write"),
        }
    }
}

/// `s` as one word of a POSIX shell command line, quoted only when it must be: `1`, `'(1, 2)'`,
/// `"b'x'"`, `"b'\\xff'"` (in double quotes a backslash is written twice). What a message says
/// to pass (`--drop WORD`) can then be pasted as it is.
pub fn shell_word(s: &str) -> String {
    let plain = |c: char| c.is_ascii_alphanumeric() || "_-.,:/=+@%^".contains(c);
    if !s.is_empty() && s.chars().all(plain) {
        s.to_string()
    } else if !s.contains('\'') {
        format!("'{s}'")
    } else if !s.contains('!') {
        // `!` would start a history expansion in an interactive bash's double quotes.
        let mut out = String::from("\"");
        for c in s.chars() {
            if "\\\"$`".contains(c) {
                out.push('\\');
            }
            out.push(c);
        }
        out + "\""
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

/// An int stored as little-endian two's complement bytes (LONG1, LONG4), in decimal.
fn bigint_decimal(le: &[u8]) -> String {
    let negative = le.last().is_some_and(|b| b & 0x80 != 0);
    // The magnitude, big-endian: the bytes as they are, or for a negative number their
    // two's complement (invert, add one).
    let mut mag: Vec<u8> = le.iter().rev().map(|b| if negative { !b } else { *b }).collect();
    if negative {
        for b in mag.iter_mut().rev() {
            let (v, carry) = b.overflowing_add(1);
            *b = v;
            if !carry {
                break;
            }
        }
    }
    // Long division by 10, least significant digit first.
    let mut digits = Vec::new();
    while mag.iter().any(|&b| b != 0) {
        let mut rem = 0u32;
        for b in mag.iter_mut() {
            let cur = (rem << 8) | *b as u32;
            *b = (cur / 10) as u8;
            rem = cur % 10;
        }
        digits.push(b'0' + rem as u8);
    }
    if digits.is_empty() {
        digits.push(b'0');
    }
    if negative {
        digits.push(b'-');
    }
    digits.reverse();
    String::from_utf8(digits).expect("ASCII digits")
}

/// `repr(float)`: the shortest digits that read back as `f` (Rust's `{:e}` finds them), written
/// fixed when the decimal exponent is from -4 to 15, else as `d.ddde+XX`.
fn float_repr(f: f64) -> String {
    if f.is_nan() {
        return "nan".into();
    }
    if f.is_infinite() {
        return if f > 0.0 { "inf" } else { "-inf" }.into();
    }
    let e = format!("{f:e}");
    let (mantissa, exp) = e.split_once('e').expect("{:e} writes an exponent");
    let exp: i32 = exp.parse().expect("{:e} writes a decimal exponent");
    let (sign, mantissa) = match mantissa.strip_prefix('-') {
        Some(m) => ("-", m),
        None => ("", mantissa),
    };
    let digits: String = mantissa.chars().filter(|c| *c != '.').collect();
    if (-4..16).contains(&exp) {
        let point = exp + 1;
        let text = if point <= 0 {
            format!("0.{}{digits}", "0".repeat((-point) as usize))
        } else if point as usize >= digits.len() {
            format!("{digits}{}.0", "0".repeat(point as usize - digits.len()))
        } else {
            format!("{}.{}", &digits[..point as usize], &digits[point as usize..])
        };
        format!("{sign}{text}")
    } else {
        let exp_sign = if exp < 0 { '-' } else { '+' };
        format!("{sign}{mantissa}e{exp_sign}{:02}", exp.abs())
    }
}

/// The quote Python picks: `'`, unless the text has a `'` and no `"`.
fn quote_for(has_single: bool, has_double: bool) -> char {
    if has_single && !has_double { '"' } else { '\'' }
}

fn str_repr(s: &str, out: &mut String) {
    let q = quote_for(s.contains('\''), s.contains('"'));
    out.push(q);
    for c in s.chars() {
        match c {
            '\\' => out.push_str("\\\\"),
            '\t' => out.push_str("\\t"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            c if c == q => {
                out.push('\\');
                out.push(c);
            }
            c if c == ' ' || !(c.is_control() || c.is_whitespace()) => out.push(c),
            c if (c as u32) < 0x100 => write!(out, "\\x{:02x}", c as u32).expect("a String takes any write"),
            c if (c as u32) < 0x10000 => write!(out, "\\u{:04x}", c as u32).expect("a String takes any write"),
            c => write!(out, "\\U{:08x}", c as u32).expect("a String takes any write"),
        }
    }
    out.push(q);
}

fn bytes_repr(b: &[u8], out: &mut String) {
    let q = quote_for(b.contains(&b'\''), b.contains(&b'"'));
    out.push('b');
    out.push(q);
    for &c in b {
        match c {
            b'\\' => out.push_str("\\\\"),
            b'\t' => out.push_str("\\t"),
            b'\n' => out.push_str("\\n"),
            b'\r' => out.push_str("\\r"),
            c if c as char == q => {
                out.push('\\');
                out.push(q);
            }
            0x20..=0x7e => out.push(c as char),
            c => write!(out, "\\x{c:02x}").expect("a String takes any write"),
        }
    }
    out.push(q);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The root of a pickle stream, as repr writes it.
    fn repr_of(stream: &[u8]) -> String {
        let p = Pickle::parse(stream).unwrap_or_else(|e| panic!("{e}"));
        p.repr(p.root())
    }

    /// Each expected string is what CPython 3.12's `repr` prints for the value, each stream what
    /// its `pickle.dumps(value, protocol=2)` writes (bytes through `_codecs.encode`).
    #[test]
    fn reprs_match_python() {
        for (stream, want) in [
            (&b"\x80\x02K\x01."[..], "1"),
            (b"\x80\x02J\xfb\xff\xff\xff.", "-5"),
            (b"\x80\x02\x8a\x09\x00\x00\x00\x00\x00\x00\x00\x00@.", "1180591620717411303424"),
            (b"\x80\x02\x8a\x09\xff\xff\xff\xff\xff\xff\xff\xff\xbf.", "-1180591620717411303425"),
            (b"\x80\x02N.", "None"),
            (b"\x80\x02\x88.", "True"),
            (b"\x80\x02\x89.", "False"),
            (b"\x80\x02c_codecs\x0aencode\x0aq\x00X\x01\x00\x00\x00xq\x01X\x06\x00\x00\x00latin1q\x02\x86q\x03Rq\x04.", "b'x'"),
            (
                b"\x80\x02c_codecs\x0aencode\x0aq\x00X\x03\x00\x00\x00\xc3\xbf\x00q\x01X\x06\x00\x00\x00latin1q\x02\x86q\x03Rq\x04.",
                "b'\\xff\\x00'",
            ),
            (b"\x80\x02c_codecs\x0aencode\x0aq\x00X\x04\x00\x00\x00it'sq\x01X\x06\x00\x00\x00latin1q\x02\x86q\x03Rq\x04.", "b\"it's\""),
            (
                b"\x80\x02c_codecs\x0aencode\x0aq\x00X\x03\x00\x00\x00'\x22\x5cq\x01X\x06\x00\x00\x00latin1q\x02\x86q\x03Rq\x04.",
                "b'\\'\"\\\\'",
            ),
            (b"\x80\x02X\x03\x00\x00\x00a\x09bq\x00.", "'a\\tb'"),
            (b"\x80\x02X\x02\x00\x00\x00\xc3\xa9q\x00.", "'\u{e9}'"),
            (b"\x80\x02X\x01\x00\x00\x00\x7fq\x00.", "'\\x7f'"),
            (b"\x80\x02X\x01\x00\x00\x00'q\x00.", "\"'\""),
            (b"\x80\x02X\x02\x00\x00\x00\x22'q\x00.", "'\"\\''"),
            (b"\x80\x02X\x02\x00\x00\x00\xc2\xa0q\x00.", "'\\xa0'"),
            (b"\x80\x02X\x06\x00\x00\x00\xe6\x97\xa5\xe6\x9c\xacq\x00.", "'\u{65e5}\u{672c}'"),
            (b"\x80\x02X\x03\x00\x00\x00\xe2\x80\xa8q\x00.", "'\\u2028'"),
            (b"\x80\x02X\x04\x00\x00\x00\xf0\x9f\x98\x80q\x00.", "'\u{1f600}'"),
            (b"\x80\x02K\x01K\x02\x86q\x00.", "(1, 2)"),
            (b"\x80\x02K\x01\x85q\x00.", "(1,)"),
            (b"\x80\x02).", "()"),
            (
                b"\x80\x02c_codecs\x0aencode\x0aq\x00X\x01\x00\x00\x00xq\x01X\x06\x00\x00\x00latin1q\x02\x86q\x03Rq\x04NG?\xf8\x00\x00\x00\x00\x00\x00\x86q\x05\x86q\x06.",
                "(b'x', (None, 1.5))",
            ),
            (b"\x80\x02c__builtin__\x0afrozenset\x0aq\x00]q\x01K\x03a\x85q\x02Rq\x03.", "frozenset({3})"),
            (b"\x80\x02GCA\xc3y7\xe0\x80\x00.", "1e+16"),
            (b"\x80\x02G>\x84!\xf5\xf4\x0d\x83v.", "1.5e-07"),
        ] {
            assert_eq!(repr_of(stream), want, "{stream:?}");
        }
    }

    /// A key nested without end (a list that holds itself, inside a tuple) ends in `...` within
    /// the limits instead of overflowing the stack or filling memory.
    #[test]
    fn endless_nesting_is_cut() {
        // EMPTY_LIST, BINPUT 0, BINGET 0, APPEND (the list holds itself), TUPLE1
        let r = repr_of(b"\x80\x02]q\x00h\x00a\x85.");
        assert!(r.starts_with("([[[[") && r.contains("..."), "{r}");
        assert!(r.chars().count() <= LIMIT + 3, "{r}");
    }

    /// Each word read back by sh is the text it quotes.
    #[test]
    fn shell_words_read_back_as_the_text() {
        let texts = ["1", "info_is_success", "(1, 2)", "b'x'", r"b'\xff'", "it's $HOME `x` \"q\"", "'!'", "", "a b"];
        for t in texts {
            let w = shell_word(t);
            let out = std::process::Command::new("sh").arg("-c").arg(format!("printf %s {w}")).output().unwrap();
            assert_eq!(String::from_utf8(out.stdout).unwrap(), t, "{w}");
        }
        assert_eq!(shell_word("stats"), "stats");
        assert_eq!(shell_word("(1, 2)"), "'(1, 2)'");
        assert_eq!(shell_word(r"b'\xff'"), r#""b'\\xff'""#);
    }

    #[test]
    fn floats_are_written_as_python_writes_them() {
        for (f, want) in [
            (1.0, "1.0"),
            (-0.0, "-0.0"),
            (0.1, "0.1"),
            (1.5e-7, "1.5e-07"),
            (0.0001, "0.0001"),
            (0.00001, "1e-05"),
            (1e15, "1000000000000000.0"),
            (1e16, "1e+16"),
            (123456.789, "123456.789"),
            (1.7976931348623157e308, "1.7976931348623157e+308"),
            (5e-324, "5e-324"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
            (f64::NAN, "nan"),
        ] {
            assert_eq!(float_repr(f), want, "{f:e}");
        }
    }
}
