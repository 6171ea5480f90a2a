//! `pgser-etl score` (PGSER Alg. 2, step 2): materialize goal-swapped transitions of a
//! trajectory table and score each with the pre-trained critic, w = min(Q1, Q2)(s, g, a), into a
//! transition table (docs/tables.md) that the final trainer samples by priority.
//!
//! Streaming, in parallel, reproducibly:
//! - the achieved goals of the whole table (the swap pool, goal_dim floats per row) are read
//!   first; everything else streams in blocks ("chunks") of `--chunk-episodes` whole episodes;
//! - a window of 2 × threads chunks is swapped and scored in parallel (rayon), and their record
//!   batches are written, one row group per chunk, in chunk order, so memory is bounded by the
//!   window, not the input;
//! - chunk c draws its goals from `NpRandom::spawned(seed, [STREAM_SWAP, c])`, never from a
//!   thread's identity, so the file's bytes depend on (inputs, seed, chunk size) and on the
//!   backend that runs the critic, never on the thread count.

pub mod folder;
mod read;
mod stats;
mod table;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::mpsc::sync_channel;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use arrow_array::{ArrayRef, Float32Array, Int32Array, Int64Array, RecordBatch};
use arrow_schema::{DataType, Field, Schema, SchemaRef};
use indicatif::ProgressBar;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::agent::{Agent, Backend, checkpoint};
use crate::nprandom::NpRandom;
use crate::output::{check_not_an_input, relative_to_folder_of};
use crate::swap::{self, GoalPool, SwappedRows};
use crate::table::{SCHEMA_VERSION, TableWriter, f32_vectors};
use crate::task::{GoalMetric, Task};
use crate::trajectory::{self, Episodes, FloatType, vector_field};

pub use stats::{BINS, Histogram, QStats, merged};
pub use table::{BlockGoals, RowKey, ScoredTable};

/// Footer `kind` of a transition table.
pub const KIND: &str = "transition";
/// `--swaps` default. Four swapped goals per transition make the scored table 4× the original
/// transitions (≈ 490k rows for the paper's 2500-episode datasets): several candidate goals per
/// transition for the priority sampler to choose among, at a few hundred MB at most.
pub const DEFAULT_SWAPS: usize = 4;
/// Target output rows per chunk when `--chunk-episodes` is not given: the chunk is the unit of
/// parallel work and of output row groups, and its rows (episodes × (T − 1) × (K + originals))
/// are what scoring holds in memory and what the prioritized sampler decodes per row group, so
/// it is sized in rows, not episodes: with K = 280 swaps a fixed 64 episodes made 880k-row
/// chunks and 2 GB of memory. 12,544 rows = 64 episodes × 49 × 4 swaps, the size that was
/// fastest for K = 4 (larger chunks measured 6 % slower and 60 MB heavier).
pub const CHUNK_ROWS: usize = 12_544;
/// Rows per critic call. On burn's flex CPU backend 2048 was the fastest batch for FetchPush
/// dims (≈ 320k rows/s; 4096 halves it: the activations fall out of cache), docs/domain.md.
pub const Q_BATCH: usize = 2048;
/// Spawn key of the swap streams under `--seed` (chunk c uses `[STREAM_SWAP, c]`).
const STREAM_SWAP: u64 = 0x5357_4150; // "SWAP"

/// The transition table's columns (docs/tables.md); vectors are float32 with non-null items.
pub fn schema(task: &Task) -> SchemaRef {
    let f = FloatType::Float32;
    Arc::new(Schema::new(vec![
        Field::new("episode", DataType::Int64, false),
        Field::new("step", DataType::Int32, false),
        Field::new("goal_episode", DataType::Int64, false),
        Field::new("goal_step", DataType::Int32, false),
        vector_field("obs", f, task.obs_dim, false),
        vector_field("action", f, task.act_dim, false),
        vector_field("next_obs", f, task.obs_dim, false),
        vector_field("next_achieved_goal", f, task.goal_dim, false),
        vector_field("goal", f, task.goal_dim, false),
        Field::new("reward", DataType::Float32, false),
        Field::new("q", DataType::Float32, false),
    ]))
}

/// An input file: its path relative to the transition table's folder, and its sha256.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FileRef {
    pub path: String,
    pub sha256: String,
}

