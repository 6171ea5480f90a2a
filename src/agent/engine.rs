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

    /// Every agent's policy, agent i on `rows[i]` (raw observations and goals, `n` rows).
    fn act_all(&self, norms: &[Normalizer], rows: &[(&[f32], &[f32])], n: usize) -> Result<Vec<Vec<f32>>>;

    /// The smallest of agent 0's critics' values for `n` rows (raw s, g, a): Alg. 2's score.
    fn q(&self, norm: &Normalizer, obs: &[f32], goal: &[f32], action: &[f32], n: usize) -> Result<Vec<f32>>;

    /// The training state, on the host.
    fn state(&self) -> Result<State>;
}
