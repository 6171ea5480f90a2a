//! `pgser-etl pipeline run`: a whole (tiny) experiment, then what re-runs after each kind of
//! change — nothing after a clean finish, only the downstream steps after an edit, the
//! missing step (and nothing after it, since it is rebuilt byte for byte) after a deletion.

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::{etl, last_json, snapshot, text, tiny_pipeline as pipeline};

/// Runs the pipeline; returns step name → status.
fn run(file: &Path, extra: &[&str]) -> BTreeMap<String, String> {
    let out =
        etl().args(["pipeline", "run"]).arg(file).args(["--json", "--threads", "2"]).args(extra).output().unwrap();
    assert!(out.status.success(), "pipeline failed: {}", text(&out.stderr));
    common::step_statuses(&out)
}

fn ran(s: &BTreeMap<String, String>) -> Vec<&str> {
    s.iter().filter(|(_, v)| v.as_str() != "up to date").map(|(k, _)| k.as_str()).collect()
}

#[test]
fn runs_once_then_only_what_changed() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), 30, 4);
    let out = dir.path().join("out");

    let first = run(&file, &[]);
    assert_eq!(first.len(), 3 + 6 + 2, "{first:?}");
    assert!(first.values().all(|s| s == "ran"), "{first:?}");
    for f in ["results.md", "results.csv", "curves_FetchReach.png", "report/fig5_q_hist.png", "report/table1.md"] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let results = std::fs::read_to_string(out.join("results.md")).unwrap();
    for v in ["baseline", "swap", "mem"] {
        assert!(results.contains(v), "{results}");
    }

    // A clean second run repeats nothing.
    let again = run(&file, &[]);
    assert!(ran(&again).is_empty(), "{again:?}");

    // More updates: every agent continues from its checkpoint; data, Q, scores, report stay.
    let file = pipeline(dir.path(), 40, 4);
    let more = run(&file, &[]);
    let mut want: Vec<String> =
        ["baseline", "swap", "mem"].iter().flat_map(|v| (0..2).map(move |s| format!("agent td3bc_{v}_s{s}"))).collect();
    want.push("results".into());
    want.sort();
    assert_eq!(ran(&more), want.iter().map(String::as_str).collect::<Vec<_>>());
    assert!(more.iter().filter(|(k, _)| k.starts_with("agent")).all(|(_, v)| v == "resumed"), "{more:?}");

    // Fewer swaps: the scores change, so the report and the -mem agents rerun, nothing else.
    let file = pipeline(dir.path(), 40, 2);
    let swaps = run(&file, &[]);
    assert_eq!(ran(&swaps), ["agent td3bc_mem_s0", "agent td3bc_mem_s1", "report", "results", "score"], "{swaps:?}");

    // A lost output is rebuilt identically: the steps that read it stay up to date.
    let scored = out.join("scored.parquet");
    let before = std::fs::read(&scored).unwrap();
    std::fs::remove_file(&scored).unwrap();
    let rebuilt = run(&file, &[]);
    assert_eq!(ran(&rebuilt), ["score"], "{rebuilt:?}");
    assert_eq!(std::fs::read(&scored).unwrap(), before);

    // A corrupted output is not trusted.
    let ckpt = out.join("agents/td3bc_swap_s1.ckpt");
    let mut bytes = std::fs::read(&ckpt).unwrap();
    let k = bytes.len() - 1;
    bytes[k] ^= 1;
    std::fs::write(&ckpt, bytes).unwrap();
    let fixed = run(&file, &[]);
    assert!(ran(&fixed).contains(&"agent td3bc_swap_s1"), "{fixed:?}");
}

#[test]
fn until_stops_and_the_next_run_resumes_there() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), 20, 4);
    let part = run(&file, &["--until", "score"]);
    assert_eq!(part.keys().map(String::as_str).collect::<Vec<_>>(), ["convert", "pretrain", "score"]);
    let dry = run(&file, &["--dry-run"]);
    assert_eq!(dry.values().filter(|s| s.as_str() == "would run").count(), 6 + 2, "{dry:?}");
    assert!(!dir.path().join("out/agents").exists(), "a dry run wrote agents");
    let rest = run(&file, &[]);
    for s in ["convert", "pretrain", "score"] {
        assert_eq!(rest[s], "up to date");
    }
    assert_eq!(ran(&rest).len(), 6 + 2);
}

