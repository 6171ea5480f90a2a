//! The out-of-core pool: β drawn from a table (one file or a folder of shards) larger than the
//! memory it may use, with every transition and every random goal coming from the whole table.
//!
//! # Why, and the scheme it replaces
//! OGBench's 100M–1B datasets do not fit a workstation's memory. Horizon Reduction's trainer keeps
//! one shard in memory, reloads another synchronously every 1000 updates, and draws every goal,
//! the random ones too, from that shard alone: for 1000 updates the agent sees a thousandth of the
//! data, and its training stops while the next shard loads.
//!
//! # The scheme
//! - **Blocks.** A block is one Parquet row group: pgser's writers cut row groups on episode
//!   boundaries, so a block is a run of whole episodes of one shard, and HER's future goals are
//!   always in memory with their transition.
//! - **Resident blocks.** The pool holds `S` blocks, as many as the budget allows (see
//!   [`Plan`]). Every transition is drawn uniformly from the episodes resident at the time.
//! - **A loader thread** reads blocks in a random permutation of all the table's blocks (a fresh
//!   one each pass, seeded), checks each against its checksums, decodes it to float32 and hands it
//!   over through a channel of one. The pool swaps it in for its oldest block **when as many
//!   transitions have been drawn as the leaving block holds** (times `draws_per_row`). So one pass
//!   of draws (as many as the table holds) is one pass of loading, in which every block is
//!   resident once for about the same number of draws: the long-run share of each shard, episode
//!   and step is its share of the table. The swap points depend on the draws alone, never on the
//!   loader's timing, so the same seed gives the same batches at any speed; the loader reads
//!   ahead while the current blocks are drawn from, and a batch waits only when reading a block
//!   takes longer than drawing the previous block's transitions (counted in [`PoolStats`]).
//!   Every pass starts with the same first blocks ([`permutation`] says why), which makes each
//!   pass of draws give every block exactly its share of turns.
//! - **Random goals** (`--swap random`, OGBench's `p_randomgoal`) come from a **reservoir** of
//!   achieved goals and observations, refreshed from every block as it enters: a block of `r`
//!   observations replaces `R · r / N` reservoir entries (oldest first, the fraction carried
//!   between blocks), drawn uniformly from its observations. After one pass the reservoir holds a
//!   uniform sample of the whole table's observations, from every shard in proportion to its rows,
//!   far more spread than the resident blocks. It is first filled the same way from every block
//!   (one read of the observation and achieved-goal columns at start), so it is a sample of the
//!   whole table from the first batch on.
//!
//! # How it differs from drawing in memory
//! In memory, each row's transition and random goal are uniform over the whole table, every row
//! independently. In the pool they are uniform over the resident episodes and the reservoir, which
//! change as the passes go: marginally the same distribution over a pass, but rows of one batch
//! share a smaller set of episodes (rows in one batch fall in the same episode about `N / P` times
//! as often as uniform draws do, for P resident episodes of N; tests/pool.rs bounds it), and the
//! random numbers are used differently, so batches are not those of the in-memory sampler. When
//! the whole table fits the budget, [`open`] holds it in memory and the batches are the in-memory
//! ones, number for number.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{Receiver, sync_channel};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow, bail};
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{ArrowReaderMetadata, ArrowReaderOptions, ParquetRecordBatchReaderBuilder};
use rayon::prelude::*;

use super::view::{GoalSource, InMemory, View};
use crate::nprandom::NpRandom;
use crate::task::Task;
use crate::trajectory::folder::{TableFolder, is_folder, shard_footer};
use crate::trajectory::read::{append, check_keys};
use crate::trajectory::{Episodes, Footer};

/// Spawn keys of the pool's generators: the loader's permutations (with the pass number) and the
/// reservoir's draws. The batch streams use 1–4 and OGBench's layout its own.
const KEY_PERMUTATION: u64 = 5;
const KEY_RESERVOIR: u64 = 6;
/// The share of the budget the goal reservoir may take.
const RESERVOIR_SHARE: f64 = 0.125;
/// Blocks held beyond the resident ones: one waiting in the channel, and one being decoded (its
/// Arrow arrays and its float32 copy side by side).
const IN_FLIGHT: u64 = 3;
/// The columns a block reads.
const VECTORS: [&str; 4] = ["obs", "achieved_goal", "desired_goal", "action"];

