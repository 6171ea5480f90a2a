//! The `-mem` variant end to end: pre-train Q with random swapping, score swapped transitions,
//! train on the scored table with prioritized sampling (from disk and from memory).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;

use common::*;
use pgser::sampler::priority::PriorityConfig;
use pgser::sampler::scored::{BLOCK_BATCHES, ScoredSampler};
use pgser::score::ScoredTable;

fn train(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_pgser-train")).args(args).output().unwrap();
    assert!(out.status.success(), "pgser-train {args:?}:\n{}", text(&out.stderr));
    text(&out.stdout)
}

/// The FetchReach sample as a table, a Q pre-trained on it with random swapping, and the
/// table of 2 scored swaps per transition plus the transition with its own goal: made once for
/// all tests here.
fn scored() -> &'static (tempfile::TempDir, PathBuf, PathBuf) {
    static S: OnceLock<(tempfile::TempDir, PathBuf, PathBuf)> = OnceLock::new();
    S.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let traj = dir.path().join("reach.parquet");
        let data = repo().join("data");
        convert_ok(&[&data.join("fetch_reach_expert_50.pkl"), &data.join("fetch_reach_random_200.pkl")], &traj, &[]);
        let q = dir.path().join("q.ckpt");
        train(&[
            "--data",
            traj.to_str().unwrap(),
            "-o",
            q.to_str().unwrap(),
            "--swap",
            "random",
            "--updates",
            "300",
            "--batch-size",
            "256",
            "--eval-episodes",
            "0",
            "--seed",
            "2",
        ]);
        let scored = dir.path().join("scored.parquet");
        let out = etl()
            .args(["score", "--q", q.to_str().unwrap(), "--data", traj.to_str().unwrap(), "-o"])
            .arg(&scored)
            .args(["--swaps", "2", "--seed", "3", "--include-original"])
            .output()
            .unwrap();
        assert!(out.status.success(), "score: {}", text(&out.stderr));
        (dir, traj, scored)
    })
}