#[test]
fn bad_pipelines_fail_in_one_line_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), 20, 4);
    let good = std::fs::read_to_string(&file).unwrap();
    for (from, to, says) in [
        ("batch_size = 64", "batch_sise = 64", "batch_sise"),
        ("task = \"FetchReach\"", "task = \"FetchNothing\"", "FetchNothing"),
        ("episodes = [12, 24]", "episodes = [12]", "2 pickles but 1"),
        ("seeds = [0, 1]", "seeds = []", "must not be empty"),
    ] {
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, good.replace(from, to)).unwrap();
        let out = etl().args(["pipeline", "run"]).arg(&bad).output().unwrap();
        let err = text(&out.stderr);
        assert!(!out.status.success());
        assert!(err.contains("bad.toml") && err.contains(says), "{says}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!dir.path().join("out").exists(), "{says}: wrote outputs");
    }
    let out = etl().args(["pipeline", "run"]).arg(&file).args(["--until", "nope"]).output().unwrap();
    assert!(text(&out.stderr).contains("--until nope: no such step"), "{}", text(&out.stderr));
}

#[test]
fn every_output_is_rebuilt_byte_for_byte() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), 20, 2);
    let out = dir.path().join("out");
    run(&file, &[]);
    let first = snapshot(&out);
    for kind in [
        "traj.parquet",
        "q.ckpt",
        "q.ckpt.resume",
        "q.ckpt.metrics.jsonl",
        "scored.parquet",
        "agents/td3bc_mem_s1.ckpt",
        "report/table1.json",
        "report/fig5_q_hist.png",
        "results.csv",
        "curves_FetchReach.png",
    ] {
        assert!(first.contains_key(Path::new(kind)), "{kind} missing: {:?}", first.keys());
    }

    // A lost Q is pre-trained again into the same bytes, so nothing that reads it reruns.
    std::fs::remove_file(out.join("q.ckpt")).unwrap();
    let again = run(&file, &[]);
    assert_eq!(ran(&again), ["pretrain"], "{again:?}");
    assert!(snapshot(&out) == first, "q.ckpt was not rebuilt byte for byte");

    // A whole second run from nothing writes every file (checkpoints, resume states, metrics,
    // tables, report, results, figures) byte for byte as the first.
    std::fs::remove_dir_all(&out).unwrap();
    run(&file, &[]);
    let second = snapshot(&out);
    assert_eq!(second.keys().collect::<Vec<_>>(), first.keys().collect::<Vec<_>>());
    for (path, bytes) in &first {
        assert!(&second[path] == bytes, "{} differs between two identical runs", path.display());
    }
}

#[test]
fn a_resume_that_fails_keeps_the_checkpoint_and_only_stale_ones_are_set_aside() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), 20, 2);
    let out = dir.path().join("out");
    run(&file, &[]);
    let ckpt = out.join("agents/td3bc_baseline_s0.ckpt");
    let resume = out.join("agents/td3bc_baseline_s0.ckpt.resume");
    let (ckpt_bytes, resume_bytes) = (std::fs::read(&ckpt).unwrap(), std::fs::read(&resume).unwrap());

    // An unreadable resume state while continuing to more updates: the step stops with the
    // cause and the checkpoint stays as it was (it used to be retrained from scratch).
    std::fs::write(&resume, b"not a safetensors file").unwrap();
    let file = pipeline(dir.path(), 30, 2);
    let o = etl().args(["pipeline", "run"]).arg(&file).args(["--threads", "2"]).output().unwrap();
    let err = text(&o.stderr);
    assert!(!o.status.success(), "a broken resume state was not reported");
    assert!(err.contains("td3bc_baseline_s0") && err.contains("left as it was"), "{err}");
    assert!(std::fs::read(&ckpt).unwrap() == ckpt_bytes, "the checkpoint was overwritten");
    assert!(!out.join("agents/td3bc_baseline_s0.ckpt.stale").exists());

    // Other settings: the checkpoint cannot be continued, so the agent is trained from scratch
    // and the old one is kept aside as .stale (with its resume state and metrics).
    std::fs::write(&resume, &resume_bytes).unwrap();
    let changed = std::fs::read_to_string(&file).unwrap().replace("updates = 30\n", "updates = 30\ntau = 0.01\n");
    std::fs::write(&file, changed).unwrap();
    let statuses = run(&file, &[]);
    assert_eq!(statuses["agent td3bc_baseline_s0"], "ran", "{statuses:?}");
    let stale = |ext: &str| out.join(format!("agents/td3bc_baseline_s0.ckpt{ext}.stale"));
    assert!(std::fs::read(stale("")).unwrap() == ckpt_bytes, "the stale checkpoint was not kept");
    assert!(std::fs::read(stale(".resume")).unwrap() == resume_bytes);
    assert!(stale(".metrics.jsonl").exists());
    assert!(std::fs::read(&ckpt).unwrap() != ckpt_bytes);
}