/// Options of a pool besides its budget.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoolConfig {
    /// Memory the pool may use, in bytes.
    pub budget: u64,
    /// Transitions drawn per transition loaded: 1 makes a pass of draws a pass of loading; 2
    /// keeps each block twice as long (half the reading, for samplers faster than the disk).
    pub draws_per_row: f64,
    pub seed: u64,
}

/// Opens `path` within `budget` bytes: the whole table in memory when it fits (the in-memory
/// sampler's batches, number for number), the pool otherwise.
pub fn open(path: &Path, budget: u64, seed: u64) -> Result<Box<dyn View>> {
    Ok(match Beta::open(path, budget, seed)? {
        Beta::Whole(data) => Box::new(InMemory(data)),
        Beta::Pool(pool) => pool,
    })
}

/// β for a sampler within a budget: whole, or a pool.
pub enum Beta {
    Whole(Arc<Episodes>),
    Pool(Box<Pool>),
}

impl Beta {
    /// β as draws see it.
    pub fn view(&self) -> &dyn View {
        match self {
            Beta::Whole(d) => d.as_ref(),
            Beta::Pool(p) => p.as_ref(),
        }
    }

    /// The arrays a trainer fits its normalizer on (observations; desired and achieved goals):
    /// the whole table, or the pool's first blocks, a uniform sample of the table's blocks.
    pub fn normalizer_arrays(&self) -> (Vec<&[f32]>, Vec<&[f32]>) {
        match self {
            Beta::Whole(d) => (vec![&d.obs[..]], vec![&d.g[..], &d.ag[..]]),
            Beta::Pool(p) => {
                let (obs, g, ag) = p.resident_arrays();
                (obs, g.into_iter().chain(ag).collect())
            }
        }
    }

    /// Plans `path` against `budget` and opens it.
    pub fn open(path: &Path, budget: u64, seed: u64) -> Result<Beta> {
        let cfg = PoolConfig { budget, draws_per_row: 1.0, seed };
        let layout = Layout::open(path)?;
        Ok(match Plan::of(&layout, budget)? {
            Plan::Whole => Beta::Whole(Arc::new(Episodes::load(path)?)),
            Plan::Pool { slots, reservoir } => {
                Beta::Pool(Box::new(Pool::start(Arc::new(layout), cfg, slots, reservoir, (0, 0))?))
            }
        })
    }
}

/// Bytes of a table held whole (what [`Layout::bytes`] plans with).
pub fn bytes_of(data: &Episodes) -> u64 {
    4 * (data.obs.len() + data.ag.len() + data.g.len() + data.u.len()) as u64
}

/// One shard of the table, as the pool reads it.
struct Shard {
    path: PathBuf,
    /// The shard's own footer (its own rows and episodes): what `check_keys` checks rows against.
    footer: Footer,
    meta: ArrowReaderMetadata,
}

/// One block: a row group of a shard, holding whole episodes.
#[derive(Debug, Clone, Copy)]
struct BlockInfo {
    shard: usize,
    group: usize,
    /// The block's first row in its shard.
    first_row: usize,
    episodes: usize,
    /// The table-wide number of its first episode.
    first_episode: u64,
}

/// Where every block of a table is, read from footers and Parquet metadata only.
pub struct Layout {
    task: Task,
    t: usize,
    episodes: u64,
    shards: Vec<Shard>,
    blocks: Vec<BlockInfo>,
}

