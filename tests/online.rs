//! `pgser-train online` end to end at a tiny scale (FetchReach): a run is the same bits whatever
//! the thread count and however often it is stopped and resumed, it refuses to continue another
//! run, and DDPG + HER learns FetchReach.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::*;
use pgser::eval::EvalReport;
use pgser::trajectory::Episodes;
use safetensors::SafeTensors;

/// Two epochs of two cycles of two episodes, three updates per cycle, small networks.
const TINY: &[&str] = &[
    "--task",
    "FetchReach",
    "--cycles",
    "2",
    "--episodes-per-cycle",
    "2",
    "--updates-per-cycle",
    "3",
    "--batch-size",
    "32",
    "--buffer-size",
    "5000",
    "--hidden",
    "16",
    "--layers",
    "2",
    "--eval-episodes",
    "2",
    "--seed",
    "3",
];

fn online(out: &Path, threads: usize, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["online", "-o", out.to_str().unwrap(), "--threads", &threads.to_string()])
        .args(TINY)
        .args(args)
        .output()
        .unwrap()
}

fn online_ok(out: &Path, threads: usize, args: &[&str]) -> serde_json::Value {
    let o = online(out, threads, &[args, &["--json"]].concat());
    assert!(o.status.success(), "pgser-train online {args:?} failed:\n{}", text(&o.stderr));
    last_json(&text(&o.stdout))
}

/// Every tensor of a safetensors file, by name, as bytes.
fn tensors(path: &Path) -> Vec<(String, Vec<u8>)> {
    let bytes = std::fs::read(path).unwrap();
    let st = SafeTensors::deserialize(&bytes).unwrap();
    let mut all: Vec<(String, Vec<u8>)> = st.tensors().into_iter().map(|(n, v)| (n, v.data().to_vec())).collect();
    all.sort();
    all
}

fn with_suffix(p: &Path, s: &str) -> PathBuf {
    PathBuf::from(format!("{}{s}", p.display()))
}

/// The metrics lines without their timings (which are the only thing allowed to differ).
fn metrics(ckpt: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(with_suffix(ckpt, ".metrics.jsonl")).unwrap();
    text.lines()
        .map(|l| {
            let mut v: serde_json::Value = serde_json::from_str(l).unwrap();
            for k in ["env_steps_per_sec", "updates_per_sec", "seconds"] {
                v.as_object_mut().unwrap().remove(k).unwrap();
            }
            v
        })
        .collect()
}

/// Asserts that two runs ended in the same state: checkpoint and resume tensors, buffer, metrics.
fn assert_same_run(a: &Path, b: &Path) {
    assert_eq!(tensors(a), tensors(b), "{} vs {}: checkpoint tensors", a.display(), b.display());
    let (ra, rb) = (with_suffix(a, ".resume"), with_suffix(b, ".resume"));
    assert_eq!(tensors(&ra), tensors(&rb), "resume tensors");
    let (ba, bb) = (
        Episodes::load(&with_suffix(a, ".buffer.parquet")).unwrap(),
        Episodes::load(&with_suffix(b, ".buffer.parquet")).unwrap(),
    );
    assert_eq!((ba.n, &ba.obs, &ba.ag, &ba.g, &ba.u), (bb.n, &bb.obs, &bb.ag, &bb.g, &bb.u), "replay buffers");
    assert_eq!(metrics(a), metrics(b), "metrics");
}

#[test]
fn a_run_is_the_same_bits_at_any_thread_count_and_across_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let one = dir.path().join("one.ckpt");
    let summary = online_ok(&one, 1, &["--epochs", "2"]);
    assert_eq!((summary["epochs"].as_u64(), summary["updates"].as_u64()), (Some(2), Some(12)));
    assert_eq!(summary["env_steps"].as_u64(), Some(2 * 2 * 2 * 50));
    assert!(summary["env_steps_per_sec"].as_f64().unwrap() > 0.0 && summary["updates_per_sec"].as_f64().unwrap() > 0.0);
    let lines = metrics(&one);
    assert_eq!(lines.len(), 2);
    let eval: EvalReport = serde_json::from_value(lines[1]["eval"].clone()).unwrap();
    assert_eq!(eval.episodes, 2);
    // The checkpoint is an ordinary pgser agent: `eval` runs it.
    let ev = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["eval", "--ckpt", one.to_str().unwrap(), "--episodes", "2", "--json"])
        .output()
        .unwrap();
    assert!(ev.status.success(), "{}", text(&ev.stderr));

    let two = dir.path().join("two.ckpt");
    online_ok(&two, 2, &["--epochs", "2"]);
    assert_same_run(&one, &two);

    // Stopped after epoch 1, continued to epoch 2.
    let split = dir.path().join("split.ckpt");
    online_ok(&split, 2, &["--epochs", "1"]);
    online_ok(&split, 2, &["--epochs", "2", "--resume"]);
    assert_same_run(&one, &split);

    // Stopped after every cycle (--max-minutes 0), so resumed inside epochs too.
    let cycles = dir.path().join("cycles.ckpt");
    let mut s = online_ok(&cycles, 1, &["--epochs", "2", "--max-minutes", "0"]);
    assert_eq!((s["finished"].as_bool(), s["cycles"].as_u64()), (Some(false), Some(1)));
    for _ in 0..3 {
        s = online_ok(&cycles, 1, &["--epochs", "2", "--max-minutes", "0", "--resume"]);
    }
    assert_eq!((s["finished"].as_bool(), s["cycles"].as_u64()), (Some(true), Some(4)));
    assert_same_run(&one, &cycles);
}

