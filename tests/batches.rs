//! `pgser-train batches`: the batches a run trains on, written out. The same flags and seed give
//! the same rows at any thread count; rows are what the sampler promises (original rows first,
//! then prioritized rows of the scored table with their weights); bad inputs leave no file.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int64Type};
use common::*;

fn batches(data: &Path, out: &Path, args: &[&str], threads: usize) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["batches", "--data", data.to_str().unwrap(), "-o", out.to_str().unwrap()])
        .args(["--threads", &threads.to_string()])
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn same_seed_same_bytes_at_any_thread_count_and_rows_are_where_they_say() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, scored) = reach_tables(tmp.path());
    let (a, b) = (tmp.path().join("a.parquet"), tmp.path().join("b.parquet"));
    let args = ["--count", "5", "--batch-size", "64", "--aug-ratio", "0.25", "--is-beta", "0.5", "--seed", "7"];
    for (threads, out) in [(1, &a), (2, &b)] {
        let o = batches(&scored, out, &args, threads);
        assert!(o.status.success(), "{}", text(&o.stderr));
    }
    // Equal tables (the footer's command line differs: it names --threads and the output).
    assert!(read_table(&a).0.columns() == read_table(&b).0.columns(), "1 vs 2 threads");
    let rows = read_table(&a).0;
    let n = rows.num_rows();
    assert_eq!(n, 5 * 64);
    let col = |name: &str| rows.column_by_name(name).unwrap().clone();
    let batch = col("batch");
    let scored_row = col("scored_row");
    let weight = col("weight");
    let (batch, scored_row, weight) = (
        batch.as_primitive::<Int64Type>(),
        scored_row.as_primitive::<Int64Type>(),
        weight.as_primitive::<Float32Type>(),
    );
    for i in 0..n {
        assert_eq!(batch.value(i), (i / 64) as i64);
        // 48 rows of the original data (weight 1, no scored row), then 16 prioritized rows.
        let prioritized = i % 64 >= 48;
        assert_eq!(scored_row.value(i) >= 0, prioritized, "row {i}");
        let w = weight.value(i);
        assert!(if prioritized { w > 0.0 && w <= 1.0 } else { w == 1.0 }, "row {i}: weight {w}");
    }
    // Some prioritized rows are down-weighted, so the weights were really applied.
    assert!((0..n).any(|i| weight.value(i) < 1.0));
    // Another seed, other batches; no --is-beta, weights all 1; a trajectory table, no scored rows.
    let o = batches(&scored, &b, &["--count", "5", "--batch-size", "64", "--aug-ratio", "0.25", "--seed", "8"], 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(read_table(&a).0.columns() != read_table(&b).0.columns(), "seeds 7 and 8 drew the same batches");
    let o = batches(&table, &b, &["--count", "2", "--swap", "random"], 2);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let rows = read_table(&b).0;
    let n = rows.num_rows();
    assert_eq!(n, 2 * 512);
    let sr = rows.column_by_name("scored_row").unwrap().as_primitive::<Int64Type>().clone();
    assert!((0..n).all(|i| sr.value(i) == -1));
}

#[test]
fn bad_inputs_name_the_fault_and_leave_no_file() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, scored) = reach_tables(tmp.path());
    let out = tmp.path().join("out.parquet");
    let cases: [(&Path, &[&str], &str); 4] = [
        (&tmp.path().join("missing.parquet"), &[], "missing.parquet"),
        (&scored, &["--swap", "random"], "--swap random with a scored table"),
        (&scored, &["--aug-ratio", "1.5"], "--aug-ratio 1.5"),
        (&table, &["--batch-size", "0"], "--batch-size must be at least 1"),
    ];
    for (data, args, want) in cases {
        let o = batches(data, &out, args, 2);
        let err = text(&o.stderr);
        assert!(!o.status.success() && err.contains(want), "{args:?}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "one line: {err}");
        assert!(!out.exists(), "{args:?} left a file");
    }
}
