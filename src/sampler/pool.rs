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
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Result, anyhow};
use rayon::prelude::*;

mod layout;
mod loader;
mod schedule;

use super::view::{GoalSource, View};
use crate::nprandom::NpRandom;
use crate::task::Task;
use crate::trajectory::Episodes;
use layout::{Arrays, Block};
pub use layout::{Layout, Plan};
use loader::{advise_huge_pages, keep_large_buffers_returnable, settle_after_open, spawn_loader};
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

    /// A trajectory table (a file or a table folder) held within `budget`.
    pub fn within(path: &Path, budget: super::view::Budget, seed: u64) -> Result<Beta> {
        use super::view::Budget;
        Ok(match budget {
            Budget::Unbounded => Beta::Whole(Arc::new(Episodes::load(path)?)),
            Budget::Bytes { bytes, draws_per_row } => Beta::open(path, bytes, draws_per_row, seed)?,
            Budget::ShardWindow(rows) => Beta::Pool(Box::new(Pool::window(Layout::open(path)?, rows, seed)?)),
        })
    }

    /// Plans `path` against `budget` and opens it, a pool keeping each block for `draws_per_row`
    /// draws per transition.
    pub fn open(path: &Path, budget: u64, draws_per_row: u32, seed: u64) -> Result<Beta> {
        let layout = Layout::open(path)?;
        Ok(match Plan::of(&layout, budget)? {
            Plan::Whole => Beta::Whole(Arc::new(Episodes::load(path)?)),
            Plan::Pool { slots, reservoir } => {
                Beta::Pool(Box::new(Pool::planned(layout, (budget, draws_per_row), seed, (slots, reservoir))?))
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
    /// Resident blocks, oldest first.
    resident: VecDeque<Block>,
    /// Resident episode → (position in `resident`, episode within it).
    index: Vec<(u32, u32)>,
    /// The first resident episode number of each position in `resident`.
    starts: Vec<usize>,
    keys: Keys,
    /// The reservoir's vectors, slot by slot, and the table-wide (episode, step) of each.
    goal_at: Vec<(u64, u32)>,
    goal_ag: Vec<f32>,
    goal_obs: Vec<f32>,
    /// Transitions drawn since the last swap.
    drawn: f64,
    loader: Mutex<Receiver<Result<Block>>>,
    /// Leaving blocks' arrays, back to the loader.
    spare: SyncSender<Arrays>,
    stats: PoolStats,
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
        let (loader, spare) = spawn_loader(layout.clone(), cfg, slots, next_entry);
        let (mut goal_ag, mut goal_obs) = (vec![0.0; reservoir * gd], vec![0.0; reservoir * od]);
        advise_huge_pages(&mut goal_ag, reservoir * gd);
        advise_huge_pages(&mut goal_obs, reservoir * od);
        let mut pool = Pool {
            layout,
            cfg,
            slots,
            entries,
            next_entry,
            resident,
            index: Vec::new(),
            starts: Vec::new(),
            keys,
            goal_at: vec![(0, 0); reservoir],
            goal_ag,
            goal_obs,
            drawn,
            loader: Mutex::new(loader),
            spare,
            stats: PoolStats::default(),
        };
        pool.reindex();
        pool.materialize()?;
        settle_after_open();
        Ok(pool)
    }

    /// A fresh pool of `layout` within `(budget, draws_per_row)`, as [`Plan::of`] split that
    /// budget into `slots` resident blocks and a reservoir of `reservoir` goals.
    pub fn planned(
        layout: Layout,
        (budget, draws_per_row): (u64, u32),
        seed: u64,
        (slots, reservoir): (usize, usize),
    ) -> Result<Pool> {
        let cfg = PoolConfig { budget, draws_per_row: draws_per_row as f64, seed, window: None };
        Pool::start(Arc::new(layout), cfg, slots, reservoir, (0, 0))
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
                .map(|(&id, slots)| {
                    Ok(take(&layout.read_columns(id, &[true, true, false, false], Default::default())?, slots))
                })
                .collect::<Result<Vec<_>>>()?,
        );
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
    pub fn window(layout: Layout, rows: u64, seed: u64) -> Result<Pool> {
        if rows == 0 {
            anyhow::bail!("--shard-window must be at least 1 update");
        }
        let cfg = PoolConfig { budget: 0, draws_per_row: 1.0, seed, window: Some(rows) };
        Pool::start(Arc::new(layout.by_shard()), cfg, 1, 0, (0, 0))
    }

    /// Whether this is a shard window (`Pool::window`).
    pub fn is_window(&self) -> bool {
        self.cfg.window.is_some()
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
        self.starts.clear();
        for (slot, b) in self.resident.iter().enumerate() {
            self.starts.push(self.index.len());
            self.index.extend((0..b.n).map(|e| (slot as u32, e as u32)));
        }
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
                let (slot, _) = self.index[rng.below(self.index.len())];
                let aug = self.resident[slot as usize].aug.as_ref().expect("every block carries its scored rows");
                let row = aug.tree.find(rng.random() * aug.tree.total());
                let (local, step) = (row / (steps * per), (row / per) % steps);
                ScoredDraw { e: self.starts[slot as usize] + local, step, slot: slot as usize, row }
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
            && self.resident.iter().all(|b| b.ag.iter().zip(&b.obs).all(|(a, o)| a.to_bits() == o.to_bits()))
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
        let mut wait = Duration::ZERO;
        let next = {
            let rx = self.loader.get_mut().expect("the loader's channel is never poisoned");
            match rx.try_recv() {
                Ok(b) => b,
                Err(_) => {
                    let b = rx.recv().map_err(|_| anyhow!("the pool's loader stopped"))?;
                    wait = t0.elapsed();
                    self.stats.waits += 1;
                    self.stats.waited += wait;
                    self.stats.longest_wait = self.stats.longest_wait.max(wait);
                    b
                }
            }
        }?;
        let want = self.entries.get(self.next_entry);
        assert_eq!(next.id, want, "the loader and the pool agree on the order of entries");
        self.next_entry += 1;
        self.stats.swaps += 1;
        let mut leaving = self.resident.pop_front().expect("a pool holds blocks");
        // Its arrays go back to the loader to be filled again (`spawn_loader`). What is freed
        // (its scored rows; the arrays when the loader has a spare already) returns its pages to
        // the system (`keep_large_buffers_returnable`), milliseconds for a large block: done off
        // the drawing thread, so no batch waits for it.
        let unused = match self.spare.try_send(leaving.take_arrays()) {
            Err(TrySendError::Full(a) | TrySendError::Disconnected(a)) => Some(a),
            Ok(()) => None,
        };
        if unused.is_some() || leaving.aug.is_some() {
            std::thread::spawn(move || drop((leaving, unused)));
        }
        let (t, od, gd) = (self.layout.t, self.layout.task.obs_dim, self.layout.task.goal_dim);
        let len = self.goal_at.len();
        for j in self.keys.feed(&self.layout, next.id) {
            let slot = j % len;
            let (_, e, s) = self.keys.slots[slot];
            let (e, s) = (e as usize, s as usize);
            self.set_goal(slot, (next.first_episode + e as u64, s as u32), next.ag(e, s, t, gd), next.obs(e, s, t, od));
        }
        self.resident.push_back(next);
        self.reindex();
        self.stats.longest_swap = self.stats.longest_swap.max(t0.elapsed().saturating_sub(wait));
        Ok(())
    }

    /// Reservoir slot `slot` now holds the goal of table-wide (episode, step) `at`.
    fn set_goal(&mut self, slot: usize, at: (u64, u32), ag: &[f32], obs: &[f32]) {
        self.goal_at[slot] = at;
        self.goal_ag[slot * ag.len()..][..ag.len()].copy_from_slice(ag);
        self.goal_obs[slot * obs.len()..][..obs.len()].copy_from_slice(obs);
    }

    fn block(&self, e: usize) -> (&Block, usize) {
        let (slot, local) = self.index[e];
        (&self.resident[slot as usize], local as usize)
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
        if self.goal_at.is_empty() {
            // A shard window: uniform over the held shard's observations; the slot is the row.
            let (e, s) = (rng.below(self.index.len()), rng.below(self.layout.t));
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
        self.drawn += rows as f64;
        loop {
            let leaving = self.resident.front().expect("at least two blocks resident");
            let due = due(&self.layout, &self.cfg, leaving.id);
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