impl Layout {
    /// The blocks of a table file or table folder; a row group that does not hold whole
    /// episodes is refused, naming the shard and row group.
    pub fn open(path: &Path) -> Result<Layout> {
        let (footer, shards): (Footer, Vec<(PathBuf, Footer, u64)>) = if is_folder(path) {
            let folder = TableFolder::open(path)?;
            let shards = folder
                .manifest
                .shards
                .iter()
                .map(|s| {
                    let p = folder.dir.join(&s.file);
                    Ok((p.clone(), shard_footer(&p)?, s.first_episode as u64))
                })
                .collect::<Result<_>>()?;
            (folder.footer().clone(), shards)
        } else {
            let f = shard_footer(path)?;
            (f.clone(), vec![(path.to_path_buf(), f, 0)])
        };
        let (t, mut blocks, mut opened) = (footer.t, Vec::new(), Vec::new());
        if t < 2 {
            bail!("{}: episodes of {t} step(s) hold no transition", path.display());
        }
        for (i, (p, f, first_episode)) in shards.into_iter().enumerate() {
            let file = crate::output::open_input(&p)?;
            let meta = ArrowReaderMetadata::load(&file, ArrowReaderOptions::new())
                .with_context(|| format!("{}: not a readable Parquet file", p.display()))?;
            let mut row = 0usize;
            for (g, rg) in meta.metadata().row_groups().iter().enumerate() {
                let rows = rg.num_rows() as usize;
                if row % t != 0 || rows % t != 0 {
                    bail!(
                        "{}: row group {g} holds rows {row}..{}, not whole episodes of T = {t} (pgser's writers cut row \
                         groups between episodes; convert the data again)",
                        p.display(),
                        row + rows
                    );
                }
                let first = first_episode + (row / t) as u64;
                blocks.push(BlockInfo { shard: i, group: g, first_row: row, episodes: rows / t, first_episode: first });
                row += rows;
            }
            if row != f.rows {
                bail!("{}: its row groups hold {row} rows but its footer says {}", p.display(), f.rows);
            }
            opened.push(Shard { path: p, footer: f, meta });
        }
        Ok(Layout { task: footer.task(), t, episodes: footer.episodes as u64, shards: opened, blocks })
    }

    /// Float32 bytes of one episode as a block holds it.
    fn episode_bytes(&self) -> u64 {
        let (t, task) = (self.t as u64, &self.task);
        4 * (t * (task.obs_dim + task.goal_dim) as u64 + (t - 1) * (task.goal_dim + task.act_dim) as u64)
    }

    /// Float32 bytes of the whole table in memory.
    pub fn bytes(&self) -> u64 {
        self.episodes * self.episode_bytes()
    }

    /// Bytes of one reservoir entry: an achieved goal, an observation, and where they came from.
    fn entry_bytes(&self) -> u64 {
        4 * (self.task.obs_dim + self.task.goal_dim) as u64 + 16
    }

    /// Reads block `id`: its chunks checked against the shard's checksums, every row checked as
    /// `Episodes::load` checks them, decoded to float32.
    fn read(&self, id: usize) -> Result<Block> {
        self.read_columns(id, &[true; 4])
    }

    /// Reads the columns of block `id` that `which` marks (in [`VECTORS`] order); the others
    /// stay empty. The reservoir's first fill reads observations and achieved goals only.
    fn read_columns(&self, id: usize, which: &[bool; 4]) -> Result<Block> {
        let b = self.blocks[id];
        let shard = &self.shards[b.shard];
        let at = format!("{} (row group {})", shard.path.display(), b.group);
        let file = crate::output::open_input(&shard.path)?;
        let verifier = crate::table::Verifier::new(&shard.path, shard.meta.metadata())?;
        let mut names = vec!["episode", "step"];
        names.extend(VECTORS.iter().zip(which).filter(|(_, w)| **w).map(|(n, _)| *n));
        verifier.check_row_groups(&[b.group], &verifier.columns_of(&names))?;
        let builder = ParquetRecordBatchReaderBuilder::new_with_metadata(file, shard.meta.clone());
        let schema = builder.schema().clone();
        let roots = names
            .iter()
            .map(|n| schema.index_of(n).map_err(|_| anyhow!("{at}: no `{n}` column")))
            .collect::<Result<Vec<_>>>()?;
        let mask = ProjectionMask::roots(builder.parquet_schema(), roots);
        let t = self.t;
        let reader = builder
            .with_projection(mask)
            .with_row_groups(vec![b.group])
            .with_batch_size(64 * t)
            .build()
            .with_context(|| format!("{at}: cannot read"))?;
        let task = &self.task;
        let dims = [task.obs_dim, task.goal_dim, task.goal_dim, task.act_dim];
        let steps = [t, t, t - 1, t - 1];
        let mut out: [Vec<f32>; 4] =
            std::array::from_fn(|k| Vec::with_capacity(if which[k] { b.episodes * steps[k] * dims[k] } else { 0 }));
        let mut row = b.first_row;
        for batch in reader {
            let batch = batch.with_context(|| format!("{at}: cannot read the rows after row {row}"))?;
            check_keys(&at, &batch, row, &shard.footer)?;
            for (k, v) in out.iter_mut().enumerate().filter(|(k, _)| which[*k]) {
                let col = batch.column_by_name(VECTORS[k]).expect("projected");
                append(v, col, VECTORS[k], dims[k], steps[k] < t, row, t).map_err(|e| anyhow!("{at}: {e}"))?;
            }
            row += batch.num_rows();
        }
        if row != b.first_row + b.episodes * t {
            bail!("{at}: {} rows read where the row group holds {}", row - b.first_row, b.episodes * t);
        }
        let [obs, ag, g, u] = out;
        Ok(Block { id, n: b.episodes, first_episode: b.first_episode, obs, ag, g, u })
    }
}

