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
//!   one each pass, seeded), checks each against its checksums, decodes it to float32 (into the
//!   arrays of a block that left, handed back to it) and hands it over through a channel of one.
//!   The pool swaps it in for its oldest block **when as many transitions have been drawn as the
//!   leaving block holds** (times `draws_per_row`, `--draws-per-row`). So one pass
//!   of draws (as many as the table holds) is one pass of loading, in which every block is
//!   resident once for about the same number of draws: the long-run share of each shard, episode
//!   and step is its share of the table. The swap points depend on the draws alone, never on the
//!   loader's timing, so the same seed gives the same batches at any speed; the loader reads
//!   ahead while the current blocks are drawn from, and a batch waits only when reading a block
//!   takes longer than drawing the previous block's transitions (counted in [`PoolStats`]).
//!   Every pass starts with the same first blocks (`schedule::permutation` says why), which makes each
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
//! # PGSER within a budget (`-mem` from a scored table or scored folder)
//! - **Each block carries its scored rows.** The scored rows of a transition sit at a fixed place
//!   in a scored table (`per` rows per transition, in episode and step order, episodes numbered
//!   across the folder), so a block reads the scored rows of its own episodes beside them: their
//!   stored goals (from anywhere in the table: `score` draws them from every shard) and their q,
//!   checked row by row to be the block's transitions. β's rows rebuild the rest (s, a, s′) and
//!   the reward is recomputed, as in memory. The plan counts these rows in the block's size.
//! - **Priorities are the block's own.** When a block enters, its rows' priorities are computed
//!   from their q within the block (`--priority rank` ranks them among the block's rows), and a
//!   prioritized draw picks a resident block in proportion to its transitions, then a row of it
//!   in proportion to its priority. Nothing table-wide stays in memory: the priorities of N
//!   scored rows cost nothing until their block is resident, where they take 4 bytes a row, and
//!   a 1B-transition table's 4B scored rows need no 16 GB sum tree.
//! - **What that changes.** In memory, a row's probability is its priority over the whole table's;
//!   here it is its priority over its block's, times its block's share of transitions. Every block
//!   thus gets its share of prioritized draws over a pass, and within a block the draws prefer
//!   what the critic calls reachable exactly as in memory. With `--priority q`, a block whose rows
//!   score higher on average no longer gets more draws than its size; with `rank`, rank 1 is the
//!   block's best row rather than the table's (for α = 1 the top tenth of a block of n rows draws
//!   H(n/10)/H(n) of its draws: 0.69 for n = 980, where the table of N rows gives H(N/10)/H(N)).
//!   `--is-beta` needs table-wide probabilities and is refused within a budget.
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
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use rayon::prelude::*;

mod buffers;
mod layout;
mod loader;
mod resident;
mod schedule;

use super::view::{GoalSource, View};
use crate::nprandom::NpRandom;
use crate::task::Task;
use crate::trajectory::Episodes;
use buffers::Floats;
use layout::{Block, IN_FLIGHT};
pub use layout::{Layout, Plan};
use loader::Loader;
use resident::Resident;
use schedule::{Entries, Keys};

/// Options of a pool besides its budget.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoolConfig {
    /// Memory the pool may use, in bytes.
    pub budget: u64,
    /// Transitions drawn per transition loaded: 1 makes a pass of draws a pass of loading; 2
    /// keeps each block twice as long (half the reading, for samplers faster than the disk).
    pub draws_per_row: f64,
    pub seed: u64,
    /// A shard window: one shard resident, the next in table order after this many draws.
    pub window: Option<u64>,
}

/// Where a stream opens a pool: after `batches` batches of `rows` draws each (a resumed run's
/// position), so the pool it holds is the one an uninterrupted run holds there, read once.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Position {
    pub batches: u64,
    pub rows: usize,
}

impl Position {
    /// A fresh stream's: before its first batch.
    pub const START: Position = Position { batches: 0, rows: 0 };
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

