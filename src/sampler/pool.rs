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
//!   The pool rotates it in for its oldest block **when as many transitions have been drawn as the
//!   leaving block holds** (times `draws_per_row`, `--draws-per-row`). So one pass
//!   of draws (as many as the table holds) is one pass of loading, in which every block is
//!   resident once for about the same number of draws: the long-run share of each shard, episode
//!   and step is its share of the table. The rotation points depend on the draws alone, never on the
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
//! the whole table fits the budget, [`super::open::plan`] holds it in memory and the batches are the in-memory
//! ones, number for number.

use std::collections::VecDeque;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Result, bail};
use rayon::prelude::*;

mod buffers;
mod layout;
mod loader;
mod reservoir;
mod resident;
mod schedule;

use super::view::{RandomGoal, View};
use crate::nprandom::NpRandom;
use crate::task::Task;
pub(crate) use buffers::advise_huge_pages;
use layout::Block;
pub use layout::{Layout, Plan};
use loader::Loader;
use reservoir::Reservoir;
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
    /// Blocks rotated in since the pool started (or resumed).
    pub rotations: u64,
    /// Rotations that had to wait for their block.
    pub waits: u64,
    pub waited: Duration,
    pub longest_wait: Duration,
    /// The longest rotation itself, its wait left out: placing the block, feeding the reservoir and
    /// re-indexing the resident episodes, which the drawing thread does between two batches.
    pub longest_rotation: Duration,
}

/// β within a memory budget (see the module doc).
pub struct Pool {
    layout: Arc<Layout>,
    cfg: PoolConfig,
    slots: usize,
    entries: Entries,
    /// The next entry to rotate in.
    next_entry: u64,
    /// Resident blocks, oldest first, and their episodes.
    resident: Resident,
    /// The random goals: a sample of the whole table's, not of the resident blocks'.
    reservoir: Reservoir,
    /// Transitions drawn since the last rotation.
    drawn: f64,
    /// Started once the pool is filled (`start`), so opening holds no block in flight.
    loader: Mutex<Option<Loader>>,
    /// The next block, taken from the loader ahead of its rotation (`stage`).
    staged: Option<Result<Block>>,
    /// A rotation that failed: every later refresh fails with it, so no batch is drawn from blocks
    /// that should have left.
    failed: Option<String>,
    stats: PoolStats,
}

impl Pool {
    /// The pool at `at` (after `at.batches` batches of `at.rows` draws each; none for a fresh
    /// one): the rotations and reservoir refreshes those draws made are replayed on block sizes alone,
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
        let reservoir = Reservoir::new(&layout, keys)?;
        let mut pool = Pool {
            layout,
            cfg,
            slots,
            entries,
            next_entry,
            resident: Resident::new(slots),
            reservoir,
            drawn,
            loader: Mutex::new(None),
            staged: None,
            failed: None,
            stats: PoolStats::default(),
        };
        for b in resident {
            pool.resident.enter(b);
        }
        pool.reservoir.fill(&pool.layout, &pool.resident)?;
        let layout = pool.layout.clone();
        *pool.loader.get_mut().expect("not shared yet") = Some(Loader::spawn(layout, cfg, slots, pool.next_entry));
        Ok(pool)
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
    pub fn rotates_within(&self, rows: usize) -> bool {
        let leaving = self.resident.front().expect("a pool holds blocks");
        self.drawn + rows as f64 >= due(&self.layout, &self.cfg, leaving.id)
    }

    /// Takes back `rows` draws that `refresh` counted and that took no block in (batches drawn
    /// ahead, then dropped): the pool is then as it was before them.
    pub fn unrefresh(&mut self, rows: usize) {
        assert!(self.drawn >= rows as f64, "only draws counted since the last rotation are taken back");
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
        self.reservoir.len()
    }

    /// The resident blocks' arrays (observations, desired goals, achieved goals): what a trainer
    /// fits its normalizer on, a uniform sample of the table's blocks.
    pub fn resident_arrays(&self) -> [Vec<&[f32]>; 3] {
        let r = &self.resident;
        [
            r.iter().map(|b| &b.obs[..]).collect(),
            r.iter().map(|b| &b.g[..]).collect(),
            r.iter().map(|b| &b.ag[..]).collect(),
        ]
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
        !self.layout.is_image()
            && self.layout.task.goal_dim == self.layout.task.obs_dim
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
    fn rotate(&mut self) -> Result<()> {
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
        self.stats.rotations += 1;
        // The leaving block goes back whole: the loader fills its arrays with a later block and
        // drops the rest (its scored rows), off the drawing thread.
        let leaving = self.resident.leave();
        self.loader.get_mut().expect("the loader is never poisoned").as_mut().expect("started").give_back(leaving);
        self.reservoir.enter(&self.layout, &next);
        self.resident.enter(next);
        self.stats.longest_rotation = self.stats.longest_rotation.max(t0.elapsed().saturating_sub(wait));
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

    /// Takes the next block from the loader ahead of the rotation that needs it, waiting for it
    /// if need be, so that rotation does not wait: what a sampler that stops drawing ahead at one
    /// (`python/src/sampler/ogbench.rs`) does while its learner uses up the batches ready. The
    /// block counts among the plan's blocks in flight (it left the loader's channel).
    pub fn stage(&mut self) {
        if self.staged.is_none() && self.failed.is_none() {
            self.staged = Some(self.next_block().0);
        }
    }

    fn block(&self, e: usize) -> (&Block, usize) {
        self.resident.episode(e)
    }
}

/// The draws after which block `id`, the oldest resident, leaves: as many as it has transitions,
/// times `draws_per_row`. The live pool and its replay on resume both rotate by this.
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
        if b.obs.is_empty() {
            return &[];
        }
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
    fn random_goal(&self, rng: &mut NpRandom) -> RandomGoal {
        if self.reservoir.is_empty() {
            // A shard window: uniform over the held shard's observations; the slot is the row.
            let (e, s) = (rng.below(self.resident.episodes()), rng.below(self.layout.t));
            let (episode, slot) = (self.episode_number(e), (e * self.layout.t + s) as u64);
            return RandomGoal { episode, step: s as u32, slot };
        }
        self.reservoir.draw(rng)
    }
    fn goal_ag(&self, g: RandomGoal) -> &[f32] {
        if self.reservoir.is_empty() {
            let t = self.layout.t as u64;
            return self.ag((g.slot / t) as usize, (g.slot % t) as usize);
        }
        self.reservoir.ag(g.slot)
    }
    fn goal_obs(&self, g: RandomGoal) -> &[f32] {
        if self.reservoir.is_empty() {
            let t = self.layout.t as u64;
            return self.obs((g.slot / t) as usize, (g.slot % t) as usize);
        }
        self.reservoir.obs(g.slot)
    }
    fn image_shape(&self) -> &[usize] {
        &self.layout.image_shape
    }
    fn image(&self, e: usize, s: usize) -> &[u8] {
        let (b, l) = self.block(e);
        b.image(l, s, self.layout.t, self.layout.task.obs_dim)
    }
    fn goal_image(&self, g: RandomGoal, back: usize) -> &[u8] {
        if self.reservoir.is_empty() {
            let t = self.layout.t as u64;
            return self.image((g.slot / t) as usize, ((g.slot % t) as usize).saturating_sub(back));
        }
        self.reservoir.image(g.slot, back)
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
            if let Err(e) = self.rotate() {
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
            self.reservoir.len()
        )
    }
}