/// How a table meets a budget.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plan {
    /// The table fits: held whole.
    Whole,
    /// `slots` resident blocks and a reservoir of `reservoir` goals.
    Pool { slots: usize, reservoir: usize },
}

impl Plan {
    /// The budget's split: the reservoir takes an eighth (at most one entry per observation of the
    /// table) and as much again while it is first filled, [`IN_FLIGHT`] blocks are set aside, and
    /// the rest holds blocks of the largest size.
    /// Refused, saying what would do, when fewer than two blocks fit. The budget is β's: the
    /// process's own memory (code, networks, batches, Parquet metadata) comes on top of it, and
    /// BENCHMARKS.md measures the whole.
    pub fn of(layout: &Layout, budget: u64) -> Result<Plan> {
        if layout.bytes() <= budget {
            return Ok(Plan::Whole);
        }
        let block = layout.blocks.iter().map(|b| b.episodes as u64).max().unwrap_or(0) * layout.episode_bytes();
        let observations = layout.episodes * layout.t as u64;
        let reservoir =
            ((budget as f64 * RESERVOIR_SHARE) as u64 / layout.entry_bytes()).min(observations).max(1) as usize;
        // The reservoir twice: its first fill gathers every block's entries before they are placed.
        let fixed = 2 * reservoir as u64 * layout.entry_bytes() + IN_FLIGHT * block;
        let slots = budget.saturating_sub(fixed) / block.max(1);
        if slots < 2 {
            let need = fixed + 2 * block;
            bail!(
                "a memory budget of {} holds fewer than two of the table's row groups ({} each as float32, {} more \
                 for reading and the goal reservoir); give at least {}, or convert with a smaller --row-group-rows",
                crate::progress::bytes(budget),
                crate::progress::bytes(block),
                crate::progress::bytes(fixed),
                crate::progress::bytes(need)
            );
        }
        if slots as usize >= layout.blocks.len() {
            return Ok(Plan::Whole);
        }
        Ok(Plan::Pool { slots: slots as usize, reservoir })
    }
}

/// A resident block.
struct Block {
    id: usize,
    n: usize,
    first_episode: u64,
    obs: Vec<f32>,
    ag: Vec<f32>,
    g: Vec<f32>,
    u: Vec<f32>,
}

impl Block {
    fn obs(&self, e: usize, s: usize, t: usize, d: usize) -> &[f32] {
        &self.obs[(e * t + s) * d..][..d]
    }
    fn ag(&self, e: usize, s: usize, t: usize, d: usize) -> &[f32] {
        &self.ag[(e * t + s) * d..][..d]
    }
}

/// The order blocks enter in, as one sequence over the passes: entry i is block
/// `permutation(.., i / B)[i % B]`. Computed, never stored beyond the current pass, so both the
/// loader and a resumed pool can find entry i without reading anything.
struct Entries {
    blocks: usize,
    head: usize,
    seed: u64,
    pass: u64,
    order: Vec<usize>,
}

impl Entries {
    fn new(blocks: usize, head: usize, seed: u64) -> Entries {
        Entries { blocks, head, seed, pass: 0, order: permutation(blocks, head, seed, 0) }
    }

    fn get(&mut self, i: u64) -> usize {
        let pass = i / self.blocks as u64;
        if pass != self.pass {
            self.order = permutation(self.blocks, self.head, self.seed, pass);
            self.pass = pass;
        }
        self.order[(i % self.blocks as u64) as usize]
    }
}

