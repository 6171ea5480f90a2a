//! Prioritized batches of scored swapped transitions (β_aug, the output of `pgser-etl score`),
//! read from memory or straight from the Parquet file.
//!
//! Only the priorities (a sum tree, 16 bytes per row) and the row-group index stay in memory.
//! Rows are drawn in blocks of `BLOCK_BATCHES` batches: a background thread draws a block's row
//! indices (stratified over the sum tree, seeded by (seed, block)), sorts them, reads each row
//! group that holds any of them once, scatters the rows into the block's batches and hands them
//! to the trainer through a bounded channel. One pass over the file then serves a whole block,
//! so reading keeps ahead of training while memory stays at two blocks, whatever the file size.
//! In memory (`--aug-in-memory`) the same draws are served from arrays, so both modes give the
//! same batches for the same seed.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use anyhow::{Context, Result, bail};
use arrow_array::RecordBatch;
use arrow_array::cast::AsArray;
use arrow_array::types::Float32Type;
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{
    ArrowReaderMetadata, ArrowReaderOptions, ParquetRecordBatchReaderBuilder, RowSelection, RowSelector,
};
use rayon::prelude::*;

use super::priority::{PriorityConfig, SumTree};
use crate::agent::Batch;
use crate::env::rng::NpRandom;
use crate::task::Task;

/// Batches per block: one read of the file serves this many batches.
pub const BLOCK_BATCHES: usize = 256;
/// Spawn key of the prioritized draws (the agent and β's sampler use 1–3).
const STREAM_AUG: u64 = 4;
/// The columns a training row needs, in `Batch` order.
const COLUMNS: [&str; 5] = ["obs", "goal", "action", "reward", "next_obs"];

/// A scored transition table: its footer and the shape of its row groups.
pub struct ScoredTable {
    pub path: PathBuf,
    pub footer: crate::score::Footer,
    pub task: Task,
    pub gamma: f64,
    pub rows: usize,
    /// First row of each row group, plus the total at the end.
    pub group_starts: Vec<usize>,
    /// The Parquet metadata, parsed once: every block reads many row groups, and re-parsing the
    /// footer of a large file per row group would cost as much as the reads.
    metadata: ArrowReaderMetadata,
}

impl ScoredTable {
    pub fn open(path: &Path) -> Result<ScoredTable> {
        let at = path.display();
        let footer = crate::score::read_footer(path)?;
        let file = File::open(path).with_context(|| format!("{at}: cannot open"))?;
        let metadata = ArrowReaderMetadata::load(&file, ArrowReaderOptions::default())
            .with_context(|| format!("{at}: not a Parquet file"))?;
        let mut group_starts = vec![0usize];
        for rg in metadata.metadata().row_groups() {
            group_starts.push(group_starts.last().unwrap() + rg.num_rows() as usize);
        }
        let rows = *group_starts.last().unwrap();
        if rows == 0 {
            bail!("{at}: the table has no rows");
        }
        Ok(ScoredTable {
            path: path.to_path_buf(),
            task: footer.task(),
            gamma: footer.gamma,
            footer,
            rows,
            group_starts,
            metadata,
        })
    }

    /// The trajectory table β this one was made from, and its recorded sha256.
    pub fn trajectory(&self) -> (PathBuf, String) {
        (self.footer.source_table(&self.path), self.footer.source.sha256.clone())
    }

    fn builder(&self) -> Result<ParquetRecordBatchReaderBuilder<File>> {
        let file = File::open(&self.path).with_context(|| format!("{}: cannot open", self.path.display()))?;
        Ok(ParquetRecordBatchReaderBuilder::new_with_metadata(file, self.metadata.clone()))
    }

