//! Silent corruption is detected: tables carry CRC-32s of every column chunk and checkpoints of
//! every tensor, checked on every read and by `pgser-etl verify`. A bit flipped anywhere in a small
//! table or checkpoint is either reported in one line naming the file, or provably harmless: the
//! values read are the written ones.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::*;

fn train(table: &Path, ckpt: &Path) {
    let o = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", table.to_str().unwrap(), "-o", ckpt.to_str().unwrap()])
        .args(["--updates", "5", "--hidden", "16", "--batch-size", "32", "--eval-episodes", "0"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
}

/// Every kind of file pgser writes verifies, and says what it checked.
#[test]
fn every_file_pgser_writes_verifies() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, scored) = reach_tables(tmp.path());
    let ckpt = tmp.path().join("reach.ckpt");
    let batches = tmp.path().join("b.parquet");
    let o = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["batches", "--data", scored.to_str().unwrap(), "--count", "2", "-o", batches.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let resume = tmp.path().join("reach.ckpt.resume");
    let o = etl().arg("verify").args([&table, &scored, &batches, &ckpt, &resume]).arg("--json").output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let lines: Vec<serde_json::Value> = text(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    let kinds: Vec<&str> = lines.iter().map(|l| l["kind"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["trajectory", "transition", "batches", "pgser-agent", "pgser-agent-resume"]);
    assert!(lines.iter().all(|l| l["verified"] == true && l["parts"].as_u64().unwrap() > 0), "{lines:?}");
}

/// Flips bit `bit` of byte `at` of `src` into `dst`.
fn flipped(src: &Path, dst: &Path, at: usize, bit: u8) {
    let mut b = std::fs::read(src).unwrap();
    b[at] ^= 1 << bit;
    std::fs::write(dst, b).unwrap();
}

/// Byte positions spread over a file of `len` bytes, every region included: the first and last
/// 64 bytes one by one (magic numbers, lengths, the start of the metadata), and ~`n` more
/// evenly spaced through the rest (pages, the footer's Thrift and JSON).
fn positions(len: usize, n: usize) -> Vec<usize> {
    let mut p: Vec<usize> = (0..64.min(len)).chain(len.saturating_sub(64)..len).collect();
    p.extend((64..len.saturating_sub(64)).step_by((len / n).max(1)));
    p.sort();
    p.dedup();
    p
}

/// A corrupt file's error: one line that names it.
fn names_the_file(err: &anyhow::Error, path: &Path) -> bool {
    let line = format!("{err:#}");
    !line.contains('\n') && line.contains(path.to_str().unwrap())
}

#[test]
fn a_flipped_bit_in_a_table_is_detected_or_harmless() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, scored) = reach_tables(tmp.path());
    for src in [&table, &scored] {
        let (want, _) = read_table(src);
        let footer = pgser::table::read_footer(src).unwrap();
        let bad = tmp.path().join("bad.parquet");
        let len = std::fs::metadata(src).unwrap().len() as usize;
        let (mut detected, mut harmless) = (0, 0);
        for (i, at) in positions(len, 300).into_iter().enumerate() {
            flipped(src, &bad, at, (i % 8) as u8);
            match pgser::verify::verify(&bad) {
                Err(e) => {
                    assert!(names_the_file(&e, &bad), "byte {at}: {e:#}");
                    detected += 1;
                }
                Ok(r) => {
                    // Verified (or unverifiable, when the flip hit the footer's created_by): the
                    // columns and the footer read back as written.
                    let (got, _) = read_table(&bad);
                    assert!(got.columns() == want.columns(), "byte {at}: values changed, undetected ({r:?})");
                    assert_eq!(pgser::table::read_footer(&bad).unwrap(), footer, "byte {at}: footer changed");
                    harmless += 1;
                }
            }
        }
        eprintln!("{}: {len} bytes, {detected} flips detected, {harmless} harmless", src.display());
        assert!(detected > harmless, "most flips land in checked bytes");
    }
}

/// `pgser-etl query` hands a table to polars, which decodes its pages unchecked: at every flipped
/// bit where `verify` refuses the file for its checksums (or cannot open it), the query's scan
/// refuses it with the same line; elsewhere the query reads the written values, or fails in one
/// line where polars' stricter footer parser refuses what arrow-rs reads past.
#[test]
fn query_refuses_what_verify_refuses_at_every_flipped_bit() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, _) = reach_tables(tmp.path());
    let all = |p: &Path| -> anyhow::Result<polars::prelude::DataFrame> {
        let lf = pgser::query::scan(p)?;
        pgser::query::collect(lf).map_err(|e| anyhow::anyhow!("{}", pgser::query::first_line(&e)))
    };
    let want = all(&table).unwrap();
    let bad = tmp.path().join("bad.parquet");
    let len = std::fs::metadata(&table).unwrap().len() as usize;
    let (mut same_error, mut same_values) = (0, 0);
    for (i, at) in positions(len, 200).into_iter().enumerate() {
        flipped(&table, &bad, at, (i % 8) as u8);
        let verified = pgser::verify::verify(&bad).map_err(|e| format!("{e:#}"));
        let checked = pgser::table::open_checked(&bad, None).map(|_| ()).map_err(|e| format!("{e:#}"));
        match (checked, all(&bad)) {
            (Err(door), Err(e)) => {
                assert_eq!(format!("{e:#}"), door, "byte {at}");
                assert_eq!(verified.as_ref().unwrap_err(), &door, "byte {at}: verify says otherwise");
                same_error += 1;
            }
            (Err(door), Ok(_)) => panic!("byte {at}: {door}, yet the query read the file"),
            (Ok(()), Ok(got)) => {
                assert!(got.equals_missing(&want), "byte {at}: the query read other values, unrefused ({verified:?})");
                same_values += 1;
            }
            // A flip in the footer's Thrift that arrow-rs reads past and polars refuses (a
            // ColumnOrder union with no variant): an error, never other values.
            (Ok(()), Err(e)) => assert!(!format!("{e:#}").contains('\n'), "byte {at}: {e:#}"),
        }
    }
    eprintln!("{len} bytes: {same_error} flips refused as verify refuses them, {same_values} read as written");
    assert!(same_error > same_values, "most flips land in checked bytes");
}