/// The reservoir's entries as (block, episode in it, step): what the pool's random numbers decide
/// alone, before any data is read. Vectors are filled in from the blocks afterwards
/// ([`Pool::materialize`], [`Pool::swap`]).
struct Keys {
    slots: Vec<(u32, u32, u32)>,
    /// Next slot to replace (the oldest).
    next: usize,
    /// The fraction of an entry owed to the next block.
    carry: f64,
    rng: NpRandom,
}

impl Keys {
    /// The first fill: every block gives its share of entries (carry-rounded, so they sum to
    /// `len`), uniform over its observations, each block's from a generator of its own; then the
    /// entries are put in a random order, since they are replaced oldest first and in block order
    /// the first shards' entries would all go before any of the last ones'.
    fn first(layout: &Layout, len: usize, seed: u64) -> Keys {
        let mut slots = Vec::with_capacity(len);
        let mut carry = 0.0;
        for (id, b) in layout.blocks.iter().enumerate() {
            carry += len as f64 * b.episodes as f64 / layout.episodes as f64;
            let mut k = carry.floor() as usize;
            carry -= k as f64;
            if id + 1 == layout.blocks.len() {
                k = len - slots.len();
            }
            let mut rng = NpRandom::spawned(seed, &[KEY_RESERVOIR, 1 + id as u64]);
            for _ in 0..k {
                slots.push((id as u32, rng.below(b.episodes) as u32, rng.below(layout.t) as u32));
            }
        }
        let mut rng = NpRandom::spawned(seed, &[KEY_RESERVOIR]);
        for i in (1..slots.len()).rev() {
            slots.swap(i, rng.below(i + 1));
        }
        Keys { slots, next: 0, carry: 0.0, rng }
    }

    /// Block `id` enters: it replaces its share of entries, `R · r / N` for its `r` observations
    /// (the fraction carried), oldest first. Returns the slots it wrote.
    fn feed(&mut self, layout: &Layout, id: usize) -> std::ops::Range<usize> {
        let b = layout.blocks[id];
        let len = self.slots.len();
        self.carry += len as f64 * b.episodes as f64 / layout.episodes as f64;
        let k = (self.carry.floor() as usize).min(len);
        self.carry -= k as f64;
        let from = self.next;
        for j in 0..k {
            let (e, s) = (self.rng.below(b.episodes), self.rng.below(layout.t));
            self.slots[(from + j) % len] = (id as u32, e as u32, s as u32);
        }
        self.next = (from + k) % len;
        from..from + k
    }
}

/// What waiting for the disk cost, so far.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PoolStats {
    /// Blocks swapped in since the pool started (or resumed).
    pub swaps: u64,
    /// Swaps that had to wait for their block.
    pub waits: u64,
    pub waited: Duration,
    pub longest_wait: Duration,
}

/// β within a memory budget (see the module doc).
pub struct Pool {
    layout: Arc<Layout>,
    cfg: PoolConfig,
    slots: usize,
    entries: Entries,
    /// The next entry to swap in.
    next_entry: u64,
    /// Resident blocks, oldest first.
    resident: VecDeque<Block>,
    /// Resident episode → (position in `resident`, episode within it).
    index: Vec<(u32, u32)>,
    keys: Keys,
    /// The reservoir's vectors, slot by slot, and the table-wide (episode, step) of each.
    goal_at: Vec<(u64, u32)>,
    goal_ag: Vec<f32>,
    goal_obs: Vec<f32>,
    /// Transitions drawn since the last swap.
    drawn: f64,
    loader: Mutex<Receiver<Result<Block>>>,
    stats: PoolStats,
}

