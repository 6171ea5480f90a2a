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

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use anyhow::{Context, Result, bail};
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int32Type, Int64Type};
use arrow_array::{Array, RecordBatch};
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{
    ArrowReaderMetadata, ArrowReaderOptions, ParquetRecordBatchReaderBuilder, RowSelection, RowSelector,
};
use rayon::prelude::*;

use super::RowKey;
use super::priority::{PriorityConfig, SumTree};
use crate::agent::Batch;
use crate::nprandom::NpRandom;
use crate::task::Task;
use crate::trajectory::Episodes;

/// Batches per block, at least: one read of the file serves a block (see `block_batches`).
pub const BLOCK_BATCHES: usize = 256;
/// Batches per block, at most: 4096 × k keys in flight (28 MB at k = 256), two blocks queued.
pub const MAX_BLOCK_BATCHES: usize = 4096;
/// Spawn key of the prioritized draws (the agent and β's sampler use 1–3).
const STREAM_AUG: u64 = 4;
/// The columns that name a row's transition and goal.
const COLUMNS: [&str; 4] = ["episode", "step", "goal_episode", "goal_step"];

/// The scored rows of a block of β ([`ScoredTable::read_goals`]): each row's stored goal, its q,
/// and (when asked for) its goal's table-wide (episode, step).
pub struct BlockGoals {
    pub goal: Vec<f32>,
    pub q: Vec<f32>,
    pub at: Vec<[u32; 2]>,
}

/// A scored transition table (one file, or a scored folder's shards as one table): its footer and
/// the shape of its row groups.
pub struct ScoredTable {
    /// The file or the scored folder.
    pub path: PathBuf,
    pub footer: crate::score::Footer,
    pub task: Task,
    pub gamma: f64,
    pub rows: usize,
    /// First row of each row group (numbered across the files), plus the total at the end.
    pub group_starts: Vec<usize>,
    /// The files in order, with their parsed metadata.
    files: Vec<ScoredFile>,
    /// Row group → (file, its row group within the file).
    group_at: Vec<(u32, u32)>,
    /// The trajectory table the rows were made from.
    source: PathBuf,
}

/// One file of a scored table. The Parquet metadata is parsed once: every block reads many row
/// groups, and re-parsing the footer of a large file per row group would cost as much as the reads.
struct ScoredFile {
    path: PathBuf,
    metadata: ArrowReaderMetadata,
    /// The table's number of the file's first row.
    first_row: usize,
    /// Its chunks' checksums: each reader checks the chunks it reads, when it reads them.
    verifier: crate::table::Verifier,
}

/// The columns the in-memory samplers read from every row (q, and the keys that name each
/// row's transition and goal): [`ScoredTable::check_whole`] checks them.
const WHOLE: [&str; 5] = ["q", "episode", "step", "goal_episode", "goal_step"];

impl ScoredTable {
    /// The scored table at `path` (a file whose footer says so, or a scored folder), or None when
    /// `path` is something else (a trajectory table or folder, left to its own reader).
    pub fn open_if_scored(path: &Path) -> Result<Option<ScoredTable>> {
        match crate::table::read_footer(path) {
            Ok(f) if f["kind"] == crate::score::KIND => Ok(Some(ScoredTable::open(path)?)),
            _ if crate::score::folder::is_scored_folder(path) => Ok(Some(ScoredTable::open(path)?)),
            _ => Ok(None),
        }
    }

