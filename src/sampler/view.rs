//! β as a draw sees it: whole episodes it can draw transitions and future goals from, and a way
//! to draw a goal from anywhere in the table.
//!
//! Two things are a view. [`InMemory`] is the whole table held as [`Episodes`]: every episode is
//! resident, and a random goal is an (episode, step) uniform over all its observations. The
//! out-of-core pool (`pool.rs`) holds only some episodes at a time, within a memory budget, and
//! draws random goals from a reservoir fed from the whole table. Samplers written against
//! `View` (pgser's own batches, OGBench's layout) run on either unchanged, so a table larger than
//! memory needs no second sampler.
//!
//! Episode numbers a view hands out (`0..episodes()`) are positions among the resident episodes;
//! [`View::episode_number`] turns one into the table-wide number (in shard order across a
//! folder) that a batch reports as where a row came from.

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;

use crate::nprandom::NpRandom;
use crate::task::Task;
use crate::trajectory::Episodes;

/// Where a random goal came from, and where its vectors can be read in the view that drew it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GoalSource {
    /// The table-wide episode number of the goal's observation.
    pub episode: u64,
    /// Its step, in `0..t()`.
    pub step: u32,
    /// The view's own handle on the goal's data (a flat row, or a reservoir slot).
    pub slot: u64,
}

/// β as a draw sees it (see the module doc).
pub trait View: Send + Sync {
    fn task(&self) -> &Task;
    /// Resident episodes, numbered `0..episodes()`.
    fn episodes(&self) -> usize;
    /// Observations per episode (T); an episode has T − 1 transitions.
    fn t(&self) -> usize;
    /// o[e, s], s < T.
    fn obs(&self, e: usize, s: usize) -> &[f32];
    /// ag[e, s], s < T.
    fn ag(&self, e: usize, s: usize) -> &[f32];
    /// The desired goal g[e, s], s < T − 1.
    fn goal(&self, e: usize, s: usize) -> &[f32];
    /// u[e, s], s < T − 1.
    fn action(&self, e: usize, s: usize) -> &[f32];
    /// The table-wide number of resident episode `e`.
    fn episode_number(&self, e: usize) -> u64;
    /// An observation drawn uniformly from the whole table (every episode of every shard, every
    /// step `0..T`), as a goal source.
    fn random_goal(&self, rng: &mut NpRandom) -> GoalSource;
    /// The achieved goal of a source `random_goal` returned.
    fn goal_ag(&self, g: GoalSource) -> &[f32];
    /// The observation of a source `random_goal` returned.
    fn goal_obs(&self, g: GoalSource) -> &[f32];
    /// Called between batches: a pool takes in the blocks its loader has read when their turn
    /// comes. Never changes what is resident in the middle of a batch.
    fn refresh(&mut self) -> Result<()> {
        Ok(())
    }
}

/// The whole table in memory.
#[derive(Debug, Clone)]
pub struct InMemory(pub Arc<Episodes>);

impl View for InMemory {
    fn task(&self) -> &Task {
        &self.0.task
    }
    fn episodes(&self) -> usize {
        self.0.n
    }
    fn t(&self) -> usize {
        self.0.t
    }
    fn obs(&self, e: usize, s: usize) -> &[f32] {
        self.0.obs(e, s)
    }
    fn ag(&self, e: usize, s: usize) -> &[f32] {
        self.0.ag(e, s)
    }
    fn goal(&self, e: usize, s: usize) -> &[f32] {
        self.0.goal(e, s)
    }
    fn action(&self, e: usize, s: usize) -> &[f32] {
        self.0.action(e, s)
    }
    fn episode_number(&self, e: usize) -> u64 {
        e as u64
    }
    /// `swap::random_goal`: one draw of `below(n · t)`, as the in-memory sampler has always made it.
    fn random_goal(&self, rng: &mut NpRandom) -> GoalSource {
        let (e, s) = crate::swap::random_goal(self.0.n, self.0.t, rng);
        GoalSource { episode: e as u64, step: s as u32, slot: (e * self.0.t + s) as u64 }
    }
    fn goal_ag(&self, g: GoalSource) -> &[f32] {
        self.0.ag(g.episode as usize, g.step as usize)
    }
    fn goal_obs(&self, g: GoalSource) -> &[f32] {
        self.0.obs(g.episode as usize, g.step as usize)
    }
}

/// How much of β a sampler may hold.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Budget {
    /// The whole table in memory (today's samplers, number for number).
    #[default]
    Unbounded,
    /// At most this many bytes: the whole table when it fits, an out-of-core pool otherwise.
    Bytes(u64),
}

/// Opens a trajectory table (a file or a table folder) as a view within `budget`.
pub fn open(path: &Path, budget: Budget, seed: u64) -> Result<Box<dyn View>> {
    let _ = seed;
    match budget {
        Budget::Unbounded => Ok(Box::new(InMemory(Arc::new(Episodes::load(path)?)))),
        Budget::Bytes(b) => super::pool::open(path, b, seed),
    }
}