/// The order blocks enter in pass `pass`: every block once. Pass 0 is a seeded permutation;
/// every later pass starts with the same `head` blocks (pass 0's first ones, the first fill) and
/// shuffles the rest afresh.
///
/// Why the fixed head: a block is resident for `S` swaps. The first fill's block k leaves at swap
/// k + 1, having had k + 1 of its S turns; as the pass ends, the same block enters again as the
/// next pass's k-th and has S − 1 − k turns before the pass's last swap. So within every pass of
/// draws each block is resident for exactly S turns, and each shard's share of the draws is its
/// share of the rows, up to sampling noise, with no block half-drawn at a pass's edges.
fn permutation(blocks: usize, head: usize, seed: u64, pass: u64) -> Vec<usize> {
    let shuffle = |p: &mut [usize], pass: u64| {
        let mut rng = NpRandom::spawned(seed, &[KEY_PERMUTATION, pass]);
        for i in (1..p.len()).rev() {
            p.swap(i, rng.below(i + 1));
        }
    };
    let mut p: Vec<usize> = (0..blocks).collect();
    shuffle(&mut p, 0);
    if pass > 0 {
        shuffle(&mut p[head..], pass);
    }
    p
}

impl Pool {
    /// The pool after `batches` batches of `rows` draws each (0 for a fresh one): the swaps and
    /// reservoir refreshes those draws made are replayed on block sizes alone, then the resident
    /// blocks are read (in parallel) and the reservoir's vectors filled from the blocks its
    /// entries name (observations and achieved goals only), and the loader starts at the next
    /// entry. A resumed run thus draws what an uninterrupted one does, number for number.
    pub fn start(
        layout: Arc<Layout>,
        cfg: PoolConfig,
        slots: usize,
        reservoir: usize,
        (batches, rows): (u64, usize),
    ) -> Result<Pool> {
        keep_large_buffers_returnable();
        let mut entries = Entries::new(layout.blocks.len(), slots, cfg.seed);
        let mut queue: VecDeque<usize> = (0..slots as u64).map(|i| entries.get(i)).collect();
        let mut next_entry = slots as u64;
        let mut keys = Keys::first(&layout, reservoir, cfg.seed);
        let mut drawn = 0.0;
        for _ in 0..batches {
            drawn += rows as f64;
            loop {
                let due = cfg.draws_per_row * (layout.blocks[queue[0]].episodes * (layout.t - 1)) as f64;
                if drawn < due {
                    break;
                }
                drawn -= due;
                queue.pop_front();
                let id = entries.get(next_entry);
                next_entry += 1;
                keys.feed(&layout, id);
                queue.push_back(id);
            }
        }
        let resident: VecDeque<Block> = queue.par_iter().map(|&id| layout.read(id)).collect::<Result<Vec<_>>>()?.into();
        let (od, gd) = (layout.task.obs_dim, layout.task.goal_dim);
        let mut pool = Pool {
            layout: layout.clone(),
            cfg,
            slots,
            entries,
            next_entry,
            resident,
            index: Vec::new(),
            keys,
            goal_at: vec![(0, 0); reservoir],
            goal_ag: vec![0.0; reservoir * gd],
            goal_obs: vec![0.0; reservoir * od],
            drawn,
            loader: Mutex::new(spawn_loader(layout, cfg.seed, slots, next_entry)),
            stats: PoolStats::default(),
        };
        pool.reindex();
        pool.materialize()?;
        Ok(pool)
    }

    /// Fills every reservoir slot's vectors from the block its key names: resident blocks from
    /// memory, the others read (observations and achieved goals only), a block per thread, each
    /// dropped as soon as its entries are copied out, so memory is the reservoir and one block
    /// per thread, never the table's columns.
    fn materialize(&mut self) -> Result<()> {
        let mut by_block: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
        for (slot, &(id, _, _)) in self.keys.slots.iter().enumerate() {
            by_block.entry(id as usize).or_default().push(slot);
        }
        let layout = &self.layout;
        let (t, od, gd) = (layout.t, layout.task.obs_dim, layout.task.goal_dim);
        let keys = &self.keys.slots;
        // A block's entries, flat: their slots, table-wide (episode, step), achieved goals and
        // observations (at most the reservoir's own size over all blocks).
        type Entries = (Vec<usize>, Vec<(u64, u32)>, Vec<f32>, Vec<f32>);
        let take = |b: &Block, slots: &[usize]| -> Entries {
            let mut out: Entries = (slots.to_vec(), Vec::new(), Vec::new(), Vec::new());
            for &slot in slots {
                let (_, e, s) = keys[slot];
                let (e, s) = (e as usize, s as usize);
                out.1.push((b.first_episode + e as u64, s as u32));
                out.2.extend_from_slice(b.ag(e, s, t, gd));
                out.3.extend_from_slice(b.obs(e, s, t, od));
            }
            out
        };
        let resident: std::collections::BTreeMap<usize, &Block> = self.resident.iter().map(|b| (b.id, b)).collect();
        let mut entries: Vec<Entries> =
            by_block.iter().filter_map(|(id, slots)| resident.get(id).map(|b| take(b, slots))).collect();
        let others: Vec<(&usize, &Vec<usize>)> = by_block.iter().filter(|(id, _)| !resident.contains_key(id)).collect();
        entries.extend(
            others
                .into_par_iter()
                .map(|(&id, slots)| Ok(take(&layout.read_columns(id, &[true, true, false, false])?, slots)))
                .collect::<Result<Vec<_>>>()?,
        );
        for (slots, at, ag, obs) in entries {
            for (i, slot) in slots.into_iter().enumerate() {
                self.goal_at[slot] = at[i];
                self.goal_ag[slot * gd..][..gd].copy_from_slice(&ag[i * gd..][..gd]);
                self.goal_obs[slot * od..][..od].copy_from_slice(&obs[i * od..][..od]);
            }
        }
        Ok(())
    }

