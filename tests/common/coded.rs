//! A coded table folder for the out-of-core pool's tests (`tests/pool.rs`, `tests/pool_mem.rs`):
//! every observation and achieved goal of the folder's episode e, step s is e·1000 + s, so every
//! value in a batch says which row it came from. The folder has four shards of unequal size cut
//! into row groups of 5 episodes (96 blocks), and `BUDGET` holds 6 of them, so at any time 30 of
//! the 480 episodes are resident.

use std::path::{Path, PathBuf};

use pgser::task::Task;
use pgser::trajectory::folder::Manifest;
use pgser::trajectory::{Episodes, FloatType, Footer};

pub const SHARDS: [usize; 4] = [120, 75, 180, 105];
pub const EPISODES: usize = 480;
/// FetchReach's T.
pub const T: usize = 50;
pub const GROUP_EPISODES: usize = 5;
/// Holds 6 blocks of 5 episodes beside the reservoir and the blocks in flight (pool.rs `Plan`).
pub const BUDGET: u64 = 240_000;
pub const BATCH: usize = 98;
/// One pass: as many draws as the table has transitions.
pub const PASS_BATCHES: usize = EPISODES * (T - 1) / BATCH;

/// The coded folder, written once per test into `dir`.
pub fn folder(dir: &Path) -> PathBuf {
    folder_of(dir, &Task::known("FetchReach").unwrap())
}

/// A PointMaze-shaped task (T = 50) whose goals are its whole observations (2 values), as
/// OGBench's PointMaze's are.
pub fn point_task() -> Task {
    Task {
        name: "pointmaze-medium-navigate-v0".into(),
        t: T,
        obs_dim: 2,
        goal_dim: 2,
        act_dim: 2,
        threshold: 1.0,
        metric: pgser::task::GoalMetric::Euclidean,
    }
}

/// The coded folder of `task`'s shapes (T must be [`T`]), written into `dir`.
pub fn folder_of(dir: &Path, task: &Task) -> PathBuf {
    let out = dir.join("coded");
    std::fs::create_dir_all(&out).unwrap();
    let mut first = 0;
    let mut files = Vec::new();
    for (i, &n) in SHARDS.iter().enumerate() {
        // Desired goals are never reached (−1), so rewards say nothing here; the values do.
        let d = coded_of(task, first, n);
        let file = format!("coded-{i}.parquet");
        let footer = Footer::new(&d.task, FloatType::Float32, n, "test".into());
        pgser::sampler::replay::stage_table(&d, &out.join(&file), GROUP_EPISODES * T, &footer)
            .unwrap()
            .commit()
            .unwrap();
        files.push(file);
        first += n;
    }
    Manifest::of_shards(&out, &files, "test", false, None).unwrap().write(&out).unwrap();
    out
}

/// FetchReach-shaped episodes whose observations and achieved goals of (episode e, step s) are
/// (first + e)·1000 + s, actions that over 10⁵, and desired goals −1 (never reached).
pub fn coded(first: usize, n: usize) -> Episodes {
    coded_of(&Task::known("FetchReach").unwrap(), first, n)
}

/// [`coded`] episodes of `task`'s shapes.
pub fn coded_of(task: &Task, first: usize, n: usize) -> Episodes {
    let task = task.clone();
    let code = |e: usize, s: usize| ((first + e) * 1000 + s) as f32;
    let (mut obs, mut ag, mut g, mut u) = (vec![], vec![], vec![], vec![]);
    for e in 0..n {
        for s in 0..T {
            obs.extend(std::iter::repeat_n(code(e, s), task.obs_dim));
            ag.extend(std::iter::repeat_n(code(e, s), task.goal_dim));
            if s + 1 < T {
                g.extend(std::iter::repeat_n(-1.0, task.goal_dim));
                u.extend(std::iter::repeat_n(code(e, s) / 1e5, task.act_dim));
            }
        }
    }
    let footer = Footer::new(&task, FloatType::Float32, n, "test".into());
    Episodes { footer, task, n, t: T, obs, ag, g, u, images: Vec::new() }
}

