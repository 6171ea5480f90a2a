//! The report module: Welch's t-test against known values, `pgser-etl report` end to end on a
//! tiny FetchReach run (Fig. 5 PNG, Table 1 JSON), Table 1's two definitions of negatives on
//! hand-made scored tables, and Table 2 from hand-written metrics files (Table 2 across tasks,
//! with the paper's values: `table2.rs`).

mod common;

use std::path::Path;
use std::process::Command;
use std::sync::Arc;

use arrow_array::{Float32Array, Int32Array, Int64Array, RecordBatch};
use arrow_schema::{DataType, Field, Schema};
use common::*;
use pgser::nprandom::NpRandom;
use pgser::report;

/// Width and height from a PNG's IHDR chunk (after checking the signature).
fn png_size(path: &Path) -> (u32, u32) {
    let b = std::fs::read(path).unwrap();
    assert!(b.len() > 24, "{}: too short for a PNG", path.display());
    assert_eq!(&b[..8], b"\x89PNG\r\n\x1a\n", "{}: no PNG signature", path.display());
    assert_eq!(&b[12..16], b"IHDR");
    let be = |i: usize| u32::from_be_bytes(b[i..i + 4].try_into().unwrap());
    (be(16), be(20))
}

#[test]
fn welch_matches_known_values() {
    // Hand-computed: means 3 and 6, variances 2.5 and 10 → t = −3/√2.5, df = 6.25/1.0625.
    let (t, df, p) = report::welch_t_test(&[1.0, 2.0, 3.0, 4.0, 5.0], &[2.0, 4.0, 6.0, 8.0, 10.0]).unwrap();
    assert!((t + 1.897_366_6).abs() < 1e-6, "t {t}");
    assert!((df - 5.882_352_9).abs() < 1e-6, "df {df}");
    assert!((p - 0.107_531).abs() < 1e-4, "p {p}");
    // Wikipedia's Welch example 1 (t −2.46, df 25.0, p 0.021).
    let a = [27.5, 21.0, 19.0, 23.6, 17.0, 17.9, 16.9, 20.1, 21.9, 22.6, 23.1, 19.6, 19.0, 21.7, 21.4];
    let b = [27.1, 22.0, 20.8, 23.4, 23.4, 23.5, 25.8, 22.0, 24.8, 20.2, 21.9, 22.1, 22.9, 20.5, 24.4];
    let (t, df, p) = report::welch_t_test(&a, &b).unwrap();
    assert!(
        (t + 2.455_356).abs() < 1e-5 && (df - 24.988_53).abs() < 1e-3 && (p - 0.021_378).abs() < 1e-4,
        "{t} {df} {p}"
    );
    // Symmetric in its arguments up to the sign of t.
    let (t2, _, p2) = report::welch_t_test(&b, &a).unwrap();
    assert!((t2 + t).abs() < 1e-12 && (p2 - p).abs() < 1e-12);
    // One-sided (H1: mean(a) > mean(b)): a's mean is lower, so p is near 1; the other way round
    // it is half the two-sided p, and the two add up to 1.
    let up = report::welch_greater(&a, &b).unwrap();
    let down = report::welch_greater(&b, &a).unwrap();
    assert!((down - p / 2.0).abs() < 1e-12 && (up - (1.0 - p / 2.0)).abs() < 1e-12, "{up} {down} {p}");
    assert!(report::welch_greater(&[1.0], &a).is_none());
}

#[test]
fn welch_is_undefined_without_two_samples_or_any_variance() {
    assert!(report::welch_t_test(&[1.0], &[1.0, 2.0]).is_none());
    assert!(report::welch_t_test(&[1.0, 2.0], &[]).is_none());
    assert!(report::welch_t_test(&[3.0, 3.0, 3.0], &[5.0, 5.0]).is_none());
    // One side constant is fine: the other carries the variance.
    assert!(report::welch_t_test(&[3.0, 3.0, 3.0], &[5.0, 6.0]).is_some());
}