#[test]
fn a_killed_stack_resumes_every_agent_as_unstacked_uninterrupted_runs_end() {
    // The six agent cells train as one stack (the default); the run is killed once they have
    // checkpoints, then run again: every cell resumes, and each ends with the weights and metrics
    // of the same cell trained alone (batch = 1) without interruption.
    let stacked = tempfile::tempdir().unwrap();
    let file = pipeline(stacked.path(), 300, 2);
    let text_of = std::fs::read_to_string(&file).unwrap().replace("save_every = 0", "save_every = 10");
    std::fs::write(&file, &text_of).unwrap();
    run(&file, &["--until", "score"]);
    let out = stacked.path().join("out");
    let mut child =
        etl().args(["pipeline", "run"]).arg(&file).args(["--threads", "2", "--no-measure"]).spawn().unwrap();
    let last = out.join("agents/td3bc_mem_s1.ckpt");
    let t0 = std::time::Instant::now();
    while !last.exists() {
        assert!(t0.elapsed().as_secs() < 300, "no checkpoint appeared");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(!out.join(".pipeline/agent_td3bc_mem_s1.json").exists(), "the stack finished before it was killed");
    let resumed = run(&file, &[]);
    for (name, status) in &resumed {
        if name.starts_with("agent") {
            assert_eq!(status, "resumed", "{resumed:?}");
        }
    }

    let alone = tempfile::tempdir().unwrap();
    let file = pipeline(alone.path(), 300, 2);
    std::fs::write(&file, text_of.replace("updates = 300\n", "updates = 300\nbatch = 1\n")).unwrap();
    run(&file, &[]);
    for v in ["baseline", "swap", "mem"] {
        for s in 0..2 {
            let f = format!("agents/td3bc_{v}_s{s}.ckpt");
            let (a, b) = (out.join(&f), alone.path().join("out").join(&f));
            assert_eq!(common::checkpoint_weights(&a), common::checkpoint_weights(&b), "{f}");
            let metrics = |p: &Path| std::fs::read(pgser::train::metrics_path(p)).unwrap();
            assert!(metrics(&a) == metrics(&b), "{f}: metrics differ");
        }
    }
}

#[test]
fn jobs_2_writes_what_jobs_1_writes() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), 20, 2);
    let out = dir.path().join("out");
    run(&file, &["--jobs", "1"]);
    let one = snapshot(&out);
    std::fs::remove_dir_all(&out).unwrap();
    let two = run(&file, &["--jobs", "2"]);
    assert!(two.values().all(|s| s == "ran"), "{two:?}");
    let got = snapshot(&out);
    assert_eq!(got.keys().collect::<Vec<_>>(), one.keys().collect::<Vec<_>>());
    for (path, bytes) in &one {
        assert!(&got[path] == bytes, "{} differs between --jobs 1 and --jobs 2", path.display());
    }
    let o = etl().args(["pipeline", "run"]).arg(&file).args(["--jobs", "2", "--partition", "x"]).output().unwrap();
    assert!(text(&o.stderr).contains("--partition is for --executor slurm"), "{}", text(&o.stderr));
}