/// The shard holding the folder's episode `e`.
pub fn shard_of(e: usize) -> usize {
    let mut end = 0;
    SHARDS
        .iter()
        .position(|&n| {
            end += n;
            e < end
        })
        .unwrap()
}

/// (episode, step) a coded value names.
pub fn decode(v: f32) -> (usize, usize) {
    let v = v as usize;
    (v / 1000, v % 1000)
}

/// Pearson's statistic of `counts` against equal expectation, and the bound a uniform draw
/// exceeds with probability about 1e-4 (Wilson–Hilferty).
pub fn chi_square(counts: &[u64]) -> (f64, f64) {
    let total: u64 = counts.iter().sum();
    let e = total as f64 / counts.len() as f64;
    let stat = counts.iter().map(|&c| (c as f64 - e).powi(2) / e).sum();
    let k = (counts.len() - 1) as f64;
    let z = 3.72;
    let bound = k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3);
    (stat, bound)
}

/// Shares of shards in `episodes` against their shares of rows: the largest gap, in points.
pub fn worst_share_gap(episodes: impl Iterator<Item = usize>) -> f64 {
    let mut counts = [0u64; 4];
    for e in episodes {
        counts[shard_of(e)] += 1;
    }
    let total: u64 = counts.iter().sum();
    (0..4)
        .map(|i| (100.0 * counts[i] as f64 / total as f64 - 100.0 * SHARDS[i] as f64 / EPISODES as f64).abs())
        .fold(0.0, f64::max)
}

/// A critic trained for a few updates on table (or folder) `data`, written to `dir/q.ckpt`.
pub fn critic(dir: &Path, data: &Path) -> PathBuf {
    let q = dir.join("q.ckpt");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .arg("--data")
        .arg(data)
        .arg("-o")
        .arg(&q)
        .args(["--updates", "30", "--batch-size", "98", "--hidden", "16", "--eval-episodes", "0", "--swap", "random"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", super::text(&o.stderr));
    q
}

/// `score`'s options: `swaps` goals per transition, no original goals, CPU.
pub fn score_options(
    data: &Path,
    q: &Path,
    out: &Path,
    (swaps, seed): (usize, u64),
    threads: usize,
    shard: Option<usize>,
) -> pgser::score::ScoreOptions {
    pgser::score::ScoreOptions {
        checkpoint: q.to_path_buf(),
        data: data.to_path_buf(),
        output: out.to_path_buf(),
        swaps,
        seed,
        include_original: false,
        device: pgser::agent::Backend::Cpu,
        chunk_episodes: None,
        goal_sample: None,
        threads,
        shard,
        command: "test".into(),
    }
}

/// Flips bits `mask` of the byte in the middle of the chunk of the first column whose path
/// starts with `leaf` ("action", "goal.") in the last row group of `file`; returns that row group.
pub fn flip_in_last_chunk(file: &Path, leaf: &str, mask: u8) -> usize {
    use parquet::file::reader::{FileReader, SerializedFileReader};
    let reader = SerializedFileReader::new(std::fs::File::open(file).unwrap()).unwrap();
    let last = reader.metadata().num_row_groups() - 1;
    let rg = reader.metadata().row_group(last);
    let chunk = rg.columns().iter().find(|c| c.column_path().string().starts_with(leaf)).expect("such a column");
    let (start, len) = chunk.byte_range();
    let mut bytes = std::fs::read(file).unwrap();
    bytes[(start + len / 2) as usize] ^= mask;
    std::fs::write(file, &bytes).unwrap();
    last
}

/// The first error of `data` within `budget`: at opening, or in the first `batches` batches.
pub fn first_failure(
    data: &Path,
    cfg: &pgser::sampler::stream::StreamConfig,
    budget: pgser::sampler::view::Budget,
    batches: usize,
) -> String {
    use pgser::sampler::stream::BatchSource;
    let e = match BatchSource::open_within(data, cfg, budget) {
        Err(e) => e,
        Ok(src) => {
            let mut s = src.start(cfg).unwrap();
            (0..batches).find_map(|_| s.next_batch().err()).expect("the fault is met")
        }
    };
    format!("{e:#}")
}
