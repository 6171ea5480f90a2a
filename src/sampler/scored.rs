//! Prioritized batches of scored swapped transitions (β_aug, the output of `pgser-etl score`),
//! read from memory or straight from the Parquet file.
//!
//! Only the priorities (a sum tree, 4 bytes per row) and the row-group index stay in memory.
//! Rows are drawn in blocks of 256–4096 batches (`block_batches`, larger for larger tables): a
//! background thread draws a block's row indices (stratified over the sum tree, seeded by
//! (seed, block)), sorts them, reads each row group that holds any of them once, and hands the
//! block's batches to the trainer through a bounded channel. One pass over the file then serves
//! a whole block, so reading keeps ahead of training while memory stays at two blocks of keys.
//! In memory (`--aug-in-memory`) the same draws are served from arrays, so both modes give the
//! same batches for the same seed.
//!
//! A row is read as its four keys only — (episode, step) of the transition and (goal_episode,
//! goal_step) of its goal — and rebuilt from the original data β, which the trainer holds in
//! memory anyway: s, a, s′ from the transition, g from the achieved goal it names (its own
//! desired goal when goal_step = −1), r = R(φ(s′), g) with the task's reward. Those are the very
//! values `score` wrote (same float32 casts, same reward function; `tests/mem.rs` checks it),
//! at 24 bytes of integers per row to decode instead of 232 of floats: the disk reads of a
//! block are an order of magnitude cheaper, and `--aug-in-memory` holds 16 bytes a row.

use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use anyhow::{Context, Result, bail};
use rayon::prelude::*;

use super::RowKey;
use super::priority::{PriorityConfig, SumTree};
use crate::agent::Batch;
use crate::nprandom::NpRandom;
use crate::score::ScoredTable;
use crate::trajectory::Episodes;

/// Batches per block, at least: one read of the file serves a block (see `block_batches`).
pub const BLOCK_BATCHES: usize = 256;
/// Batches per block, at most: 4096 × k keys in flight (28 MB at k = 256), two blocks queued.
pub const MAX_BLOCK_BATCHES: usize = 4096;
/// Spawn key of the prioritized draws (the agent and β's sampler use 1–3).
const STREAM_AUG: u64 = 4;

/// The training rows of `keys` (in that order), rebuilt from β.
pub fn gather(beta: &Episodes, keys: impl Iterator<Item = RowKey>) -> Batch {
    super::rows(beta, keys).gather(&super::table(beta))
}

/// A batch of prioritized rows with their importance weights (all 1 without `--is-beta`).
pub struct AugBatch {
    pub rows: Vec<usize>,
    /// Each row's transition and goal in β.
    pub keys: Vec<RowKey>,
    pub batch: Batch,
    pub weights: Vec<f32>,
}

/// What the worker hands over per batch: rows, their keys and weights (28 bytes a row). The
/// trainer's thread rebuilds the rows from β (a few memcpys), so a block in flight costs its
/// keys, not its floats.
struct Drawn {
    rows: Vec<usize>,
    keys: Vec<RowKey>,
    weights: Vec<f32>,
}

/// The prioritized sampler: yields batch after batch of `k` rows.
pub struct ScoredSampler {
    rx: Receiver<Result<Drawn>>,
    worker: Option<JoinHandle<()>>,
    beta: Arc<Episodes>,
    pub tree: Arc<SumTree>,
    /// Batches per block for this table and batch size.
    pub block_batches: usize,
}

/// Where row keys come from.
enum Rows {
    Memory(Vec<RowKey>),
    Disk(Box<ScoredTable>),
}

/// Batches per block: one pass over the file's row groups serves a block, so a large table
/// gets large blocks (draws ≈ rows / 8, between `BLOCK_BATCHES` and `MAX_BLOCK_BATCHES`
/// batches). On 82M rows, 256-batch blocks re-read the whole key columns every 65k draws.
pub fn block_batches(rows: usize, k: usize) -> usize {
    (rows / (8 * k.max(1))).clamp(BLOCK_BATCHES, MAX_BLOCK_BATCHES)
}

impl ScoredSampler {
    /// Starts drawing batches of `k` rows from batch number `first` on (a resumed run passes
    /// the updates already done, and gets the batches an uninterrupted run would have had).
    pub fn start(
        table: ScoredTable,
        beta: Arc<Episodes>,
        cfg: &PriorityConfig,
        k: usize,
        seed: u64,
        first: u64,
        in_memory: bool,
    ) -> Result<ScoredSampler> {
        table.check_whole()?;
        let q = table.read_q()?;
        let tree = Arc::new(SumTree::new(
            cfg.priorities(q, table.gamma).with_context(|| format!("{}", table.path.display()))?,
        ));
        let per_block = block_batches(table.rows, k);
        let rows = if in_memory { Rows::Memory(table.read_keys(&beta)?) } else { Rows::Disk(Box::new(table)) };
        let (tx, rx) = sync_channel(2 * per_block);
        let is_beta = cfg.is_beta;
        let t = tree.clone();
        let b = beta.clone();
        let draw = Draw { tree: t, k, seed, per_block, is_beta };
        let worker = std::thread::Builder::new()
            .name("pgser-aug-sampler".into())
            .spawn(move || produce(&rows, &b, &draw, first, &tx))
            .context("cannot start the sampler thread")?;
        Ok(ScoredSampler { rx, worker: Some(worker), beta, tree, block_batches: per_block })
    }