#[test]
fn sigterm_saves_a_training_step_that_resumes_to_the_uninterrupted_bytes() {
    // `pipeline step`, what a Slurm job runs, stopped by SIGTERM halfway through a pre-training
    // that has no scheduled save: it saves there and fails; the next run resumes and ends with
    // the bytes of a run that was never stopped.
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), 20, 2);
    let toml =
        std::fs::read_to_string(&file).unwrap().replace("[pretrain]\nupdates = 40", "[pretrain]\nupdates = 1500");
    std::fs::write(&file, &toml).unwrap();
    let out = dir.path().join("out");
    // Run from the folder with a relative path, so that the paths the outputs record are the
    // same as those of the uninterrupted run in another folder.
    let here = |dir: &Path, args: &[&str]| {
        let o = etl().current_dir(dir).args(["pipeline", "run", "tiny.toml", "--json"]).args(args).output().unwrap();
        assert!(o.status.success(), "pipeline failed: {}", text(&o.stderr));
        let r = last_json(&text(&o.stdout));
        r["steps"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| (s["name"].as_str().unwrap().to_string(), s["status"].as_str().unwrap().to_string()))
            .collect::<BTreeMap<_, _>>()
    };
    here(dir.path(), &["--until", "convert"]);
    let mut child = etl()
        .current_dir(dir.path())
        .args(["pipeline", "step", "tiny.toml", "pretrain", "--threads", "2"])
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = std::io::BufReader::new(child.stderr.take().unwrap());
    let mut said = String::new();
    while !said.contains("pretrain: running") {
        assert!(std::io::BufRead::read_line(&mut stderr, &mut said).unwrap() > 0, "no start: {said}");
    }
    std::thread::sleep(std::time::Duration::from_millis(1000));
    // SAFETY: signals the child this test started.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    std::io::Read::read_to_string(&mut stderr, &mut said).unwrap();
    assert!(!child.wait().unwrap().success(), "{said}");
    let at = said.split("stopped by SIGTERM at update ").nth(1).unwrap_or_else(|| panic!("no SIGTERM save: {said}"));
    let updates: u64 = at.split(' ').next().unwrap().parse().unwrap();
    assert!(updates > 0 && updates < 1500, "stopped at update {updates}: {said}");
    assert_eq!(said.trim().lines().filter(|l| l.contains("error")).count(), 1, "{said}");
    assert!(!out.join(".pipeline/pretrain.json").exists(), "an interrupted step was recorded");
    // `pipeline status` says how far it got, from its checkpoint.
    let o = etl().current_dir(dir.path()).args(["pipeline", "status", "tiny.toml", "--json"]).output().unwrap();
    let states: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let pretrain = states.as_array().unwrap().iter().find(|s| s["name"] == "pretrain").unwrap();
    assert_eq!(pretrain["state"], "stopped", "{pretrain}");
    assert_eq!(pretrain["progress"]["updates"], updates, "{pretrain}");
    assert_eq!(pretrain["progress"]["of"], 1500, "{pretrain}");
    let o = etl().current_dir(dir.path()).args(["pipeline", "status", "tiny.toml"]).output().unwrap();
    let line = text(&o.stdout).lines().find(|l| l.contains("] pretrain:")).unwrap().to_string();
    assert!(line.contains(&format!("pretrain: stopped — {updates} of 1.5k updates saved")), "{line}");

    let resumed = here(dir.path(), &["--until", "pretrain"]);
    assert_eq!(resumed["pretrain"], "resumed", "{resumed:?}");
    let alone = tempfile::tempdir().unwrap();
    std::fs::write(alone.path().join("tiny.toml"), &toml).unwrap();
    here(alone.path(), &["--until", "pretrain"]);
    let (want, got) = (snapshot(&alone.path().join("out")), snapshot(&out));
    assert_eq!(got.keys().collect::<Vec<_>>(), want.keys().collect::<Vec<_>>());
    for (path, bytes) in &want {
        assert!(&got[path] == bytes, "{} differs from an uninterrupted run", path.display());
    }
}

