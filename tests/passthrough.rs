//! Nothing lost between formats: every array of a WGCSL pickle or an OGBench file survives
//! `convert` → `export`, with its values, dtype and shape, bit for bit; what a format cannot hold
//! is refused by name (and `--drop` leaves it out), never dropped silently.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use pgser::dtype::Kind;
use pgser::ogbench::npz;
use pgser::pickle::write::{ArrayOut, write_dict};
use pgser::pickle::{Obj, Pickle};

/// One array of a pickled dict as pgser's reader sees it: dtype (kind, bytes, stored
/// big-endian), shape and native little-endian C-order bytes.
#[derive(Debug, PartialEq)]
struct Array {
    key: String,
    kind: Kind,
    size: usize,
    big_endian: bool,
    shape: Vec<usize>,
    data: Vec<u8>,
}

fn arrays_of(path: &Path) -> Vec<Array> {
    let bytes = std::fs::read(path).unwrap();
    let mut p = Pickle::parse(&bytes).unwrap();
    let Obj::Dict(entries) = p.get(p.root()).clone() else { panic!("{}: not a dict", path.display()) };
    entries
        .into_iter()
        .map(|(k, v)| {
            let key = p.as_text(k).unwrap().into_owned();
            let Obj::Array(a) = p.take(v) else { panic!("{key}: not an array") };
            Array {
                key,
                kind: a.dtype.kind,
                size: a.dtype.size,
                big_endian: a.dtype.big_endian,
                shape: a.shape.clone(),
                data: a.data.into_owned(),
            }
        })
        .collect()
}

fn export(table: &Path, format: &str, out: &Path, extra: &[&str]) -> std::process::Output {
    etl().arg("export").arg(table).args(["--format", format, "-o"]).arg(out).args(extra).output().unwrap()
}

fn export_ok(table: &Path, format: &str, out: &Path, extra: &[&str]) {
    let o = export(table, format, out, extra);
    assert!(o.status.success(), "export {format} failed: {}", text(&o.stderr));
}

/// `export` fails in one line naming `want`, and leaves nothing at `out`.
fn export_refused(table: &Path, format: &str, out: &Path, extra: &[&str], want: &str) {
    let o = export(table, format, out, extra);
    let e = text(&o.stderr);
    assert!(!o.status.success() && e.contains(want) && e.trim().lines().count() == 1, "{want}: {e}");
    assert!(!out.exists(), "{want}: {} was left", out.display());
}

#[test]
fn wgcsl_buffers_written_by_numpy_come_back_whole() {
    // WGCSL's own info_is_success, an int per step, and (in the second) bools, a big-endian
    // Fortran-order float32 array, per-episode ints, uint8 and a 2×2 int16 per transition.
    let dir = tempfile::tempdir().unwrap();
    for name in ["wgcsl_info", "wgcsl_mixed"] {
        let src = repo().join(format!("tests/fixtures/passthrough/{name}.pkl"));
        let table = dir.path().join(format!("{name}.parquet"));
        convert_ok(&[&src], &table, &["--task".into(), "FetchReach".into()]);
        check_roundtrip(&table, &[&src], &[]);
        let back = dir.path().join(format!("{name}.pkl"));
        export_ok(&table, "wgcsl", &back, &[]);
        // pgser's reader: the same keys in the same order, dtypes with their byte order, shapes
        // and values; numpy: the same arrays as it loads them.
        assert_eq!(arrays_of(&back), arrays_of(&src), "{name}");
        py_ok("check_same_arrays.py", &[src.to_str().unwrap(), back.to_str().unwrap()]);
    }
}

