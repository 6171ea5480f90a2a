//! Machine semantics on hand-written opcode streams (numpy-written files are covered by the
//! integration tests against Python).

use super::*;

fn parse(b: &[u8]) -> Pickle<'_> {
    Pickle::parse(b).unwrap_or_else(|e| panic!("{e}"))
}

fn err(b: &[u8]) -> String {
    Pickle::parse(b).expect_err("must fail").to_string()
}

#[test]
fn memoized_list_is_seen_mutated_through_get() {
    // EMPTY_LIST, BINPUT 0, MARK, BININT1 1, APPENDS, POP, BINGET 0, TUPLE1, STOP
    let p = parse(b"\x80\x02]q\x00(K\x01e0h\x00\x85.");
    let Obj::Tuple(t) = p.get(p.root()) else { panic!() };
    let Obj::List(l) = p.get(t[0]) else { panic!() };
    assert!(matches!(p.get(l[0]), Obj::Int(1)));
}

#[test]
fn protocol0_text_opcodes() {
    let p = parse(b"S'a\\x41\\n\\''\n.");
    assert!(matches!(p.get(p.root()), Obj::Bytes(b) if b.as_ref() == b"aA\n'"));
    let p = parse(b"V\\u0041\xe9\n.");
    assert!(matches!(p.get(p.root()), Obj::Str(s) if s == "A\u{e9}"));
    let p = parse(b"I01\n.");
    assert!(matches!(p.get(p.root()), Obj::Bool(true)));
    let p = parse(b"L-12345678901L\n.");
    assert!(matches!(p.get(p.root()), Obj::Int(-12345678901)));
    let p = parse(b"F-1.5e3\n.");
    assert!(matches!(p.get(p.root()), Obj::Float(v) if *v == -1500.0));
}

#[test]
fn repeated_dict_key_keeps_the_last_value() {
    let p = parse(b"\x80\x04}(\x8c\x01aK\x01\x8c\x01aK\x02u.");
    let Obj::Dict(d) = p.get(p.root()) else { panic!() };
    assert_eq!(d.len(), 1);
    assert!(matches!(p.get(d[0].1), Obj::Int(2)));
}

#[test]
fn long1_is_twos_complement() {
    let p = parse(b"\x80\x02\x8a\x02\xff\x7f.");
    assert!(matches!(p.get(p.root()), Obj::Int(32767)));
    let p = parse(b"\x80\x02\x8a\x01\xff.");
    assert!(matches!(p.get(p.root()), Obj::Int(-1)));
    let p = parse(b"\x80\x02\x8a\x00.");
    assert!(matches!(p.get(p.root()), Obj::Int(0)));
}

#[test]
fn self_referencing_list_parses_without_looping() {
    let p = parse(b"\x80\x02]q\x00h\x00a.");
    let Obj::List(l) = p.get(p.root()) else { panic!() };
    assert_eq!(l, &vec![p.root()]);
}

#[test]
fn refusals_name_what_was_refused() {
    assert!(err(b"\x80\x06.").contains("unsupported pickle protocol 6"));
    assert!(err(b"\x80\x02}}b.").contains("refused BUILD on a dict"));
    // bytearray(5) would allocate a size chosen by the file.
    assert!(err(b"c__builtin__\nbytearray\n(K\x05tR.").contains("expected bytes"));
    assert!(err(b"\x80\x04c_codecs\nencode\n(\x8c\x01a\x8c\x05utf-8tR.").contains("latin1"));
    assert!(err(b"\x80\x04cnumpy\nload\n.").contains("refused global `numpy.load`"));
    assert!(err(b"\x80\x04\x8c\x05numpy\x8c\x07testing\x93.").contains("refused global `numpy.testing`"));
    assert!(err(b"\x80\x02P1\n.").contains("persistent id"));
}

#[test]
fn lengths_are_checked_before_use() {
    // BINBYTES8 claiming 2^62 bytes: refused without allocating.
    let e = err(b"\x80\x04\x8e\x00\x00\x00\x00\x00\x00\x00\x40.");
    assert!(e.contains("past the end of the file"), "{e}");
    assert!(err(b"\x80\x04\x95\xff\xff\xff\xff\xff\xff\xff\xff").contains("past the end"));
}