/// A pipeline whose expert is a trained actor: simulated data, the expert read from
/// `expert_checkpoint`, trained online first when that file is absent.
fn expert_pipeline(dir: &Path, checkpoint: &Path) -> std::path::PathBuf {
    let toml = format!(
        r#"
name = "trained_expert"
task = "FetchReach"
out = "out"
[data]
expert = 4
random = 4
seed = 7
noise = 0.1
expert_checkpoint = "{c}"
[expert]
epochs = 1
cycles = 2
episodes_per_cycle = 2
updates_per_cycle = 3
batch_size = 32
buffer_size = 5000
hidden = 16
layers = 2
eval_episodes = 2
seed = 3
[train]
batch_size = 32
eval_every = 0
eval_episodes = 2
save_every = 0
[pretrain]
updates = 10
[score]
swaps = 1
[agents]
variants = ["baseline"]
updates = 10
"#,
        c = checkpoint.display()
    );
    let path = dir.join("expert.toml");
    std::fs::write(&path, toml).unwrap();
    path
}

#[test]
fn a_missing_expert_is_trained_online_and_the_data_collected_from_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let absent = dir.path().join("experts/reach.ckpt");
    let file = expert_pipeline(dir.path(), &absent);

    let first = run(&file, &[]);
    assert_eq!(first.get("expert").map(String::as_str), Some("ran"), "{first:?}");
    assert!(first.values().all(|s| s == "ran"), "{first:?}");
    let trained = out.join("expert/expert.ckpt");
    assert!(trained.exists() && out.join("expert/expert.ckpt.metrics.jsonl").exists());
    assert!(!absent.exists(), "the pipeline writes only under its out folder");

    // The expert episodes are what `collect --policy checkpoint:` writes from that actor.
    let alone = dir.path().join("alone.pkl");
    let o = etl()
        .args(["collect", "--task", "FetchReach", "--episodes", "4", "--seed", "7", "--noise", "0.1", "--policy"])
        .arg(format!("checkpoint:{}", trained.display()))
        .arg("-o")
        .arg(&alone)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(std::fs::read(&alone).unwrap(), std::fs::read(out.join("data/expert.pkl")).unwrap());

    // The same expert shipped at the given path: no training, and the data (keyed by the
    // checkpoint's bytes, not its path) and everything after it stay up to date.
    std::fs::create_dir_all(absent.parent().unwrap()).unwrap();
    std::fs::copy(&trained, &absent).unwrap();
    let shipped = run(&file, &[]);
    assert!(!shipped.contains_key("expert"), "{shipped:?}");
    assert!(ran(&shipped).is_empty(), "{shipped:?}");

    // An expert of another task is refused before any step runs, naming the file.
    let reach = std::fs::read_to_string(&file).unwrap();
    let push = dir.path().join("push.toml");
    std::fs::write(&push, reach.replace("\"FetchReach\"", "\"FetchPush\"").replace("out = \"out\"", "out = \"push\""))
        .unwrap();
    let o = etl().args(["pipeline", "run"]).arg(&push).output().unwrap();
    let err = text(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("expert_checkpoint") && err.contains("trained on FetchReach, not FetchPush"), "{err}");
    assert!(!dir.path().join("push").exists(), "nothing written");
}

/// A run's records name outputs as that run planned them, relative to the folder it was started
/// in; a run or `pipeline status` started from another folder (the file given by another path)
/// finds every step up to date and runs nothing.
#[test]
fn status_and_rerun_agree_from_any_folder() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("pipelines");
    std::fs::create_dir(&sub).unwrap();
    pipeline(&sub, 20, 2);
    let here = |cwd: &Path, file: &str, cmd: &[&str]| {
        let o = etl().current_dir(cwd).args(["pipeline"]).args(cmd).arg(file).output().unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        o
    };
    let first = common::step_statuses(&here(&sub, "tiny.toml", &["run", "--json", "--threads", "2"]));
    assert!(first.values().all(|s| s == "ran"), "{first:?}");
    let before = snapshot(&sub.join("out"));

    // From the parent folder, the same file as pipelines/tiny.toml.
    let states: serde_json::Value =
        serde_json::from_slice(&here(dir.path(), "pipelines/tiny.toml", &["status", "--json"]).stdout).unwrap();
    assert_eq!(states.as_array().unwrap().len(), first.len());
    for s in states.as_array().unwrap() {
        assert_eq!(s["state"], "up to date", "{s}");
    }
    let again = common::step_statuses(&here(dir.path(), "pipelines/tiny.toml", &["run", "--json"]));
    assert!(again.values().all(|s| s == "up to date"), "{again:?}");
    assert!(snapshot(&sub.join("out")) == before, "a rerun from another folder changed outputs");
}