/// The `pgser` footer of a transition table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Footer {
    pub schema_version: u32,
    pub kind: String,
    pub task: String,
    #[serde(rename = "T")]
    pub t: usize,
    pub obs_dim: usize,
    pub goal_dim: usize,
    pub act_dim: usize,
    pub goal_metric: GoalMetric,
    pub success_threshold: f64,
    pub float_type: FloatType,
    /// Episodes of the source table (of its shard, in a scored folder's shard); `transitions` =
    /// episodes × (T − 1).
    pub episodes: usize,
    pub transitions: usize,
    /// transitions × (swaps + include_original).
    pub rows: usize,
    /// The trajectory table (original data β) the transitions come from.
    pub source: FileRef,
    pub checkpoint: FileRef,
    /// The checkpoint's discount γ; the histogram spans [−1/(1−γ), 0].
    pub gamma: f64,
    pub seed: u64,
    pub swaps: usize,
    pub include_original: bool,
    pub chunk_episodes: usize,
    /// `--goal-sample K`: goals came from K achieved goals drawn uniformly from the whole table
    /// (absent: from every achieved goal).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub goal_sample: Option<usize>,
    pub q: QStats,
    /// Set in a scored folder's shards (`folder.rs`): which shard of the table folder this one
    /// scored. Its `episodes`, `transitions` and `rows` are then the shard's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<folder::ShardOf>,
    pub command: String,
    pub pgser_version: String,
}

impl Footer {
    pub fn task(&self) -> Task {
        Task {
            name: self.task.clone(),
            t: self.t,
            obs_dim: self.obs_dim,
            goal_dim: self.goal_dim,
            act_dim: self.act_dim,
            threshold: self.success_threshold,
            metric: self.goal_metric,
        }
    }

    /// Where the source trajectory table of the transition table at `scored` is.
    pub fn source_table(&self, scored: &Path) -> PathBuf {
        resolve(scored, &self.source.path)
    }

    /// Where the checkpoint that scored the transition table at `scored` is.
    pub fn checkpoint_file(&self, scored: &Path) -> PathBuf {
        resolve(scored, &self.checkpoint.path)
    }
}

/// A footer path, relative to the folder of the table at `table` (absolute ones stay).
fn resolve(table: &Path, recorded: &str) -> PathBuf {
    let p = Path::new(recorded);
    match table.parent() {
        Some(dir) if p.is_relative() => dir.join(p),
        _ => p.to_path_buf(),
    }
}

/// The footer of a transition table, refusing other tables in one line.
pub fn read_footer(path: &Path) -> Result<Footer> {
    let at = path.display();
    let json = crate::table::read_footer(path)?;
    match json.get("kind").and_then(|k| k.as_str()) {
        Some(KIND) => {}
        Some(kind) => bail!("{at}: a {kind} table, not a transition table from `pgser-etl score`"),
        None => bail!("{at}: the footer names no table kind; a transition table from `pgser-etl score` is expected"),
    }
    let f: Footer = serde_json::from_value(json).with_context(|| format!("{at}: malformed transition footer"))?;
    if f.schema_version != SCHEMA_VERSION {
        bail!("{at}: table schema version {}; this pgser reads version {SCHEMA_VERSION}", f.schema_version);
    }
    Ok(f)
}

#[derive(Debug, Clone)]
pub struct ScoreOptions {
    pub checkpoint: PathBuf,
    pub data: PathBuf,
    pub output: PathBuf,
    pub swaps: usize,
    pub seed: u64,
    pub include_original: bool,
    pub device: Backend,
    /// None: as many episodes as fit `CHUNK_ROWS` rows (at least one).
    pub chunk_episodes: Option<usize>,
    /// Worker threads; 0: rayon's default (`RAYON_NUM_THREADS`, else one per core).
    pub threads: usize,
    /// Draw goals from this many achieved goals, sampled uniformly from the whole table, instead of
    /// holding every one: bounds memory at K × goal_dim floats (None: every achieved goal).
    pub goal_sample: Option<usize>,
    /// With a table folder scored into a scored folder: score only this shard (one array task of
    /// a cluster job) and leave the manifest to a run without it (`folder.rs`).
    pub shard: Option<usize>,
    pub command: String,
}

