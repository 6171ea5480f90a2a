//! `pgser-etl pipeline run --executor slurm` against a real single-node Slurm that the test
//! starts (`common/slurm.rs`): the tiny pipeline through Slurm writes the bytes of a local run;
//! a failed step cancels the steps that read it and a resubmission after the fix runs only the
//! rest; a training job sent SIGTERM saves, and its resubmission resumes to the weights of an
//! uninterrupted run; two concurrent submissions run each step once. The cluster's own faults:
//! a job requeued mid-training, its node set DOWN, and its `--time` run out. Without Slurm (or root)
//! each test prints `SKIPPED …` and returns; `make test` then says so too.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use common::slurm::{Cluster, cluster};
use common::{folder_pipeline, snapshot, step_statuses, text, tiny_pipeline};

/// One cluster at a time: the machine has few cores, and each test's timing matters.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

fn serial() -> MutexGuard<'static, ()> {
    ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner())
}

/// `pgser-etl ARGS` in `dir` with the cluster's settings.
fn etl(c: &Cluster, dir: &Path, args: &[&str]) -> Output {
    c.etl().current_dir(dir).args(args).output().unwrap()
}

/// Every job log of the pipeline in `dir`, for failure messages and counting.
fn job_logs(dir: &Path) -> String {
    let mut all = String::new();
    if let Ok(entries) = std::fs::read_dir(dir.join("out/.pipeline/logs")) {
        let mut paths: Vec<_> = entries.map(|e| e.unwrap().path()).collect();
        paths.sort();
        for p in paths {
            all += &format!("--- {}\n{}\n", p.display(), std::fs::read_to_string(&p).unwrap_or_default());
        }
    }
    all
}

fn ok(c: &Cluster, dir: &Path, o: Output, what: &str) -> Output {
    assert!(o.status.success(), "{what} failed: {}\n{}{}", text(&o.stderr), job_logs(dir), c.logs());
    o
}

/// A local `pipeline run tiny.toml ARGS` in `dir`.
fn local(dir: &Path, args: &[&str]) -> BTreeMap<String, String> {
    local_file(dir, "tiny.toml", args)
}

/// A local `pipeline run FILE ARGS` in `dir`.
fn local_file(dir: &Path, file: &str, args: &[&str]) -> BTreeMap<String, String> {
    let o = common::etl()
        .current_dir(dir)
        .args(["pipeline", "run", file, "--json", "--threads", "2", "--no-measure"])
        .args(args)
        .output()
        .unwrap();
    assert!(o.status.success(), "local run failed: {}", text(&o.stderr));
    step_statuses(&o)
}

const SLURM_WAIT: [&str; 7] = ["pipeline", "run", "tiny.toml", "--executor", "slurm", "--wait", "--json"];