#[test]
fn report_cli_writes_fig5_and_table1() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let table = d.join("reach.parquet");
    let data = repo().join("data");
    convert_ok(&[&data.join("fetch_reach_expert_50.pkl"), &data.join("fetch_reach_random_200.pkl")], &table, &[]);
    let ckpt = d.join("q.ckpt");
    let out = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", table.to_str().unwrap(), "-o", ckpt.to_str().unwrap()])
        .args(["--updates", "300", "--hidden", "32", "--batch-size", "64", "--eval-episodes", "0"])
        .output()
        .unwrap();
    assert!(out.status.success(), "pgser-train failed: {}", text(&out.stderr));
    let scored = d.join("scored.parquet");
    let out = etl()
        .args(["score", "--q", ckpt.to_str().unwrap(), "--data", table.to_str().unwrap(), "-o"])
        .arg(&scored)
        .args(["--swaps", "2"])
        .output()
        .unwrap();
    assert!(out.status.success(), "score failed: {}", text(&out.stderr));

    let rep = d.join("rep");
    // A small SVC training set keeps the test fast whatever this tiny critic learned.
    let args = ["--seed", "3", "--svm-max-train", "500", "--json"];
    let out = etl().arg("report").arg(&scored).arg("-o").arg(&rep).args(args).output().unwrap();
    assert!(out.status.success(), "report failed: {}", text(&out.stderr));
    let printed: serde_json::Value = serde_json::from_str(text(&out.stdout).trim()).unwrap();

    assert_eq!(png_size(&rep.join("fig5_q_hist.png")), report::FIG_SIZE);
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rep.join("table1.json")).unwrap()).unwrap();
    assert_eq!(j, printed, "--json prints what table1.json holds");
    // The first source (the expert pickle) gave 50 episodes of 49 transitions each.
    assert_eq!(j["positives"], 50 * 49);
    assert_eq!(j["negatives"], 50 * 49);
    assert_eq!(j["negatives_available"], 250 * 49 * 2);
    assert_eq!(j["task"], "FetchReach");
    let classifiers = j["classifiers"].as_array().unwrap();
    assert_eq!(classifiers.len(), 4);
    for c in classifiers {
        let a = c["accuracy"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&a), "{c}");
        assert_eq!(c["test"], 1470, "{c}");
    }
    assert_eq!(classifiers[3]["train"], 500, "--svm-max-train caps the SVC's training rows");
    // The controlled table: one swapped row of each positive transition, so its pool is the
    // positives' 2 swaps each, not the whole table's.
    let c = &j["controlled"];
    assert_eq!(c["negatives"], 50 * 49);
    assert_eq!(c["negatives_available"], 50 * 49 * 2);
    let cc = c["classifiers"].as_array().unwrap();
    assert_eq!(cc.len(), 4);
    for (p, k) in classifiers.iter().zip(cc) {
        assert_eq!((&p["name"], &p["train"], &p["test"]), (&k["name"], &k["train"], &k["test"]), "same classifiers");
        assert!((0.0..=1.0).contains(&k["accuracy"].as_f64().unwrap()), "{k}");
    }
    assert!(c["negative_q_mean"].as_f64().unwrap().is_finite());
    let md = std::fs::read_to_string(rep.join("table1.md")).unwrap();
    assert!(md.contains("| classifier | train | test | accuracy |") && md.contains("SVC"), "{md}");
    assert_eq!(md.matches("| classifier | train | test | accuracy |").count(), 2, "{md}");
    assert!(
        md.contains("## Controlled negatives") && md.contains("of the 4900 swapped rows of those transitions"),
        "{md}"
    );
    let q_pos = j["positive_q_mean"].as_f64().unwrap();
    assert!((-60.0..=1.0).contains(&q_pos), "{q_pos}");

    // Same seed, same report (the JSON holds no timings).
    let rep2 = d.join("rep2");
    let out = etl().arg("report").arg(&scored).arg("-o").arg(&rep2).args(args).output().unwrap();
    assert!(out.status.success());
    let j2: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(rep2.join("table1.json")).unwrap()).unwrap();
    assert_eq!(j["classifiers"], j2["classifiers"]);
    assert_eq!(j["controlled"], j2["controlled"]);
    assert_eq!(std::fs::read(rep.join("table1.md")).unwrap(), std::fs::read(rep2.join("table1.md")).unwrap());
    assert_eq!(
        std::fs::read(rep.join("fig5_q_hist.png")).unwrap(),
        std::fs::read(rep2.join("fig5_q_hist.png")).unwrap()
    );

    // Fig. 5's histograms are in table1.json as drawn: densities that integrate to 1, one per
    // class, over an axis fitted to the data (not Q's whole range [−1/(1−γ), 0], where data a
    // few units below 0 would be two thin bars): the lowest and the highest Q fall in the first
    // and the last bin.
    let h = &j["fig5_hist"];
    let (lo, hi) = (h["lo"].as_f64().unwrap(), h["hi"].as_f64().unwrap());
    let (pos, neg) = (j["positive_q_mean"].as_f64().unwrap(), j["negative_q_mean"].as_f64().unwrap());
    assert!(lo < pos.min(neg) && pos.max(neg) < hi, "{lo} {hi}");
    let width = (hi - lo) / 50.0;
    let mut edges = (false, false);
    for class in ["positives", "negatives"] {
        let d: Vec<f64> = h[class].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
        assert_eq!(d.len(), 50);
        assert!((d.iter().sum::<f64>() * width - 1.0).abs() < 1e-9, "{class}");
        edges = (edges.0 || d[0] > 0.0, edges.1 || d[49] > 0.0);
    }
    assert_eq!(edges, (true, true), "the axis [{lo}, {hi}] is not fitted to the data");
    fig5_across_tasks(d, &rep, &j);

    // A checkpoint changed since scoring is refused in one line that names it.
    let mut bytes = std::fs::read(&ckpt).unwrap();
    bytes.push(0);
    std::fs::write(&ckpt, bytes).unwrap();
    let rep3 = d.join("rep3");
    let out = etl().arg("report").arg(&scored).arg("-o").arg(&rep3).args(args).output().unwrap();
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("q.ckpt") && err.contains("sha256"), "{err}");
    assert!(!rep3.join("table1.json").exists());
}

