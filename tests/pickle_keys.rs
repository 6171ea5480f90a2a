//! A WGCSL pickle's dict keys that cannot name a column: one that is not a string is named as
//! Python's repr writes it, refused with the `--drop` that leaves it out (quoted for the shell),
//! and left out when told. Bytes that are UTF-8 (Python 2's str keys) name a column by their text.

mod common;

use common::*;

#[test]
fn keys_that_are_not_strings_are_refused_with_the_drop_that_leaves_them_out() {
    // make_key_pickles.py: an int and a tuple key (protocol 4), bytes that are not UTF-8 and
    // bytes that are (protocol 2), a str and bytes of the same text.
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    py_ok("make_key_pickles.py", &[d.to_str().unwrap()]);
    let out = d.join("t.parquet");
    let run = |src: &str, drop: &[&str]| {
        let mut args = vec!["--task".to_string(), "FetchReach".into()];
        for k in drop {
            args.extend(["--drop".to_string(), k.to_string()]);
        }
        convert(&[&d.join(src)], &out, &args)
    };
    let refused = |src: &str, drop: &[&str], want: &str| {
        let o = run(src, drop);
        let e = text(&o.stderr);
        assert!(!o.status.success() && e.contains(want) && e.trim().lines().count() == 1, "{want}: {e}");
        assert!(!out.exists(), "{want}: an output was left");
    };
    let columns = || {
        let (batch, _) = read_table(&out);
        batch.schema().fields().iter().map(|f| f.name().clone()).collect::<Vec<_>>()
    };
    let base = ["episode", "step", "obs", "achieved_goal", "desired_goal", "action"];

    refused(
        "int_key.pkl",
        &[],
        "int_key.pkl: key 1 (int, not a string): a table column needs a text name; pass --drop 1 to convert without it",
    );
    refused(
        "int_key.pkl",
        &["1"],
        "key (1, 2) (tuple, not a string): a table column needs a text name; pass --drop '(1, 2)' to convert",
    );
    let o = run("int_key.pkl", &["1", "(1, 2)"]);
    let e = text(&o.stderr);
    assert!(o.status.success(), "{e}");
    assert!(e.contains("int_key.pkl: key 1 (--drop)") && e.contains("int_key.pkl: key (1, 2) (--drop)"), "{e}");
    assert_eq!(columns(), base);
    std::fs::remove_file(&out).unwrap();

    refused(
        "bytes_key.pkl",
        &[],
        r#"key b'\xff' (bytes, not UTF-8 text): a table column needs a text name; pass --drop "b'\\xff'" to convert"#,
    );
    let o = run("bytes_key.pkl", &[r"b'\xff'"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(columns(), [&base[..], &["phase"]].concat());
    std::fs::remove_file(&out).unwrap();

    // A str key and bytes of the same text would be two columns of one name.
    refused(
        "twice.pkl",
        &[],
        "twice.pkl: key 'phase' is there twice, as a str and as bytes: a table has one column of a name; pass --drop \
         phase to convert without both",
    );
    let o = run("twice.pkl", &["phase"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(columns(), base);
    std::fs::remove_file(&out).unwrap();

    // A repr that names no key is refused as any unknown --drop is.
    refused("bytes_key.pkl", &[r"b'\xff'", "(1, 2)"], "--drop (1, 2): no input has a key");

    // Arrays of dtypes no column holds (strings, Python objects): named by key with the `--drop`
    // that leaves them out, which then converts (the parser keeps their place instead of refusing
    // the whole file, which named no key). Both ways numpy pickles an array.
    for p in ["arrays_p2.pkl", "arrays_p5.pkl"] {
        refused(
            p,
            &[],
            &format!("{p}: key 'labels' holds values of dtype unicode string (U6), which a table column cannot keep"),
        );
        refused(p, &["labels"], "key 'tags' holds values of dtype object (O8), which a table column cannot keep");
        let o = run(p, &["labels", "tags"]);
        assert!(o.status.success(), "{p}: {}", text(&o.stderr));
        assert_eq!(columns(), [&base[..], &["info_is_success"]].concat());
        std::fs::remove_file(&out).unwrap();
    }
}
