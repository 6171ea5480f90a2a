//! Protocol 0/1 text arguments and latin-1 byte strings.

/// `str.encode('latin1')`: every char must be below 256.
pub(super) fn latin1(s: &str) -> Result<Vec<u8>, String> {
    s.chars().map(|c| u8::try_from(c as u32).map_err(|_| format!("char U+{:04X} is not latin-1", c as u32))).collect()
}

/// Protocol 0 UNICODE: raw-unicode-escape (latin-1 bytes plus `\uXXXX` / `\UXXXXXXXX`).
pub(super) fn decode_raw_unicode_escape(b: &[u8]) -> Result<String, String> {
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
pub(super) fn decode_repr_string(line: &[u8]) -> Result<Vec<u8>, String> {
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
