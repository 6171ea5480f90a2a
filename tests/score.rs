//! `pgser-etl score` end to end: every row checked against the trajectory table it came from,
//! the reward function and the critic; byte-identical output whatever the thread count; and the
//! refusals (wrong task, wrong files) in one line with no output left behind.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int32Type, Int64Type};
use arrow_array::{Array, RecordBatch};
use common::*;
use pgser::agent::checkpoint;
use pgser::trajectory::Episodes;

/// A critic of 10 updates, tiny unless `hidden` says otherwise. Its Q values are arbitrary,
/// which is all these tests need: they check that `score` reports what the checkpoint computes.
fn train_hidden(data: &Path, ckpt: &Path, hidden: &str) {
    let out = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", data.to_str().unwrap(), "-o", ckpt.to_str().unwrap()])
        .args(["--updates", "10", "--hidden", hidden, "--batch-size", "64", "--eval-episodes", "0"])
        .output()
        .unwrap();
    assert!(out.status.success(), "pgser-train failed: {}", text(&out.stderr));
}

fn train(data: &Path, ckpt: &Path) {
    train_hidden(data, ckpt, "32");
}

/// The committed FetchReach sample (50 expert + 200 random episodes, float64) as a table, and a
/// critic trained on it; made once.
fn reach() -> &'static (tempfile::TempDir, PathBuf, PathBuf) {
    static REACH: OnceLock<(tempfile::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    REACH.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let table = dir.path().join("reach.parquet");
        let data = repo().join("data");
        convert_ok(&[&data.join("fetch_reach_expert_50.pkl"), &data.join("fetch_reach_random_200.pkl")], &table, &[]);
        let ckpt = dir.path().join("reach.ckpt");
        train(&table, &ckpt);
        (dir, table, ckpt)
    })
}

fn score_cmd(args: &[&str]) -> Command {
    let mut c = etl();
    c.arg("score").args(args);
    c
}

fn score_ok(args: &[&str]) -> String {
    let out = score_cmd(args).output().unwrap();
    assert!(out.status.success(), "score {args:?} failed: {}", text(&out.stderr));
    text(&out.stderr)
}

