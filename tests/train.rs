//! `pgser-train` end to end: learning on the committed FetchReach sample, resume, the
//! checkpoint as other tools read it, and the error paths.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use common::*;
use pgser::agent::checkpoint;
use pgser::eval::EvalReport;

fn train_cmd() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pgser-train"))
}

fn run(args: &[&str]) -> Output {
    train_cmd().args(args).output().unwrap()
}

fn run_ok(args: &[&str]) -> String {
    let out = run(args);
    assert!(out.status.success(), "pgser-train {args:?} failed:\n{}\n{}", text(&out.stdout), text(&out.stderr));
    text(&out.stdout)
}

fn one_line_error(out: &Output) -> String {
    assert!(!out.status.success(), "expected failure, got success:\n{}", text(&out.stdout));
    let err = text(&out.stderr);
    assert_eq!(err.trim_end().lines().count(), 1, "error is not one line:\n{err}");
    err
}

/// The committed FetchReach sample (50 expert + 200 random episodes) as a table, made once.
fn reach_table() -> &'static Path {
    static TABLE: OnceLock<(tempfile::TempDir, PathBuf)> = OnceLock::new();
    let (_, p) = TABLE.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("reach.parquet");
        let data = repo().join("data");
        convert_ok(&[&data.join("fetch_reach_expert_50.pkl"), &data.join("fetch_reach_random_200.pkl")], &out, &[]);
        (dir, out)
    });
    p
}

#[test]
fn td3bc_learns_fetch_reach_far_beyond_a_random_policy() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("a.ckpt");
    let data = reach_table().to_str().unwrap();
    let out = run_ok(&[
        "--data",
        data,
        "-o",
        ckpt.to_str().unwrap(),
        "--algo",
        "td3bc",
        "--updates",
        "600",
        "--batch-size",
        "256",
        "--eval-every",
        "0",
        "--eval-episodes",
        "20",
        "--seed",
        "1",
        "--json",
    ]);
    let summary = last_json(&out);
    assert_eq!(summary["updates"], 600);
    assert!(summary["updates_per_sec"].as_f64().unwrap() > 0.0);
    let learned: EvalReport = serde_json::from_value(summary["eval"].clone()).unwrap();
    let random: EvalReport = serde_json::from_str(
        run_ok(&["eval", "--random", "--task", "FetchReach", "--episodes", "20", "--json"]).trim_end(),
    )
    .unwrap();
    // A random policy almost never reaches: return ≈ −49. The learned one must get most of the
    // way (the bar for a few thousand updates is −30; 600 already clear it on Reach).
    assert!(random.return_mean < -45.0, "random {random:?}");
    assert!(learned.return_mean > -30.0 && learned.return_mean > random.return_mean + 15.0, "learned {learned:?}");
    assert!((learned.paper_score - (50.0 + learned.return_mean)).abs() < 1e-9);
    // `eval --ckpt` reproduces the in-training evaluation (same seed, same episodes).
    let again: EvalReport = serde_json::from_str(
        run_ok(&["eval", "--ckpt", ckpt.to_str().unwrap(), "--episodes", "20", "--json"]).trim_end(),
    )
    .unwrap();
    assert_eq!(again, learned);
    // Metrics: JSON lines with losses, and the final evaluation.
    let metrics = std::fs::read_to_string(dir.path().join("a.ckpt.metrics.jsonl")).unwrap();
    let last: serde_json::Value = serde_json::from_str(metrics.lines().last().unwrap()).unwrap();
    assert_eq!(last["updates"], 600);
    assert_eq!(last["eval"]["return_mean"], summary["eval"]["return_mean"]);
}

fn short_run(dir: &Path, name: &str, updates: &str, extra: &[&str]) -> (PathBuf, Output) {
    let ckpt = dir.join(name);
    let mut args = vec![
        "--data",
        reach_table().to_str().unwrap(),
        "-o",
        ckpt.to_str().unwrap(),
        "--updates",
        updates,
        "--batch-size",
        "64",
        "--hidden",
        "32",
        "--eval-episodes",
        "0",
        "--log-every",
        "5",
        "--seed",
        "4",
    ];
    args.extend_from_slice(extra);
    let out = run(&args);
    (ckpt, out)
}