#[test]
fn random_extra_arrays_of_random_dtypes_and_shapes_round_trip() {
    // 16 buffers written by numpy (make_random_pickles.py), each with 1–4 extra arrays: per step,
    // per transition or per episode, of 0–2 more dimensions of 1–3, in any dtype a column keeps,
    // either byte order and either memory order, pickled with protocol 2, 3, 4 or 5. convert
    // then export gives numpy every array back: its dtype with the byte order, shape and bytes
    // (check_same_arrays.py reads both files as stored, not as numpy's pickle.load does).
    let dir = tempfile::tempdir().unwrap();
    py_ok("make_random_pickles.py", &[dir.path().to_str().unwrap(), "16"]);
    for seed in 0..16u64 {
        let src = dir.path().join(format!("r{seed}.pkl"));
        let table = dir.path().join(format!("r{seed}.parquet"));
        let args: Vec<String> =
            ["--task", "Rand", "--threshold", "0.05", "--allow-nonfinite"].map(String::from).to_vec();
        convert_ok(&[&src], &table, &args);
        let back = dir.path().join(format!("r{seed}_back.pkl"));
        export_ok(&table, "wgcsl", &back, &[]);
        py_ok("check_same_arrays.py", &[src.to_str().unwrap(), back.to_str().unwrap()]);
    }
}

#[test]
fn minari_infos_come_back_whole() {
    // Recorded by Minari's own DataCollector with record_infos=True, in both storages: each
    // infos key becomes a column `infos/KEY`, and export writes it back into every episode's
    // infos (checked by minari.load_dataset: the same keys, dtypes, shapes and bits, and every
    // other array).
    let dir = tempfile::tempdir().unwrap();
    for storage in ["hdf5", "arrow"] {
        let src = repo().join(format!("tests/fixtures/minari/fetchreach-infos-{storage}-v0"));
        let table = dir.path().join(format!("{storage}.parquet"));
        convert_ok(&[&src], &table, &[]);
        let footer = pgser::table::read_footer(&table).unwrap();
        let p = &footer["passthrough"];
        assert_eq!(
            (p[0]["column"].as_str(), p[0]["dtype"].as_str(), &p[0]["shape"]),
            (Some("infos/distance"), Some("<f4"), &serde_json::json!([1]))
        );
        assert_eq!(
            (p[1]["column"].as_str(), p[1]["dtype"].as_str(), p[1]["per"].as_str()),
            (Some("infos/is_success"), Some("<f8"), Some("step"))
        );
        let out = dir.path().join(format!("fetchreach-infos-{storage}-v0"));
        export_ok(&table, "minari", &out, &[]);
        let o = py_ok("check_minari.py", &["same", src.to_str().unwrap(), out.to_str().unwrap()]);
        // Every array in its own dtype again: float32 actions beside float64 observations too.
        let said = last_json(&text(&o.stdout));
        for (key, pair) in said["dtypes"].as_object().unwrap() {
            assert_eq!(pair[0], pair[1], "{storage}: {key}");
        }
        assert_eq!(said["dtypes"]["actions"][1], "float32");
        // --drop leaves a key out, and says so.
        let t2 = dir.path().join(format!("{storage}_d.parquet"));
        let o = etl().arg("convert").arg(&src).arg("-o").arg(&t2).args(["--drop", "infos/distance"]).output().unwrap();
        assert!(o.status.success() && text(&o.stderr).contains("left out"), "{}", text(&o.stderr));
        let f2 = pgser::table::read_footer(&t2).unwrap();
        let cols: Vec<&str> =
            f2["passthrough"].as_array().unwrap().iter().map(|p| p["column"].as_str().unwrap()).collect();
        assert_eq!(cols, ["infos/is_success", "rewards", "terminations", "truncations"]);
    }
}