fn one_line_error(out: &Output) -> String {
    assert!(!out.status.success(), "expected failure, got success:\n{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "error is not one line:\n{err}");
    err
}

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

fn i64s(b: &RecordBatch, name: &str) -> Vec<i64> {
    b.column_by_name(name).unwrap().as_primitive::<Int64Type>().values().to_vec()
}

fn i32s(b: &RecordBatch, name: &str) -> Vec<i32> {
    b.column_by_name(name).unwrap().as_primitive::<Int32Type>().values().to_vec()
}

/// A float32 column, or the flat values of a FixedSizeList<float32> column.
fn f32s(b: &RecordBatch, name: &str) -> Vec<f32> {
    let col = b.column_by_name(name).unwrap();
    assert_eq!(col.null_count(), 0, "{name} has nulls");
    match col.as_fixed_size_list_opt() {
        Some(l) => l.values().as_primitive::<Float32Type>().values().to_vec(),
        None => col.as_primitive::<Float32Type>().values().to_vec(),
    }
}

/// Check every row of `scored` against its source table and critic.
fn check_rows(scored: &Path, table: &Path, ckpt: &Path, swaps: usize, original: bool) {
    let src = Episodes::load(table).unwrap();
    let (od, gd, ad) = (src.task.obs_dim, src.task.goal_dim, src.task.act_dim);
    let (b, _) = read_table(scored);
    let per = swaps + original as usize;
    assert_eq!(b.num_rows(), src.transitions() * per);
    let (ep, st, ge, gs) = (i64s(&b, "episode"), i32s(&b, "step"), i64s(&b, "goal_episode"), i32s(&b, "goal_step"));
    let (obs, action, next_obs) = (f32s(&b, "obs"), f32s(&b, "action"), f32s(&b, "next_obs"));
    let (next_ag, goal, reward, q) =
        (f32s(&b, "next_achieved_goal"), f32s(&b, "goal"), f32s(&b, "reward"), f32s(&b, "q"));
    let mut reached = 0;
    for i in 0..b.num_rows() {
        // Table order: transition i / per, its original first, then its swaps.
        let (e, t) = src.transition(i / per);
        assert_eq!((ep[i], st[i]), (e as i64, t as i32), "row {i}");
        assert_eq!(&obs[i * od..][..od], src.obs(e, t), "row {i} obs");
        assert_eq!(&action[i * ad..][..ad], src.action(e, t), "row {i} action");
        assert_eq!(&next_obs[i * od..][..od], src.obs(e, t + 1), "row {i} next_obs");
        assert_eq!(&next_ag[i * gd..][..gd], src.ag(e, t + 1), "row {i} next_achieved_goal");
        let g = &goal[i * gd..][..gd];
        if original && i % per == 0 {
            assert_eq!((ge[i], gs[i]), (e as i64, -1), "row {i}: an original row");
            assert_eq!(g, src.goal(e, t), "row {i} original goal");
        } else {
            let (a, s) = (ge[i] as usize, gs[i]);
            assert!(a < src.n && (0..src.t as i32).contains(&s), "row {i}: goal source ({a}, {s})");
            assert_eq!(g, src.ag(a, s as usize), "row {i}: goal is not the achieved goal at its source");
        }
        assert_eq!(reward[i], src.task.reward(src.ag(e, t + 1), g), "row {i} reward");
        reached += (reward[i] == 0.0) as usize;
    }
    assert!(reached > 0 && reached < b.num_rows(), "both rewards occur ({reached} reached)");
    // Goal sources are uniform over (episode, step): their means sit mid-range.
    let swapped: Vec<usize> = (0..b.num_rows()).filter(|i| !(original && i % per == 0)).collect();
    let mean = |v: &dyn Fn(usize) -> f64| swapped.iter().map(|&i| v(i)).sum::<f64>() / swapped.len() as f64;
    let (me, ms) = (mean(&|i| ge[i] as f64), mean(&|i| gs[i] as f64));
    assert!((me - (src.n as f64 - 1.0) / 2.0).abs() < 3.0 && (ms - 24.5).abs() < 0.5, "means {me} {ms}");
    // q is the checkpoint's min(Q1, Q2), recomputed on a sample of rows in one other batch.
    let (agent, _) = checkpoint::load(ckpt, burn::tensor::Device::flex()).unwrap();
    let rows: Vec<usize> = (0..b.num_rows()).step_by(37).collect();
    let pick = |v: &[f32], d: usize| rows.iter().flat_map(|&i| v[i * d..][..d].to_vec()).collect::<Vec<f32>>();
    let want = agent.q(&pick(&obs, od), &pick(&goal, gd), &pick(&action, ad), rows.len());
    for (k, &i) in rows.iter().enumerate() {
        assert!((q[i] - want[k]).abs() <= 1e-6 * want[k].abs().max(1.0), "row {i}: q {} vs {}", q[i], want[k]);
    }
    // In the same batch as `score` ran it (the first Q_BATCH rows of chunk 0), to the bit:
    // other batch compositions may round the last bit differently.
    let m = pgser::score::Q_BATCH.min(b.num_rows());
    assert_eq!(q[..m], agent.q(&obs[..m * od], &goal[..m * gd], &action[..m * ad], m));
    // The footer's counts and q statistics describe the column.
    let f = pgser::score::read_footer(scored).unwrap();
    assert_eq!(
        (f.rows, f.transitions, f.episodes, f.swaps, f.include_original),
        (b.num_rows(), src.transitions(), src.n, swaps, original)
    );
    let (min, max) = q.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
    assert_eq!((f.q.min, f.q.max), (min as f64, max as f64));
    let mean = q.iter().map(|&v| v as f64).sum::<f64>() / q.len() as f64;
    assert!((f.q.mean - mean).abs() < 1e-9 * mean.abs().max(1.0));
    let h = &f.q.histogram;
    assert_eq!(h.counts.iter().sum::<u64>() + h.below + h.above, b.num_rows() as u64);
    assert_eq!((h.edges[0], *h.edges.last().unwrap()), ((-1.0 / (1.0 - f.gamma)) as f32 as f64, 0.0));
    assert_eq!(f.source_table(scored).canonicalize().unwrap(), table.canonicalize().unwrap());
    assert_eq!(f.source.sha256, pgser::output::sha256_file(table).unwrap());
    assert_eq!(f.checkpoint.sha256, pgser::output::sha256_file(ckpt).unwrap());
}

#[test]
fn every_row_is_its_source_transition_with_the_drawn_goal_its_reward_and_q() {
    let (_, table, ckpt) = reach();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scored.parquet");
    let msg = score_ok(&["--q", p(ckpt), "--data", p(table), "-o", p(&out), "--swaps", "3"]);
    assert!(msg.contains("36750 rows") && msg.contains("q min/mean/max"), "{msg}");
    check_rows(&out, table, ckpt, 3, false);
    let out = dir.path().join("with_original.parquet");
    score_ok(&["--q", p(ckpt), "--data", p(table), "-o", p(&out), "--swaps", "3", "--include-original"]);
    check_rows(&out, table, ckpt, 3, true);
    // numpy and pyarrow agree, from the files alone.
    py_ok("check_scored.py", &[p(&out), p(table)]);
}

#[test]
fn output_bytes_depend_on_the_seed_not_on_the_thread_count() {
    let (_, table, _) = reach();
    let dir = tempfile::tempdir().unwrap();
    // The real network width: 2048 × 256 × 256 matrix products are where the CPU backend
    // splits work across threads (small ones it runs on one), so this is what must not vary.
    let wide = dir.path().join("wide.ckpt");
    train_hidden(table, &wide, "256");
    let ckpt = &wide;
    // Same command line in every run (it is in the footer): run from per-run folders.
    let run = |name: &str, threads: &str, seed: &str| -> Vec<u8> {
        let sub = dir.path().join(name);
        std::fs::create_dir(&sub).unwrap();
        let args = ["--q", p(ckpt), "--data", p(table), "-o", "s.parquet", "--chunk-episodes", "16", "--seed", seed];
        let out = score_cmd(&args).current_dir(&sub).env("RAYON_NUM_THREADS", threads).output().unwrap();
        assert!(out.status.success(), "{}", text(&out.stderr));
        std::fs::read(sub.join("s.parquet")).unwrap()
    };
    let one = run("one", "1", "5");
    assert_eq!(one, run("two", "2", "5"), "1 vs 2 threads");
    assert_eq!(one, run("three", "3", "5"), "1 vs 3 threads");
    assert_ne!(one, run("other_seed", "2", "6"));
}

#[test]
fn rows_do_not_depend_on_the_input_row_groups() {
    // Chunks of 7 episodes straddle row groups of 3 episodes: the rows are those of a table
    // with one row group.
    let (_, table, ckpt) = reach();
    let dir = tempfile::tempdir().unwrap();
    let small = dir.path().join("small_groups.parquet");
    let data = repo().join("data");
    let pkls = [data.join("fetch_reach_expert_50.pkl"), data.join("fetch_reach_random_200.pkl")];
    convert_ok(&[&pkls[0], &pkls[1]], &small, &["--row-group-rows".into(), "150".into()]);
    let (a, b) = (dir.path().join("a.parquet"), dir.path().join("b.parquet"));
    for (input, out) in [(table.as_path(), &a), (small.as_path(), &b)] {
        score_ok(&["--q", p(ckpt), "--data", p(input), "-o", p(out), "--chunk-episodes", "7", "--include-original"]);
    }
    // Columns, not batches: the schema carries the footer, whose source sha256 differs.
    assert_eq!(read_table(&a).0.columns(), read_table(&b).0.columns());
}

#[test]
fn a_checkpoint_for_another_task_is_refused_and_nothing_is_written() {
    let (_, reach_table, reach_ckpt) = reach();
    let dir = tempfile::tempdir().unwrap();
    let push = dir.path().join("push.parquet");
    collect_ok(&["--task", "FetchPush", "--policy", "random", "--episodes", "3", "--seed", "0", "-o", p(&push)], None);
    let push_ckpt = dir.path().join("push.ckpt");
    train(&push, &push_ckpt);
    let before = listing(dir.path());
    let out = dir.path().join("scored.parquet");
    for (ckpt, table) in [(push_ckpt.as_path(), reach_table.as_path()), (reach_ckpt.as_path(), push.as_path())] {
        let err = one_line_error(&score_cmd(&["--q", p(ckpt), "--data", p(table), "-o", p(&out)]).output().unwrap());
        assert!(err.contains(p(ckpt)) && err.contains(p(table)), "names both files: {err}");
        assert!(err.contains("FetchPush (T 50, obs 25") && err.contains("FetchReach (T 50, obs 10"), "{err}");
    }
    assert_eq!(listing(dir.path()), before, "no output and no temporary file");
}

#[test]
fn bad_inputs_fail_in_one_line_and_leave_no_file() {
    let (_, table, ckpt) = reach();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.parquet");
    let pkl = repo().join("data/fetch_reach_expert_50.pkl");
    let fails = |args: &[&str], want: &[&str]| {
        let err = one_line_error(&score_cmd(args).output().unwrap());
        assert!(want.iter().all(|w| err.contains(w)), "{args:?}: {err}");
        assert!(listing(dir.path()).is_empty(), "{args:?} left {:?}", listing(dir.path()));
    };
    // A data file that is not Parquet, or not a trajectory table.
    fails(&["--q", p(ckpt), "--data", p(&pkl), "-o", p(&out)], &["fetch_reach_expert_50.pkl", "not a Parquet file"]);
    let other = tempfile::tempdir().unwrap();
    let scored = other.path().join("scored.parquet");
    score_ok(&["--q", p(ckpt), "--data", p(table), "-o", p(&scored), "--swaps", "1"]);
    fails(&["--q", p(ckpt), "--data", p(&scored), "-o", p(&out)], &["scored.parquet", "a transition table"]);
    // A checkpoint that is not one.
    fails(&["--q", p(table), "--data", p(table), "-o", p(&out)], &["reach.parquet", "safetensors"]);
    fails(&["--q", p(&dir.path().join("none.ckpt")), "--data", p(table), "-o", p(&out)], &["none.ckpt"]);
    // Writing over an input, nothing to write, a missing output folder.
    fails(&["--q", p(ckpt), "--data", p(table), "-o", p(table)], &["would overwrite input"]);
    fails(&["--q", p(ckpt), "--data", p(table), "-o", p(&out), "--swaps", "0"], &["no rows"]);
    let nowhere = dir.path().join("missing/s.parquet");
    fails(&["--q", p(ckpt), "--data", p(table), "-o", p(&nowhere)], &["does not exist"]);
    if !cfg!(feature = "wgpu") {
        fails(&["--q", p(ckpt), "--data", p(table), "-o", p(&out), "--device", "wgpu"], &["--features wgpu"]);
    }
    // --include-original with no swaps is a table of the original transitions, scored.
    score_ok(&["--q", p(ckpt), "--data", p(table), "-o", p(&out), "--swaps", "0", "--include-original"]);
    let f = pgser::score::read_footer(&out).unwrap();
    assert_eq!((f.rows, f.transitions), (12250, 12250));
}

#[test]
fn inspect_summarises_a_transition_table() {
    let (_, table, ckpt) = reach();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("s.parquet");
    let stdout =
        score_cmd(&["--q", p(ckpt), "--data", p(table), "-o", p(&out), "--swaps", "2", "--json"]).output().unwrap();
    assert!(stdout.status.success());
    let summary: serde_json::Value = serde_json::from_str(text(&stdout.stdout).trim_end()).unwrap();
    assert_eq!(summary["rows"], 24500);
    let s = inspect_json(&out);
    assert_eq!(s["footer"]["kind"], "transition");
    assert_eq!(s["rows"], 24500);
    let q = s["columns"].as_array().unwrap().iter().find(|c| c["name"] == "q").unwrap();
    assert_eq!(q["all"]["min"], s["footer"]["q"]["min"]);
    assert_eq!(q["all"]["max"], summary["q_max"]);
    let text_out = etl().arg("inspect").arg(&out).output().unwrap();
    let report = text(&text_out.stdout);
    assert!(report.contains("transitions: 12250") && report.contains("q min/mean/max"), "{report}");
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> =
        std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    v.sort();
    v
}
