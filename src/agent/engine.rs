//! The seam between an agent and the engines that run its update, so that `train/`, `score/` and
//! evaluation never name one. Two hand-written engines implement it: the CPU's (`fused/`,
//! `--device cpu`) and the GPU's (`cuda/`, `--device cuda`). burn's update (`td3.rs`) is the
//! reference both are tested against, and what `cpu-burn`, `wgpu` and `cuda-burn` run.
//!
//! An engine owns the stack's training state while it trains: networks, targets, Adam moments and
//! step counts, in the flat layout of `State`. The agent's burn fields, which checkpoints are
//! written from, are brought up to date from `Engine::state` (`Agent::sync`).
//!
//! Data flows one way: a sampler makes `Batch`es on the host, an engine turns them into tensors.
//! An engine on a GPU may also hold the episodes themselves (`Engine::hold`): the sampler then
//! sends `Rows`, each row's place in those episodes, and the engine gathers the batch where it
//! trains. `Rows::gather` is that gather on the host, so both forms give the same batch.

use anyhow::Result;

use super::{AgentConfig, Normalizer};
use crate::nprandom::NpRandom;

/// A training batch on the host: row i is (s, g, a, r, s'). `goal` is the goal the transition is
/// trained on (original, relabelled or swapped) and `reward` was computed for that goal.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Batch {
    pub n: usize,
    pub obs: Vec<f32>,
    pub goal: Vec<f32>,
    pub action: Vec<f32>,
    pub reward: Vec<f32>,
    pub next_obs: Vec<f32>,
    /// Importance-sampling weights of the critic loss per row; empty means all 1.
    pub weight: Vec<f32>,
}

impl Batch {
    /// Appends `other`'s rows (weights are handled by the caller, who knows both halves).
    pub fn append(&mut self, other: &Batch) {
        self.n += other.n;
        self.obs.extend_from_slice(&other.obs);
        self.goal.extend_from_slice(&other.goal);
        self.action.extend_from_slice(&other.action);
        self.reward.extend_from_slice(&other.reward);
        self.next_obs.extend_from_slice(&other.next_obs);
    }
}

/// Episodes as an engine can hold them, borrowed from the sampler's table: observations and
/// achieved goals `[episodes·T, ·]`, desired goals and actions `[episodes·(T − 1), ·]`.
#[derive(Debug, Clone, Copy)]
pub struct Table<'a> {
    pub obs_dim: usize,
    pub goal_dim: usize,
    pub act_dim: usize,
    pub obs: &'a [f32],
    pub ag: &'a [f32],
    pub g: &'a [f32],
    pub u: &'a [f32],
}

impl Table<'_> {
    /// Rows of the goals a row may name: the achieved goals, then the desired goals.
    pub fn goal_rows(&self) -> usize {
        (self.ag.len() + self.g.len()) / self.goal_dim
    }

    /// Goal row `i` (`Rows::goal`'s numbering).
    pub fn goal(&self, i: usize) -> &[f32] {
        let (gd, ag_rows) = (self.goal_dim, self.ag.len() / self.goal_dim);
        if i < ag_rows { &self.ag[i * gd..(i + 1) * gd] } else { &self.g[(i - ag_rows) * gd..(i - ag_rows + 1) * gd] }
    }

    /// The table's size in bytes.
    pub fn bytes(&self) -> usize {
        4 * (self.obs.len() + self.ag.len() + self.g.len() + self.u.len())
    }
}

/// A training batch as places in a `Table`: row i is s = obs row `obs[i]`, s′ the row after it,
/// a = action row `action[i]`, g = goal row `goal[i]` (achieved goals first, then desired ones:
/// `Table::goal`), with its reward already computed for that goal on the host (by the task's
/// reward function, as for a `Batch`: so an engine that gathers on a GPU trains on the very
/// rewards the CPU engine does, whatever the goal metric). 12 bytes of indices a row instead of
/// its floats (228 bytes on FetchPush).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Rows {
    /// Which of the tables given to `Engine::hold` the rows are in.
    pub table: usize,
    pub obs: Vec<u32>,
    pub action: Vec<u32>,
    pub goal: Vec<u32>,
    pub reward: Vec<f32>,
    /// As `Batch::weight`: empty means all 1.
    pub weight: Vec<f32>,
}

impl Rows {
    pub fn len(&self) -> usize {
        self.obs.len()
    }