/// Pipeline files the fuzzer found to break planning (`tests/fixtures/fuzz/pipeline/`; the first
/// listed a seed twice, which planned two agents under one name): each is refused by `pipeline run`
/// (dry or not) and `pipeline status` in one line naming the file, with nothing written.
#[test]
fn pipeline_files_the_fuzzer_found_fail_in_one_line() {
    let found = std::fs::read_dir(common::repo().join("tests/fixtures/fuzz/pipeline")).unwrap();
    let mut n = 0;
    for entry in found {
        let src = entry.unwrap().path();
        let name = src.file_name().unwrap().to_string_lossy().into_owned();
        let dir = tempfile::tempdir().unwrap();
        std::fs::copy(&src, dir.path().join(&name)).unwrap();
        for cmd in [&["run", "--dry-run"][..], &["run"], &["status"]] {
            let o = etl().current_dir(dir.path()).arg("pipeline").args(cmd).arg(&name).output().unwrap();
            let err = text(&o.stderr);
            assert!(!o.status.success(), "pipeline {cmd:?} {name}: accepted");
            assert!(!err.contains("panicked"), "pipeline {cmd:?} {name}: {err}");
            assert_eq!(err.trim_end().lines().count(), 1, "pipeline {cmd:?} {name}: {err}");
            assert!(err.contains(&name), "pipeline {cmd:?}: {err}");
            let left: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
            assert_eq!(left.len(), 1, "pipeline {cmd:?} {name} wrote {left:?}");
        }
        n += 1;
    }
    assert!(n > 0, "no inputs in tests/fixtures/fuzz/pipeline");
}