/// A stand-in scored table with only the columns Table 1's negatives are read from: one row per
/// (episode, step, goal_step, q).
fn scored_stub(path: &Path, rows: &[(i64, i32, i32, f32)]) {
    let schema = Arc::new(Schema::new(vec![
        Field::new("episode", DataType::Int64, false),
        Field::new("step", DataType::Int32, false),
        Field::new("goal_step", DataType::Int32, false),
        Field::new("q", DataType::Float32, false),
    ]));
    let batch = RecordBatch::try_new(
        schema.clone(),
        vec![
            Arc::new(Int64Array::from_iter_values(rows.iter().map(|r| r.0))),
            Arc::new(Int32Array::from_iter_values(rows.iter().map(|r| r.1))),
            Arc::new(Int32Array::from_iter_values(rows.iter().map(|r| r.2))),
            Arc::new(Float32Array::from_iter_values(rows.iter().map(|r| r.3))),
        ],
    )
    .unwrap();
    let mut w = parquet::arrow::ArrowWriter::try_new(std::fs::File::create(path).unwrap(), schema, None).unwrap();
    w.write(&batch).unwrap();
    w.close().unwrap();
}

/// Each controlled negative is a swapped row of its own positive transition (q encodes the row),
/// one per positive, drawn among that transition's swaps; the paper's negatives come from all
/// swapped rows; original rows are never negatives; the draw is the seed's.
#[test]
fn controlled_negatives_are_swapped_rows_of_the_positive_transitions() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("scored.parquet");
    let (episodes, t1, swaps) = (10i64, 4i32, 3i32);
    // q = −(100·episode + step) − swap/100 for a swapped row; original rows (goal_step −1) +0.5.
    let mut rows = Vec::new();
    for e in 0..episodes {
        for s in 0..t1 {
            rows.push((e, s, -1, 0.5));
            for j in 0..swaps {
                rows.push((e, s, j, -((100 * e + i64::from(s)) as f32) - j as f32 / 100.0));
            }
        }
    }
    scored_stub(&path, &rows);
    let keys: Vec<(i64, i32)> = (0..4).flat_map(|e| (0..t1).map(move |s| (e, s))).filter(|k| k.1 != 2).collect();
    let n = report::negatives(&path, &keys, keys.len(), 5, &mut |_| {}).unwrap();
    assert_eq!(n.controlled.len(), keys.len());
    assert_eq!(n.controlled_available, keys.len() * swaps as usize);
    assert_eq!(n.paper.len(), keys.len());
    assert_eq!(n.paper_available, (episodes * i64::from(t1 * swaps)) as usize);
    let decode = |q: f64| -> (i64, i32, i32) {
        let whole = (-q).floor();
        let j = ((-q - whole) * 100.0).round() as i32;
        ((whole as i64) / 100, (whole as i64 % 100) as i32, j)
    };
    let mut picked = [0usize; 3];
    for (k, &q) in keys.iter().zip(&n.controlled) {
        assert!(q < 0.0, "an original row became a negative: {q}");
        let (e, s, j) = decode(q);
        assert_eq!((e, s), *k, "q {q} is not a swapped row of {k:?}");
        picked[j as usize] += 1;
    }
    assert!(picked.iter().all(|&c| c > 0), "every swap index drawn at least once: {picked:?}");
    assert!(n.paper.iter().all(|&q| q < 0.0), "original rows are not negatives");
    assert!(n.paper.iter().any(|&q| decode(q).0 >= 4), "the paper's negatives come from the whole table");
    assert_eq!(report::negatives(&path, &keys, keys.len(), 5, &mut |_| {}).unwrap(), n, "same seed, same draw");
    assert_ne!(report::negatives(&path, &keys, keys.len(), 6, &mut |_| {}).unwrap().controlled, n.controlled);

    // A positive without swapped rows, and positives out of order, are refused in one line.
    let e = report::negatives(&path, &[(0, 0), (11, 0)], 2, 5, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("scored.parquet") && e.contains("episode 11, step 0") && !e.contains('\n'), "{e}");
    let e = report::negatives(&path, &[(1, 0), (0, 3)], 2, 5, &mut |_| {}).unwrap_err().to_string();
    assert!(e.contains("scored.parquet") && e.contains("episode 0, step 3"), "{e}");
}