    /// The same pool as it is after `batches` batches of `rows` draws: what a resumed run
    /// continues from. Reads the blocks again.
    pub fn resumed(&self, batches: u64, rows: usize) -> Result<Pool> {
        Pool::start(self.layout.clone(), self.cfg, self.slots, self.goal_at.len(), (batches, rows))
    }

    /// What waiting for the disk has cost so far.
    pub fn stats(&self) -> PoolStats {
        self.stats
    }

    /// Resident episodes now.
    pub fn resident_episodes(&self) -> usize {
        self.index.len()
    }

    /// Blocks resident, and blocks in the table.
    pub fn blocks(&self) -> (usize, usize) {
        (self.slots, self.layout.blocks.len())
    }

    /// Goals in the reservoir.
    pub fn reservoir(&self) -> usize {
        self.goal_at.len()
    }

    /// The resident blocks' arrays (observations, desired goals, achieved goals): what a trainer
    /// fits its normalizer on, a uniform sample of the table's blocks.
    pub fn resident_arrays(&self) -> (Vec<&[f32]>, Vec<&[f32]>, Vec<&[f32]>) {
        let r = &self.resident;
        (
            r.iter().map(|b| &b.obs[..]).collect(),
            r.iter().map(|b| &b.g[..]).collect(),
            r.iter().map(|b| &b.ag[..]).collect(),
        )
    }

    fn reindex(&mut self) {
        self.index.clear();
        for (slot, b) in self.resident.iter().enumerate() {
            self.index.extend((0..b.n).map(|e| (slot as u32, e as u32)));
        }
    }

    /// Takes the next block from the loader in place of the oldest, and feeds the reservoir.
    fn swap(&mut self) -> Result<()> {
        let t0 = Instant::now();
        let next = {
            let rx = self.loader.get_mut().expect("the loader's channel is never poisoned");
            match rx.try_recv() {
                Ok(b) => b,
                Err(_) => {
                    let b = rx.recv().map_err(|_| anyhow!("the pool's loader stopped"))?;
                    let w = t0.elapsed();
                    self.stats.waits += 1;
                    self.stats.waited += w;
                    self.stats.longest_wait = self.stats.longest_wait.max(w);
                    b
                }
            }
        }?;
        let want = self.entries.get(self.next_entry);
        assert_eq!(next.id, want, "the loader and the pool agree on the order of entries");
        self.next_entry += 1;
        self.stats.swaps += 1;
        self.resident.pop_front();
        let (t, od, gd) = (self.layout.t, self.layout.task.obs_dim, self.layout.task.goal_dim);
        let len = self.goal_at.len();
        for j in self.keys.feed(&self.layout, next.id) {
            let slot = j % len;
            let (_, e, s) = self.keys.slots[slot];
            let (e, s) = (e as usize, s as usize);
            self.goal_at[slot] = (next.first_episode + e as u64, s as u32);
            self.goal_ag[slot * gd..][..gd].copy_from_slice(next.ag(e, s, t, gd));
            self.goal_obs[slot * od..][..od].copy_from_slice(next.obs(e, s, t, od));
        }
        self.resident.push_back(next);
        self.reindex();
        Ok(())
    }