#[test]
fn resume_reaches_the_same_weights_as_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    let (straight, out) = short_run(dir.path(), "straight.ckpt", "30", &["--swap", "random"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let (split, out) = short_run(dir.path(), "split.ckpt", "17", &["--swap", "random"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_ne!(checkpoint_weights(&straight), checkpoint_weights(&split));
    let (_, out) = short_run(dir.path(), "split.ckpt", "30", &["--swap", "random", "--resume"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(checkpoint_weights(&straight), checkpoint_weights(&split));
    // The resume states (targets, Adam, random streams) agree too, byte for byte in tensors.
    let tensors = |p: &Path| {
        let bytes = std::fs::read(checkpoint::resume_path(p)).unwrap();
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        let mut v: Vec<(String, Vec<u8>)> = st.tensors().into_iter().map(|(n, t)| (n, t.data().to_vec())).collect();
        v.sort();
        v
    };
    assert_eq!(tensors(&straight), tensors(&split));
    // So do the logged losses.
    let losses = |p: &Path| std::fs::read_to_string(pgser::train::metrics_path(p)).unwrap();
    assert_eq!(losses(&straight), losses(&split));
}

#[test]
fn the_checkpoint_is_a_plain_safetensors_file_numpy_can_run() {
    let dir = tempfile::tempdir().unwrap();
    let (ckpt, out) = short_run(dir.path(), "c.ckpt", "10", &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // Inputs and the Rust policy's outputs, for numpy to recompute from the file alone.
    let (agent, _) = checkpoint::load(&ckpt, burn::tensor::Device::flex()).unwrap();
    let mut rng = pgser::nprandom::NpRandom::new(5);
    let n = 7;
    let mut draw = |k: usize| (0..k).map(|_| rng.uniform(-2.0, 2.0) as f32).collect::<Vec<f32>>();
    let (obs, goal, action) = (draw(n * 10), draw(n * 3), draw(n * 4));
    let probe = serde_json::json!({
        "obs": obs, "goal": goal, "action": action, "n": n,
        "act": agent.act(&obs, &goal, n), "q": agent.q(&obs, &goal, &action, n),
    });
    let probe_path = dir.path().join("probe.json");
    std::fs::write(&probe_path, probe.to_string()).unwrap();
    py_ok("check_checkpoint.py", &[ckpt.to_str().unwrap(), probe_path.to_str().unwrap()]);
}

#[test]
fn bad_runs_fail_in_one_line_and_leave_no_checkpoint() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    // Data that is not a trajectory table.
    let pkl = repo().join("data/fetch_reach_expert_50.pkl");
    let ckpt = d.join("x.ckpt");
    let err = one_line_error(&run(&["--data", pkl.to_str().unwrap(), "-o", ckpt.to_str().unwrap(), "--updates", "5"]));
    assert!(err.contains("fetch_reach_expert_50.pkl") && err.contains("not a Parquet file"), "{err}");
    // --resume with nothing to resume.
    let (_, out) = short_run(d, "none.ckpt", "5", &["--resume"]);
    assert!(one_line_error(&out).contains("no checkpoint to resume"));
    // --resume with other settings.
    let (_, out) = short_run(d, "r.ckpt", "5", &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let (_, out) = short_run(d, "r.ckpt", "10", &["--resume", "--lr", "0.1"]);
    let e = one_line_error(&out);
    assert!(
        e.contains("differ from the checkpoint")
            && e.contains("(only --updates may change): --lr: saved null, given 0.1"),
        "{e}"
    );
    // The setting that differs is named, alone: here the default priority of pgser ≥ 0.4 against
    // the paper's q that a run of an older pgser recorded.
    let (_, out) = short_run(d, "r.ckpt", "10", &["--resume", "--priority", "q"]);
    let e = one_line_error(&out);
    assert!(e.contains("(only --updates may change): --priority: saved \"rank\", given \"q\""), "{e}");
    // --resume with fewer updates than the checkpoint has.
    let (_, out) = short_run(d, "r.ckpt", "3", &["--resume"]);
    assert!(one_line_error(&out).contains("already has 5 updates"), "{}", text(&out.stderr));
    // A GPU backend this build does not have.
    let (_, out) = short_run(d, "g.ckpt", "5", &["--device", "wgpu"]);
    if !cfg!(feature = "wgpu") {
        assert!(one_line_error(&out).contains("--features wgpu"));
    }
    // Writing over the input is refused.
    let data = reach_table().to_str().unwrap();
    let err = one_line_error(&run(&["--data", data, "-o", data, "--updates", "5"]));
    assert!(err.contains("input"), "{err}");
    // Nothing but the one successful run's files is left behind, and no temporary file.
    let mut left: Vec<String> =
        std::fs::read_dir(d).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    left.sort();
    assert_eq!(left, ["r.ckpt", "r.ckpt.metrics.jsonl", "r.ckpt.resume"]);
    // An eval of a file that is not a checkpoint.
    let err = one_line_error(&run(&["eval", "--ckpt", data]));
    assert!(err.contains("not a safetensors file"), "{err}");
}

#[test]
fn seeds_train_as_one_stack_with_the_weights_of_separate_runs() {
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    let table = reach_table().to_str().unwrap();
    let common =
        ["--updates", "12", "--batch-size", "64", "--hidden", "32", "--eval-episodes", "2", "--log-every", "4"];
    let mut args = vec!["--data", table, "-o", runs.to_str().unwrap(), "--seeds", "4,7", "--json"];
    args.extend(common);
    let summary: serde_json::Value = last_json(&run_ok(&args));
    assert_eq!(summary.as_array().unwrap().len(), 2, "{summary}");
    for seed in ["4", "7"] {
        let alone = dir.path().join(format!("alone{seed}.ckpt"));
        let mut args = vec!["--data", table, "-o", alone.to_str().unwrap(), "--seed", seed];
        args.extend(common);
        run_ok(&args);
        let stacked = runs.join(format!("s{seed}.ckpt"));
        assert_eq!(checkpoint_weights(&stacked), checkpoint_weights(&alone), "seed {seed}");
        let metrics = |p: &Path| std::fs::read_to_string(pgser::train::metrics_path(p)).unwrap();
        assert_eq!(metrics(&stacked), metrics(&alone), "seed {seed}: metrics");
    }
    // --seeds and --seed together are refused.
    let out = run(&["--data", table, "-o", runs.to_str().unwrap(), "--seeds", "1,2", "--seed", "3"]);
    assert!(!out.status.success() && text(&out.stderr).contains("--seed"), "{}", text(&out.stderr));
}

#[test]
fn a_log_gets_a_line_at_each_scheduled_save() {
    // stderr is a pipe here, as in a Slurm job's log or under nohup: no bar is drawn, so each
    // scheduled save says how far the run is and how its last evaluation went.
    let dir = tempfile::tempdir().unwrap();
    let runs = dir.path().join("runs");
    let args = ["--data", reach_table().to_str().unwrap(), "-o", runs.to_str().unwrap(), "--seeds", "4,7"];
    let more = ["--updates", "12", "--batch-size", "64", "--hidden", "32", "--eval-episodes", "2", "--eval-every", "4"];
    let out = train_cmd().args(args).args(more).args(["--save-every", "4"]).output().unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("training: ")).collect();
    assert_eq!(lines.len(), 2, "one line per save before the end:\n{err}");
    for (line, at) in lines.iter().zip([4u64, 8]) {
        assert!(line.starts_with(&format!("training: {at} of 12 updates saved (2 agents), ")), "{line}");
        // The mean and range of the two agents' evaluations at that update, from their metrics.
        let scores: Vec<f64> = ["s4", "s7"]
            .iter()
            .map(|s| {
                let m = std::fs::read_to_string(pgser::train::metrics_path(&runs.join(format!("{s}.ckpt")))).unwrap();
                let line: serde_json::Value = m
                    .lines()
                    .map(|l| serde_json::from_str(l).unwrap())
                    .find(|v: &serde_json::Value| v["updates"] == at)
                    .unwrap();
                line["eval"]["paper_score"].as_f64().unwrap()
            })
            .collect();
        let (lo, hi) = (scores[0].min(scores[1]), scores[0].max(scores[1]));
        let want =
            format!("; last evaluation ({at}): paper score {:.2} ({lo:.2}–{hi:.2})", (scores[0] + scores[1]) / 2.0);
        assert!(line.ends_with(&want), "{line}\nwant …{want}");
    }
}