/// A table where Q tells expert transitions from random ones but ignores the goal: the paper's
/// negatives (80 % random transitions) are separated well, the controlled ones are not. Where Q
/// does depend on the goal, the controlled table sees it.
#[test]
fn controlled_table1_is_at_chance_where_only_the_data_source_separates() {
    let dir = tempfile::tempdir().unwrap();
    let (expert, random, t1, swaps) = (100i64, 400i64, 10i32, 2i32);
    let mut rng = NpRandom::new(11);
    let keys: Vec<(i64, i32)> = (0..expert).flat_map(|e| (0..t1).map(move |s| (e, s))).collect();
    let positives: Vec<f64> = keys.iter().map(|_| -3.0 + rng.standard_normal()).collect();
    let opts = report::QReportOptions { svm_max_train: 300, seed: 2, ..Default::default() };
    for goal_matters in [false, true] {
        // Swapped rows: random transitions around Q = −25; expert ones like their own goal
        // (Q ignores the goal) or around −15 (Q knows the goal is not theirs).
        let mut rows = Vec::new();
        for e in 0..expert + random {
            for s in 0..t1 {
                for j in 0..swaps {
                    let q = match (e < expert, goal_matters) {
                        (false, _) => -25.0 + 3.0 * rng.standard_normal(),
                        (true, false) => -3.0 + rng.standard_normal(),
                        (true, true) => -15.0 + 3.0 * rng.standard_normal(),
                    };
                    rows.push((e, s, j, q as f32));
                }
            }
        }
        let path = dir.path().join(format!("scored_{goal_matters}.parquet"));
        scored_stub(&path, &rows);
        let t = report::table1(&path, &positives, &keys, 0.98, &opts).unwrap();
        // The shares count every row once, against the positives' median.
        let s = &t.shares;
        assert_eq!(s.rows, rows.len());
        assert_eq!(s.above, rows.iter().filter(|r| f64::from(r.3) > s.threshold).count());
        if s.above > 0 {
            assert!(s.settings[0].share_above > s.uniform, "q priorities favour the rows above: {s:?}");
        } else {
            assert_eq!((s.uniform, s.settings[0].share_above), (0.0, 0.0), "no row above: nothing drawn there");
        }
        assert_eq!(t.negatives.controlled_available, keys.len() * swaps as usize);
        for (paper, controlled) in t.paper.iter().zip(&t.controlled) {
            assert_eq!((paper.test, controlled.test), (600, 600));
            assert!(paper.accuracy > 0.85, "{}: paper accuracy {}", paper.name, paper.accuracy);
            if goal_matters {
                assert!(controlled.accuracy > 0.95, "{}: controlled accuracy {}", controlled.name, controlled.accuracy);
            } else {
                assert!(controlled.accuracy < 0.6, "{}: controlled accuracy {}", controlled.name, controlled.accuracy);
            }
        }
    }
}