    fn block(&self, e: usize) -> (&Block, usize) {
        let (slot, local) = self.index[e];
        (&self.resident[slot as usize], local as usize)
    }
}

/// Makes glibc give large buffers (a block's arrays, a row group's decoded pages) back to the
/// system when they are freed. By default glibc raises its mmap threshold each time such a
/// buffer is freed, up to 32 MB, after which buffers of a block's size come from the heaps of the
/// threads that allocated them and stay there when freed: measured on 10M humanoidmaze-shaped
/// rows, the process then held 0.9 GB beyond a 1 GB budget, more on a larger table. A fixed
/// threshold keeps every buffer over 1 MB a mapping of its own, returned on free. Process-wide
/// and idempotent; elsewhere than glibc it does nothing.
fn keep_large_buffers_returnable() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets an allocator parameter; it is safe to call at any time.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

/// The loader: entries `from` on ([`Entries`]), each block read and sent through a channel of
/// one. It stops when the pool is dropped (the send fails) or after a read error, which it sends.
fn spawn_loader(layout: Arc<Layout>, seed: u64, head: usize, from: u64) -> Receiver<Result<Block>> {
    let (tx, rx) = sync_channel(1);
    std::thread::Builder::new()
        .name("pgser-pool-loader".into())
        .spawn(move || {
            let mut entries = Entries::new(layout.blocks.len(), head, seed);
            for i in from.. {
                let block = layout.read(entries.get(i));
                let failed = block.is_err();
                if tx.send(block).is_err() || failed {
                    return;
                }
            }
        })
        .expect("a thread starts");
    rx
}

impl View for Pool {
    fn task(&self) -> &Task {
        &self.layout.task
    }
    fn episodes(&self) -> usize {
        self.index.len()
    }
    fn t(&self) -> usize {
        self.layout.t
    }
    fn obs(&self, e: usize, s: usize) -> &[f32] {
        let (b, l) = self.block(e);
        let d = self.layout.task.obs_dim;
        &b.obs[(l * self.layout.t + s) * d..][..d]
    }
    fn ag(&self, e: usize, s: usize) -> &[f32] {
        let (b, l) = self.block(e);
        let d = self.layout.task.goal_dim;
        &b.ag[(l * self.layout.t + s) * d..][..d]
    }
    fn goal(&self, e: usize, s: usize) -> &[f32] {
        let (b, l) = self.block(e);
        let d = self.layout.task.goal_dim;
        &b.g[(l * (self.layout.t - 1) + s) * d..][..d]
    }
    fn action(&self, e: usize, s: usize) -> &[f32] {
        let (b, l) = self.block(e);
        let d = self.layout.task.act_dim;
        &b.u[(l * (self.layout.t - 1) + s) * d..][..d]
    }
    fn episode_number(&self, e: usize) -> u64 {
        let (b, l) = self.block(e);
        b.first_episode + l as u64
    }
    fn random_goal(&self, rng: &mut NpRandom) -> GoalSource {
        let i = rng.below(self.goal_at.len());
        let (episode, step) = self.goal_at[i];
        GoalSource { episode, step, slot: i as u64 }
    }
    fn goal_ag(&self, g: GoalSource) -> &[f32] {
        let d = self.layout.task.goal_dim;
        &self.goal_ag[g.slot as usize * d..][..d]
    }
    fn goal_obs(&self, g: GoalSource) -> &[f32] {
        let d = self.layout.task.obs_dim;
        &self.goal_obs[g.slot as usize * d..][..d]
    }
    fn refresh(&mut self, rows: usize) -> Result<()> {
        self.drawn += rows as f64;
        loop {
            let leaving = self.resident.front().expect("at least two blocks resident");
            let due = self.cfg.draws_per_row * (leaving.n * (self.layout.t - 1)) as f64;
            if self.drawn < due {
                return Ok(());
            }
            self.drawn -= due;
            self.swap()?;
        }
    }
}

impl std::fmt::Debug for Pool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ids: Vec<usize> = self.resident.iter().map(|b| b.id).collect();
        write!(
            f,
            "Pool {{ task: {}, resident blocks: {ids:?}, reservoir: {} }}",
            self.layout.task.name,
            self.goal_at.len()
        )
    }
}