    /// A trajectory table (a file or a table folder) held within `budget`, a pool as it is at
    /// `at`.
    pub fn within(path: &Path, budget: super::view::Budget, seed: u64, at: Position) -> Result<Beta> {
        use super::view::Budget;
        Ok(match budget {
            Budget::Unbounded => Beta::Whole(Arc::new(Episodes::load(path)?)),
            Budget::Bytes { bytes, draws_per_row } => Beta::open(path, bytes, draws_per_row, seed, at)?,
            Budget::ShardWindow(rows) => Beta::Pool(Box::new(Pool::window(Layout::open(path)?, rows, seed, at)?)),
        })
    }

    /// Plans `path` against `budget` and opens it, a pool keeping each block for `draws_per_row`
    /// draws per transition, as it is at `at`.
    pub fn open(path: &Path, budget: u64, draws_per_row: u32, seed: u64, at: Position) -> Result<Beta> {
        let layout = Layout::open(path)?;
        Ok(match Plan::of(&layout, budget)? {
            Plan::Whole => Beta::Whole(Arc::new(Episodes::load(path)?)),
            Plan::Pool { slots, reservoir } => {
                Beta::Pool(Box::new(Pool::planned(layout, (budget, draws_per_row), seed, (slots, reservoir), at)?))
            }
        })
    }
}

/// A row drawn by priority from a resident block's scored rows ([`Pool::draw_scored`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScoredDraw {
    /// The transition's resident episode and step.
    pub e: usize,
    pub step: usize,
    /// The block's position among the resident ones, and the row among its scored rows.
    slot: usize,
    row: usize,
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
    /// The longest swap itself, its wait left out: placing the block, feeding the reservoir and
    /// re-indexing the resident episodes, which the drawing thread does between two batches.
    pub longest_swap: Duration,
}

/// β within a memory budget (see the module doc).
pub struct Pool {
    layout: Arc<Layout>,
    cfg: PoolConfig,
    slots: usize,
    entries: Entries,
    /// The next entry to swap in.
    next_entry: u64,
    /// Resident blocks, oldest first, and their episodes.
    resident: Resident,
    keys: Keys,
    /// The reservoir's vectors, slot by slot, and the table-wide (episode, step) of each.
    goal_at: Vec<(u64, u32)>,
    goal_ag: Floats,
    goal_obs: Floats,
    /// Transitions drawn since the last swap.
    drawn: f64,
    /// Started once the pool is filled (`start`), so opening holds no block in flight.
    loader: Mutex<Option<Loader>>,
    /// The next block, taken from the loader ahead of its swap (`stage`).
    staged: Option<Result<Block>>,
    /// A swap that failed: every later refresh fails with it, so no batch is drawn from blocks
    /// that should have left.
    failed: Option<String>,
    stats: PoolStats,
}