fn mean_std(v: &[f64]) -> (f64, f64) {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (m, (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt())
}

#[test]
fn results_table_from_metrics_files() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cells: [(&str, [f64; 3]); 3] =
        [("baseline", [10.0, 12.0, 14.0]), ("swap", [11.0, 13.0, 16.0]), ("mem", [30.0, 31.0, 33.0])];
    let mut runs = Vec::new();
    for (variant, scores) in &cells {
        for (seed, s) in scores.iter().enumerate() {
            let m = metrics_file(d, &format!("{variant}{seed}.metrics.jsonl"), *s, s / 50.0);
            runs.push(report_run("FetchReach", "td3bc", variant, seed as u64, m));
        }
    }
    // A second algorithm with one seed: std and p are undefined.
    runs.push(report_run("FetchReach", "td3", "mem", 0, metrics_file(d, "td3.metrics.jsonl", 20.0, 0.5)));
    let out = d.join("out");
    let r = report::results(&runs, &out).unwrap();

    let csv = std::fs::read_to_string(&r.csv).unwrap();
    let lines: Vec<Vec<&str>> = csv.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(lines.len(), 4, "{csv}");
    assert_eq!(&lines[0][..3], ["FetchReach", "td3", "mem"], "TD3 before TD3+BC");
    assert_eq!(lines[0][5], "NaN", "one seed has no std: {csv}");
    assert_eq!(lines[0][7], "", "no baseline for td3: {csv}");
    assert_eq!(lines[0].len(), 15, "two-sided and one-sided p, episodes pooled and their p: {csv}");
    let num = |s: &str| s.parse::<f64>().unwrap();
    for (i, (variant, scores)) in cells.iter().enumerate() {
        let l = &lines[i + 1];
        assert_eq!(&l[..4], ["FetchReach", "td3bc", *variant, "3"], "baseline, swap, mem order: {csv}");
        let (m, s) = mean_std(scores);
        assert!((num(l[4]) - m).abs() < 1e-12 && (num(l[5]) - s).abs() < 1e-12, "{variant}: {l:?} vs {m} {s}");
        assert!((num(l[6]) - m / 50.0).abs() < 1e-12, "success mean {l:?}");
    }
    let mem = &lines[3];
    let (_, _, p_base) = report::welch_t_test(&cells[2].1, &cells[0].1).unwrap();
    assert!((num(mem[7]) - p_base).abs() < 1e-15 && p_base < 0.05, "{mem:?}");
    assert!(num(mem[8]) < 0.05, "{mem:?}");
    assert!((num(mem[9]) - p_base / 2.0).abs() < 1e-15, "mem above baseline: one-sided p is half: {mem:?}");
    assert_eq!(lines[1][7], "", "p only for mem");
    assert_eq!(lines[1][9], "", "p only for mem");

    let md = std::fs::read_to_string(&r.markdown).unwrap();
    assert_eq!(md, report::results_markdown(&r));
    assert!(md.contains("## FetchReach"), "{md}");
    let mem_row = md.lines().find(|l| l.starts_with("| TD3+BC mem |")).unwrap_or_else(|| panic!("{md}"));
    let cols: Vec<&str> = mem_row.split('|').map(str::trim).collect();
    assert_eq!(cols[2], "31.333 ± 1.528", "{mem_row}");
    assert!(cols[7].ends_with(report::BETTER) && cols[8].ends_with(report::BETTER), "{mem_row}");
    assert!(!mem_row.contains('*') && !mem_row.contains(report::WORSE), "{mem_row}");
    // Each run evaluated 10 episodes with std 1 (metrics_file): as episodes, 5 at its score − 1
    // and 5 at + 1. Pooled over the 3 seeds: 30 episodes, their sample std.
    let episodes: Vec<f64> =
        cells[2].1.iter().flat_map(|m| (0..10).map(move |i| if i % 2 == 0 { m - 1.0 } else { m + 1.0 })).collect();
    let pooled = mean_std(&episodes).1;
    assert_eq!((cols[3], cols[6]), (format!("{pooled:.3}").as_str(), "30"), "{mem_row}");
    assert!((num(lines[3][12]) - pooled).abs() < 1e-12 && lines[3][11] == "30", "{:?}", lines[3]);
    let scores = std::fs::read_to_string(&r.scores).unwrap();
    assert!(scores.starts_with("task,algo,variant,seed,episodes,paper_score,episode_std\n"), "{scores}");
    assert!(scores.contains("\nFetchReach,td3bc,mem,2,10,33,1\n"), "{scores}");
    assert!(md.lines().any(|l| l.starts_with("| TD3+BC baseline | 12.000 ± 2.000 |")), "{md}");
    assert_eq!(r.curves, vec![out.join("curves_FetchReach.png")]);
    assert_eq!(png_size(&r.curves[0]), report::FIG_SIZE);
}

#[test]
fn results_refuse_a_run_without_a_final_evaluation() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let good = metrics_file(d, "good.metrics.jsonl", 10.0, 0.2);
    let no_eval = d.join("noeval.metrics.jsonl");
    std::fs::write(&no_eval, "{\"updates\":500,\"critic_loss\":0.5}\n").unwrap();
    let empty = d.join("empty.metrics.jsonl");
    std::fs::write(&empty, "").unwrap();
    let missing = d.join("missing.metrics.jsonl");
    for bad in [&no_eval, &empty, &missing] {
        let runs = [
            report_run("FetchReach", "td3", "baseline", 0, good.clone()),
            report_run("FetchReach", "td3", "swap", 0, bad.clone()),
        ];
        let e = report::results(&runs, &d.join("out")).unwrap_err();
        let msg = format!("{e:#}");
        assert!(msg.contains(&bad.display().to_string()), "{msg}");
        assert!(!d.join("out/results.csv").exists(), "nothing written on error");
    }
}