#[test]
fn a_flipped_bit_in_a_checkpoint_is_detected_or_harmless() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, _) = reach_tables(tmp.path());
    let ckpt = tmp.path().join("q.ckpt");
    train(&table, &ckpt);
    let want = checkpoint_weights(&ckpt);
    let bad = tmp.path().join("bad.ckpt");
    let len = std::fs::metadata(&ckpt).unwrap().len() as usize;
    let (mut detected, mut harmless) = (0, 0);
    for (i, at) in positions(len, 400).into_iter().enumerate() {
        flipped(&ckpt, &bad, at, (i % 8) as u8);
        let loaded = pgser::agent::checkpoint::load(&bad, pgser::agent::Backend::Cpu.device().unwrap());
        match loaded {
            Err(e) => {
                assert!(names_the_file(&e, &bad), "byte {at}: {e:#}");
                assert!(pgser::verify::verify(&bad).is_err(), "byte {at}: load refused it but verify did not");
                detected += 1;
            }
            Ok(_) => {
                assert_eq!(checkpoint_weights(&bad), want, "byte {at}: weights changed, undetected");
                harmless += 1;
            }
        }
    }
    eprintln!("{}: {len} bytes, {detected} flips detected, {harmless} harmless", ckpt.display());
    assert!(detected > harmless);
}

/// The byte in the middle of row group 0's chunk of leaf column `leaf` (`obs.list.item`, `q`).
fn middle_of(table: &Path, leaf: &str) -> usize {
    use parquet::file::reader::{FileReader, SerializedFileReader};
    let reader = SerializedFileReader::new(std::fs::File::open(table).unwrap()).unwrap();
    let rg = reader.metadata().row_group(0);
    let c = rg.columns().iter().find(|c| c.column_path().string() == leaf).unwrap();
    let (start, len) = c.byte_range();
    (start + len / 2) as usize
}