/// What `score` reports (`--json` prints it).
#[derive(Debug, Clone, Serialize)]
pub struct ScoreSummary {
    pub output: PathBuf,
    pub episodes: usize,
    pub transitions: usize,
    pub rows: usize,
    pub swaps: usize,
    pub include_original: bool,
    /// `--goal-sample K`: goals drawn from K achieved goals (absent: from every one).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub goal_sample: Option<usize>,
    pub q_min: f64,
    pub q_mean: f64,
    pub q_max: f64,
    pub bytes: u64,
    pub threads: usize,
    pub seconds: f64,
    pub rows_per_sec: f64,
}

/// Swap and score a trajectory table into a transition table; the output appears whole or not
/// at all.
pub fn score(o: &ScoreOptions, bar: &ProgressBar) -> Result<ScoreSummary> {
    if o.threads == 0 {
        return run(o, bar);
    }
    let pool = rayon::ThreadPoolBuilder::new().num_threads(o.threads).build().context("cannot start threads")?;
    pool.install(|| run(o, bar))
}

fn run(o: &ScoreOptions, bar: &ProgressBar) -> Result<ScoreSummary> {
    let start = Instant::now();
    if o.swaps == 0 && !o.include_original {
        bail!("{}: --swaps 0 without --include-original leaves no rows to write", o.output.display());
    }
    if o.chunk_episodes == Some(0) {
        bail!("--chunk-episodes must be at least 1");
    }
    if o.goal_sample == Some(0) {
        bail!("--goal-sample must be at least 1");
    }
    check_not_an_input(&o.output, &[o.data.clone(), o.checkpoint.clone()])?;
    if folder::scores_into_a_folder(o) {
        return folder::score(o, bar, start);
    }
    if let Some(i) = o.shard {
        bail!(
            "{}: --shard {i} scores one shard of a table folder into a scored folder; give a table folder as --data \
             and an output without .parquet",
            o.output.display()
        );
    }
    let job = Job::open(o)?;
    bar.set_length(job.transitions() as u64);
    let mut writer = TableWriter::create(&o.output, job.schema.clone())?;
    let blocks = read::Blocks::open(&o.data, job.chunk_episodes, o.include_original)?;
    let (rows, q) = job.score_blocks(blocks, &[STREAM_SWAP], &mut writer, bar)?;
    assert_eq!(rows, job.transitions() * job.per, "every transition was scored");
    let footer = job.footer(job.table.episodes, rows, q.finish(), &o.output)?;
    let bytes = writer.finish(&serde_json::to_value(&footer)?)?;
    Ok(job.summary(&footer, bytes, rows, start))
}

/// What scoring a table needs besides its rows: the critic, the task, the goal pool of the whole
/// table and the layout of the output. Shared by a single output file and a scored folder's shards.
struct Job<'a> {
    o: &'a ScoreOptions,
    table: trajectory::Footer,
    agent: Agent,
    task: Task,
    pool: GoalPool,
    /// Output rows per transition: swaps, plus its own goal with `include_original`.
    per: usize,
    chunk_episodes: usize,
    schema: SchemaRef,
    /// The source and checkpoint as every output of this job records them. Its outputs share one
    /// folder (a file's, or the scored folder), so these are computed once: each is a hash, and
    /// a table folder's digest opens every shard's footer, which per shard of a 1000-shard folder
    /// would read a million footers.
    refs: std::sync::OnceLock<(FileRef, FileRef)>,
}