/// A significant difference is marked with its direction, and the CSV's one-sided p (H1: mem
/// outperforms) tells better from worse: mem clearly above baseline (▲, one-sided p small),
/// clearly below swap (▼, one-sided p near 1), and level with both on another task (no mark).
#[test]
fn results_mark_the_direction_of_a_significant_difference() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let cells: [(&str, &str, [f64; 3]); 6] = [
        ("FetchPush", "baseline", [10.0, 12.0, 14.0]),
        ("FetchPush", "swap", [40.0, 41.0, 43.0]),
        ("FetchPush", "mem", [30.0, 31.0, 33.0]),
        ("FetchReach", "baseline", [20.0, 22.0, 24.0]),
        ("FetchReach", "swap", [21.0, 22.5, 23.0]),
        ("FetchReach", "mem", [21.0, 22.0, 23.0]),
    ];
    let mut runs = Vec::new();
    for (task, variant, scores) in &cells {
        for (seed, s) in scores.iter().enumerate() {
            let m = metrics_file(d, &format!("{task}{variant}{seed}.metrics.jsonl"), *s, s / 50.0);
            runs.push(report_run(task, "td3bc", variant, seed as u64, m));
        }
    }
    let r = report::results(&runs, &d.join("out")).unwrap();
    let mem = |task: &str| r.rows.iter().find(|row| row.task == task && row.variant == "mem").unwrap();
    let push = mem("FetchPush");
    assert!(push.p_vs_baseline.unwrap() < 0.05 && push.p_one_sided_vs_baseline.unwrap() < 0.025, "{push:?}");
    assert!(push.p_vs_swap.unwrap() < 0.05 && push.p_one_sided_vs_swap.unwrap() > 0.975, "{push:?}");
    let reach = mem("FetchReach");
    assert!(reach.p_vs_baseline.unwrap() > 0.05 && reach.p_vs_swap.unwrap() > 0.05, "{reach:?}");
    let (p_one, p_two) = (reach.p_one_sided_vs_swap.unwrap(), reach.p_vs_swap.unwrap());
    assert!((p_one - (1.0 - p_two / 2.0)).abs() < 1e-12, "mem below swap on average: {reach:?}");

    let md = std::fs::read_to_string(&r.markdown).unwrap();
    let rows: Vec<&str> = md.lines().filter(|l| l.starts_with("| TD3+BC mem |")).collect();
    assert_eq!(rows.len(), 2, "{md}");
    let cols = |row: &str| row.split('|').map(str::trim).map(String::from).collect::<Vec<_>>();
    let push_row = cols(rows[0]);
    assert!(push_row[7].ends_with(report::BETTER) && push_row[8].ends_with(report::WORSE), "{}", rows[0]);
    let reach_row = cols(rows[1]);
    for c in &reach_row[7..9] {
        assert!(!c.contains(report::BETTER) && !c.contains(report::WORSE) && !c.contains('*'), "{}", rows[1]);
    }
    assert!(md.contains("Welch's two-sided t-test") && md.contains("one-sided") && md.contains(report::WORSE), "{md}");

    let csv = std::fs::read_to_string(&r.csv).unwrap();
    let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
    assert_eq!(&header[7..11], ["p_vs_baseline", "p_vs_swap", "p_one_sided_vs_baseline", "p_one_sided_vs_swap"]);
    let push_csv: Vec<&str> = csv.lines().find(|l| l.starts_with("FetchPush,td3bc,mem,")).unwrap().split(',').collect();
    assert_eq!(push_csv[9].parse::<f64>().unwrap(), push.p_one_sided_vs_baseline.unwrap());
    assert_eq!(push_csv[10].parse::<f64>().unwrap(), push.p_one_sided_vs_swap.unwrap());
}