#[test]
fn minari_observation_keys_beside_the_goals_come_back_whole() {
    // A uint8 (2, 2) `image` in the Dict observation, recorded by Minari's DataCollector in both
    // storages: a column `observations/IMAGE` with the Box's shape (Arrow storage flattens it),
    // written back into the Dict with its subspace.
    let dir = tempfile::tempdir().unwrap();
    for storage in ["hdf5", "arrow"] {
        let src = repo().join(format!("tests/fixtures/minari/fetchreach-image-{storage}-v0"));
        let table = dir.path().join(format!("{storage}.parquet"));
        convert_ok(&[&src], &table, &[]);
        let footer = pgser::table::read_footer(&table).unwrap();
        let p = &footer["passthrough"][0];
        assert_eq!(
            (p["column"].as_str(), p["dtype"].as_str(), &p["shape"]),
            (Some("observations/image"), Some("|u1"), &serde_json::json!([2, 2]))
        );
        assert!(p["space"].as_str().unwrap().contains("uint8"), "{p}");
        let out = dir.path().join(format!("fetchreach-image-{storage}-v0"));
        export_ok(&table, "minari", &out, &[]);
        let o = py_ok("check_minari.py", &["same", src.to_str().unwrap(), out.to_str().unwrap()]);
        let said = last_json(&text(&o.stdout));
        assert_eq!(said["dtypes"]["image"], serde_json::json!(["uint8", "uint8"]));
        let t2 = dir.path().join(format!("{storage}_d.parquet"));
        let o =
            etl().arg("convert").arg(&src).arg("-o").arg(&t2).args(["--drop", "observations/image"]).output().unwrap();
        assert!(o.status.success() && text(&o.stderr).contains("left out"), "{}", text(&o.stderr));
    }
}

/// Every member of an `.npz` as (key, descr as stored, shape, little-endian C-order bytes).
fn members_of(path: &Path) -> Vec<(String, String, Vec<usize>, Vec<u8>)> {
    let mut out: Vec<_> = npz::members(path)
        .unwrap()
        .into_iter()
        .map(|m| {
            let bytes = npz::with_member(path, &m.key, |r, _| {
                let mut b = Vec::new();
                r.read_to_end(&mut b)?;
                Ok(b)
            })
            .unwrap();
            (m.key.clone(), m.stored_descr(), m.shape.clone(), bytes)
        })
        .collect();
    out.sort();
    out
}

fn ogbench_fixture(rel: &str) -> PathBuf {
    repo().join("tests/fixtures/ogbench").join(rel)
}

#[test]
fn what_a_format_cannot_hold_is_refused_by_name_and_dropped_only_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // OGBench → WGCSL: the last actions have no place in a WGCSL buffer; its other arrays do.
    let og = d.join("og.parquet");
    convert_ok(&[&ogbench_fixture("pointmaze-medium-navigate-v0.npz")], &og, &[]);
    let pkl = d.join("og.pkl");
    export_refused(&og, "wgcsl", &pkl, &[], "cannot hold each episode's last action");
    export_refused(&og, "wgcsl", &pkl, &["--drop", "qpos2"], "--drop qpos2: ");
    export_ok(&og, "wgcsl", &pkl, &["--drop", "last_action"]);
    let keys: Vec<(String, Vec<usize>)> = arrays_of(&pkl).into_iter().map(|a| (a.key, a.shape)).collect();
    assert_eq!(
        keys,
        [
            ("o", vec![4, 101, 2]),
            ("ag", vec![4, 101, 2]),
            ("u", vec![4, 100, 2]),
            ("g", vec![4, 100, 2]),
            ("terminals", vec![4, 101]),
            ("qpos", vec![4, 101, 2]),
            ("qvel", vec![4, 101, 2])
        ]
        .map(|(k, s)| (k.to_string(), s))
    );
    // Minari: per-step arrays go into each episode's infos; the last actions have no place.
    let mdir = d.join("og-v0");
    export_refused(&og, "minari", &mdir, &[], "cannot hold each episode's last action");
    export_ok(&og, "minari", &mdir, &["--drop", "last_action"]);
    let back = d.join("og_back.parquet");
    convert_ok(&[&mdir], &back, &["--task".into(), "pointmaze-medium-v0".into(), "--threshold".into(), "1".into()]);
    let footer = pgser::table::read_footer(&back).unwrap();
    let cols: Vec<&str> =
        footer["passthrough"].as_array().unwrap().iter().map(|p| p["column"].as_str().unwrap()).collect();
    // The infos in the table's order, then the rewards, terminations and truncations the export
    // wrote (made from the goals: an OGBench file records none).
    assert_eq!(cols, ["infos/terminals", "infos/qpos", "infos/qvel", "rewards", "terminations", "truncations"]);
    // WGCSL → OGBench: a per-transition array has no row on an episode's last step.
    let w = d.join("w.parquet");
    convert_ok(
        &[&repo().join("tests/fixtures/passthrough/wgcsl_info.pkl")],
        &w,
        &["--task".into(), "FetchReach".into()],
    );
    let npz_out = d.join("fetchreach-expert-v0.npz");
    export_refused(&w, "ogbench", &npz_out, &[], "passthrough column info_is_success");
    export_refused(&w, "minari", &d.join("w-v0"), &[], "passthrough column info_is_success");
    export_ok(&w, "ogbench", &npz_out, &["--drop", "info_is_success"]);
    let keys: Vec<String> = members_of(&npz_out).into_iter().map(|m| m.0).collect();
    assert_eq!(keys, ["actions", "observations", "phase", "terminals"]);
}