    /// The `q` column, streamed.
    pub fn read_q(&self) -> Result<Vec<f32>> {
        let b = self.builder()?;
        let mask = ProjectionMask::columns(b.parquet_schema(), ["q"]);
        let mut q: Vec<f32> = Vec::with_capacity(self.rows);
        for batch in b.with_projection(mask).with_batch_size(65_536).build()? {
            let batch = batch.with_context(|| format!("{}: cannot read column q", self.path.display()))?;
            let col = batch.column_by_name("q").with_context(|| format!("{}: no column q", self.path.display()))?;
            let col = col
                .as_primitive_opt::<Float32Type>()
                .with_context(|| format!("{}: q is not float32", self.path.display()))?;
            q.extend(col.values().iter());
        }
        for (i, v) in q.iter().enumerate() {
            if !v.is_finite() {
                bail!("{}: row {i}: q is {v}", self.path.display());
            }
        }
        Ok(q)
    }

    /// The training columns of `rows` (sorted, unique, within row group `rg`), in that order.
    fn read_rows(&self, rg: usize, rows: &[usize]) -> Result<Batch> {
        let b = self.builder()?;
        let mask = ProjectionMask::columns(b.parquet_schema(), COLUMNS);
        let start = self.group_starts[rg];
        let mut selectors = Vec::new();
        let mut at = start;
        for &r in rows {
            if r > at {
                selectors.push(RowSelector::skip(r - at));
            }
            selectors.push(RowSelector::select(1));
            at = r + 1;
        }
        let whole = rows.len() == self.group_starts[rg + 1] - start;
        let mut b = b.with_row_groups(vec![rg]).with_projection(mask).with_batch_size(rows.len().max(1));
        if !whole {
            b = b.with_row_selection(RowSelection::from(selectors));
        }
        let reader = b.build()?;
        let mut out = Batch::default();
        for batch in reader {
            let batch = batch.with_context(|| format!("{}: row group {rg}: read failed", self.path.display()))?;
            append(&self.path, &batch, &mut out)?;
        }
        Ok(out)
    }
}

/// Appends a record batch's training columns to `out` (as f32 slices; the table is float32).
fn append(path: &Path, batch: &RecordBatch, out: &mut Batch) -> Result<()> {
    let floats = |name: &str| -> Result<Vec<f32>> {
        let col = batch.column_by_name(name).with_context(|| format!("{}: no column {name}", path.display()))?;
        let values = match col.as_fixed_size_list_opt() {
            Some(list) => list.values().clone(),
            None => col.clone(),
        };
        let v = values
            .as_primitive_opt::<Float32Type>()
            .with_context(|| format!("{}: column {name} is not float32", path.display()))?;
        Ok(v.values().to_vec())
    };
    out.obs.extend(floats("obs")?);
    out.goal.extend(floats("goal")?);
    out.action.extend(floats("action")?);
    out.reward.extend(floats("reward")?);
    out.next_obs.extend(floats("next_obs")?);
    out.n += batch.num_rows();
    Ok(())
}

/// A batch of prioritized rows with their importance weights (all 1 without `--is-beta`).
pub struct AugBatch {
    pub rows: Vec<usize>,
    pub batch: Batch,
    pub weights: Vec<f32>,
}

/// The prioritized sampler: yields batch after batch of `k` rows.
pub struct ScoredSampler {
    rx: Receiver<Result<AugBatch>>,
    worker: Option<JoinHandle<()>>,
    pub tree: Arc<SumTree>,
}

/// Where rows come from.
enum Rows {
    Memory(Batch),
    Disk(Arc<ScoredTable>),
}

impl ScoredSampler {
    /// Starts drawing batches of `k` rows from batch number `first` on (a resumed run passes
    /// the updates already done, and gets the batches an uninterrupted run would have had).
    pub fn start(
        table: ScoredTable,
        cfg: &PriorityConfig,
        k: usize,
        seed: u64,
        first: u64,
        in_memory: bool,
    ) -> Result<ScoredSampler> {
        let q = table.read_q()?;
        let tree = Arc::new(SumTree::new(&cfg.priorities(&q, table.gamma)));
        drop(q);
        let rows = if in_memory {
            let mut all = Batch::default();
            for rg in 0..table.group_starts.len() - 1 {
                let rows: Vec<usize> = (table.group_starts[rg]..table.group_starts[rg + 1]).collect();
                let part = table.read_rows(rg, &rows)?;
                all.append(&part);
            }
            Rows::Memory(all)
        } else {
            Rows::Disk(Arc::new(table))
        };
        let (tx, rx) = sync_channel(2 * BLOCK_BATCHES);
        let is_beta = cfg.is_beta;
        let t = tree.clone();
        let worker = std::thread::Builder::new()
            .name("pgser-aug-sampler".into())
            .spawn(move || produce(&rows, &t, k, seed, first, is_beta, &tx))
            .context("cannot start the sampler thread")?;
        Ok(ScoredSampler { rx, worker: Some(worker), tree })
    }