/// Readers check what they read: training, scoring, inspect and the sampler refuse a table whose
/// chunk bytes changed, in one line naming it and the chunk, and write nothing.
#[test]
fn every_reader_refuses_a_corrupt_table() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, scored) = reach_tables(tmp.path());
    let ckpt = tmp.path().join("reach.ckpt");
    let bad_table = tmp.path().join("bad_table.parquet");
    // A bit in the middle of the first row group's obs column.
    flipped(&table, &bad_table, middle_of(&table, "obs.list.item"), 3);
    let out = tmp.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let o = |p: &str| out.join(p).to_str().unwrap().to_string();
    let runs: Vec<(PathBuf, Vec<String>)> = vec![
        (
            PathBuf::from(env!("CARGO_BIN_EXE_pgser-train")),
            vec!["--data".into(), s(&bad_table), "-o".into(), o("a.ckpt")],
        ),
        (
            PathBuf::from(env!("CARGO_BIN_EXE_pgser-etl")),
            vec!["score".into(), "--q".into(), s(&ckpt), "--data".into(), s(&bad_table), "-o".into(), o("s.parquet")],
        ),
        (PathBuf::from(env!("CARGO_BIN_EXE_pgser-etl")), vec!["inspect".into(), s(&bad_table)]),
        (
            PathBuf::from(env!("CARGO_BIN_EXE_pgser-etl")),
            vec!["export".into(), s(&bad_table), "--format".into(), "wgcsl".into(), "-o".into(), o("x.pkl")],
        ),
    ];
    for (bin, args) in runs {
        let r = Command::new(&bin).args(&args).output().unwrap();
        let err = text(&r.stderr);
        assert!(!r.status.success(), "{args:?} read a corrupt table");
        assert!(
            err.contains("bad_table.parquet: row group 0, column obs.list.item") && err.contains("checksum mismatch"),
            "{args:?}: {err}"
        );
        assert_eq!(err.trim().lines().count(), 1, "{err}");
    }
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "a reader of a corrupt table wrote something");
    // The scored table's sampler checks the columns it reads (q and the keys).
    let bad_scored = tmp.path().join("bad_scored.parquet");
    flipped(&scored, &bad_scored, middle_of(&scored, "q"), 0);
    let e = pgser::score::ScoredTable::open(&bad_scored)
        .and_then(|t| t.check_whole())
        .expect_err("a corrupt q column is refused");
    assert!(format!("{e:#}").contains("column q") && names_the_file(&e, &bad_scored), "{e:#}");
}

/// Files without checksums (another writer, an older pgser) still load, and `verify` says they
/// cannot be verified instead of calling them corrupt.
#[test]
fn files_without_checksums_load_and_are_reported_unverifiable() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, _) = reach_tables(tmp.path());
    // polars rewrites the table, carrying pgser's footer (checksums included) over to bytes
    // they are not of: not corrupt, only unverifiable.
    let copy = tmp.path().join("polars.parquet");
    py_ok("check_interop.py", &["write-traj", table.to_str().unwrap(), copy.to_str().unwrap()]);
    let r = pgser::verify::verify(&copy).unwrap();
    assert!(!r.verified && r.line().contains("cannot be verified"), "{r:?}");
    let (a, b) =
        (pgser::trajectory::Episodes::load(&table).unwrap(), pgser::trajectory::Episodes::load(&copy).unwrap());
    assert!(a.obs == b.obs && a.g == b.g && a.ag == b.ag && a.u == b.u);
    let o = etl().arg("verify").arg(&copy).output().unwrap();
    assert!(o.status.success() && text(&o.stdout).starts_with("unverified "), "{}", text(&o.stdout));
}

