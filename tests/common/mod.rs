//! Helpers shared by the integration tests: the binaries, the test venv's Python, manifests,
//! the tiny pipeline, a single-node Slurm (`slurm.rs`).
#![allow(dead_code)]

pub mod coded;
pub mod kill;
pub mod slurm;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The venv `make test` creates (numpy, pyarrow). Tests that cross-check with Python need it.
pub fn python() -> PathBuf {
    let p = repo().join(".venv/bin/python");
    assert!(p.exists(), "{} is missing: run `make venv` (or `make test`)", p.display());
    p
}

pub fn etl() -> Command {
    Command::new(env!("CARGO_BIN_EXE_pgser-etl"))
}

/// Run a script from tests/py with the venv's Python; panics with its output if it fails.
pub fn py_ok(script: &str, args: &[&str]) -> Output {
    let out = Command::new(python()).arg(repo().join("tests/py").join(script)).args(args).output().unwrap();
    assert!(out.status.success(), "{script} {args:?} failed:\n{}\n{}", text(&out.stdout), text(&out.stderr));
    out
}

pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The `--json` summary a command prints as the last line of its stdout.
pub fn last_json(stdout: &str) -> serde_json::Value {
    let line = stdout.trim_end().lines().last().unwrap_or_else(|| panic!("no JSON line on stdout"));
    serde_json::from_str(line).unwrap_or_else(|e| panic!("last stdout line is not JSON ({e}): {line}"))
}

pub fn manifest(dir: &Path) -> Vec<serde_json::Value> {
    let t = std::fs::read_to_string(dir.join("manifest.json")).unwrap();
    serde_json::from_str(&t).unwrap()
}

pub fn strings(v: &serde_json::Value) -> Vec<String> {
    v.as_array().map(|a| a.iter().map(|s| s.as_str().unwrap().to_string()).collect()).unwrap_or_default()
}

/// `pgser-etl convert` with the given arguments; returns the process output.
pub fn convert(inputs: &[&Path], out: &Path, extra: &[String]) -> Output {
    etl().arg("convert").args(inputs).arg("-o").arg(out).args(extra).output().unwrap()
}

/// Convert and require success.
pub fn convert_ok(inputs: &[&Path], out: &Path, extra: &[String]) {
    let o = convert(inputs, out, extra);
    assert!(o.status.success(), "convert {inputs:?} {extra:?} failed: {}", text(&o.stderr));
}

/// Cross-check a table against its source pickles with numpy + pyarrow, bit for bit.
pub fn check_roundtrip(parquet: &Path, inputs: &[&Path], extra: &[String]) {
    let mut args: Vec<String> = vec!["--parquet".into(), parquet.display().to_string()];
    args.extend(extra.iter().cloned());
    args.extend(inputs.iter().map(|p| p.display().to_string()));
    let args: Vec<&str> = args.iter().map(|s| s.as_str()).collect();
    py_ok("check_roundtrip.py", &args);
}

/// `pgser-etl collect` with the given arguments (threads as given, or rayon's default).
pub fn collect(args: &[&str], threads: Option<usize>) -> Output {
    let mut c = etl();
    c.arg("collect").args(args);
    if let Some(n) = threads {
        c.env("RAYON_NUM_THREADS", n.to_string());
    }
    c.output().unwrap()
}

/// Collect and require success; returns stderr (the summary line).
pub fn collect_ok(args: &[&str], threads: Option<usize>) -> String {
    let o = collect(args, threads);
    assert!(o.status.success(), "collect {args:?} failed: {}", text(&o.stderr));
    text(&o.stderr)
}