    pub fn next_batch(&mut self) -> Result<AugBatch> {
        match self.rx.recv() {
            Ok(b) => b,
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

/// The worker: block after block until the trainer hangs up.
fn produce(
    rows: &Rows,
    tree: &SumTree,
    k: usize,
    seed: u64,
    first: u64,
    is_beta: Option<f64>,
    tx: &SyncSender<Result<AugBatch>>,
) {
    let mut block = first / BLOCK_BATCHES as u64;
    let mut skip = (first % BLOCK_BATCHES as u64) as usize;
    loop {
        let batches = match draw_block(rows, tree, k, seed, block, is_beta) {
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

/// Draws block `block`'s `BLOCK_BATCHES` batches and fetches their rows.
fn draw_block(
    rows: &Rows,
    tree: &SumTree,
    k: usize,
    seed: u64,
    block: u64,
    is_beta: Option<f64>,
) -> Result<Vec<AugBatch>> {
    let mut rng = NpRandom::spawned(seed, &[STREAM_AUG, block]);
    let mut drawn = Vec::with_capacity(BLOCK_BATCHES);
    let mut buf = Vec::new();
    for _ in 0..BLOCK_BATCHES {
        tree.sample(k, &mut rng, &mut buf);
        drawn.push(buf.clone());
    }
    let fetched = match rows {
        Rows::Memory(all) => drawn.iter().map(|rows| gather(all, rows.iter().copied())).collect(),
        Rows::Disk(table) => fetch(table, &drawn)?,
    };
    Ok(drawn
        .into_iter()
        .zip(fetched)
        .map(|(rows, batch)| {
            let weights = match is_beta {
                Some(beta) => tree.is_weights(&rows, beta),
                None => vec![1.0; rows.len()],
            };
            AugBatch { rows, batch, weights }
        })
        .collect())
}

/// Copies rows of `all` (in the given order) into a new batch.
fn gather(all: &Batch, rows: impl Iterator<Item = usize>) -> Batch {
    let (od, gd) = (all.obs.len() / all.n, all.goal.len() / all.n);
    let ad = all.action.len() / all.n;
    let mut b = Batch::default();
    for r in rows {
        b.obs.extend_from_slice(&all.obs[r * od..(r + 1) * od]);
        b.goal.extend_from_slice(&all.goal[r * gd..(r + 1) * gd]);
        b.action.extend_from_slice(&all.action[r * ad..(r + 1) * ad]);
        b.reward.push(all.reward[r]);
        b.next_obs.extend_from_slice(&all.next_obs[r * od..(r + 1) * od]);
        b.n += 1;
    }
    b
}

/// Reads every row a block needs, one pass over the row groups that hold any (in parallel).
fn fetch(table: &ScoredTable, drawn: &[Vec<usize>]) -> Result<Vec<Batch>> {
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
    let parts: Vec<(Vec<usize>, Batch)> = groups
        .into_par_iter()
        .map(|(rg, rows)| table.read_rows(rg, &rows).map(|b| (rows, b)))
        .collect::<Result<_>>()?;
    // The fetched rows, concatenated in row order, and each row's position among them.
    let mut all = Batch::default();
    let mut order = Vec::new();
    for (rows, b) in parts {
        order.extend(rows);
        all.append(&b);
    }
    let position = |r: usize| order.binary_search(&r).expect("every drawn row was fetched");
    Ok(drawn.iter().map(|rows| gather(&all, rows.iter().map(|&r| position(r)))).collect())
}