    pub fn is_empty(&self) -> bool {
        self.obs.is_empty()
    }

    /// The batch these rows name, built on the host.
    pub fn gather(&self, t: &Table) -> Batch {
        let (od, ad, n) = (t.obs_dim, t.act_dim, self.len());
        let mut b = Batch { n, reward: self.reward.clone(), weight: self.weight.clone(), ..Batch::default() };
        b.obs.reserve(n * od);
        b.next_obs.reserve(n * od);
        b.action.reserve(n * ad);
        b.goal.reserve(n * t.goal_dim);
        for i in 0..n {
            let (o, a) = (self.obs[i] as usize, self.action[i] as usize);
            b.obs.extend_from_slice(&t.obs[o * od..(o + 1) * od]);
            b.next_obs.extend_from_slice(&t.obs[(o + 1) * od..(o + 2) * od]);
            b.action.extend_from_slice(&t.u[a * ad..(a + 1) * ad]);
            b.goal.extend_from_slice(t.goal(self.goal[i] as usize));
        }
        b
    }
}

/// One network's parameters, Adam moments and target copy, flat in `Shape` order (w0, b0, w1,
/// b1, …, each weight `[in, out]`).
#[derive(Debug, Clone, PartialEq)]
pub struct Net {
    pub p: Vec<f32>,
    pub m: Vec<f32>,
    pub v: Vec<f32>,
    pub target: Vec<f32>,
}

/// One agent's networks: its actor and its K critics.
#[derive(Debug, Clone, PartialEq)]
pub struct Nets {
    pub actor: Net,
    pub critics: Vec<Net>,
}

/// A stack's training state on the host.
#[derive(Debug, Clone, PartialEq)]
pub struct State {
    pub nets: Vec<Nets>,
    pub actor_step: u64,
    pub critic_step: u64,
}

/// Per agent: (critic loss, mean Q₁ over the batch, actor loss if the actor moved).
pub type Stats = Vec<(f32, f32, Option<f32>)>;

/// Floats in the CUDA engine's products: FP32 (cuBLAS's default math, the CPU engine's within
/// rounding), or TF32 tensor cores (`--device cuda-tf32`, opt-in: 10-bit mantissas in products).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    F32,
    Tf32,
}

/// Which hand-written engine a stack trains on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EngineKind {
    Cpu,
    Cuda(Precision),
}

/// What an engine does for a stack of A agents.
pub trait Engine: Send + Sync {
    /// One update of every agent, agent i on `batches[i]` (all of one size), with its normalizer
    /// and target-noise stream; `updates` is the count after this update (it decides the delayed
    /// actor and targets). With `stats`, returns the update's losses (on a GPU that waits for the
    /// update to finish, so the trainer asks only on logging steps).
    fn update(
        &mut self,
        c: &AgentConfig,
        batches: &[Batch],
        norms: &[Normalizer],
        noise_rngs: &mut [NpRandom],
        updates: u64,
        stats: bool,
    ) -> Result<Option<Stats>>;

    /// Keeps `tables` where the engine trains, so that updates can name their rows instead of
    /// carrying them (`update_rows`). Returns whether it does: an engine whose batches are in host
    /// memory anyway (the CPU's) does not, nor does a GPU the tables would not fit in beside its
    /// work; the trainer then sends `Batch`es, gathered on the host.
    fn hold(&mut self, _tables: &[Table]) -> Result<bool> {
        Ok(false)
    }

    /// `update`, agent i on the batch `rows[i]` names in the held tables (all of one size).
    fn update_rows(
        &mut self,
        _c: &AgentConfig,
        _rows: &[Rows],
        _norms: &[Normalizer],
        _noise_rngs: &mut [NpRandom],
        _updates: u64,
        _stats: bool,
    ) -> Result<Option<Stats>> {
        anyhow::bail!("this engine holds no tables: train it on batches")
    }

    /// Every agent's policy, agent i on `rows[i]` (raw observations and goals, `n` rows).
    fn act_all(&self, norms: &[Normalizer], rows: &[(&[f32], &[f32])], n: usize) -> Result<Vec<Vec<f32>>>;

    /// The smallest of agent 0's critics' values for `n` rows (raw s, g, a): Alg. 2's score.
    fn q(&self, norm: &Normalizer, obs: &[f32], goal: &[f32], action: &[f32], n: usize) -> Result<Vec<f32>>;

    /// The training state, on the host.
    fn state(&self) -> Result<State>;
}