impl Pool {
    /// The pool at `at` (after `at.batches` batches of `at.rows` draws each; none for a fresh
    /// one): the swaps and reservoir refreshes those draws made are replayed on block sizes alone,
    /// then the resident blocks are read (in parallel) and the reservoir's vectors filled from the
    /// blocks its entries name (observations and achieved goals only), and the loader starts at
    /// the next entry. A resumed run thus draws what an uninterrupted one does, number for number,
    /// and reads its blocks once.
    pub fn start(layout: Arc<Layout>, cfg: PoolConfig, slots: usize, reservoir: usize, at: Position) -> Result<Pool> {
        let Position { batches, rows } = at;
        let mut entries = entries(&layout, &cfg, slots);
        let mut queue: VecDeque<usize> = (0..slots as u64).map(|i| entries.get(i)).collect();
        let mut next_entry = slots as u64;
        let mut keys = Keys::first(&layout, reservoir, cfg.seed);
        let mut drawn = 0.0;
        for _ in 0..batches {
            drawn += rows as f64;
            loop {
                let due = due(&layout, &cfg, queue[0]);
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
        let (goal_ag, goal_obs) = (Floats::zeros(reservoir * gd)?, Floats::zeros(reservoir * od)?);
        let mut pool = Pool {
            layout,
            cfg,
            slots,
            entries,
            next_entry,
            resident: Resident::new(slots),
            keys,
            goal_at: vec![(0, 0); reservoir],
            goal_ag,
            goal_obs,
            drawn,
            loader: Mutex::new(None),
            staged: None,
            failed: None,
            stats: PoolStats::default(),
        };
        for b in resident {
            pool.resident.enter(b);
        }
        pool.materialize()?;
        let layout = pool.layout.clone();
        *pool.loader.get_mut().expect("not shared yet") = Some(Loader::spawn(layout, cfg, slots, pool.next_entry));
        Ok(pool)
    }

    /// The pool of `layout` within `(budget, draws_per_row)` at `at`, as [`Plan::of`] split that
    /// budget into `slots` resident blocks and a reservoir of `reservoir` goals.
    pub fn planned(
        layout: Layout,
        (budget, draws_per_row): (u64, u32),
        seed: u64,
        (slots, reservoir): (usize, usize),
        at: Position,
    ) -> Result<Pool> {
        let cfg = PoolConfig { budget, draws_per_row: draws_per_row as f64, seed, window: None };
        Pool::start(Arc::new(layout), cfg, slots, reservoir, at)
    }

    /// Fills every reservoir slot's vectors from the block its key names: resident blocks from
    /// memory, the others read (observations and achieved goals only), at most `IN_FLIGHT` at a
    /// time whatever the core count (the plan sets that much aside), each dropped as soon as its
    /// entries are copied out, so memory is the reservoir and those blocks, never the table's
    /// columns.
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
        for group in others.chunks(IN_FLIGHT as usize) {
            entries.extend(
                group
                    .par_iter()
                    .map(|&(&id, slots)| {
                        Ok(take(&layout.read_columns(id, &[true, true, false, false], Default::default())?, slots))
                    })
                    .collect::<Result<Vec<_>>>()?,
            );
        }
        for (slots, at, ag, obs) in entries {
            for (i, slot) in slots.into_iter().enumerate() {
                self.set_goal(slot, at[i], &ag[i * gd..][..gd], &obs[i * od..][..od]);
            }
        }
        Ok(())
    }

    /// Horizon Reduction's reload scheme, emulated (`--shard-window`): one shard of `layout` (with
    /// its scored rows, when it carries them) resident at a time, shard 0 first, the next in table
    /// order after `rows` draws (counted with the batch about to be drawn, so, as in Horizon
    /// Reduction's loop, shard 0 serves one batch less than the others), no reservoir: every goal, random ones included, comes from the
    /// held shard. Loading still runs ahead in the loader thread, so this emulates what the scheme
    /// draws, not its pauses (bench/ogbench_peer.py measures those).
    pub fn window(layout: Layout, rows: u64, seed: u64, at: Position) -> Result<Pool> {
        if rows == 0 {
            anyhow::bail!("--shard-window must be at least 1 update");
        }
        let cfg = PoolConfig { budget: 0, draws_per_row: 1.0, seed, window: Some(rows) };
        Pool::start(Arc::new(layout.by_shard()), cfg, 1, 0, at)
    }

    /// Whether this is a shard window (`Pool::window`).
    pub fn is_window(&self) -> bool {
        self.cfg.window.is_some()
    }

    /// Whether `refresh(rows)` would take a block in: a sampler that draws batches ahead stops
    /// there until it knows the next batch's size (`python/src/sampler/ogbench.rs`).
    pub fn swaps_within(&self, rows: usize) -> bool {
        let leaving = self.resident.front().expect("a pool holds blocks");
        self.drawn + rows as f64 >= due(&self.layout, &self.cfg, leaving.id)
    }

    /// Takes back `rows` draws that `refresh` counted and that took no block in (batches drawn
    /// ahead, then dropped): the pool is then as it was before them.
    pub fn unrefresh(&mut self, rows: usize) {
        assert!(self.drawn >= rows as f64, "only draws counted since the last swap are taken back");
        self.drawn -= rows as f64;
    }

    /// What waiting for the disk has cost so far.
    pub fn stats(&self) -> PoolStats {
        self.stats
    }

    /// Resident episodes now.
    pub fn resident_episodes(&self) -> usize {
        self.resident.episodes()
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

    /// Whether the blocks carry a scored table's rows (`-mem`).
    pub fn is_scored(&self) -> bool {
        self.layout.scored.is_some()
    }

    /// `k` rows drawn by priority from the resident blocks' scored rows: a block in proportion
    /// to its transitions (through a uniform resident episode), then one of its rows in
    /// proportion to its priority within the block. Panics without a scored table.
    pub fn draw_scored(&self, k: usize, rng: &mut NpRandom) -> Vec<ScoredDraw> {
        let per = self.layout.scored.as_ref().expect("the pool carries scored rows").per;
        let steps = self.layout.t - 1;
        (0..k)
            .map(|_| {
                let (slot, first) = self.resident.slot_of(rng.below(self.resident.episodes()));
                let aug = self.resident[slot].aug.as_ref().expect("every block carries its scored rows");
                let row = aug.tree.find(rng.random() * aug.tree.total());
                let (local, step) = (row / (steps * per), (row / per) % steps);
                ScoredDraw { e: first + local, step, slot, row }
            })
            .collect()
    }

    /// The scored table's number of a drawn row.
    pub fn scored_row(&self, d: &ScoredDraw) -> u64 {
        self.resident[d.slot].aug.as_ref().expect("scored").first_row + d.row as u64
    }

    /// Whether the task's goals are its whole observations, as the resident blocks show (every
    /// achieved goal equal to its observation, bit for bit): then a scored row's stored goal is
    /// the observation it was taken from.
    pub fn goals_are_observations(&self) -> bool {
        self.layout.task.goal_dim == self.layout.task.obs_dim
            && self.resident.iter().all(|b| b.ag.iter().zip(b.obs.iter()).all(|(a, o)| a.to_bits() == o.to_bits()))
    }

    /// The table-wide (episode, step) of the goal a drawn row was scored with: only when the
    /// layout keeps them (`Layout::with_goal_sources`).
    pub fn scored_goal_source(&self, d: &ScoredDraw) -> Option<(u64, usize)> {
        let at = &self.resident[d.slot].aug.as_ref().expect("scored").at;
        at.get(d.row).map(|&[e, s]| (e as u64, s as usize))
    }

    /// The goal a drawn row was scored with.
    pub fn scored_goal(&self, d: &ScoredDraw) -> &[f32] {
        let gd = self.layout.task.goal_dim;
        &self.resident[d.slot].aug.as_ref().expect("scored").goal[d.row * gd..][..gd]
    }

    /// Takes the next block from the loader in place of the oldest, and feeds the reservoir.
    fn swap(&mut self) -> Result<()> {
        let t0 = Instant::now();
        let (next, wait) = match self.staged.take() {
            Some(b) => (b, Duration::ZERO),
            None => self.next_block(),
        };
        let next = next?;
        let want = self.entries.get(self.next_entry);
        if next.id != want {
            bail!("the pool's loader sent block {} where block {want} was due", next.id);
        }
        self.next_entry += 1;
        self.stats.swaps += 1;
        // The leaving block goes back whole: the loader fills its arrays with a later block and
        // drops the rest (its scored rows), off the drawing thread.
        let leaving = self.resident.leave();
        self.loader.get_mut().expect("the loader is never poisoned").as_mut().expect("started").give_back(leaving);
        let (t, od, gd) = (self.layout.t, self.layout.task.obs_dim, self.layout.task.goal_dim);
        let len = self.goal_at.len();
        for j in self.keys.feed(&self.layout, next.id) {
            let slot = j % len;
            let (_, e, s) = self.keys.slots[slot];
            let (e, s) = (e as usize, s as usize);
            self.set_goal(slot, (next.first_episode + e as u64, s as u32), next.ag(e, s, t, gd), next.obs(e, s, t, od));
        }
        self.resident.enter(next);
        self.stats.longest_swap = self.stats.longest_swap.max(t0.elapsed().saturating_sub(wait));
        Ok(())
    }

    /// The next block from the loader, waiting for it when it is not ready (counted in the
    /// stats), and how long that took.
    fn next_block(&mut self) -> (Result<Block>, Duration) {
        let t0 = Instant::now();
        let loader = self.loader.get_mut().expect("the loader is never poisoned").as_mut().expect("started");
        if let Some(b) = loader.ready() {
            return (b, Duration::ZERO);
        }
        let b = loader.wait();
        let wait = t0.elapsed();
        self.stats.waits += 1;
        self.stats.waited += wait;
        self.stats.longest_wait = self.stats.longest_wait.max(wait);
        (b, wait)
    }

    /// Takes the next block from the loader ahead of the swap that needs it, waiting for it if
    /// need be, so that swap does not wait: what a sampler that stops drawing ahead at a swap
    /// (`python/src/sampler/ogbench.rs`) does while its learner uses up the batches ready. The
    /// block counts among the plan's blocks in flight (it left the loader's channel).
    pub fn stage(&mut self) {
        if self.staged.is_none() && self.failed.is_none() {
            self.staged = Some(self.next_block().0);
        }
    }

    /// Reservoir slot `slot` now holds the goal of table-wide (episode, step) `at`.
    fn set_goal(&mut self, slot: usize, at: (u64, u32), ag: &[f32], obs: &[f32]) {
        self.goal_at[slot] = at;
        self.goal_ag.as_mut_slice()[slot * ag.len()..][..ag.len()].copy_from_slice(ag);
        self.goal_obs.as_mut_slice()[slot * obs.len()..][..obs.len()].copy_from_slice(obs);
    }

    fn block(&self, e: usize) -> (&Block, usize) {
        self.resident.episode(e)
    }
}

/// The draws after which block `id`, the oldest resident, leaves: as many as it has transitions,
/// times `draws_per_row`. The live pool and its replay on resume both swap by this.
fn due(layout: &Layout, cfg: &PoolConfig, id: usize) -> f64 {
    match cfg.window {
        Some(draws) => draws as f64,
        None => cfg.draws_per_row * (layout.blocks[id].episodes * (layout.t - 1)) as f64,
    }
}

/// The order blocks enter in: shards in table order for a window, else seeded passes.
fn entries(layout: &Layout, cfg: &PoolConfig, head: usize) -> Entries {
    match cfg.window {
        Some(_) => Entries::in_order(layout.blocks.len()),
        None => Entries::new(layout.blocks.len(), head, cfg.seed),
    }
}

impl View for Pool {
    fn task(&self) -> &Task {
        &self.layout.task
    }
    fn episodes(&self) -> usize {
        self.resident.episodes()
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
        if self.goal_at.is_empty() {
            // A shard window: uniform over the held shard's observations; the slot is the row.
            let (e, s) = (rng.below(self.resident.episodes()), rng.below(self.layout.t));
            let (episode, slot) = (self.episode_number(e), (e * self.layout.t + s) as u64);
            return GoalSource { episode, step: s as u32, slot };
        }
        let i = rng.below(self.goal_at.len());
        let (episode, step) = self.goal_at[i];
        GoalSource { episode, step, slot: i as u64 }
    }
    fn goal_ag(&self, g: GoalSource) -> &[f32] {
        if self.goal_at.is_empty() {
            let t = self.layout.t as u64;
            return self.ag((g.slot / t) as usize, (g.slot % t) as usize);
        }
        let d = self.layout.task.goal_dim;
        &self.goal_ag[g.slot as usize * d..][..d]
    }
    fn goal_obs(&self, g: GoalSource) -> &[f32] {
        if self.goal_at.is_empty() {
            let t = self.layout.t as u64;
            return self.obs((g.slot / t) as usize, (g.slot % t) as usize);
        }
        let d = self.layout.task.obs_dim;
        &self.goal_obs[g.slot as usize * d..][..d]
    }
    fn refresh(&mut self, rows: usize) -> Result<()> {
        if let Some(e) = &self.failed {
            bail!("{e}");
        }
        self.drawn += rows as f64;
        loop {
            let leaving = self.resident.front().expect("at least two blocks resident");
            let due = due(&self.layout, &self.cfg, leaving.id);
            if self.drawn < due {
                return Ok(());
            }
            if let Err(e) = self.swap() {
                let e = format!("{e:#}");
                self.failed = Some(e.clone());
                bail!("{e}");
            }
            self.drawn -= due;
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