#[test]
fn sigterm_saves_at_a_cycle_boundary_and_the_run_resumes_to_the_same_bits() {
    let dir = tempfile::tempdir().unwrap();
    let straight = dir.path().join("straight.ckpt");
    online_ok(&straight, 1, &["--epochs", "4"]);
    let killed = dir.path().join("killed.ckpt");
    let child = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["online", "-o", killed.to_str().unwrap(), "--threads", "1", "--epochs", "4"])
        .args(TINY)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Once the first epoch is saved, ask it to stop (it may also have finished by then).
    let start = std::time::Instant::now();
    while !killed.exists() && start.elapsed().as_secs() < 60 {
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let out = child.wait_with_output().unwrap();
    if !out.status.success() {
        let err = text(&out.stderr);
        assert!(err.trim_end().lines().last().unwrap().contains("stopped by SIGTERM"), "{err}");
        online_ok(&killed, 1, &["--epochs", "4", "--resume"]);
    }
    assert_same_run(&straight, &killed);
}

#[test]
fn resume_refuses_another_run_in_one_line() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("a.ckpt");
    let err = |o: Output| {
        assert!(!o.status.success());
        let e = text(&o.stderr);
        assert_eq!(e.trim_end().lines().count(), 1, "{e}");
        e
    };
    let e = err(online(&ckpt, 1, &["--epochs", "1", "--resume"]));
    assert!(e.contains("a.ckpt") && e.contains("no checkpoint"), "{e}");
    online_ok(&ckpt, 1, &["--epochs", "1"]);
    let e = err(online(&ckpt, 1, &["--epochs", "2", "--resume", "--noise-eps", "0.1"]));
    assert!(e.contains("only --epochs may change"), "{e}");
    online_ok(&ckpt, 1, &["--epochs", "2", "--resume"]);
    let e = err(online(&ckpt, 1, &["--epochs", "1", "--resume"]));
    assert!(e.contains("cannot be shortened"), "{e}");
    let e = err(online(&ckpt, 1, &["--epochs", "1", "--relabel-rate", "1.5"]));
    assert!(e.contains("--relabel-rate must be in [0, 1], got 1.5"), "{e}");
}

#[test]
fn ddpg_her_learns_fetch_reach_in_a_few_epochs() {
    let dir = tempfile::tempdir().unwrap();
    let ckpt = dir.path().join("reach.ckpt");
    let o = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["online", "-o", ckpt.to_str().unwrap(), "--task", "FetchReach", "--json"])
        .args(["--epochs", "2", "--cycles", "10", "--episodes-per-cycle", "4", "--updates-per-cycle", "20"])
        .args(["--batch-size", "256", "--hidden", "64", "--eval-episodes", "20", "--seed", "1"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let s = last_json(&text(&o.stdout));
    let eval: EvalReport = serde_json::from_value(s["eval"].clone()).unwrap();
    assert!(eval.success_rate >= 0.8, "{eval:?}");
    // The expert's data: `collect --policy checkpoint:FILE` runs the trained actor.
    let data = dir.path().join("expert.parquet");
    let policy = format!("checkpoint:{}", ckpt.display());
    collect_ok(
        &["--task", "FetchReach", "--policy", &policy, "--episodes", "4", "--seed", "5", "-o", data.to_str().unwrap()],
        None,
    );
    let expert = Episodes::load(&data).unwrap();
    let reached =
        (0..4).filter(|&e| expert.task.success(expert.ag(e, expert.t - 1), expert.goal(e, expert.t - 2))).count();
    assert!(reached >= 3, "{reached} of 4 collected episodes end at the goal");
}
