//! `pgser-etl pipeline run` before its first step: what it refuses (each mistake named in one
//! line, with nothing written), and what it says the run will cost.

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::{etl, last_json, repo, text};

/// A FetchReach pipeline on the committed sample pickles, small enough for seconds; `pickles`
/// are file names under data/, `extra` is appended to the file.
fn pipeline(dir: &Path, name: &str, pickles: &[&str], episodes: &[usize], extra: &str) -> PathBuf {
    let data = repo().join("data");
    let pickles: Vec<String> = pickles.iter().map(|p| format!("{:?}", data.join(p).display().to_string())).collect();
    let toml = format!(
        r#"
name = "plan"
task = "FetchReach"
out = "out"
[data]
pickles = [{}]
episodes = {episodes:?}
[train]
batch_size = 64
eval_every = 20
eval_episodes = 4
save_every = 0
log_every = 10
[pretrain]
updates = 40
[agents]
variants = ["baseline", "mem"]
seeds = [0, 1]
updates = 30
{extra}
"#,
        pickles.join(", ")
    );
    let path = dir.join(name);
    std::fs::write(&path, toml).unwrap();
    path
}

const EXPERT: &str = "fetch_reach_expert_50.pkl";
const RANDOM: &str = "fetch_reach_random_200.pkl";

fn run(file: &Path, extra: &[&str]) -> Output {
    etl().args(["pipeline", "run"]).arg(file).args(["--threads", "2"]).args(extra).output().unwrap()
}

/// Runs and requires success; returns the `--json` report.
fn report(file: &Path, extra: &[&str]) -> serde_json::Value {
    let out = run(file, &[&["--json"], extra].concat());
    assert!(out.status.success(), "pipeline failed: {}", text(&out.stderr));
    last_json(&text(&out.stdout))
}

/// The run fails with one line that says `says`, and the folder holds only what it held.
fn fails_before_any_work(file: &Path, extra: &[&str], says: &str) {
    let dir = file.parent().unwrap();
    let before = listing(dir);
    for dry in [true, false] {
        let mut args = extra.to_vec();
        if dry {
            args.push("--dry-run");
        }
        let out = run(file, &args);
        let err = text(&out.stderr);
        assert!(!out.status.success(), "{says}: succeeded");
        assert!(err.contains(says), "{says}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert_eq!(listing(dir), before, "{says}: wrote files");
    }
}

fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut all: Vec<PathBuf> = walk(dir);
    all.sort();
    all
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let mut all = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            all.extend(walk(&p));
        }
        all.push(p);
    }
    all
}

#[test]
fn a_single_pickle_needs_positive_episodes_before_any_step_runs() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), "one.toml", &[EXPERT], &[12], "");
    fails_before_any_work(&file, &[], "[report] positive_episodes is required");
    let out = run(&file, &["--dry-run"]);
    assert!(text(&out.stderr).contains(EXPERT), "names the pickle: {}", text(&out.stderr));

    // Too many positives is refused too; a valid count plans.
    let file = pipeline(dir.path(), "one.toml", &[EXPERT], &[12], "[report]\npositive_episodes = 13");
    fails_before_any_work(&file, &[], "positive_episodes = 13: must be between 1 and the 12 episodes");
    let file = pipeline(dir.path(), "one.toml", &[EXPERT], &[12], "[report]\npositive_episodes = 12");
    let r = report(&file, &["--dry-run", "--no-measure"]);
    assert_eq!(r["steps"].as_array().unwrap().len(), 1 + 2 + 4 + 2);
    // Two pickles: the first one's episodes are the positives, as before.
    let file = pipeline(dir.path(), "two.toml", &[EXPERT, RANDOM], &[12, 24], "");
    report(&file, &["--dry-run", "--no-measure"]);
}