    /// Opens a scored file, or a scored folder (`score::folder`) as the one table of its shards.
    pub fn open(path: &Path) -> Result<ScoredTable> {
        let (footer, paths, source) = if crate::score::folder::is_scored_folder(path) {
            let folder = crate::score::folder::ScoredFolder::open(path)?;
            let source = folder.source_table();
            (folder.manifest.footer.clone(), folder.shard_paths(), source)
        } else {
            let footer = crate::score::read_footer(path)?;
            let source = footer.source_table(path);
            (footer, vec![path.to_path_buf()], source)
        };
        let mut group_starts = vec![0usize];
        let mut files = Vec::with_capacity(paths.len());
        let mut group_at = Vec::new();
        for (i, p) in paths.into_iter().enumerate() {
            let at = p.display();
            let first_row = *group_starts.last().unwrap();
            let file = crate::output::open_input(&p)?;
            let metadata = ArrowReaderMetadata::load(&file, ArrowReaderOptions::default())
                .with_context(|| format!("{at}: not a Parquet file"))?;
            for (g, rg) in metadata.metadata().row_groups().iter().enumerate() {
                let Ok(n) = usize::try_from(rg.num_rows()) else {
                    bail!("{at}: row group {g} has a negative row count: the file is corrupt");
                };
                group_starts.push(group_starts.last().unwrap() + n);
                group_at.push((i as u32, g as u32));
            }
            // Nothing table-wide is read here: a pool reads a block's rows at a time and checks
            // them then (`read_goals`); the samplers that hold the table check it first
            // (`check_whole`).
            let verifier = crate::table::Verifier::new(&p, metadata.metadata())?;
            files.push(ScoredFile { path: p, metadata, first_row, verifier });
        }
        let rows = *group_starts.last().unwrap();
        if rows == 0 {
            bail!("{}: the table has no rows", path.display());
        }
        if rows != footer.rows {
            bail!("{}: {rows} rows where the footer says {}", path.display(), footer.rows);
        }
        Ok(ScoredTable {
            path: path.to_path_buf(),
            task: footer.task(),
            gamma: footer.gamma,
            footer,
            rows,
            group_starts,
            files,
            group_at,
            source,
        })
    }

    /// Checks the chunks of every row group's columns that the in-memory samplers read (q and
    /// the keys), in parallel: what a sampler that holds the whole table calls before reading it.
    pub fn check_whole(&self) -> Result<()> {
        for f in &self.files {
            f.verifier.check(&f.verifier.columns_of(&WHOLE))?;
        }
        Ok(())
    }

    /// The trajectory table β this one was made from, and its recorded sha256.
    pub fn trajectory(&self) -> (PathBuf, String) {
        (self.source.clone(), self.footer.source.sha256.clone())
    }

    fn builder(&self, file: &ScoredFile) -> Result<ParquetRecordBatchReaderBuilder<File>> {
        let f = File::open(&file.path).with_context(|| format!("{}: cannot open", file.path.display()))?;
        Ok(ParquetRecordBatchReaderBuilder::new_with_metadata(f, file.metadata.clone()))
    }

    /// The `q` column, streamed, file after file.
    pub fn read_q(&self) -> Result<Vec<f32>> {
        let mut q: Vec<f32> = Vec::with_capacity(self.rows);
        for file in &self.files {
            let at = file.path.display();
            let b = self.builder(file)?;
            let mask = ProjectionMask::columns(b.parquet_schema(), ["q"]);
            let before = q.len();
            for batch in b.with_projection(mask).with_batch_size(65_536).build()? {
                let batch = batch.with_context(|| format!("{at}: cannot read column q"))?;
                let col = batch.column_by_name("q").with_context(|| format!("{at}: no column q"))?;
                let col = col.as_primitive_opt::<Float32Type>().with_context(|| format!("{at}: q is not float32"))?;
                q.extend(col.values().iter());
            }
            for (i, v) in q[before..].iter().enumerate() {
                if !v.is_finite() {
                    bail!("{at}: row {i}: q is {v}");
                }
            }
        }
        Ok(q)
    }