/// `pgser-etl inspect --json` of a table.
pub fn inspect_json(path: &Path) -> serde_json::Value {
    let o = etl().args(["inspect", "--json"]).arg(path).output().unwrap();
    assert!(o.status.success(), "inspect {} failed: {}", path.display(), text(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

/// A whole Parquet file as one record batch, and its row-group count.
pub fn read_table(path: &Path) -> (arrow_array::RecordBatch, usize) {
    use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
    let builder = ParquetRecordBatchReaderBuilder::try_new(std::fs::File::open(path).unwrap()).unwrap();
    let groups = builder.metadata().num_row_groups();
    let schema = builder.schema().clone();
    let batches: Vec<_> = builder.build().unwrap().map(|b| b.unwrap()).collect();
    (arrow_select::concat::concat_batches(&schema, &batches).unwrap(), groups)
}

/// `pgser-etl convert INPUT -o OUT EXTRA…` must fail with one line that names the input and says
/// `want`, and leave no `out`.
pub fn convert_fails(input: &Path, out: &Path, extra: &[&str], want: &str) {
    let o = etl().arg("convert").arg(input).arg("-o").arg(out).args(extra).output().unwrap();
    let e = text(&o.stderr);
    assert!(!o.status.success() && e.contains(want) && e.trim().lines().count() == 1, "{want}: {e}");
    assert!(e.contains(&*input.file_name().unwrap().to_string_lossy()), "{e}");
    assert!(!out.exists(), "{want}: an output was left");
}

/// A float32 trajectory table's achieved goals, every row's in order.
pub fn achieved_goals(table: &Path) -> Vec<f32> {
    use arrow_array::cast::AsArray;
    let (t, _) = read_table(table);
    let ag = t.column_by_name("achieved_goal").unwrap().as_fixed_size_list();
    ag.values().as_primitive::<arrow_array::types::Float32Type>().values().to_vec()
}

/// A checkpoint's online weights (actor, critic1, critic2), for comparing runs exactly.
pub fn checkpoint_weights(path: &Path) -> Vec<Vec<f32>> {
    let (agent, _) = pgser::agent::checkpoint::load(path, burn::tensor::Device::flex()).unwrap();
    [&agent.actor, &agent.critics].iter().flat_map(|n| n.tensors()).map(|(_, v)| v).collect()
}

/// `DIR/FILE`: a FetchReach pipeline named `name` on the committed sample pickles (12 expert + 24
/// random episodes), its outputs in `DIR/out`, with `rest` (its [train], [pretrain], … tables).
pub fn sample_pipeline(dir: &Path, file: &str, name: &str, rest: &str) -> PathBuf {
    let data = repo().join("data");
    let toml = format!(
        "name = \"{name}\"\ntask = \"FetchReach\"\nout = \"out\"\n[data]\npickles = [\"{e}\", \"{r}\"]\nepisodes = [12, 24]\n{rest}",
        e = data.join("fetch_reach_expert_50.pkl").display(),
        r = data.join("fetch_reach_random_200.pkl").display(),
    );
    let path = dir.join(file);
    std::fs::write(&path, toml).unwrap();
    path
}

/// `DIR/tiny.toml`: [`sample_pipeline`] with counts small enough for seconds.
pub fn tiny_pipeline(dir: &Path, agent_updates: u64, swaps: usize) -> PathBuf {
    sample_pipeline(dir, "tiny.toml", "tiny", &tiny_settings(agent_updates, swaps))
}

/// The tiny pipeline's tables after `[data]`: [train], [pretrain], [score], [report], [agents].
fn tiny_settings(agent_updates: u64, swaps: usize) -> String {
    format!(
        r#"[train]
batch_size = 64
eval_every = 0
eval_episodes = 4
save_every = 0
log_every = 10
[pretrain]
updates = 40
[score]
swaps = {swaps}
[report]
seed = 1
[agents]
seeds = [0, 1]
updates = {agent_updates}
"#
    )
}

/// Every file under `out` except the step records, by path relative to `out`.
pub fn snapshot(out: &Path) -> std::collections::BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, files: &mut std::collections::BTreeMap<PathBuf, Vec<u8>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                if p.file_name().unwrap() != ".pipeline" {
                    walk(root, &p, files);
                }
            } else {
                files.insert(p.strip_prefix(root).unwrap().to_path_buf(), std::fs::read(&p).unwrap());
            }
        }
    }
    let mut files = std::collections::BTreeMap::new();
    walk(out, out, &mut files);
    files
}

/// The committed FetchReach sample (50 expert + 200 random episodes) as a trajectory table in
/// `dir`, and a scored table of it (2 swaps + the original goal per transition, scored by a
/// critic of 10 updates): real tables as pgser writes them, for readers to be checked on.
pub fn reach_tables(dir: &Path) -> (PathBuf, PathBuf) {
    let table = dir.join("reach.parquet");
    let data = repo().join("data");
    convert_ok(&[&data.join("fetch_reach_expert_50.pkl"), &data.join("fetch_reach_random_200.pkl")], &table, &[]);
    let ckpt = dir.join("reach.ckpt");
    let out = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", table.to_str().unwrap(), "-o", ckpt.to_str().unwrap()])
        .args(["--updates", "10", "--hidden", "32", "--batch-size", "64", "--eval-episodes", "0"])
        .output()
        .unwrap();
    assert!(out.status.success(), "pgser-train failed: {}", text(&out.stderr));
    let scored = dir.join("scored.parquet");
    let out = etl()
        .args(["score", "--q", ckpt.to_str().unwrap(), "--data", table.to_str().unwrap(), "-o"])
        .arg(&scored)
        .args(["--swaps", "2", "--include-original"])
        .output()
        .unwrap();
    assert!(out.status.success(), "score failed: {}", text(&out.stderr));
    (table, scored)
}