#[test]
fn convert_refuses_what_a_table_cannot_keep_and_drops_it_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let n = 2;
    let (t, f8) = (50, |count: usize| vec![0u8; count * 8]);
    let (o, ag, u, g) = (f8(n * t * 10), f8(n * t * 3), f8(n * (t - 1) * 4), f8(n * (t - 1) * 3));
    let wrong = f8(3 * 2);
    let write = |path: &Path, extra: Option<(&str, Vec<usize>, &[u8])>| {
        let mut arrays = vec![
            ArrayOut::from_bytes("o", vec![n, t, 10], &o),
            ArrayOut::from_bytes("ag", vec![n, t, 3], &ag),
            ArrayOut::from_bytes("u", vec![n, t - 1, 4], &u),
            ArrayOut::from_bytes("g", vec![n, t - 1, 3], &g),
        ];
        if let Some((k, shape, bytes)) = extra {
            arrays.push(ArrayOut::from_bytes(k, shape, bytes));
        }
        write_dict(&mut std::fs::File::create(path).unwrap(), &mut arrays).unwrap();
    };
    let src = d.join("buf.pkl");
    let out = d.join("t.parquet");
    let fails = |extra: &[&str], want: &str| {
        let o = etl()
            .arg("convert")
            .arg(&src)
            .arg("-o")
            .arg(&out)
            .args(["--task", "FetchReach"])
            .args(extra)
            .output()
            .unwrap();
        let e = text(&o.stderr);
        assert!(!o.status.success() && e.contains(want) && e.trim().lines().count() == 1, "{want}: {e}");
        assert!(!out.exists(), "{want}: an output was left");
    };
    // An array whose first dimension is not the episodes': no row of the table is its.
    write(&src, Some(("stats", vec![3, 2], &wrong)));
    fails(
        &[],
        "key 'stats' has shape (3, 2); an array kept beside o, ag, u, g has the 2 episodes first; pass --drop stats",
    );
    let o2 = etl()
        .arg("convert")
        .arg(&src)
        .arg("-o")
        .arg(&out)
        .args(["--task", "FetchReach", "--drop", "stats"])
        .output()
        .unwrap();
    assert!(o2.status.success() && text(&o2.stderr).contains("left out"), "{}", text(&o2.stderr));
    std::fs::remove_file(&out).unwrap();
    // A name of the table's own columns.
    write(&src, Some(("action", vec![n], &f8(n))));
    fails(&[], "key 'action' has the name of one of the table's own columns; pass --drop action");
    // --drop of a key no input has.
    write(&src, None);
    fails(&["--drop", "qpos"], "--drop qpos: no input has a key 'qpos'");
}