/// A file cut short (a half-finished copy): every command that reads one refuses it in one line
/// naming it, and writes nothing.
#[test]
fn truncated_files_are_refused_by_every_reader() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, scored) = reach_tables(tmp.path());
    let ckpt = tmp.path().join("reach.ckpt");
    let cut = |src: &Path, name: &str, keep: f64| {
        let b = std::fs::read(src).unwrap();
        let dst = tmp.path().join(name);
        std::fs::write(&dst, &b[..(b.len() as f64 * keep) as usize]).unwrap();
        dst
    };
    let out = tmp.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let o = |p: &str| out.join(p).to_str().unwrap().to_string();
    let (etl_bin, train_bin) = (env!("CARGO_BIN_EXE_pgser-etl"), env!("CARGO_BIN_EXE_pgser-train"));
    for keep in [0.5, 0.999] {
        let (t, sc, ck) = (cut(&table, "t.parquet", keep), cut(&scored, "s.parquet", keep), cut(&ckpt, "c.ckpt", keep));
        let runs: Vec<(&str, Vec<String>, &Path)> = vec![
            (train_bin, vec!["--data".into(), s(&t), "-o".into(), o("a.ckpt")], &t),
            (train_bin, vec!["--data".into(), s(&sc), "-o".into(), o("b.ckpt")], &sc),
            (
                etl_bin,
                vec!["score".into(), "--q".into(), s(&ckpt), "--data".into(), s(&t), "-o".into(), o("s.parquet")],
                &t,
            ),
            (
                etl_bin,
                vec!["score".into(), "--q".into(), s(&ck), "--data".into(), s(&table), "-o".into(), o("s.parquet")],
                &ck,
            ),
            (train_bin, vec!["eval".into(), "--ckpt".into(), s(&ck), "--episodes".into(), "1".into()], &ck),
            (etl_bin, vec!["inspect".into(), s(&t)], &t),
            (etl_bin, vec!["verify".into(), s(&sc)], &sc),
            (etl_bin, vec!["export".into(), s(&t), "--format".into(), "minari".into(), "-o".into(), o("x-v0")], &t),
        ];
        for (bin, args, bad) in runs {
            let r = Command::new(bin).args(&args).output().unwrap();
            let err = text(&r.stderr);
            assert!(!r.status.success(), "{args:?} accepted a file cut to {keep}");
            // verify reports each file on stdout (CORRUPT …), its error line counts them.
            let said = format!("{}{err}", text(&r.stdout));
            assert!(
                said.contains(bad.to_str().unwrap()),
                "{args:?}: the error does not name {}: {said}",
                bad.display()
            );
            assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        }
        assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "a reader of a truncated file wrote something");
    }
}

/// Tables the fuzzers found to crash a reader (`fuzz/`), kept as regression tests in
/// `tests/fixtures/fuzz/TARGET/` (the `table` and `scored` targets' here; the pipeline target's
/// are read by tests/pipeline.rs): each file read by `verify`, `inspect` and the scored-table
/// sampler gives an error in one line naming the file, never a panic.
/// `scored/negative-chunk-offset.parquet`: a footer whose column chunk offset is negative, which
/// parquet's `byte_range` asserts on.
#[test]
fn inputs_the_fuzzers_found_fail_in_one_line() {
    let mut found = 0;
    let folders = ["table", "scored"].map(|t| repo().join("tests/fixtures/fuzz").join(t));
    for entry in folders.iter().filter(|d| d.exists()).flat_map(|d| std::fs::read_dir(d).unwrap()) {
        let p = entry.unwrap().path();
        found += 1;
        for cmd in ["verify", "inspect"] {
            let o = etl().arg(cmd).arg(&p).output().unwrap();
            // verify reports each file on stdout (`CORRUPT FILE: …`) and sums up on stderr.
            let (said, err) = (text(&o.stdout), text(&o.stderr));
            assert!(!o.status.success(), "{cmd} {}: accepted", p.display());
            assert!(!err.contains("panicked"), "{cmd} {}: {err}", p.display());
            assert_eq!(err.trim_end().lines().count(), 1, "{cmd}: {err}");
            let line = if cmd == "verify" { said } else { err };
            assert!(
                line.contains(&*p.file_name().unwrap().to_string_lossy()) && line.contains("corrupt"),
                "{cmd}: {line}"
            );
        }
        let e = pgser::score::ScoredTable::open(&p)
            .and_then(|t| t.check_whole())
            .expect_err("a corrupt scored table opened and checked");
        assert!(names_the_file(&e, &p), "{e:#}");
    }
    assert!(found > 0, "no inputs in {folders:?}");
}