    /// The stored goals and q of rows `r0..r1`, which must be the scored rows of whole episodes
    /// from table-wide episode `first_episode` on, `per` rows per transition of T = `t`, in order:
    /// what the out-of-core pool holds beside a block of β (`pool.rs`). Every row's episode and step
    /// are checked against that, so a scored table that is not the block's is refused, naming the
    /// file and row. With `sources`, each row's goal (episode, step) is kept too (OGBench's layout
    /// reports where a goal came from); a row that keeps its transition's own desired goal
    /// (`goal_step` −1) is then refused, as it names no observation.
    pub fn read_goals(
        &self,
        (r0, r1): (usize, usize),
        first_episode: u64,
        t: usize,
        per: usize,
        sources: bool,
    ) -> Result<BlockGoals> {
        let gd = self.task.goal_dim;
        let (mut goal, mut q) = (Vec::with_capacity((r1 - r0) * gd), Vec::with_capacity(r1 - r0));
        let mut goal_at: Vec<[u32; 2]> = Vec::with_capacity(if sources { r1 - r0 } else { 0 });
        let names: &[&str] = if sources {
            &["episode", "step", "goal", "q", "goal_episode", "goal_step"]
        } else {
            &["episode", "step", "goal", "q"]
        };
        let first = self.group_starts.partition_point(|&s| s <= r0) - 1;
        let mut row = r0;
        for rg in first..self.group_starts.len() - 1 {
            let (start, end) = (self.group_starts[rg], self.group_starts[rg + 1]);
            if start >= r1 {
                break;
            }
            let (f, local) = self.group_at[rg];
            let file = &self.files[f as usize];
            let at = format!("{} (row group {local})", file.path.display());
            let (a, b) = (row - start, r1.min(end) - start);
            // Every column read (the stored goal too, which the pool trains on), on this thread:
            // the pool's loader calls this and must not wait on the global pool.
            file.verifier.check_row_groups_here(&[local as usize], &file.verifier.columns_of(names))?;
            let builder = self.builder(file)?;
            let mask = ProjectionMask::columns(builder.parquet_schema(), names.iter().copied());
            let mut selectors = Vec::new();
            if a > 0 {
                selectors.push(RowSelector::skip(a));
            }
            selectors.push(RowSelector::select(b - a));
            let reader = builder
                .with_row_groups(vec![local as usize])
                .with_projection(mask)
                .with_row_selection(RowSelection::from(selectors))
                .with_batch_size(65_536)
                .build()
                .with_context(|| format!("{at}: cannot read"))?;
            for batch in reader {
                let batch =
                    batch.with_context(|| format!("{at}: cannot read the rows after row {}", row - file.first_row))?;
                let col = |name: &str| batch.column_by_name(name).with_context(|| format!("{at}: no column {name}"));
                let (Some(ep), Some(st), Some(qs)) = (
                    col("episode")?.as_primitive_opt::<Int64Type>(),
                    col("step")?.as_primitive_opt::<Int32Type>(),
                    col("q")?.as_primitive_opt::<Float32Type>(),
                ) else {
                    bail!("{at}: episode must be int64, step int32 and q float32");
                };
                for i in 0..batch.num_rows() {
                    let k = row + i - r0;
                    let want = (first_episode + (k / ((t - 1) * per)) as u64, (k / per) % (t - 1));
                    let (e, s, v) = (ep.value(i), st.value(i), qs.value(i));
                    if (e, s as i64) != (want.0 as i64, want.1 as i64) || !v.is_finite() {
                        bail!(
                            "{}: row {}: (episode {e}, step {s}, q {v}) where its original data's block holds episode {} step \
                             {} here with a finite q: the scored table does not match its original data",
                            file.path.display(),
                            row + i - file.first_row,
                            want.0,
                            want.1
                        );
                    }
                }
                let list = col("goal")?.as_fixed_size_list_opt().filter(|l| l.value_length() as usize == gd);
                let values = list.and_then(|l| l.values().as_primitive_opt::<Float32Type>());
                let Some(values) = values.filter(|v| v.null_count() == 0) else {
                    bail!("{at}: `goal` must be {gd} non-null float32 values per row");
                };
                let vals = &values.values()[list.expect("checked").value_offset_at(0)..][..batch.num_rows() * gd];
                if let Some(j) = vals.iter().position(|v| !v.is_finite()) {
                    bail!(
                        "{}: row {}: `goal`[{}] is {}",
                        file.path.display(),
                        row + j / gd - file.first_row,
                        j % gd,
                        vals[j]
                    );
                }
                if sources {
                    let (Some(ge), Some(gs)) = (
                        col("goal_episode")?.as_primitive_opt::<Int64Type>(),
                        col("goal_step")?.as_primitive_opt::<Int32Type>(),
                    ) else {
                        bail!("{at}: goal_episode must be int64 and goal_step int32");
                    };
                    for i in 0..batch.num_rows() {
                        let (e, s) = (ge.value(i), gs.value(i));
                        if !(0..=u32::MAX as i64).contains(&e) || !(0..t as i32).contains(&s) {
                            bail!(
                                "{}: row {}: goal (episode {e}, step {s}) is no observation of its original data{}",
                                file.path.display(),
                                row + i - file.first_row,
                                if s == -1 {
                                    " (the row keeps its transition's own desired goal: --include-original)"
                                } else {
                                    ""
                                }
                            );
                        }
                        goal_at.push([e as u32, s as u32]);
                    }
                }
                goal.extend_from_slice(vals);
                q.extend_from_slice(qs.values());
                row += batch.num_rows();
            }
        }
        if row != r1 {
            bail!(
                "{}: rows {row}..{r1} are missing: the table ends before its original data does",
                self.path.display()
            );
        }
        Ok(BlockGoals { goal, q, at: goal_at })
    }