#[test]
fn missing_or_foreign_pickles_an_unbuilt_device_and_an_unwritable_out_fail_first() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), "missing.toml", &[EXPERT, "fetch_reach_nothing.pkl"], &[12, 24], "");
    fails_before_any_work(&file, &[], "[data] pickles: ");
    fails_before_any_work(&file, &[], "fetch_reach_nothing.pkl: cannot open");

    // FetchReach pickles in a FetchPush pipeline: the dimensions do not fit.
    let file = pipeline(dir.path(), "push.toml", &[EXPERT, RANDOM], &[12, 24], "");
    let push = std::fs::read_to_string(&file).unwrap().replace("FetchReach", "FetchPush");
    std::fs::write(&file, push).unwrap();
    fails_before_any_work(&file, &[], "fetch_reach_expert_50.pkl: dimension mismatch");

    let file = pipeline(dir.path(), "device.toml", &[EXPERT, RANDOM], &[12, 24], "");
    if !cfg!(feature = "wgpu") {
        fails_before_any_work(&file, &["--device", "wgpu"], "--device wgpu: this pgser was built without that backend");
    }
    // Built with cuda-burn on a machine without the driver, it is the driver's line instead (docs/gpu.md).
    if !cfg!(feature = "cuda-burn") {
        fails_before_any_work(
            &file,
            &["--device", "cuda-burn"],
            "--device cuda-burn: this pgser was built without that backend (rebuild with `make build-cuda`",
        );
    }
    // The hand-written CUDA engine is in every build: without the NVIDIA driver, one line says so.
    if !pgser::agent::cuda::driver_present() {
        fails_before_any_work(
            &file,
            &["--device", "cuda"],
            "--device cuda: no NVIDIA driver here (libcuda.so.1 does not load)",
        );
    }

    // Tests run as root, whom file modes do not stop: out under a regular file cannot be made.
    std::fs::write(dir.path().join("a_file"), "not a folder").unwrap();
    let text = std::fs::read_to_string(&file).unwrap().replace("out = \"out\"", "out = \"a_file/out\"");
    std::fs::write(&file, text).unwrap();
    fails_before_any_work(&file, &[], "out = \"");
    fails_before_any_work(&file, &[], "a_file is a file, not a folder");

    // A setting that only the step would have refused.
    let file = pipeline(dir.path(), "batch.toml", &[EXPERT, RANDOM], &[12, 24], "batch_size = 0");
    fails_before_any_work(&file, &[], "[agents] (agent td3bc_baseline_s0): batch_size = 0");
    let file = pipeline(dir.path(), "draws.toml", &[EXPERT, RANDOM], &[12, 24], "draws_per_row = 2");
    fails_before_any_work(&file, &[], "draws_per_row = 2 needs memory_budget");
}

/// Updates of the plan's training steps that the cost must count.
fn updates(r: &serde_json::Value) -> u64 {
    r["cost"]["per_step"].as_array().unwrap().iter().map(|s| s["updates"].as_u64().unwrap()).sum()
}