/// `table` rewritten to `out` with its `pgser` footer changed by `edit`, and checksummed again as
/// pgser's writer does: a footer that holds its checksum but says what pgser never writes.
fn with_footer(table: &Path, out: &Path, edit: impl Fn(&mut serde_json::Value)) {
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    let builder = ParquetRecordBatchReaderBuilder::try_new(std::fs::File::open(table).unwrap()).unwrap();
    let schema = builder.schema().clone();
    let batches: Vec<_> = builder.build().unwrap().map(|b| b.unwrap()).collect();
    let mut footer = pgser::table::read_footer(table).unwrap();
    footer.as_object_mut().unwrap().remove(pgser::table::CHECKSUMS_KEY);
    edit(&mut footer);
    let mut w = pgser::table::TableWriter::create(out, schema).unwrap();
    w.write_row_groups(&batches).unwrap();
    w.finish(&footer).unwrap();
}

/// A footer whose checksum holds but whose passthrough column has a dtype no column holds
/// (float16; a kind character of two bytes, which a reader cutting the descr by byte panicked
/// on; none at all) is refused in one line naming the file and the column, by every reader:
/// export in each format (which leaves nothing), inspect, verify and the training loader. So is
/// each footer the fuzzer found to crash one (`fuzz/fuzz_targets/footer.rs`,
/// tests/fixtures/fuzz/footer/), which is the whole footer of the same table.
#[test]
fn a_footer_with_a_dtype_no_column_holds_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good = d.join("good.parquet");
    let src = repo().join("tests/fixtures/passthrough/wgcsl_info.pkl");
    convert_ok(&[&src], &good, &["--task".into(), "FetchReach".into()]);
    let mut cases: Vec<(String, serde_json::Value)> = Vec::new();
    for (i, dtype) in ["<f2", "<é4", "é", ""].into_iter().enumerate() {
        let mut f = pgser::table::read_footer(&good).unwrap();
        f["passthrough"][0]["dtype"] = dtype.into();
        cases.push((format!("dtype{i}"), f));
    }
    let found = std::fs::read_dir(repo().join("tests/fixtures/fuzz/footer")).unwrap();
    for entry in found {
        let p = entry.unwrap().path();
        let f = serde_json::from_slice(&std::fs::read(&p).unwrap()).unwrap();
        cases.push((p.file_stem().unwrap().to_string_lossy().into_owned(), f));
    }
    let n = cases.len();
    for (name, footer) in cases {
        let table = d.join(format!("{name}.parquet"));
        with_footer(&good, &table, |f| *f = footer.clone());
        let at = table.to_str().unwrap();
        let says = |what: &str, e: &str| {
            assert!(!e.contains("panicked"), "{name}: {what}: {e}");
            assert_eq!(e.trim().lines().count(), 1, "{name}: {what}: {e}");
            assert!(e.contains(at) && e.contains("info_is_success"), "{name}: {what}: {e}");
        };
        for (format, out) in [("wgcsl", "back.pkl"), ("minari", "back-v0"), ("ogbench", "back.npz")] {
            let out = d.join(out);
            let o = export(&table, format, &out, &[]);
            assert!(!o.status.success(), "{name}: export {format} accepted the table");
            says(&format!("export {format}"), &text(&o.stderr));
            assert!(!out.exists(), "{name}: export {format} left {}", out.display());
        }
        for cmd in ["inspect", "verify"] {
            let o = etl().arg(cmd).arg(&table).output().unwrap();
            assert!(!o.status.success(), "{name}: {cmd} accepted the table");
            // verify reports each file on stdout, and sums up on stderr.
            let e = text(&o.stderr);
            let said = if cmd == "verify" { text(&o.stdout) } else { e.clone() };
            assert!(!e.contains("panicked"), "{name}: {cmd}: {e}");
            says(cmd, &said);
        }
        let e = pgser::trajectory::Episodes::load(&table).expect_err("the loader accepted the table");
        says("load", &format!("{e:#}"));
    }
    assert!(n > 4, "no inputs in tests/fixtures/fuzz/footer");
}
