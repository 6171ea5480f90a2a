//! Helpers shared by the integration tests: the binaries, the test venv's Python, manifests,
//! the tiny pipeline, a single-node Slurm (`slurm.rs`).
#![allow(dead_code)]

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

/// A checkpoint's online weights (actor, critic1, critic2), for comparing runs exactly.
pub fn checkpoint_weights(path: &Path) -> Vec<Vec<f32>> {
    let (agent, _) = pgser::agent::checkpoint::load(path, burn::tensor::Device::flex()).unwrap();
    [&agent.actor, &agent.critics].iter().flat_map(|n| n.tensors()).map(|(_, v)| v).collect()
}

/// `DIR/tiny.toml`: FetchReach from the committed sample pickles, with counts small enough for
/// seconds; its outputs go to `DIR/out`.
pub fn tiny_pipeline(dir: &Path, agent_updates: u64, swaps: usize) -> PathBuf {
    let data = repo().join("data");
    let toml = format!(
        r#"
name = "tiny"
task = "FetchReach"
out = "out"
[data]
pickles = ["{e}", "{r}"]
episodes = [12, 24]
[train]
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
"#,
        e = data.join("fetch_reach_expert_50.pkl").display(),
        r = data.join("fetch_reach_random_200.pkl").display(),
    );
    let path = dir.join("tiny.toml");
    std::fs::write(&path, toml).unwrap();
    path
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