    pub fn next_batch(&mut self) -> Result<AugBatch> {
        let (rows, keys, weights) = self.next_keys()?;
        let batch = gather(&self.beta, keys.iter().copied());
        Ok(AugBatch { batch, keys, rows, weights })
    }

    /// The next batch as its scored rows, their keys in β and their weights, not yet gathered.
    pub fn next_keys(&mut self) -> Result<(Vec<usize>, Vec<RowKey>, Vec<f32>)> {
        match self.rx.recv() {
            Ok(d) => d.map(|d| (d.rows, d.keys, d.weights)),
            Err(_) => bail!("the prioritized sampler stopped"),
        }
    }
}

impl Drop for ScoredSampler {
    fn drop(&mut self) {
        // Closing the channel makes the worker's next send fail, which ends it.
        let (_, dead) = sync_channel(0);
        self.rx = dead;
        if let Some(w) = self.worker.take() {
            let _ = w.join();
        }
    }
}

/// How blocks are drawn.
struct Draw {
    tree: Arc<SumTree>,
    k: usize,
    seed: u64,
    per_block: usize,
    is_beta: Option<f64>,
}

/// The worker: block after block until the trainer hangs up.
fn produce(rows: &Rows, beta: &Episodes, d: &Draw, first: u64, tx: &SyncSender<Result<Drawn>>) {
    let per_block = d.per_block as u64;
    let (mut block, mut skip) = (first / per_block, (first % per_block) as usize);
    loop {
        let batches = match draw_block(rows, beta, d, block) {
            Ok(b) => b,
            Err(e) => {
                let _ = tx.send(Err(e));
                return;
            }
        };
        for b in batches.into_iter().skip(skip) {
            if tx.send(Ok(b)).is_err() {
                return;
            }
        }
        skip = 0;
        block += 1;
    }
}

/// Draws block `block`'s batches (from the stream of (seed, block)) and fetches their keys.
fn draw_block(rows: &Rows, beta: &Episodes, d: &Draw, block: u64) -> Result<Vec<Drawn>> {
    let mut rng = NpRandom::spawned(d.seed, &[STREAM_AUG, block]);
    let mut drawn = Vec::with_capacity(d.per_block);
    let mut buf = Vec::new();
    for _ in 0..d.per_block {
        d.tree.sample(d.k, &mut rng, &mut buf);
        drawn.push(buf.clone());
    }
    let keys: Vec<Vec<RowKey>> = match rows {
        Rows::Memory(all) => drawn.iter().map(|rows| rows.iter().map(|&r| all[r]).collect()).collect(),
        Rows::Disk(table) => fetch(table, beta, &drawn)?,
    };
    Ok(drawn
        .into_iter()
        .zip(keys)
        .map(|(rows, keys)| {
            let weights = match d.is_beta {
                Some(beta) => d.tree.is_weights(&rows, beta),
                None => vec![1.0; rows.len()],
            };
            Drawn { rows, keys, weights }
        })
        .collect())
}

/// The pool the samplers' threads read row groups on, as many threads as the global pool. Not
/// the global pool itself: the trainer draws its batches there (`next_batch` inside a
/// `par_iter_mut`) and blocks until this sampler delivers. A global worker waiting inside a
/// fetch's join may pick up such a blocking draw, and then never returns to finish the fetch
/// the draw waits for: a hang, seen in tests/mem.rs once the update itself used the pool more.
fn fetch_pool() -> &'static rayon::ThreadPool {
    static POOL: std::sync::OnceLock<rayon::ThreadPool> = std::sync::OnceLock::new();
    POOL.get_or_init(|| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(rayon::current_num_threads())
            .thread_name(|i| format!("pgser-fetch-{i}"))
            .build()
            .expect("the samplers' thread pool starts")
    })
}

/// Reads the keys of every row a block needs, one pass over the row groups that hold any (in
/// parallel), and returns them batch by batch.
fn fetch(table: &ScoredTable, beta: &Episodes, drawn: &[Vec<usize>]) -> Result<Vec<Vec<RowKey>>> {
    let mut wanted: Vec<usize> = drawn.iter().flatten().copied().collect();
    wanted.sort_unstable();
    wanted.dedup();
    // Row groups and the wanted rows in each.
    let mut groups: Vec<(usize, Vec<usize>)> = Vec::new();
    for r in wanted {
        let rg = table.group_starts.partition_point(|&s| s <= r) - 1;
        match groups.last_mut() {
            Some((g, rows)) if *g == rg => rows.push(r),
            _ => groups.push((rg, vec![r])),
        }
    }
    let parts: Vec<(Vec<usize>, Vec<RowKey>)> = fetch_pool().install(|| {
        groups
            .into_par_iter()
            .map(|(rg, rows)| table.read_rows(rg, &rows, beta).map(|k| (rows, k)))
            .collect::<Result<_>>()
    })?;
    // The fetched rows' keys in row order, and each row's position among them.
    let mut keys = Vec::new();
    let mut order = Vec::new();
    for (rows, k) in parts {
        order.extend(rows);
        keys.extend(k);
    }
    let key = |r: usize| keys[order.binary_search(&r).expect("every drawn row was fetched")];
    Ok(drawn.iter().map(|rows| rows.iter().map(|&r| key(r)).collect()).collect())
}