/// A metrics file: a loss line, an early evaluation at 0, and the final evaluation `score`.
pub fn metrics_file(dir: &Path, name: &str, score: f64, success: f64) -> PathBuf {
    let p = dir.join(name);
    let eval = |u: u64, s: f64, ok: f64| {
        format!(
            "{{\"updates\":{u},\"eval\":{{\"episodes\":10,\"return_mean\":{},\"return_std\":1.0,\"success_rate\":{ok},\"paper_score\":{s}}}}}",
            s - 50.0
        )
    };
    let text = format!(
        "{{\"updates\":500,\"critic_loss\":0.5,\"q_mean\":-3.0}}\n{}\n{{\"updates\":1500,\"critic_loss\":0.4}}\n{}\n{{\"updates\":2500,\"critic_loss\":0.3}}\n",
        eval(1000, 0.0, 0.0),
        eval(2000, score, success)
    );
    std::fs::write(&p, text).unwrap();
    p
}

pub fn report_run(task: &str, algo: &str, variant: &str, seed: u64, metrics: PathBuf) -> pgser::report::Run {
    pgser::report::Run { task: task.into(), algo: algo.into(), variant: variant.into(), seed, metrics }
}

/// A Table 2 of two tasks written by `report::results` into `dir/results`: FetchPush TD3+BC
/// baseline and mem over 3 seeds (final success 0.1, 0.2, 0.3 and 0.5, 0.6, 0.7), FetchReach TD3
/// mem over 1 seed (success 0.5: std NaN, no p) and TD3+BC baseline over 3 (0.8, 0.9, 1.0).
pub fn results_table(dir: &Path) -> pgser::report::Results {
    /// (task, algo, variant, each seed's final (paper score, success rate)).
    type Cell = (&'static str, &'static str, &'static str, &'static [(f64, f64)]);
    let cells: [Cell; 4] = [
        ("FetchPush", "td3bc", "baseline", &[(10.0, 0.1), (12.0, 0.2), (14.0, 0.3)]),
        ("FetchPush", "td3bc", "mem", &[(30.0, 0.5), (31.0, 0.6), (33.0, 0.7)]),
        ("FetchReach", "td3", "mem", &[(20.0, 0.5)]),
        ("FetchReach", "td3bc", "baseline", &[(40.0, 0.8), (45.0, 0.9), (47.0, 1.0)]),
    ];
    let mut runs = Vec::new();
    for (task, algo, variant, seeds) in cells {
        for (seed, (score, success)) in seeds.iter().enumerate() {
            let m = metrics_file(dir, &format!("{task}_{algo}_{variant}_{seed}.metrics.jsonl"), *score, *success);
            runs.push(report_run(task, algo, variant, seed as u64, m));
        }
    }
    pgser::report::results(&runs, &dir.join("results")).unwrap()
}

/// Step name → status from the JSON report a `pipeline run --json` prints as its last stdout line.
pub fn step_statuses(o: &Output) -> std::collections::BTreeMap<String, String> {
    let out = text(&o.stdout);
    let last = out.lines().last().unwrap_or_else(|| panic!("no report on stdout: {}", text(&o.stderr)));
    let r: serde_json::Value = serde_json::from_str(last).unwrap();
    r["steps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|s| (s["name"].as_str().unwrap().to_string(), s["status"].as_str().unwrap().to_string()))
        .collect()
}

/// `DIR/reach/`: a table folder of three FetchReach shards made from the committed sample
/// pickles — `reach-0.parquet` the first 8 expert episodes, `reach-1.parquet` and
/// `reach-2.parquet` the first 8 and 12 random ones — each converted alone, with the manifest
/// a convert of a folder writes. Its footer lists three sources, so a report's positives default
/// to the first shard's 8 (expert) episodes, as with two pickles.
pub fn reach_folder(dir: &Path) -> PathBuf {
    let data = repo().join("data");
    let folder = dir.join("reach");
    std::fs::create_dir_all(&folder).unwrap();
    let parts =
        [("fetch_reach_expert_50.pkl", 8), ("fetch_reach_random_200.pkl", 8), ("fetch_reach_random_200.pkl", 12)];
    let mut files = Vec::new();
    for (i, (pickle, episodes)) in parts.into_iter().enumerate() {
        let file = format!("reach-{i}.parquet");
        let args = ["--task".to_string(), "FetchReach".into(), "--episodes".into(), episodes.to_string()];
        convert_ok(&[&data.join(pickle)], &folder.join(&file), &args);
        files.push(file);
    }
    pgser::trajectory::folder::Manifest::of_shards(&folder, &files, "tests/common reach_folder", false, None)
        .unwrap()
        .write(&folder)
        .unwrap();
    folder
}

/// `DIR/folder.toml`: the tiny pipeline's settings (2 swaps) over `[data] table` = [`reach_folder`]'s
/// folder, made in `DIR` when absent; outputs in `DIR/out`.
pub fn folder_pipeline(dir: &Path, agent_updates: u64) -> PathBuf {
    if !dir.join("reach/manifest.json").exists() {
        reach_folder(dir);
    }
    let toml = format!(
        "name = \"folder\"\ntask = \"FetchReach\"\nout = \"out\"\n[data]\ntable = \"reach\"\n{}",
        tiny_settings(agent_updates, 2)
    );
    let path = dir.join("folder.toml");
    std::fs::write(&path, toml).unwrap();
    path
}