/// A Q given by path (`[pretrain] checkpoint`) replaces the pre-training, and named arms train
/// beside -mem: each arm's cells are its own, tested against baseline in results.csv, and the
/// report gives each -mem arm's share of draws above the own-goal median. A study joins them.
#[test]
fn named_arms_train_from_a_given_q_and_a_study_joins_them() {
    let dir = tempfile::tempdir().unwrap();
    let first = pipeline(dir.path(), 20, 4);
    run(&first, &["--until", "score"]);
    let given = dir.path().join("given_q.ckpt");
    std::fs::copy(dir.path().join("out/q.ckpt"), &given).unwrap();

    let arms = dir.path().join("arms");
    std::fs::create_dir(&arms).unwrap();
    let rest = format!(
        r#"[train]
batch_size = 64
eval_every = 0
eval_episodes = 4
save_every = 0
[pretrain]
checkpoint = "{}"
updates = 40
[agents]
variants = ["baseline", "mem", "mem_a3", "mem_q"]
seeds = [0, 1]
updates = 20
[agents.arms.mem_a3]
variant = "mem"
priority_alpha = 3.0
[agents.arms.mem_q]
variant = "mem"
priority = "q"
"#,
        given.display()
    );
    let file = common::sample_pipeline(&arms, "arms.toml", "arms", &rest);
    let steps = run(&file, &[]);
    assert!(!steps.contains_key("pretrain"), "a given Q is not trained again: {steps:?}");
    for id in ["baseline_s0", "mem_s1", "mem_a3_s0", "mem_q_s1"] {
        assert_eq!(steps.get(&format!("agent td3bc_{id}")).map(String::as_str), Some("ran"), "{steps:?}");
    }
    let out = arms.join("out");
    let csv = std::fs::read_to_string(out.join("results.csv")).unwrap();
    for arm in ["mem_a3", "mem_q"] {
        let row = csv
            .lines()
            .find(|l| l.starts_with(&format!("FetchReach,td3bc,{arm},2,")))
            .unwrap_or_else(|| panic!("{csv}"));
        let p_vs_baseline = row.split(',').nth(7).unwrap();
        assert!(p_vs_baseline.parse::<f64>().is_ok_and(|p| (0.0..=1.0).contains(&p)), "{row}");
    }
    let t1: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report/table1.json")).unwrap()).unwrap();
    let settings: Vec<(String, f64)> = t1["priority"]["settings"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s["priority"].as_str().unwrap().to_string(), s["priority_alpha"].as_f64().unwrap()))
        .collect();
    // `mem` and `mem_a3` name no priority: the default's (rank), at α = 1 and 3.
    assert_eq!(settings, [("rank".to_string(), 1.0), ("rank".to_string(), 3.0), ("q".to_string(), 1.0)]);
    assert_eq!(t1["priority"]["rows"].as_u64(), t1["negatives_available"].as_u64());

    // The same Q at another path is another scored table's footer: score runs again, and only
    // the steps whose inputs then change follow it.
    let moved = dir.path().join("moved_q.ckpt");
    std::fs::rename(&given, &moved).unwrap();
    std::fs::write(&file, std::fs::read_to_string(&file).unwrap().replace("given_q.ckpt", "moved_q.ckpt")).unwrap();
    let again = run(&file, &[]);
    assert_eq!(again["score"], "ran", "{again:?}");
    assert_eq!(again["agent td3bc_baseline_s0"], "up to date");

    // A study of the arms against the baseline.
    let study = dir.path().join("study.toml");
    let arm = |label: &str, variant: &str, x: &str, priority: &str| {
        format!(
            "[[arm]]\nlabel = \"{label}\"\nresults = \"arms/out\"\nvariant = \"{variant}\"\n{x}{priority}report = \"arms/out/report\"\n"
        )
    };
    std::fs::write(
        &study,
        format!(
            "name = \"s\"\ntitle = \"arms\"\nout = \"study\"\ntask = \"FetchReach\"\nalgo = \"td3bc\"\nx_label = \"α\"\n\
             [[arm]]\nlabel = \"baseline\"\nresults = \"arms/out\"\nvariant = \"baseline\"\n{}{}",
            arm("rank α=1", "mem", "x = 1\nseries = \"rank\"\n", ""),
            arm("rank α=3", "mem_a3", "x = 3\nseries = \"rank\"\n", "priority = \"rank:3\"\n"),
        ),
    )
    .unwrap();
    let o = etl().args(["study"]).arg(&study).arg("--json").output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let s = last_json(&text(&o.stdout));
    let rows = s["rows"].as_array().unwrap();
    assert_eq!(rows.len(), 3);
    assert_eq!(rows[2]["share_above"], t1["priority"]["settings"][1]["share_above"]);
    assert_eq!(rows[1]["share_above"], t1["priority"]["settings"][0]["share_above"], "no priority: the default's");
    assert!(rows[1]["p"][0].as_f64().is_some() && rows[0]["p"].as_array().unwrap().is_empty(), "{s}");
    for f in ["study.md", "study.csv", "study.png"] {
        assert!(dir.path().join("study").join(f).exists(), "{f}");
    }
    // An arm whose report lacks its priority is named.
    std::fs::write(&study, std::fs::read_to_string(&study).unwrap().replace("rank:3", "rank:2")).unwrap();
    let o = etl().args(["study"]).arg(&study).output().unwrap();
    let e = text(&o.stderr);
    assert!(!o.status.success() && e.contains("arm 3") && e.contains("no share for priority rank:2"), "{e}");
}