/// The committed results tables (`results/*/results.md`) are what `results_markdown` makes of
/// the CSV beside them, and each CSV's p values are Welch's tests of its own means and stds:
/// the agents' metrics files are not in the repository, so when the table format changes the
/// markdown is regenerated from the CSV, and this keeps the two from drifting apart.
#[test]
fn committed_results_tables_follow_from_their_csv() {
    let mut checked = 0;
    for entry in std::fs::read_dir(repo().join("results")).unwrap() {
        let dir = entry.unwrap().path();
        let csv_path = dir.join("results.csv");
        if !csv_path.is_file() {
            continue;
        }
        let csv = std::fs::read_to_string(&csv_path).unwrap();
        let rows: Vec<report::ResultRow> = csv.lines().skip(1).map(|l| result_row(&csv_path, l)).collect();
        // Per-seed scores with a group's mean and std: m + s·z with z of sample std 1.
        let seeds = |r: &report::ResultRow| -> Vec<f64> {
            let a = ((r.seeds - 1) as f64 / 2.0).sqrt();
            let mut v = vec![r.paper_score_mean; r.seeds];
            v[0] -= a * r.paper_score_std;
            v[r.seeds - 1] += a * r.paper_score_std;
            v
        };
        for r in rows.iter().filter(|r| r.variant == "mem") {
            for (other, two, one) in
                [("baseline", r.p_vs_baseline, r.p_one_sided_vs_baseline), ("swap", r.p_vs_swap, r.p_one_sided_vs_swap)]
            {
                // A study's pipeline may train -mem alone (its references are another grid's):
                // then it has no p to check.
                let Some(o) = rows.iter().find(|x| x.task == r.task && x.algo == r.algo && x.variant == other) else {
                    assert!(two.is_none() && one.is_none(), "{}: {r:?}", csv_path.display());
                    continue;
                };
                // Both sides without spread (a saturated task: every seed at the same score) have
                // no t statistic, and the CSV leaves the p values empty.
                let Some((_, _, p)) = report::welch_t_test(&seeds(r), &seeds(o)) else {
                    assert!(two.is_none() && one.is_none(), "{}: {r:?}", csv_path.display());
                    continue;
                };
                let p1 = report::welch_greater(&seeds(r), &seeds(o)).unwrap();
                let (two, one) = (two.unwrap(), one.unwrap());
                assert!((p - two).abs() < 1e-9 * two && (p1 - one).abs() < 1e-9 * one, "{}: {r:?}", csv_path.display());
            }
        }
        let scores = dir.join("scores.csv");
        let results = report::Results { rows, markdown: dir.join("results.md"), csv: csv_path, scores, curves: vec![] };
        let md = std::fs::read_to_string(&results.markdown).unwrap();
        assert_eq!(md, report::results_markdown(&results), "{}", results.markdown.display());
        checked += 1;
    }
    assert!(checked >= 1, "no results/*/results.csv");
}

/// One line of a results.csv as the row that wrote it.
fn result_row(path: &Path, line: &str) -> report::ResultRow {
    let f: Vec<&str> = line.split(',').collect();
    // 11 fields before pgser kept the episodes' spread, 15 since.
    assert!(f.len() == 11 || f.len() == 15, "{}: {line}", path.display());
    let at = |i: usize| f.get(i).copied().unwrap_or("");
    let num = |s: &str| s.parse::<f64>().unwrap_or_else(|e| panic!("{}: {s}: {e}", path.display()));
    let p = |s: &str| if s.is_empty() { None } else { Some(num(s)) };
    report::ResultRow {
        task: f[0].into(),
        algo: f[1].into(),
        variant: f[2].into(),
        seeds: f[3].parse().unwrap(),
        paper_score_mean: num(f[4]),
        paper_score_std: num(f[5]),
        success_mean: num(f[6]),
        p_vs_baseline: p(f[7]),
        p_vs_swap: p(f[8]),
        p_one_sided_vs_baseline: p(f[9]),
        p_one_sided_vs_swap: p(f[10]),
        episodes: p(at(11)).map(|n| n as usize),
        paper_score_std_episodes: p(at(12)),
        p_episodes_vs_baseline: p(at(13)),
        p_episodes_vs_swap: p(at(14)),
    }
}

