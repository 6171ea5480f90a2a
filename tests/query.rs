//! `pgser-etl query`: SQL over a scored table and over a results CSV, checked against answers
//! computed here by hand from the same files; the output formats; and bad queries, which fail
//! in one line naming the fault and leave no output file.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;

use arrow_array::Array;
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type, Int32Type, Int64Type};
use common::*;

fn query(args: &[&str]) -> Output {
    etl().arg("query").args(args).output().unwrap()
}

fn query_ok(args: &[&str]) -> String {
    let o = query(args);
    assert!(o.status.success(), "query {args:?} failed: {}", text(&o.stderr));
    text(&o.stdout)
}

/// CSV text (no quoting) as a header and rows of fields.
fn csv(text: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let mut lines = text.lines().map(|l| l.split(',').map(str::to_string).collect::<Vec<_>>());
    (lines.next().unwrap_or_default(), lines.collect())
}

fn num(s: &str) -> f64 {
    s.parse().unwrap_or_else(|e| panic!("{s:?}: {e}"))
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// The --help example: mean Q per goal episode of the swapped rows, against sums taken here
/// over the table as arrow-rs reads it.
#[test]
fn mean_q_per_goal_episode_of_a_scored_table() {
    let dir = tempfile::tempdir().unwrap();
    let (_, scored) = reach_tables(dir.path());
    let sql = "SELECT goal_episode, AVG(q) AS mean_q, AVG(reward) AS mean_reward, COUNT(*) AS n \
               FROM scored WHERE goal_step >= 0 GROUP BY goal_episode ORDER BY goal_episode";
    let (header, rows) = csv(&query_ok(&[sql, p(&scored)]));
    assert_eq!(header, ["goal_episode", "mean_q", "mean_reward", "n"]);

    let (b, _) = read_table(&scored);
    let col = |n: &str| b.column_by_name(n).unwrap().clone();
    let (ge, gs) = (col("goal_episode"), col("goal_step"));
    let (ge, gs) = (ge.as_primitive::<Int64Type>(), gs.as_primitive::<Int32Type>());
    let (q, r) = (col("q"), col("reward"));
    let (q, r) = (q.as_primitive::<Float32Type>(), r.as_primitive::<Float32Type>());
    let mut by_hand: BTreeMap<i64, (f64, f64, u64)> = BTreeMap::new();
    let mut originals = 0;
    for i in 0..b.num_rows() {
        if gs.value(i) < 0 {
            originals += 1;
            continue;
        }
        let e = by_hand.entry(ge.value(i)).or_default();
        e.0 += f64::from(q.value(i));
        e.1 += f64::from(r.value(i));
        e.2 += 1;
    }
    assert_eq!(originals, 250 * 49, "--include-original rows are in the table and left out by WHERE");
    assert_eq!(rows.len(), by_hand.len());
    for (row, (episode, (q_sum, r_sum, n))) in rows.iter().zip(&by_hand) {
        assert_eq!(num(&row[0]) as i64, *episode);
        assert_eq!(num(&row[3]) as u64, *n);
        let (mq, mr) = (q_sum / *n as f64, r_sum / *n as f64);
        // AVG of a float32 column is float32: compare to its precision.
        assert!((num(&row[1]) - mq).abs() <= 1e-5 * (1.0 + mq.abs()), "{row:?}: mean q {mq}");
        assert!((num(&row[2]) - mr).abs() <= 1e-5, "{row:?}: mean reward {mr}");
    }
    assert_eq!(by_hand.values().map(|v| v.2).sum::<u64>(), 250 * 49 * 2);
}

/// Success rate per task over all runs of a results table (each row's success_mean weighted by
/// its seeds): FetchPush (0.2·3 + 0.6·3) / 6 = 0.4, FetchReach (0.5·1 + 0.9·3) / 4 = 0.8.
#[test]
fn success_rate_per_task_of_a_results_csv() {
    let dir = tempfile::tempdir().unwrap();
    let r = results_table(dir.path());
    let sql = "SELECT task, SUM(success_mean * seeds) / SUM(seeds) AS success_rate, SUM(seeds) AS runs \
               FROM results GROUP BY task ORDER BY task";
    let (header, rows) = csv(&query_ok(&[sql, p(&r.csv)]));
    assert_eq!(header, ["task", "success_rate", "runs"]);
    assert_eq!(rows.len(), 2);
    assert_eq!((rows[0][0].as_str(), rows[0][2].as_str()), ("FetchPush", "6"));
    assert_eq!((rows[1][0].as_str(), rows[1][2].as_str()), ("FetchReach", "4"));
    assert!((num(&rows[0][1]) - 0.4).abs() < 1e-12, "{rows:?}");
    assert!((num(&rows[1][1]) - 0.8).abs() < 1e-12, "{rows:?}");
    // Empty p cells are nulls, a one-seed std is NaN, and the p values are numbers.
    let sql = "SELECT variant, p_vs_baseline, paper_score_std FROM t ORDER BY task, algo, variant";
    let (_, rows) = csv(&query_ok(&[sql, &format!("t={}", p(&r.csv))]));
    let mem = &r.rows.iter().find(|x| x.task == "FetchPush" && x.variant == "mem").unwrap();
    assert_eq!(rows[1][0], "mem");
    assert_eq!(num(&rows[1][1]), mem.p_vs_baseline.unwrap(), "{rows:?}");
    assert_eq!(rows[0][1], "", "baseline has no p: {rows:?}");
    assert!(num(&rows[2][2]).is_nan(), "{rows:?}");
}

/// -o writes the format its name or flag says, atomically; JSON Lines has one object per row.
#[test]
fn outputs_in_each_format() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let r = results_table(d);
    let sql = "SELECT task, variant, seeds, success_mean FROM results WHERE algo = 'td3bc' ORDER BY task, variant";
    let json = query_ok(&[sql, p(&r.csv), "--json"]);
    let objs: Vec<serde_json::Value> = json.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(objs.len(), 3, "{json}");
    let base = r.rows.iter().find(|x| x.task == "FetchPush" && x.variant == "baseline").unwrap();
    let want =
        serde_json::json!({"task": "FetchPush", "variant": "baseline", "seeds": 3, "success_mean": base.success_mean});
    assert_eq!(objs[0], want);
    // Keys in the SELECT's order, as the CSV header has them (not sorted).
    let first = json.lines().next().unwrap();
    let at = |k: &str| first.find(&format!("\"{k}\":")).unwrap();
    assert!(at("task") < at("variant") && at("variant") < at("seeds") && at("seeds") < at("success_mean"), "{first}");

    let pq = d.join("out.parquet");
    let o = query(&[sql, p(&r.csv), "-o", p(&pq)]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("3 rows"), "{}", text(&o.stderr));
    let (b, _) = read_table(&pq);
    assert_eq!(b.num_rows(), 3);
    let success = b.column_by_name("success_mean").unwrap().as_primitive::<Float64Type>().values().to_vec();
    let want: Vec<f64> = ["baseline", "mem"]
        .iter()
        .map(|v| {
            r.rows.iter().find(|x| x.task == "FetchPush" && x.algo == "td3bc" && x.variant == *v).unwrap().success_mean
        })
        .collect();
    assert_eq!(&success[..2], &want[..]);

    let out_csv = d.join("out.txt");
    let o = query(&[sql, p(&r.csv), "-o", p(&out_csv), "--csv"]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(std::fs::read_to_string(&out_csv).unwrap(), query_ok(&[sql, p(&r.csv)]));
}

fn one_line_error(o: &Output) -> String {
    assert!(!o.status.success(), "expected a failure: {}", text(&o.stdout));
    let err = text(&o.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "not one line:\n{err}");
    err
}

/// Bad SQL, an unknown column or table, a missing input, nested columns in CSV and a Parquet
/// result without a file: one line that names the fault, exit 1, no output file, no temporary.
#[test]
fn bad_queries_fail_in_one_line_and_leave_no_file() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let results = results_table(d).csv;
    let out = d.join("out");
    std::fs::create_dir(&out).unwrap();
    let o = out.join("r.csv");
    let cases: [(&str, &str, &str); 4] = [
        ("SELEC task FROM results", "results", "SELEC"),
        ("SELECT no_such_column FROM results", "results", "no_such_column"),
        ("SELECT task FROM nowhere", "results", "nowhere"),
        ("SELECT task FROM results", "missing", "missing.csv"),
    ];
    for (sql, input, needle) in cases {
        let path = if input == "missing" { d.join("missing.csv") } else { results.clone() };
        let e = one_line_error(&query(&[sql, p(&path), "-o", p(&o)]));
        assert!(e.contains(needle) && e.starts_with("pgser-etl: error: "), "{sql}: {e}");
        assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "{sql}: a file was left: {e}");
    }
    let e = one_line_error(&query(&["SELECT task FROM results", p(&results), "--parquet"]));
    assert!(e.contains("-o"), "{e}");
    let e = one_line_error(&query(&["SELECT 1", "a.parquet", "b/a.parquet"]));
    assert!(e.contains("`a`") && e.contains("NAME=PATH"), "{e}");
}

/// Vectors cannot go into CSV: the failure is one line and leaves no file; Parquet keeps them.
#[test]
fn vector_columns_go_to_parquet_not_csv() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (traj, _) = reach_tables(d);
    let sql = "SELECT episode, achieved_goal FROM reach WHERE step = 49 ORDER BY episode";
    let bad = d.join("last.csv");
    let e = one_line_error(&query(&[sql, p(&traj), "-o", p(&bad)]));
    assert!(e.contains("last.csv"), "{e}");
    assert!(!bad.exists());
    let good = d.join("last.parquet");
    let o = query(&[sql, p(&traj), "-o", p(&good)]);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let (b, _) = read_table(&good);
    let (src, _) = read_table(&traj);
    assert_eq!(b.num_rows(), 250);
    let ag = b.column_by_name("achieved_goal").unwrap().as_fixed_size_list().clone();
    let src_ag = src.column_by_name("achieved_goal").unwrap().as_fixed_size_list().clone();
    for e in [0usize, 17, 249] {
        let row = src_ag.value(e * 50 + 49);
        assert_eq!(ag.value(e).as_primitive::<Float64Type>().values(), row.as_primitive::<Float64Type>().values());
    }
    assert_eq!(ag.null_count(), 0);
}