#[test]
fn the_cost_counts_the_updates_that_will_run_and_is_measured_by_default() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), "plan.toml", &[EXPERT, RANDOM], &[12, 24], "");

    // Everything runs: the Q's 40 updates and 4 agents × 30.
    let out = run(&file, &["--dry-run", "--json"]);
    let err = text(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("cost: 9 steps, 160 updates ") && err.contains("updates/s measured"), "{err}");
    let first = last_json(&text(&out.stdout));
    let r = &first;
    let cost = &r["cost"];
    assert_eq!((cost["steps"].as_u64(), cost["updates"].as_u64(), updates(r)), (Some(9), Some(160), 160));
    assert!(cost["seconds"].as_f64().unwrap() > 0.0, "{cost}");
    let m = &cost["measured"];
    assert!(m["updates_per_sec"].as_object().unwrap().values().all(|v| v.as_f64().unwrap() > 0.0), "{m}");
    assert!(m["env_steps_per_sec"].as_f64().unwrap() > 0.0 && m["scored_rows_per_sec"].as_f64().unwrap() > 0.0);
    // Data 36 episodes × 49 transitions × 4 swaps; evaluations every 20 updates and at the end,
    // 4 episodes of 50 steps each: 2 for the Q and each agent.
    assert_eq!(cost["scored_rows"].as_u64(), Some(36 * 49 * 4));
    assert_eq!(cost["env_steps"].as_u64(), Some(5 * 2 * 4 * 50));
    assert!(!dir.path().join("out").exists(), "a dry run wrote its out folder");

    // Data, Q and scores done: only the agents are left to pay for.
    report(&file, &["--until", "score", "--no-measure"]);
    let r = report(&file, &["--dry-run", "--no-measure"]);
    assert_eq!((r["cost"]["steps"].as_u64(), updates(&r)), (Some(6), 4 * 30));
    assert!(r["cost"]["seconds"].is_null() && r["cost"]["measured"].is_null(), "{}", r["cost"]);

    // Finished: the disk estimate is what a checkpoint takes, and bounds the zstd tables.
    report(&file, &["--no-measure"]);
    let out = dir.path().join("out");
    let estimated = |name: &str| {
        let steps = first["cost"]["per_step"].as_array().unwrap();
        steps.iter().find(|s| s["name"] == name).unwrap()["bytes"].as_u64().unwrap() as f64
    };
    let size = |f: &str| std::fs::metadata(out.join(f)).unwrap().len() as f64;
    let ckpt =
        ["", ".resume", ".metrics.jsonl"].iter().map(|x| size(&format!("agents/td3bc_mem_s1.ckpt{x}"))).sum::<f64>();
    assert!((ckpt / estimated("agent td3bc_mem_s1") - 1.0).abs() < 0.01, "{ckpt} bytes");
    assert!(size("traj.parquet") < estimated("convert") && size("scored.parquet") < estimated("score"));

    // Then 10 more updates per agent: each continues from its checkpoint.
    assert_eq!(report(&file, &["--dry-run"])["cost"]["steps"].as_u64(), Some(0));
    let more = std::fs::read_to_string(&file).unwrap().replace("updates = 30", "updates = 40");
    std::fs::write(&file, more).unwrap();
    let r = report(&file, &["--dry-run", "--no-measure"]);
    assert_eq!((r["cost"]["steps"].as_u64(), updates(&r)), (Some(4 + 1), 4 * 10));
    let r = report(&file, &["--no-measure"]);
    assert_eq!(updates(&r), 4 * 10, "a real run states the same cost");
}

#[test]
fn simulated_data_is_checked_too() {
    let dir = tempfile::tempdir().unwrap();
    let file = pipeline(dir.path(), "sim.toml", &[EXPERT], &[12], "");
    let sim = std::fs::read_to_string(&file).unwrap();
    let start = sim.find("pickles").unwrap();
    let end = sim.find("[train]").unwrap();
    let with = |data: &str| {
        std::fs::write(&file, format!("{}{data}\n{}", &sim[..start], &sim[end..])).unwrap();
        file.clone()
    };
    let r = report(&with("expert = 3\nrandom = 5"), &["--dry-run", "--no-measure", "--until", "collect_expert"]);
    assert_eq!(r["cost"]["per_step"][0]["env_steps"].as_u64(), Some(3 * 49), "{}", r["cost"]);
    assert_eq!(r["steps"].as_array().unwrap().len(), 1);
    fails_before_any_work(&with("expert = 3\nrandom = 0"), &[], "[data] random (step collect_random)");
    fails_before_any_work(&with("expert = 3\nrandom = 5\nnoise = -1.0"), &[], "[data] expert (step collect_expert)");
}