#[test]
fn numpy_dtype_byte_order_comes_from_build() {
    // numpy.dtype('f4', False, True) then BUILD (3, '>', None, None, None, -1, -1, 0);
    // an array reconstructed from it is byte-swapped to native order.
    let mut s = b"\x80\x02cnumpy.core.multiarray\n_reconstruct\ncnumpy\nndarray\nK\x00\x85C\x01b\x87R".to_vec();
    s.extend_from_slice(b"(K\x01K\x02\x85cnumpy\ndtype\nX\x02\x00\x00\x00f4\x89\x88\x87R");
    s.extend_from_slice(b"(K\x03X\x01\x00\x00\x00>NNNJ\xff\xff\xff\xffJ\xff\xff\xff\xffK\x00tb");
    s.extend_from_slice(b"\x89C\x08");
    s.extend_from_slice(&1.5f32.to_be_bytes());
    s.extend_from_slice(&(-2.0f32).to_be_bytes());
    s.extend_from_slice(b"tb.");
    let p = parse(&s);
    let Obj::Array(a) = p.get(p.root()) else { panic!("{:?}", p.get(p.root())) };
    assert_eq!(a.shape, vec![2]);
    let v: Vec<f32> = a.data.chunks(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    assert_eq!(v, vec![1.5, -2.0]);
}

/// The writer against a file numpy 1.26 wrote with `pickle.dump(d, f, protocol=3)`: reading it
/// and writing the arrays back gives the same bytes, memo numbering and all.
#[test]
fn writer_reproduces_numpy_1_protocol_3_byte_for_byte() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/np1_p3.pkl");
    let original = std::fs::read(&path).unwrap();
    let mut p = parse(&original);
    let Obj::Dict(entries) = p.get(p.root()).clone() else { panic!("not a dict") };
    let mut arrays = Vec::new();
    for (k, v) in entries {
        let key = p.as_text(k).unwrap().into_owned();
        let Obj::Array(a) = p.take(v) else { panic!("{key} is not an array") };
        arrays.push((key, a));
    }
    let mut out: Vec<write::ArrayOut> =
        arrays.iter().map(|(k, a)| write::ArrayOut::from_bytes(k, a.shape.clone(), &a.data)).collect();
    let mut written = Vec::new();
    write::write_dict(&mut written, &mut out).unwrap();
    assert_eq!(written.len(), original.len());
    assert!(written == original, "bytes differ from numpy's");
}

#[test]
fn writer_output_reads_back_and_small_arrays_use_short_bytes() {
    let values: Vec<u8> = [1.5f64, -0.0, f64::MIN_POSITIVE].iter().flat_map(|v| v.to_le_bytes()).collect();
    let big: Vec<u8> = (0..300u32).flat_map(|i| (i as f64).to_le_bytes()).collect();
    let mut out =
        vec![write::ArrayOut::from_bytes("a", vec![1, 3], &values), write::ArrayOut::from_bytes("b", vec![300], &big)];
    let mut bytes = Vec::new();
    write::write_dict(&mut bytes, &mut out).unwrap();
    let mut p = parse(&bytes);
    let Obj::Dict(entries) = p.get(p.root()).clone() else { panic!() };
    let shapes: Vec<Vec<usize>> = entries
        .iter()
        .map(|&(_, v)| match p.take(v) {
            Obj::Array(a) => {
                assert_eq!(a.dtype, crate::dtype::Dtype::F64);
                a.shape
            }
            o => panic!("{}", o.type_name()),
        })
        .collect();
    assert_eq!(shapes, [vec![1, 3], vec![300]]);
    // A single entry is SETITEM, not MARK … SETITEMS.
    let mut one = vec![write::ArrayOut::from_bytes("a", vec![3], &values)];
    let mut bytes = Vec::new();
    write::write_dict(&mut bytes, &mut one).unwrap();
    assert_eq!(&bytes[bytes.len() - 2..], b"s.");
    parse(&bytes);
}

#[test]
fn writer_refuses_a_source_of_the_wrong_length() {
    let short = [0u8; 16];
    let mut out = vec![write::ArrayOut::from_bytes("o", vec![3], &short)];
    let e = write::write_dict(&mut Vec::new(), &mut out).unwrap_err().to_string();
    assert!(e.contains("needs 24 bytes") && e.contains("gave 16"), "{e}");
}