/// `pgser-etl fig5` on the report `rep` (FetchReach) and copies of it relabelled as the other
/// tasks: a panel per task in the paper's order, Table 1 across tasks with both negatives, and
/// one-line refusals of a duplicate task, a task the paper does not have and an old report.
fn fig5_across_tasks(d: &Path, rep: &Path, j: &serde_json::Value) {
    let one = d.join("fig5_one");
    let o = etl().arg("fig5").arg(rep).arg("-o").arg(&one).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(png_size(&one.join("fig5_all.png")), (600, 450));
    assert!(text(&o.stderr).contains("no report for FetchPush, FetchPickAndPlace"), "{}", text(&o.stderr));

    let mut inputs = Vec::new();
    for task in
        ["HandManipulateEggRotate", "FetchSlide", "FetchPush", "HandManipulateBlockRotateZ", "FetchPickAndPlace"]
    {
        let mut k = j.clone();
        k["task"] = serde_json::json!(task);
        let f = d.join(format!("{task}.json"));
        std::fs::write(&f, k.to_string()).unwrap();
        inputs.push(f);
    }
    inputs.push(rep.join("table1.json"));
    let all = d.join("fig5_all");
    let o = etl().arg("fig5").args(&inputs).arg("-o").arg(&all).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(png_size(&all.join("fig5_all.png")), (1800, 900));
    let md = std::fs::read_to_string(all.join("table1_all.md")).unwrap();
    assert_eq!(md, text(&o.stdout));
    assert!(
        md.contains("| classifier | FetchReach | FetchPush | FetchPick | FetchSlide | HandBlock-Z | HandEgg-Rotate |"),
        "{md}"
    );
    // Each cell: the paper's negatives' accuracy / the controlled negatives'.
    let c0 = &j["classifiers"][0];
    let k0 = &j["controlled"]["classifiers"][0];
    let cell = format!("{:.3} / {:.3}", c0["accuracy"].as_f64().unwrap(), k0["accuracy"].as_f64().unwrap());
    let row = md.lines().find(|l| l.starts_with(&format!("| {} |", c0["name"].as_str().unwrap()))).unwrap();
    assert_eq!(row.matches(&cell).count(), 6, "{row}");

    let refused = |inputs: &[&Path], want: &str| {
        let out = d.join("fig5_refused");
        let o = etl().arg("fig5").args(inputs).arg("-o").arg(&out).output().unwrap();
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains(want), "{err} should say {want}");
        assert!(!out.exists());
    };
    // The same Q reported twice (a task split over two pipelines, one per learner; the copy
    // records other paths) is drawn once; a second report with other numbers is refused.
    let mut k = j.clone();
    k["scored"] = serde_json::json!("out/elsewhere/scored.parquet");
    let twin = d.join("twin.json");
    std::fs::write(&twin, k.to_string()).unwrap();
    let once = d.join("fig5_once");
    let o = etl().arg("fig5").arg(rep).arg(&twin).arg("-o").arg(&once).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(png_size(&once.join("fig5_all.png")), (600, 450));
    k["positives"] = serde_json::json!(j["positives"].as_u64().unwrap() + 1);
    std::fs::write(&twin, k.to_string()).unwrap();
    refused(&[rep, twin.as_path()], "a second report for FetchReach with other numbers");
    let mut k = j.clone();
    k["task"] = serde_json::json!("PointReach");
    let f = d.join("point.json");
    std::fs::write(&f, k.to_string()).unwrap();
    refused(&[f.as_path()], "task PointReach is not one of the paper's");
    let mut k = j.clone();
    k.as_object_mut().unwrap().remove("fig5_hist");
    let f = d.join("old.json");
    std::fs::write(&f, k.to_string()).unwrap();
    refused(&[f.as_path()], "has no fig5_hist");
}

/// OGBench's mazes are scored as OGBench scores them: the final success rate in percent (an
/// episode ends at its goal, so the paper score would count steps), tested and pooled as such
/// (each episode 0 or 100).
#[test]
fn ogbench_tasks_are_scored_by_success_in_percent() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let mut runs = Vec::new();
    for (variant, success) in [("baseline", [0.1, 0.2, 0.3]), ("swap", [0.2, 0.3, 0.4]), ("mem", [0.6, 0.7, 0.8])] {
        for (seed, p) in success.iter().enumerate() {
            // A paper score unrelated to success: the table must not use it.
            let m = metrics_file(d, &format!("{variant}{seed}.metrics.jsonl"), 900.0 - seed as f64, *p);
            runs.push(report_run("pointmaze-medium-navigate-v0", "td3bc", variant, seed as u64, m));
        }
    }
    let r = report::results(&runs, &d.join("out")).unwrap();
    let mem = r.rows.iter().find(|row| row.variant == "mem").unwrap();
    let (m, s) = mean_std(&[60.0, 70.0, 80.0]);
    assert!((mem.paper_score_mean - m).abs() < 1e-9 && (mem.paper_score_std - s).abs() < 1e-9, "{mem:?}");
    let (_, _, p) = report::welch_t_test(&[60.0, 70.0, 80.0], &[10.0, 20.0, 30.0]).unwrap();
    assert!((mem.p_vs_baseline.unwrap() - p).abs() < 1e-12, "{mem:?}");
    // Pooled: 10 episodes per seed, 6, 7, 8 of them successes.
    let episodes: Vec<f64> =
        [6, 7, 8].iter().flat_map(|&k| (0..10).map(move |i| if i < k { 100.0 } else { 0.0 })).collect();
    assert!((mem.paper_score_std_episodes.unwrap() - mean_std(&episodes).1).abs() < 1e-9, "{mem:?}");
    let md = std::fs::read_to_string(&r.markdown).unwrap();
    assert!(md.contains("| agent | success (%) |") && md.contains("OGBench's tasks"), "{md}");
}