#[test]
fn every_committed_pipeline_plans_and_is_listed_in_the_pipelines_readme() {
    // The experiment files are what users run (and what the GPU bundle runs on a machine where
    // nothing can be edited): each must still parse and plan with today's spec, from a fresh out
    // folder, and the README's table must name it. A copy of pipelines/ beside links to data/
    // and results/ keeps their relative paths (pickles, experts, committed Qs) and puts `out`
    // in a temporary folder; a dry run writes nothing there.
    let dir = tempfile::tempdir().unwrap();
    let root = repo();
    for d in ["data", "results"] {
        std::os::unix::fs::symlink(root.join(d), dir.path().join(d)).unwrap();
    }
    let copy = dir.path().join("pipelines");
    std::fs::create_dir(&copy).unwrap();
    let readme = std::fs::read_to_string(root.join("pipelines/README.md")).unwrap();
    let mut planned = 0;
    for e in std::fs::read_dir(root.join("pipelines")).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_str().unwrap().to_string();
        if !name.ends_with(".toml") {
            continue;
        }
        assert!(listed(&readme).contains(&name), "pipelines/README.md does not list {name}");
        // Study files join other pipelines' results (`pgser-etl study`); they are not pipelines.
        if name.ends_with("_study.toml") {
            continue;
        }
        std::fs::copy(&p, copy.join(&name)).unwrap();
        // A pipeline over an existing table (`[data] table`) that is not committed (a dataset
        // made by a bench script, hundreds of MB) cannot be checked here, only parsed and planned.
        let pipeline = pgser::pipeline::Pipeline::load(&copy.join(&name)).unwrap_or_else(|e| panic!("{name}: {e:#}"));
        if let pgser::pipeline::Data::Table { path } = &pipeline.data
            && !path.exists()
        {
            let steps = pgser::pipeline::plan(&pipeline).unwrap_or_else(|e| panic!("{name}: {e:#}"));
            assert!(steps.iter().any(|s| s.name == "score"), "{name}: no score step");
            eprintln!("{name}: [data] table {} is not here: planned, not dry-run", path.display());
            planned += 1;
            continue;
        }
        let out =
            etl().args(["pipeline", "run"]).arg(copy.join(&name)).args(["--dry-run", "--no-measure"]).output().unwrap();
        assert!(out.status.success(), "{name}: {}", text(&out.stderr));
        let said = text(&out.stderr) + &text(&out.stdout);
        assert!(said.contains("would run (dry run)"), "{name}: {said}");
        planned += 1;
    }
    assert!(planned >= 20, "only {planned} pipelines found");
    assert!(!dir.path().join("out").exists(), "a dry run wrote its out folder");
}

#[test]
fn no_pipeline_with_committed_results_leaves_its_priority_to_the_default() {
    // pgser's default priority changed (q to rank, 0.4: RESULTS.md, "Rank priorities on every
    // task"). A file whose results are committed must say what its -mem arms drew with, so that
    // running it again with a later pgser measures the same thing: each -mem arm names its
    // priority, or `[train]` / `[agents]` does.
    let root = repo();
    let mut checked = 0;
    for e in std::fs::read_dir(root.join("pipelines")).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_str().unwrap().to_string();
        if !name.ends_with(".toml") || name.ends_with("_study.toml") {
            continue;
        }
        let doc: toml::Table = std::fs::read_to_string(&p).unwrap().parse().unwrap();
        let stem = doc["name"].as_str().unwrap();
        if !root.join("results").join(stem).join("results.csv").exists() {
            continue;
        }
        let set = |t: Option<&toml::Value>| t.and_then(|t| t.get("priority")).is_some();
        let agents = doc.get("agents");
        if set(doc.get("train")) || set(agents) {
            checked += 1;
            continue;
        }
        let arms = agents.and_then(|a| a.get("arms"));
        let variants = agents.and_then(|a| a.get("variants")).and_then(|v| v.as_array()).cloned().unwrap_or_default();
        for v in variants.iter().filter_map(|v| v.as_str()) {
            let arm = arms.and_then(|a| a.get(v));
            let mem = v == "mem" || arm.and_then(|a| a.get("variant")).and_then(|x| x.as_str()) == Some("mem");
            assert!(!mem || set(arm), "{name}: -mem arm {v} names no priority, and its results are committed");
        }
        checked += 1;
    }
    assert!(checked >= 20, "only {checked} pipelines with results found");
}

/// The file names a README's `code` spans name: `a.toml`, and `a_{b,c}_d.toml` as both names.
fn listed(readme: &str) -> Vec<String> {
    fn expand(t: &str) -> Vec<String> {
        let (Some(open), Some(close)) = (t.find('{'), t.find('}')) else { return vec![t.to_string()] };
        t[open + 1..close]
            .split(',')
            .flat_map(|alt| expand(&format!("{}{alt}{}", &t[..open], &t[close + 1..])))
            .collect()
    }
    readme.split('`').skip(1).step_by(2).filter(|t| t.ends_with(".toml")).flat_map(expand).collect()
}