#[test]
fn a_slurm_run_writes_the_bytes_of_a_local_run() {
    let _one = serial();
    let Some(c) = cluster("a_slurm_run_writes_the_bytes_of_a_local_run") else { return };
    let dir = tempfile::tempdir().unwrap();
    let (d, out) = (dir.path(), dir.path().join("out"));
    tiny_pipeline(d, 20, 2);
    let t0 = Instant::now();
    local(d, &[]);
    eprintln!("the tiny pipeline locally: {:.1} s", t0.elapsed().as_secs_f64());
    let want = snapshot(&out);
    std::fs::remove_dir_all(&out).unwrap();

    let t0 = Instant::now();
    let o = ok(&c, d, etl(&c, d, &SLURM_WAIT), "the Slurm run");
    eprintln!("the tiny pipeline through Slurm: {:.1} s", t0.elapsed().as_secs_f64());
    let s = step_statuses(&o);
    assert_eq!(s.len(), 11, "{s:?}");
    assert!(s.values().all(|v| v == "ran"), "{s:?}");
    let got = snapshot(&out);
    assert_eq!(got.keys().collect::<Vec<_>>(), want.keys().collect::<Vec<_>>());
    for (path, bytes) in &want {
        assert!(&got[path] == bytes, "{} differs between the local and the Slurm run", path.display());
    }
    // One job per step, and the agent grid as an array of one element (one stack).
    let logs: Vec<String> = std::fs::read_dir(out.join(".pipeline/logs"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(logs.len(), 6, "{logs:?}");
    assert!(logs.iter().any(|l| l.starts_with("agents-") && l.ends_with("_0.log")), "{logs:?}");

    let st = ok(&c, d, etl(&c, d, &["pipeline", "status", "tiny.toml", "--json"]), "status");
    let states: Vec<serde_json::Value> = serde_json::from_slice(&st.stdout).unwrap();
    assert!(states.iter().all(|s| s["state"] == "up to date"), "{states:?}");

    // Submitted again: nothing to do, no job.
    let again = ok(&c, d, etl(&c, d, &SLURM_WAIT[..5]), "a second submission");
    assert!(text(&again.stdout).trim().is_empty(), "{}", text(&again.stdout));
    assert!(text(&again.stderr).contains("nothing to submit"), "{}", text(&again.stderr));
}

#[test]
fn a_failed_step_cancels_what_reads_it_and_a_resubmission_runs_only_the_rest() {
    let _one = serial();
    let Some(c) = cluster("a_failed_step_cancels_what_reads_it_and_a_resubmission_runs_only_the_rest") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (d, out) = (dir.path(), dir.path().join("out"));
    tiny_pipeline(d, 20, 2);
    // A file where the agents' folder goes: the agent grid fails, results cannot run.
    std::fs::create_dir_all(&out).unwrap();
    std::fs::write(out.join("agents"), "in the way").unwrap();
    let o = etl(&c, d, &SLURM_WAIT);
    let err = text(&o.stderr);
    assert!(!o.status.success(), "a failed step was not reported: {err}");
    let s = step_statuses(&o);
    assert_eq!(s["agent td3bc_mem_s1"], "failed", "{s:?}");
    assert_eq!(s["results"], "not run", "{s:?}");
    for step in ["convert", "pretrain", "score", "report"] {
        assert_eq!(s[step], "ran", "{s:?}");
    }
    assert!(err.contains("failed") && err.contains(".pipeline/logs/agents-") && err.contains("results"), "{err}");
    assert_eq!(err.trim().lines().last().unwrap().matches("error").count(), 1, "{err}");

    let st = ok(&c, d, etl(&c, d, &["pipeline", "status", "tiny.toml", "--json"]), "status");
    let states: BTreeMap<String, serde_json::Value> = serde_json::from_slice::<Vec<serde_json::Value>>(&st.stdout)
        .unwrap()
        .into_iter()
        .map(|s| (s["name"].as_str().unwrap().to_string(), s))
        .collect();
    assert_eq!(states["agent td3bc_baseline_s0"]["state"], "failed");
    assert!(states["agent td3bc_baseline_s0"]["log"].as_str().unwrap().contains("agents-"));
    assert_eq!(states["results"]["state"], "not started");
    assert_eq!(states["report"]["state"], "up to date");
    let human = ok(&c, d, etl(&c, d, &["pipeline", "status", "tiny.toml"]), "status");
    assert!(text(&human.stdout).contains("agent td3bc_swap_s1: failed (log "), "{}", text(&human.stdout));

    std::fs::remove_file(out.join("agents")).unwrap();
    let o = ok(&c, d, etl(&c, d, &SLURM_WAIT), "the resubmission");
    let s = step_statuses(&o);
    for (step, status) in &s {
        let want = if step.starts_with("agent") || step == "results" { "ran" } else { "up to date" };
        assert_eq!(status, want, "{step}: {s:?}");
    }
}

#[test]
fn a_training_job_stopped_by_sigterm_resumes_to_the_weights_of_an_uninterrupted_run() {
    let _one = serial();
    let Some(c) = cluster("a_training_job_stopped_by_sigterm_resumes_to_the_weights_of_an_uninterrupted_run") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (d, out) = (dir.path(), dir.path().join("out"));
    let file = tiny_pipeline(d, 20, 2);
    // A pre-training long enough to be stopped halfway, with no scheduled save: the checkpoint
    // can only come from SIGTERM.
    let toml =
        std::fs::read_to_string(&file).unwrap().replace("[pretrain]\nupdates = 40", "[pretrain]\nupdates = 1500");
    std::fs::write(&file, &toml).unwrap();

    let o = ok(
        &c,
        d,
        etl(&c, d, &["pipeline", "run", "tiny.toml", "--executor", "slurm", "--until", "pretrain"]),
        "submit",
    );
    let ids: Vec<String> = text(&o.stdout).lines().map(str::to_string).collect();
    assert_eq!(ids.len(), 2, "convert and pretrain: {ids:?}");
    let log = out.join(format!(".pipeline/logs/pretrain-{}.log", ids[1]));
    let t0 = Instant::now();
    while !std::fs::read_to_string(&log).unwrap_or_default().contains("pretrain: running") {
        assert!(t0.elapsed() < Duration::from_secs(120), "pretrain never started\n{}{}", job_logs(d), c.logs());
        std::thread::sleep(Duration::from_millis(100));
    }
    std::thread::sleep(Duration::from_millis(1000));
    let term = c.command("scancel").args(["--signal=TERM", &ids[1]]).output().unwrap();
    assert!(term.status.success(), "scancel: {}", text(&term.stderr));
    c.wait_gone(&ids[1..], Duration::from_secs(120));
    let said = std::fs::read_to_string(&log).unwrap();
    let at = said.split("stopped by SIGTERM at update ").nth(1).unwrap_or_else(|| panic!("no SIGTERM save: {said}"));
    let updates: u64 = at.split(' ').next().unwrap().parse().unwrap();
    assert!(updates > 0 && updates < 1500, "stopped at update {updates}: {said}");
    assert!(out.join("q.ckpt").exists() && out.join("q.ckpt.resume").exists(), "no checkpoint saved: {said}");
    assert!(!out.join(".pipeline/pretrain.json").exists(), "an interrupted step was recorded as finished");

    let o = ok(&c, d, etl(&c, d, &[&SLURM_WAIT[..], &["--until", "pretrain"]].concat()), "the resubmission");
    let s = step_statuses(&o);
    assert_eq!((s["convert"].as_str(), s["pretrain"].as_str()), ("up to date", "resumed"), "{s:?}");

    // The same pipeline never interrupted, locally: the same bytes (weights, optimizer, metrics).
    assert_same_files(&snapshot(&out), &uninterrupted(&toml, &["--until", "pretrain"]));
}

#[test]
fn two_concurrent_submissions_run_each_step_once() {
    let _one = serial();
    let Some(c) = cluster("two_concurrent_submissions_run_each_step_once") else { return };
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    tiny_pipeline(d, 20, 2);
    let spawn = || {
        c.etl()
            .current_dir(d)
            .args(SLURM_WAIT)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let (a, b) = (spawn(), spawn());
    let (a, b) = (a.wait_with_output().unwrap(), b.wait_with_output().unwrap());
    let (a, b) = (ok(&c, d, a, "submission A"), ok(&c, d, b, "submission B"));
    let (sa, sb) = (step_statuses(&a), step_statuses(&b));
    let logs = job_logs(d);
    for name in sa.keys() {
        // Every runner logs "[i/n] NAME: ran …" (or "resumed") when it ran the step.
        let runs =
            logs.matches(&format!("] {name}: ran")).count() + logs.matches(&format!("] {name}: resumed")).count();
        assert_eq!(runs, 1, "{name} ran {runs} times\n{logs}");
        let ran: Vec<&str> = [&sa[name], &sb[name]].into_iter().map(String::as_str).filter(|s| *s == "ran").collect();
        assert_eq!(ran.len(), 1, "{name}: {} and {}", sa[name], sb[name]);
    }
    // Whether they met at a lock depends on the scheduler's timing; say it, do not require it.
    eprintln!("the two submissions met at a step lock {} time(s)", logs.matches("waiting for its lock").count());
}

/// The job id of `step` from the pipeline's job list (`OUT/.pipeline/slurm.jsonl`), once its
/// submission has written it.
fn job_of(out: &Path, step: &str) -> String {
    let t0 = Instant::now();
    loop {
        let jobs = std::fs::read_to_string(out.join(".pipeline/slurm.jsonl")).unwrap_or_default();
        let found = jobs.lines().filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok()).find(|j| {
            j["elements"]
                .as_array()
                .is_some_and(|e| e.iter().filter_map(|x| x.as_array()).flatten().any(|s| s.as_str() == Some(step)))
        });
        if let Some(j) = found {
            return j["id"].as_str().unwrap().to_string();
        }
        assert!(t0.elapsed() < Duration::from_secs(60), "no job for {step} submitted");
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Waits until `file` exists and holds `needle` (a job log's line; "" for any file).
fn wait_for(c: &Cluster, dir: &Path, file: &Path, needle: &str, limit: Duration) {
    let t0 = Instant::now();
    while !std::fs::read(file).is_ok_and(|t| String::from_utf8_lossy(&t).contains(needle)) {
        assert!(t0.elapsed() < limit, "{} never held {needle:?}\n{}{}", file.display(), job_logs(dir), c.logs());
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// `pipeline run tiny.toml --executor slurm --wait --json ARGS` in the background.
fn submit_and_wait(c: &Cluster, dir: &Path, args: &[&str]) -> std::process::Child {
    c.etl()
        .current_dir(dir)
        .args(SLURM_WAIT)
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

/// The tiny pipeline with a pre-training of `updates` that saves every `save_every`.
fn long_pretrain(dir: &Path, updates: u64, save_every: u64) -> String {
    let file = tiny_pipeline(dir, 20, 2);
    let toml = std::fs::read_to_string(&file)
        .unwrap()
        .replace("[pretrain]\nupdates = 40", &format!("[pretrain]\nupdates = {updates}"))
        .replace("save_every = 0", &format!("save_every = {save_every}"));
    std::fs::write(&file, &toml).unwrap();
    toml
}

/// `pipeline run tiny.toml ARGS` locally in a fresh folder: the uninterrupted run's files.
fn uninterrupted(toml: &str, args: &[&str]) -> BTreeMap<std::path::PathBuf, Vec<u8>> {
    let alone = tempfile::tempdir().unwrap();
    std::fs::write(alone.path().join("tiny.toml"), toml).unwrap();
    local(alone.path(), args);
    snapshot(&alone.path().join("out"))
}

fn assert_same_files(got: &BTreeMap<std::path::PathBuf, Vec<u8>>, want: &BTreeMap<std::path::PathBuf, Vec<u8>>) {
    assert_eq!(got.keys().collect::<Vec<_>>(), want.keys().collect::<Vec<_>>());
    for (path, bytes) in want {
        assert!(&got[path] == bytes, "{} differs from an uninterrupted run", path.display());
    }
}

/// `scontrol requeue` of a running training job (what preemption does): Slurm stops it and runs
/// its script again; the step resumes from its checkpoint, the submission's `--wait` follows it
/// to the end, and the files are those of a run never interrupted.
#[test]
fn a_requeued_training_job_resumes_to_the_bytes_of_an_uninterrupted_run() {
    let _one = serial();
    let Some(c) = cluster("a_requeued_training_job_resumes_to_the_bytes_of_an_uninterrupted_run") else { return };
    let dir = tempfile::tempdir().unwrap();
    let (d, out) = (dir.path(), dir.path().join("out"));
    let toml = long_pretrain(d, 3000, 500);
    let child = submit_and_wait(&c, d, &["--until", "pretrain"]);
    let id = job_of(&out, "pretrain");
    let log = out.join(format!(".pipeline/logs/pretrain-{id}.log"));
    wait_for(&c, d, &log, "pretrain: running", Duration::from_secs(120));
    // A scheduled save first, so the requeue finds a checkpoint whatever signal it sends.
    wait_for(&c, d, &out.join("q.ckpt.resume"), "", Duration::from_secs(120));
    let rq = c.command("scontrol").args(["requeue", &id]).output().unwrap();
    assert!(rq.status.success(), "scontrol requeue: {}{}", text(&rq.stderr), c.logs());
    let o = ok(&c, d, child.wait_with_output().unwrap(), "the requeued submission");
    let s = step_statuses(&o);
    assert_eq!((s["convert"].as_str(), s["pretrain"].as_str()), ("ran", "resumed"), "{s:?}\n{}", job_logs(d));
    // One log, two attempts (`--open-mode=append`).
    let said = std::fs::read_to_string(&log).unwrap();
    assert_eq!(said.matches("pretrain: running").count(), 2, "{said}");
    assert_same_files(&snapshot(&out), &uninterrupted(&toml, &["--until", "pretrain"]));
}

/// The node set DOWN under a running training job: the job ends (NODE_FAIL; it was submitted
/// `--no-requeue`, as on a site whose failed jobs are not requeued), the jobs that read its
/// outputs are cancelled, and a resubmission once the node is back runs only what is left,
/// resuming the training from its last save, to the bytes of an uninterrupted run.
#[test]
fn a_node_down_fails_its_job_cancels_dependents_and_a_resubmission_runs_the_rest() {
    let _one = serial();
    let Some(c) = cluster("a_node_down_fails_its_job_cancels_dependents_and_a_resubmission_runs_the_rest") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (d, out) = (dir.path(), dir.path().join("out"));
    let toml = long_pretrain(d, 3000, 500);
    let child = submit_and_wait(&c, d, &["--sbatch-arg=--no-requeue"]);
    let id = job_of(&out, "pretrain");
    let log = out.join(format!(".pipeline/logs/pretrain-{id}.log"));
    wait_for(&c, d, &log, "pretrain: running", Duration::from_secs(120));
    wait_for(&c, d, &out.join("q.ckpt.resume"), "", Duration::from_secs(120));
    let down = c.command("scontrol").args(["update", "nodename=pgsernode", "state=down", "reason=pgser-test"]).output();
    assert!(down.unwrap().status.success(), "scontrol update state=down failed{}", c.logs());
    let o = child.wait_with_output().unwrap();
    assert!(!o.status.success(), "a failed job was not reported: {}", text(&o.stderr));
    let s = step_statuses(&o);
    assert_eq!(s["convert"], "ran", "{s:?}");
    assert_eq!(s["pretrain"], "failed", "{s:?}");
    for (step, status) in &s {
        if !["convert", "pretrain"].contains(&step.as_str()) {
            assert_eq!(status, "not run", "{step}: {s:?}");
        }
    }
    assert!(!out.join(".pipeline/pretrain.json").exists(), "a killed step was recorded as finished");

    // The node back: `resume` is refused while the killed job is still completing on it.
    let t0 = Instant::now();
    loop {
        let back = c.command("scontrol").args(["update", "nodename=pgsernode", "state=resume"]).output().unwrap();
        let idle = c.command("sinfo").args(["--noheader", "--format=%T"]).output().unwrap();
        if back.status.success() || text(&idle.stdout).trim() == "idle" {
            break;
        }
        let why = format!("{}{}", text(&back.stderr), text(&idle.stdout));
        assert!(t0.elapsed() < Duration::from_secs(60), "the node never came back: {why}{}", c.logs());
        std::thread::sleep(Duration::from_millis(500));
    }
    let o = ok(&c, d, etl(&c, d, &SLURM_WAIT), "the resubmission");
    let s = step_statuses(&o);
    for (step, status) in &s {
        let want = match step.as_str() {
            "convert" => "up to date",
            "pretrain" => "resumed",
            _ => "ran",
        };
        assert_eq!(status, want, "{step}: {s:?}");
    }
    assert_same_files(&snapshot(&out), &uninterrupted(&toml, &[]));
}

/// A job given too little `--time`: Slurm sends SIGTERM at its limit, the training saves and
/// exits before KillWait's SIGKILL, the submission reports the step failed with its log, and a
/// resubmission without the limit continues from the save to the end.
#[test]
fn a_job_past_its_time_limit_saves_and_a_resubmission_continues_it() {
    let _one = serial();
    let Some(c) = cluster("a_job_past_its_time_limit_saves_and_a_resubmission_continues_it") else { return };
    // Slurm checks time limits every 30 s, so a 1-minute job ends 60 to 90 s after it starts:
    // the pre-training must take longer than that here. Measured on this machine first.
    let probe = tempfile::tempdir().unwrap();
    long_pretrain(probe.path(), 2000, 0);
    let t0 = Instant::now();
    local(probe.path(), &["--until", "pretrain"]);
    let rate = 2000.0 / t0.elapsed().as_secs_f64();
    let updates = ((rate * 150.0 / 1000.0).ceil() as u64).max(2) * 1000;
    eprintln!("pre-training at {rate:.0} updates/s: {updates} updates for ~150 s");

    let dir = tempfile::tempdir().unwrap();
    let (d, out) = (dir.path(), dir.path().join("out"));
    long_pretrain(d, updates, 0);
    let child = submit_and_wait(&c, d, &["--until", "pretrain", "--sbatch-arg=--time=1"]);
    let id = job_of(&out, "pretrain");
    let o = child.wait_with_output().unwrap();
    let s = step_statuses(&o);
    assert_eq!((s["convert"].as_str(), s["pretrain"].as_str()), ("ran", "failed"), "{s:?}\n{}", job_logs(d));
    let said = std::fs::read_to_string(out.join(format!(".pipeline/logs/pretrain-{id}.log"))).unwrap();
    assert!(said.contains("DUE TO TIME LIMIT"), "not stopped by its time limit: {said}");
    let at = said.split("stopped by SIGTERM at update ").nth(1).unwrap_or_else(|| panic!("no SIGTERM save: {said}"));
    let stopped: u64 = at.split(' ').next().unwrap().parse().unwrap();
    assert!(stopped > 0 && stopped < updates, "stopped at update {stopped} of {updates}");

    let o = ok(&c, d, etl(&c, d, &[&SLURM_WAIT[..], &["--until", "pretrain"]].concat()), "the resubmission");
    let s = step_statuses(&o);
    assert_eq!((s["convert"].as_str(), s["pretrain"].as_str()), ("up to date", "resumed"), "{s:?}");
    // Continued to the end, not restarted: the checkpoint is at the last update, and its loss
    // lines (kept across the stop) are every 10 updates once. That the bytes are an
    // uninterrupted run's after a SIGTERM save is the test above; here it would cost 150 s more.
    let (agent, _) = pgser::agent::checkpoint::load(&out.join("q.ckpt"), burn::tensor::Device::flex()).unwrap();
    assert_eq!(agent.updates, updates);
    let lines = std::fs::read_to_string(out.join("q.ckpt.metrics.jsonl")).unwrap();
    let logged: Vec<u64> = lines
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|v| v.get("eval").is_none())
        .map(|v| v["updates"].as_u64().unwrap())
        .collect();
    // Every 10 updates once (`log_every = 10`), across the stop.
    assert!(logged == (1..=updates / 10).map(|k| k * 10).collect::<Vec<_>>(), "{} loss lines", logged.len());
}

/// `pipeline run folder.toml --executor slurm --wait --json --array-parallelism 2` in the background.
fn submit_folder(c: &Cluster, dir: &Path) -> std::process::Child {
    c.etl()
        .current_dir(dir)
        .args(["pipeline", "run", "folder.toml", "--executor", "slurm", "--wait", "--json", "--array-parallelism", "2"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap()
}

/// The jobs of `OUT/.pipeline/slurm.jsonl`, oldest first.
fn submitted_jobs(out: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(out.join(".pipeline/slurm.jsonl")).unwrap_or_default();
    text.lines().map(|l| serde_json::from_str(l).unwrap()).collect()
}

/// `pipeline status folder.toml --json`: step name → its state object.
fn folder_status(c: &Cluster, dir: &Path) -> BTreeMap<String, serde_json::Value> {
    let st = ok(c, dir, etl(c, dir, &["pipeline", "status", "folder.toml", "--json"]), "status");
    serde_json::from_slice::<Vec<serde_json::Value>>(&st.stdout)
        .unwrap()
        .into_iter()
        .map(|s| (s["name"].as_str().unwrap().to_string(), s))
        .collect()
}

/// The folder pipeline written into `d` and run locally there: its outputs' bytes, with `d/out`
/// then removed for the Slurm run to write again. In `d` itself: a checkpoint records its data's
/// path, so the same folder is needed for the same bytes.
fn folder_run_locally(d: &Path) -> BTreeMap<std::path::PathBuf, Vec<u8>> {
    folder_pipeline(d, 20);
    local_file(d, "folder.toml", &[]);
    let want = snapshot(&d.join("out"));
    std::fs::remove_dir_all(d.join("out")).unwrap();
    want
}

/// `[data] table` over a table folder of 3 shards: the score step goes to Slurm as one job array
/// of 3 elements (one per shard, `pipeline step FILE score --shard K`) and its own job after it,
/// which `pipeline status` shows while they run; the run writes the bytes of a local run — the
/// scored folder's shards and manifest, the agents, the report and the results.
#[test]
fn a_table_folder_is_scored_by_a_job_array_of_its_shards_into_the_bytes_of_a_local_run() {
    let _one = serial();
    let Some(c) = cluster("a_table_folder_is_scored_by_a_job_array_of_its_shards_into_the_bytes_of_a_local_run") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (d, out) = (dir.path(), dir.path().join("out"));
    let want = folder_run_locally(d);
    for f in ["scored/manifest.json", "scored/reach-0.parquet", "scored/reach-2.parquet", "results.csv"] {
        assert!(want.contains_key(Path::new(f)), "the local run wrote no {f}");
    }

    let child = submit_folder(&c, d);
    // Once the array is submitted (before its elements can have run: they wait for the Q's job),
    // status shows it under the score step.
    let array = job_of(&out, "score");
    let st = folder_status(&c, d);
    let shards = &st["score"]["shards"];
    assert_eq!(shards["job"], array.as_str(), "{st:?}");
    assert_eq!(shards["of"], 3, "{shards}");
    let counted: u64 =
        ["done", "running", "pending", "failed", "not_started"].iter().map(|k| shards[k].as_u64().unwrap()).sum();
    assert_eq!(counted, 3, "{shards}");
    let human = ok(&c, d, etl(&c, d, &["pipeline", "status", "folder.toml"]), "status");
    assert!(text(&human.stdout).contains(&format!("shards (job array {array}): ")), "{}", text(&human.stdout));

    let o = ok(&c, d, child.wait_with_output().unwrap(), "the Slurm run");
    let s = step_statuses(&o);
    assert_eq!(s.len(), 10, "{s:?}");
    assert!(s.values().all(|v| v == "ran"), "{s:?}\n{}", job_logs(d));
    let got = snapshot(&out);
    assert_eq!(got.keys().collect::<Vec<_>>(), want.keys().collect::<Vec<_>>());
    for (path, bytes) in &want {
        assert!(&got[path] == bytes, "{} differs between the local and the Slurm run", path.display());
    }

    // The jobs: pretrain, the shard array (3 elements, each scoring its shard), score's own job
    // after it, the agent array, report, results.
    let jobs = submitted_jobs(&out);
    assert_eq!(jobs.len(), 6, "{jobs:?}");
    assert_eq!((jobs[1]["id"].as_str(), jobs[1]["shards"].as_bool()), (Some(array.as_str()), Some(true)));
    assert_eq!(jobs[1]["elements"], serde_json::json!([["score"], ["score"], ["score"]]));
    assert_eq!(jobs[2]["elements"], serde_json::json!([["score"]]));
    assert!(jobs[2].get("shards").is_none() && jobs[2]["array"] == false, "{}", jobs[2]);
    for k in 0..3 {
        let log = std::fs::read_to_string(out.join(format!(".pipeline/logs/score_shards-{array}_{k}.log"))).unwrap();
        assert!(log.contains(&format!("score shard {k} of 3: ran")), "element {k}: {log}");
    }
    // The step's own job found every shard scored: it wrote the manifest and the record only.
    let own =
        std::fs::read_to_string(out.join(format!(".pipeline/logs/score-{}.log", jobs[2]["id"].as_str().unwrap())));
    assert!(own.unwrap().contains("score: ran"), "{}", job_logs(d));
    let st = folder_status(&c, d);
    assert!(st.values().all(|s| s["state"] == "up to date" && s.get("shards").is_none()), "{st:?}");
}

/// An element that fails (shard 1's path taken by a folder) fails the score step: its own job is
/// cancelled, as is everything reading the scored folder; the run and `pipeline status` name the
/// element's log; a resubmission after the fix scores the missing shard (the others are kept)
/// and runs the rest, to the bytes of a local run.
#[test]
fn a_failed_shard_fails_the_score_step_with_its_log_and_a_resubmission_finishes_it() {
    let _one = serial();
    let Some(c) = cluster("a_failed_shard_fails_the_score_step_with_its_log_and_a_resubmission_finishes_it") else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let (d, out) = (dir.path(), dir.path().join("out"));
    let want = folder_run_locally(d);
    let blocker = out.join("scored/reach-1.parquet/in_the_way");
    std::fs::create_dir_all(&blocker).unwrap();
    let o = submit_folder(&c, d).wait_with_output().unwrap();
    let err = text(&o.stderr);
    assert!(!o.status.success(), "a failed shard was not reported: {err}");
    let s = step_statuses(&o);
    assert_eq!(s["pretrain"], "ran", "{s:?}");
    assert_eq!(s["score"], "failed", "{s:?}\n{}", job_logs(d));
    for (step, status) in s.iter().filter(|(k, _)| !["pretrain", "score"].contains(&k.as_str())) {
        assert_eq!(status, "not run", "{step}: {s:?}");
    }
    let array = job_of(&out, "score");
    let log = format!(".pipeline/logs/score_shards-{array}_1.log");
    assert!(err.contains(&log), "{err}");
    let st = folder_status(&c, d);
    assert_eq!(st["score"]["state"], "failed", "{st:?}");
    assert!(st["score"]["log"].as_str().unwrap().ends_with(&log), "{st:?}");
    let shards = &st["score"]["shards"];
    assert_eq!((shards["done"].as_u64(), shards["failed"].as_u64()), (Some(2), Some(1)), "{shards}");
    assert!(!out.join("scored/manifest.json").exists(), "a manifest with a shard missing");

    std::fs::remove_dir_all(out.join("scored/reach-1.parquet")).unwrap();
    let o = ok(&c, d, submit_folder(&c, d).wait_with_output().unwrap(), "the resubmission");
    let s = step_statuses(&o);
    for (step, status) in &s {
        assert_eq!(status, if step == "pretrain" { "up to date" } else { "ran" }, "{step}: {s:?}");
    }
    assert_same_files(&snapshot(&out), &want);
}