    /// Every row's keys, in order (16 bytes a row), checked against β's shape.
    pub fn read_keys(&self, beta: &Episodes) -> Result<Vec<RowKey>> {
        let mut all = Vec::with_capacity(self.rows);
        for rg in 0..self.group_starts.len() - 1 {
            let rows: Vec<usize> = (self.group_starts[rg]..self.group_starts[rg + 1]).collect();
            all.extend(self.read_rows(rg, &rows, beta)?);
        }
        Ok(all)
    }

    /// The keys of `rows` (sorted, unique, within row group `rg`), in that order, checked
    /// against β's shape so a row can never index outside it.
    fn read_rows(&self, rg: usize, rows: &[usize], beta: &Episodes) -> Result<Vec<RowKey>> {
        let (f, local) = self.group_at[rg];
        let file = &self.files[f as usize];
        let b = self.builder(file)?;
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
        let mut b = b.with_row_groups(vec![local as usize]).with_projection(mask).with_batch_size(rows.len().max(1));
        if !whole {
            b = b.with_row_selection(RowSelection::from(selectors));
        }
        let reader = b.build()?;
        let mut out = Vec::with_capacity(rows.len());
        for batch in reader {
            let batch = batch.with_context(|| format!("{}: row group {local}: read failed", file.path.display()))?;
            append_keys(&file.path, &batch, beta, rows, file.first_row, &mut out)?;
        }
        Ok(out)
    }
}

/// Appends a record batch's row keys to `out`; `rows` are the table rows being read, of the file
/// whose first row is the table's `first_row` (for errors, which name the file's row).
fn append_keys(
    path: &Path,
    batch: &RecordBatch,
    beta: &Episodes,
    rows: &[usize],
    first_row: usize,
    out: &mut Vec<RowKey>,
) -> Result<()> {
    let at = path.display();
    let col = |name: &str| batch.column_by_name(name).with_context(|| format!("{at}: no column {name}"));
    let (ep, st) = (col("episode")?.as_primitive_opt::<Int64Type>(), col("step")?.as_primitive_opt::<Int32Type>());
    let (gep, gst) =
        (col("goal_episode")?.as_primitive_opt::<Int64Type>(), col("goal_step")?.as_primitive_opt::<Int32Type>());
    let (Some(ep), Some(st), Some(gep), Some(gst)) = (ep, st, gep, gst) else {
        bail!("{at}: episode/goal_episode must be int64 and step/goal_step int32");
    };
    for i in 0..batch.num_rows() {
        let (e, s, ge, gs) = (ep.value(i), st.value(i), gep.value(i), gst.value(i));
        let ok = (0..beta.n as i64).contains(&e)
            && (0..beta.t as i32 - 1).contains(&s)
            && (0..beta.n as i64).contains(&ge)
            && (-1..beta.t as i32).contains(&gs);
        if !ok {
            let row = rows.get(out.len()).copied().unwrap_or_default().saturating_sub(first_row);
            bail!(
                "{at}: row {row}: (episode {e}, step {s}, goal_episode {ge}, goal_step {gs}) is outside its original data ({} episodes of {} steps)",
                beta.n,
                beta.t
            );
        }
        out.push(RowKey { episode: e as u32, step: s as u32, goal_episode: ge as u32, goal_step: gs });
    }
    Ok(())
}

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