#[test]
fn the_mem_agent_learns_fetch_reach() {
    let (dir, _, scored) = scored();
    let ckpt = dir.path().join("mem.ckpt");
    let out = train(&[
        "--data",
        scored.to_str().unwrap(),
        "-o",
        ckpt.to_str().unwrap(),
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
    let ret = summary["eval"]["return_mean"].as_f64().unwrap();
    assert!(ret > -30.0, "mem agent return {ret}");
}

fn short(scored: &Path, ckpt: &Path, updates: &str, extra: &[&str]) {
    let mut args = vec![
        "--data",
        scored.to_str().unwrap(),
        "-o",
        ckpt.to_str().unwrap(),
        "--updates",
        updates,
        "--batch-size",
        "32",
        "--hidden",
        "16",
        "--eval-episodes",
        "0",
        "--seed",
        "9",
    ];
    args.extend_from_slice(extra);
    train(&args);
}

#[test]
fn disk_and_memory_sampling_train_the_same_agent_and_resume_exactly() {
    let (dir, _, scored) = scored();
    let d = dir.path();
    // Past one block, so the resumed run starts inside the second block.
    let n = (BLOCK_BATCHES + 40).to_string();
    let (disk, mem, split) = (d.join("disk.ckpt"), d.join("inmem.ckpt"), d.join("split.ckpt"));
    short(scored, &disk, &n, &["--is-beta", "0.4"]);
    short(scored, &mem, &n, &["--is-beta", "0.4", "--aug-in-memory"]);
    assert_eq!(checkpoint_weights(&disk), checkpoint_weights(&mem));
    short(scored, &split, &(BLOCK_BATCHES + 7).to_string(), &["--is-beta", "0.4"]);
    short(scored, &split, &n, &["--is-beta", "0.4", "--resume"]);
    assert_eq!(checkpoint_weights(&disk), checkpoint_weights(&split));
}

#[test]
fn disk_batches_hold_the_rows_they_name() {
    let (_, _, scored) = scored();
    let cfg = PriorityConfig { is_beta: Some(1.0), ..PriorityConfig::default() };
    let table = ScoredTable::open(scored).unwrap();
    let beta = std::sync::Arc::new(pgser::sampler::open::beta_of(&table).unwrap());
    let mut disk = ScoredSampler::start(table, beta, &cfg, 64, 5, 0, false).unwrap();
    // Batch row i must equal table row rows[i].
    let (t, _) = read_table(scored);
    let obs = t.column_by_name("obs").unwrap();
    let obs = arrow_array::cast::AsArray::as_fixed_size_list(obs);
    let list = |name: &str| arrow_array::cast::AsArray::as_fixed_size_list(t.column_by_name(name).unwrap()).clone();
    let (goal, action, next_obs) = (list("goal"), list("action"), list("next_obs"));
    let reward = arrow_array::cast::AsArray::as_primitive::<arrow_array::types::Float32Type>(
        t.column_by_name("reward").unwrap(),
    )
    .clone();
    let f32s = |a: &arrow_array::ArrayRef| {
        arrow_array::cast::AsArray::as_primitive::<arrow_array::types::Float32Type>(a).values().to_vec()
    };
    let goal_step = arrow_array::cast::AsArray::as_primitive::<arrow_array::types::Int32Type>(
        t.column_by_name("goal_step").unwrap(),
    )
    .clone();
    let mut originals = 0;
    let tree = disk.tree.clone();
    for _ in 0..3 {
        let b = disk.next_batch().unwrap();
        assert_eq!(b.rows.len(), 64);
        for (i, &r) in b.rows.iter().enumerate() {
            assert_eq!(&b.batch.obs[i * 10..(i + 1) * 10], &f32s(&obs.value(r))[..], "row {r}");
            // Rebuilt from β by the row's keys: equal to what `score` wrote, bit for bit.
            assert_eq!(&b.batch.goal[i * 3..(i + 1) * 3], &f32s(&goal.value(r))[..], "row {r}");
            assert_eq!(&b.batch.action[i * 4..(i + 1) * 4], &f32s(&action.value(r))[..], "row {r}");
            assert_eq!(&b.batch.next_obs[i * 10..(i + 1) * 10], &f32s(&next_obs.value(r))[..], "row {r}");
            assert_eq!(b.batch.reward[i].to_bits(), reward.value(r).to_bits(), "row {r}");
            originals += (goal_step.value(r) == -1) as usize;
            // IS weights: (N·P(i))^−1 / max, with max at the least likely row.
            assert!(b.weights[i] > 0.0 && b.weights[i] <= 1.0);
            assert!((b.weights[i] as f64 - tree.is_weights(&[r], 1.0)[0] as f64).abs() < 1e-6);
        }
    }
    assert!(originals > 0, "no row with its own desired goal was drawn");
}

#[test]
fn a_scored_table_with_changed_original_data_is_refused() {
    let (dir, traj, scored) = scored();
    // A copy of the scored table beside a different "reach.parquet".
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::copy(scored, other.join("scored.parquet")).unwrap();
    let rel = pgser::table::read_footer(scored).unwrap()["source"]["path"].as_str().unwrap().to_string();
    let fake = other.join(&rel);
    std::fs::create_dir_all(fake.parent().unwrap()).unwrap();
    if fake.canonicalize().ok() != traj.canonicalize().ok() {
        let out = etl()
            .args(["collect", "--task", "FetchReach", "--policy", "random", "--episodes", "2", "--seed", "0", "-o"])
            .arg(&fake)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", text(&out.stderr));
        let out = Command::new(env!("CARGO_BIN_EXE_pgser-train"))
            .args(["--data", other.join("scored.parquet").to_str().unwrap(), "-o"])
            .arg(other.join("x.ckpt"))
            .args(["--updates", "2", "--eval-episodes", "0"])
            .output()
            .unwrap();
        assert!(!out.status.success());
        let err = text(&out.stderr);
        assert!(err.contains("has changed since scoring"), "{err}");
        assert!(!other.join("x.ckpt").exists());
    }
}

/// Training settings from `pgser-train` flag names, as a pipeline file gives them.
fn config(toml: &str) -> pgser::train::TrainConfig {
    let table: toml::Table = toml.parse().unwrap();
    pgser::pipeline::train_config(&[&table]).unwrap()
}

#[test]
fn a_stack_of_cells_writes_what_each_cell_writes_alone_and_resumes_exactly() {
    // Three cells of a grid — baseline (seed 0), random swapping (seed 1), prioritized -mem with IS
    // weights (seed 2) — trained as one stack, first to 20 updates then continued to 40 (what a
    // batched pipeline step does after a crash), against each trained alone to 40 at once.
    let (_, traj, scored) = scored();
    let dir = tempfile::tempdir().unwrap();
    let shared = "batch_size = 64\nhidden = 32\nlayers = 2\neval_every = 20\neval_episodes = 3\nsave_every = 10\nlog_every = 5\n";
    let cells = |updates: u64, dir: &Path, resume: bool| {
        [
            (traj, "seed = 0\nswap = \"none\""),
            (traj, "seed = 1\nswap = \"random\""),
            (scored, "seed = 2\nis_beta = 0.4"),
        ]
        .iter()
        .enumerate()
        .map(|(i, (data, own))| pgser::train::Cell {
            data: data.to_path_buf(),
            out: dir.join(format!("c{i}.ckpt")),
            cfg: config(&format!("{shared}updates = {updates}\n{own}")),
            resume,
        })
        .collect::<Vec<_>>()
    };
    let commands: Vec<String> = (0..3).map(|i| format!("cell {i}")).collect();
    let bar = indicatif::ProgressBar::hidden();
    let device = || pgser::agent::Backend::Cpu;
    let stacked = dir.path().join("stack");
    let alone = dir.path().join("alone");
    std::fs::create_dir_all(&stacked).unwrap();
    std::fs::create_dir_all(&alone).unwrap();
    pgser::train::train_stack(&cells(20, &stacked, false), device(), &commands, &bar).unwrap();
    let done = pgser::train::train_stack(&cells(40, &stacked, true), device(), &commands, &bar).unwrap();
    assert!(done.iter().all(|s| s.updates == 40 && s.eval.is_some()));
    for (i, cell) in cells(40, &alone, false).into_iter().enumerate() {
        pgser::train::train(&cell.data, &cell.out, &cell.cfg, false, device(), &commands[i], &bar).unwrap();
    }
    for i in 0..3 {
        for ext in ["", ".resume", ".metrics.jsonl"] {
            let f = format!("c{i}.ckpt{ext}");
            let (a, b) = (std::fs::read(stacked.join(&f)).unwrap(), std::fs::read(alone.join(&f)).unwrap());
            assert!(
                a == b,
                "{f}: the stacked cell differs from the cell trained alone:\n{}\nvs\n{}",
                String::from_utf8_lossy(&a),
                String::from_utf8_lossy(&b)
            );
        }
    }
    // The cells' agents really differ (own seeds and data), and each was evaluated.
    assert_ne!(std::fs::read(stacked.join("c0.ckpt")).unwrap(), std::fs::read(stacked.join("c1.ckpt")).unwrap());
    let metrics = std::fs::read_to_string(stacked.join("c2.ckpt.metrics.jsonl")).unwrap();
    assert_eq!(metrics.matches("\"eval\"").count(), 2, "{metrics}");

    // Cells that cannot share a stack are refused in one line naming the cell.
    let mut bad = cells(40, &dir.path().join("bad"), false);
    bad[1].cfg.batch_size = 32;
    let err = pgser::train::train_stack(&bad, device(), &commands, &bar).unwrap_err().to_string();
    assert!(err.contains("c1.ckpt") && err.contains("share"), "{err}");
}