impl<'a> Job<'a> {
    fn open(o: &'a ScoreOptions) -> Result<Job<'a>> {
        let table = read::footer(&o.data)?;
        let (agent, _) = checkpoint::load(&o.checkpoint, o.device.device()?)?;
        check_compatible(&agent.task, &o.checkpoint, &table, &o.data)?;
        let task = table.task();
        let pool = read::goal_pool(&o.data, &table, o.goal_sample.map(|k| (k, o.seed)))?;
        let per = o.swaps + o.include_original as usize;
        let chunk_episodes = o.chunk_episodes.unwrap_or((CHUNK_ROWS / ((table.t - 1) * per).max(1)).max(1));
        let schema = schema(&task);
        Ok(Job { o, table, agent, task, pool, per, chunk_episodes, schema, refs: std::sync::OnceLock::new() })
    }

    /// Transitions of the whole input table.
    fn transitions(&self) -> usize {
        self.table.episodes * (self.table.t - 1)
    }

    /// Swaps and scores `blocks` into `writer`, a window of 2 × threads chunks at a time, chunk
    /// `c` drawing from the stream spawned from (seed, `key`…, c). Returns the rows written and
    /// their q statistics.
    fn score_blocks(
        &self,
        blocks: impl Iterator<Item = Result<(usize, Episodes)>> + Send,
        key: &[u64],
        writer: &mut TableWriter,
        bar: &ProgressBar,
    ) -> Result<(usize, stats::QAccumulator)> {
        let window = 2 * rayon::current_num_threads();
        let mut q = stats::QAccumulator::new(self.agent.config.gamma);
        let mut rows = 0;
        std::thread::scope(|s| -> Result<()> {
            // The reader runs ahead by one window, overlapping decoding with scoring.
            let (tx, rx) = sync_channel(window);
            let reader = s.spawn(move || {
                for (index, block) in blocks.enumerate() {
                    if tx.send(block.map(|(first, b)| (index, first, b))).is_err() {
                        break;
                    }
                }
            });
            let scored = (|| -> Result<()> {
                loop {
                    let mut pending = Vec::with_capacity(window);
                    while pending.len() < window {
                        match rx.recv() {
                            Ok(block) => pending.push(block?),
                            Err(_) => break,
                        }
                    }
                    if pending.is_empty() {
                        return Ok(());
                    }
                    let scored: Vec<(RecordBatch, stats::QAccumulator)> = pending
                        .par_iter()
                        .map(|(index, first, block)| {
                            let key: Vec<u64> = key.iter().copied().chain([*index as u64]).collect();
                            self.score_block(&key, *first, block)
                        })
                        .collect::<Result<_>>()?;
                    let (batches, accumulators): (Vec<_>, Vec<_>) = scored.into_iter().unzip();
                    accumulators.iter().for_each(|a| q.merge(a));
                    let n: usize = batches.iter().map(|b| b.num_rows()).sum();
                    writer.write_row_groups(&batches)?;
                    rows += n;
                    crate::progress::advance(bar, (n / self.per) as u64)?;
                }
            })();
            // Joined on every path, errors included: the scope waits for the reader's closure but
            // not for its OS thread, which would still be exiting after score returned (the leak
            // LeakSanitizer found in convert's hashing thread). Dropping the receiver first ends a
            // reader blocked on a full window.
            drop(rx);
            if let Err(panic) = reader.join() {
                std::panic::resume_unwind(panic);
            }
            scored
        })?;
        Ok((rows, q))
    }

    /// Swap, score and lay out one chunk (episodes `first ..` of the table), drawing its goals
    /// from the stream spawned from (seed, `key`).
    fn score_block(&self, key: &[u64], first: usize, block: &Episodes) -> Result<(RecordBatch, stats::QAccumulator)> {
        let (o, task) = (self.o, &self.task);
        let mut rng = NpRandom::spawned(o.seed, key);
        let rows = swap::swap_block(block, first, &self.pool, task, o.swaps, o.include_original, &mut rng);
        let q = critic_scores(&self.agent, task, &rows);
        if let Some(i) = q.iter().position(|v| !v.is_finite()) {
            bail!(
                "{}: the critic gives Q = {} for episode {} step {} with the goal of episode {} step {}; the checkpoint \
                 is damaged",
                o.checkpoint.display(),
                q[i],
                rows.episode[i],
                rows.step[i],
                rows.goal_episode[i],
                rows.goal_step[i]
            );
        }
        let mut acc = stats::QAccumulator::new(self.agent.config.gamma);
        acc.add(&q);
        Ok((record_batch(&self.schema, task, rows, q)?, acc))
    }

    /// The footer of an output at `output` holding `rows` rows of `episodes` episodes.
    fn footer(&self, episodes: usize, rows: usize, q: QStats, output: &Path) -> Result<Footer> {
        let (o, task) = (self.o, &self.task);
        if self.refs.get().is_none() {
            let _ = self.refs.set((file_ref(&o.data, output)?, file_ref(&o.checkpoint, output)?));
        }
        let (source, checkpoint) = self.refs.get().cloned().expect("set above");
        Ok(Footer {
            schema_version: SCHEMA_VERSION,
            kind: KIND.to_string(),
            task: task.name.clone(),
            t: task.t,
            obs_dim: task.obs_dim,
            goal_dim: task.goal_dim,
            act_dim: task.act_dim,
            goal_metric: task.metric,
            success_threshold: task.threshold,
            float_type: FloatType::Float32,
            episodes,
            transitions: episodes * (task.t - 1),
            rows,
            source,
            checkpoint,
            gamma: self.agent.config.gamma,
            seed: o.seed,
            swaps: o.swaps,
            include_original: o.include_original,
            chunk_episodes: self.chunk_episodes,
            goal_sample: o.goal_sample,
            q,
            shard: None,
            command: o.command.clone(),
            pgser_version: env!("CARGO_PKG_VERSION").to_string(),
        })
    }

    fn summary(&self, f: &Footer, bytes: u64, scored_rows: usize, start: Instant) -> ScoreSummary {
        let seconds = start.elapsed().as_secs_f64();
        ScoreSummary {
            output: self.o.output.clone(),
            episodes: f.episodes,
            transitions: f.transitions,
            rows: f.rows,
            swaps: f.swaps,
            include_original: f.include_original,
            goal_sample: f.goal_sample,
            q_min: f.q.min,
            q_mean: f.q.mean,
            q_max: f.q.max,
            bytes,
            threads: rayon::current_num_threads(),
            seconds,
            rows_per_sec: scored_rows as f64 / seconds,
        }
    }
}

/// The checkpoint must have been trained for the table's task: same name, T and dimensions.
fn check_compatible(ckpt: &Task, ckpt_path: &Path, table: &trajectory::Footer, data: &Path) -> Result<()> {
    let t = table.task();
    let shape = |k: &Task| format!("{} (T {}, obs {}, goal {}, act {})", k.name, k.t, k.obs_dim, k.goal_dim, k.act_dim);
    if (&ckpt.name, ckpt.t, ckpt.obs_dim, ckpt.goal_dim, ckpt.act_dim)
        != (&t.name, t.t, t.obs_dim, t.goal_dim, t.act_dim)
    {
        bail!(
            "{}: the checkpoint is for {} but {} holds {}; score a table with a critic trained on the same task",
            ckpt_path.display(),
            shape(ckpt),
            data.display(),
            shape(&t)
        );
    }
    Ok(())
}

fn file_ref(input: &Path, output: &Path) -> Result<FileRef> {
    Ok(FileRef {
        path: relative_to_folder_of(input, output)?.display().to_string(),
        sha256: crate::trajectory::folder::digest(input)?,
    })
}

/// min(Q1, Q2) of every row, [`Q_BATCH`] rows per critic call (no autodiff, no per-row tensor).
fn critic_scores(agent: &Agent, task: &Task, r: &SwappedRows) -> Vec<f32> {
    let (od, gd, ad) = (task.obs_dim, task.goal_dim, task.act_dim);
    let mut q = Vec::with_capacity(r.n);
    for s in (0..r.n).step_by(Q_BATCH) {
        let m = (r.n - s).min(Q_BATCH);
        q.extend(agent.q(&r.obs[s * od..][..m * od], &r.goal[s * gd..][..m * gd], &r.action[s * ad..][..m * ad], m));
    }
    q
}

/// The rows as Arrow columns, moving the vectors without copying them.
fn record_batch(schema: &SchemaRef, task: &Task, r: SwappedRows, q: Vec<f32>) -> Result<RecordBatch> {
    let columns: Vec<ArrayRef> = vec![
        Arc::new(Int64Array::from(r.episode)),
        Arc::new(Int32Array::from(r.step)),
        Arc::new(Int64Array::from(r.goal_episode)),
        Arc::new(Int32Array::from(r.goal_step)),
        f32_vectors(r.obs, task.obs_dim)?,
        f32_vectors(r.action, task.act_dim)?,
        f32_vectors(r.next_obs, task.obs_dim)?,
        f32_vectors(r.next_achieved_goal, task.goal_dim)?,
        f32_vectors(r.goal, task.goal_dim)?,
        Arc::new(Float32Array::from(r.reward)),
        Arc::new(Float32Array::from(q)),
    ];
    Ok(RecordBatch::try_new(schema.clone(), columns)?)
}