/// `[data] oracle`: OGBench's recipe for the dataset the task names, made by a `collect_oracle`
/// step as the dataset's `.npz` and its `-val` file, converted under the environment's name,
/// with every episode a positive of the report; the results score success in percent.
#[test]
fn an_ogbench_pipeline_makes_its_data_by_the_recipe() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("pm.toml");
    std::fs::write(
        &file,
        r#"name = "pm"
task = "pointmaze-medium-stitch-v0"
out = "out"
[data]
oracle = 24
seed = 3
[train]
gamma = 0.99
batch_size = 32
eval_every = 40
eval_episodes = 5
[pretrain]
updates = 40
[agents]
algos = ["td3bc"]
seeds = [0]
updates = 40
"#,
    )
    .unwrap();
    let steps = run(&file, &[]);
    assert!(steps.values().all(|s| s == "ran"), "{steps:?}");
    assert!(steps.contains_key("collect_oracle"), "{steps:?}");
    let out = dir.path().join("out");
    for f in ["data/pointmaze-medium-stitch-v0.npz", "data/pointmaze-medium-stitch-v0-val.npz", "report/table1.md"] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let footer = pgser::table::read_footer(&out.join("traj.parquet")).unwrap();
    assert_eq!(
        (footer["task"].as_str(), footer["T"].as_u64(), footer["episodes"].as_u64()),
        (Some("pointmaze-medium-v0"), Some(201), Some(24))
    );
    let table1: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report/table1.json")).unwrap()).unwrap();
    assert_eq!(table1["positive_episodes"].as_u64(), Some(24), "{table1}");
    let results = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(results.contains("| agent | success (%) |"), "{results}");
    // The same data as `collect` makes by hand.
    let by_hand = dir.path().join("pointmaze-medium-stitch-v0.npz");
    let o = etl()
        .args([
            "collect",
            "--task",
            "pointmaze-medium-stitch-v0",
            "--policy",
            "oracle",
            "--episodes",
            "24",
            "--seed",
            "3",
            "-o",
        ])
        .arg(&by_hand)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let arrays = |p: &Path| {
        let mut v = Vec::new();
        for key in ["observations", "actions", "terminals"] {
            v.push(
                pgser::ogbench::npz::with_member(p, key, |r, _| {
                    let mut b = Vec::new();
                    std::io::Read::read_to_end(r, &mut b)?;
                    Ok(b)
                })
                .unwrap(),
            );
        }
        v
    };
    assert_eq!(arrays(&out.join("data/pointmaze-medium-stitch-v0.npz")), arrays(&by_hand));
    // A task that names no OGBench dataset cannot take oracle data.
    std::fs::write(
        &file,
        std::fs::read_to_string(&file).unwrap().replace("pointmaze-medium-stitch-v0", "pointmaze-medium-v0"),
    )
    .unwrap();
    let o = etl().args(["pipeline", "run"]).arg(&file).output().unwrap();
    assert!(!o.status.success() && text(&o.stderr).contains("names none"), "{}", text(&o.stderr));
}

/// A pipeline over a user's pickle that carries what a table cannot keep (a dict of settings, a
/// list of names): refused before any step, saying where the keys go; run with `[data] drop`;
/// and `drop` is in the convert step's key, so changing it reruns convert and what reads β.
#[test]
fn drop_leaves_a_pickles_metadata_out_and_is_part_of_the_key() {
    let dir = tempfile::tempdir().unwrap();
    common::py_ok("make_key_pickles.py", &[dir.path().to_str().unwrap()]);
    let write = |drop: &str| {
        let toml = format!(
            r#"
name = "meta"
task = "FetchReach"
out = "out"
[data]
pickles = ["metadata.pkl"]
{drop}
[train]
batch_size = 32
eval_every = 0
eval_episodes = 0
save_every = 0
[pretrain]
updates = 5
[report]
positive_episodes = 2
[agents]
variants = ["baseline"]
updates = 5
"#
        );
        let path = dir.path().join("meta.toml");
        std::fs::write(&path, toml).unwrap();
        path
    };
    let file = write("");
    let o = etl().args(["pipeline", "run"]).arg(&file).args(["--until", "pretrain"]).output().unwrap();
    let err = text(&o.stderr);
    assert!(!o.status.success());
    assert!(err.contains("[data] drop") && err.contains("metadata.pkl: key 'meta' is a dict"), "{err}");
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    assert!(!dir.path().join("out").exists(), "nothing written");

    let file = write("drop = [\"meta\", \"names\"]");
    let first = run(&file, &["--until", "pretrain"]);
    assert_eq!(ran(&first), ["convert", "pretrain"], "{first:?}");
    let traj = dir.path().join("out/traj.parquet");
    let columns = |p: &Path| {
        let (batch, _) = common::read_table(p);
        batch.schema().fields().iter().map(|f| f.name().clone()).collect::<Vec<_>>()
    };
    assert_eq!(columns(&traj).last().map(String::as_str), Some("info_is_success"));
    assert!(ran(&run(&file, &["--until", "pretrain"])).is_empty());

    // Another drop list: convert reruns (its key changed), and so does the step that reads β.
    let file = write("drop = [\"meta\", \"names\", \"info_is_success\"]");
    let second = run(&file, &["--until", "pretrain"]);
    assert_eq!(ran(&second), ["convert", "pretrain"], "{second:?}");
    assert_eq!(columns(&traj).last().map(String::as_str), Some("action"));
}
