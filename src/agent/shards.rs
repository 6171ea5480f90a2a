//! A stack of agents split across the CPU's cores, on burn's engine (`--device cpu-burn`).
//!
//! On the flex backend one stack runs each layer as one batched product, but the rest of an
//! update (burn's elementwise ops, its autodiff bookkeeping, Adam, Polyak) runs on the thread that
//! calls it, so two cores ran a stack of 10 at one core's worth (BENCHMARKS.md). Shards are
//! independent sub-stacks, one per worker thread, that update side by side. An agent's numbers do
//! not depend on the stack it sits in (its rows of every batched product are its own; the tests
//! in `tests.rs` check this to the bit), so the shard count changes the speed, never the
//! checkpoints: a run on 2 threads writes the bytes of the same run on 1. A GPU gets one shard: a
//! stack there is one queue of kernels, and splitting it only adds launches. So does the
//! hand-written CPU engine (`--device cpu`, `fused/`), which spreads its own pieces over the
//! pool.

use burn::tensor::Tensor;
use rayon::prelude::*;

use super::engine::{Rows, Table};
use super::{Agent, Backend, Batch, UpdateStats};
use crate::task::Task;

/// Agents trained in lockstep, held as `parts`: contiguous sub-stacks of near-equal size. Agent i
/// of the whole is agent `i - starts[p]` of part p.
pub struct Shards {
    parts: Vec<Agent>,
    starts: Vec<usize>,
    /// With more than one part, a one-thread pool per part that runs its work. Inside a part
    /// burn's own rayon use (the batched product's per-matrix split, gemm's threads) must stay
    /// on that part's core: in the shared pool the two parts' small tasks interleave and wait on
    /// each other, and a stack of 10 in two parts ran no faster than in one (measured).
    pools: Vec<rayon::ThreadPool>,
}

/// Parts for a stack of `agents` on `backend`: one per worker thread of the current rayon pool on
/// burn's CPU backend (at most one per agent); one on a GPU, and on the hand-written CPU engine,
/// which spreads its own work over the pool.
fn shard_count(agents: usize, backend: Backend) -> usize {
    if backend == Backend::CpuBurn { rayon::current_num_threads().clamp(1, agents.max(1)) } else { 1 }
}

impl Shards {
    /// `agents` (stacks, each usually of one agent, all with the same settings, task and update
    /// count) regrouped in order into the parts `backend` wants; the first `len % parts` get one
    /// more. Where `backend` has a hand-written engine (`cpu`, `cuda`), the stack trains on it;
    /// that fails, in one line, where the engine cannot start (no GPU).
    pub fn new(agents: Vec<Agent>, backend: Backend) -> anyhow::Result<Shards> {
        assert!(!agents.is_empty(), "no agent to shard");
        let arithmetic = agents[0].config.arithmetic;
        if !arithmetic.is_native() && backend.engine().is_none() {
            anyhow::bail!(
                "--arithmetic {} with --device {}: only the CPU engine (--device cpu) has it; burn's products round as gemm picks",
                arithmetic.name(),
                backend.name()
            );
        }
        let k = shard_count(agents.len(), backend).clamp(1, agents.len());
        let mut rest = agents.into_iter();
        let (mut parts, mut starts, mut start) = (Vec::with_capacity(k), Vec::with_capacity(k), 0);
        let units = rest.len();
        for p in 0..k {
            let take = units / k + usize::from(p < units % k);
            let group: Vec<Agent> = rest.by_ref().take(take).collect();
            starts.push(start);
            start += group.iter().map(Agent::agents).sum::<usize>();
            let mut part = if group.len() == 1 { group.into_iter().next().expect("one") } else { Agent::stack(group) };
            if let Some(kind) = backend.engine() {
                part.attach(kind)?;
            }
            parts.push(part);
        }
        let pools = if k > 1 {
            (0..k)
                .map(|p| {
                    rayon::ThreadPoolBuilder::new()
                        .num_threads(1)
                        .thread_name(move |_| format!("pgser-shard-{p}"))
                        .build()
                        .expect("a one-thread pool")
                })
                .collect()
        } else {
            Vec::new()
        };
        Ok(Shards { parts, starts, pools })
    }

    /// Agents in all parts.
    pub fn agents(&self) -> usize {
        self.parts.iter().map(Agent::agents).sum()
    }

    /// Updates done so far (the same for every agent).
    pub fn updates(&self) -> u64 {
        self.parts[0].updates
    }

    pub fn task(&self) -> &Task {
        &self.parts[0].task
    }

    /// The stacks, in order.
    pub fn parts(&self) -> &[Agent] {
        &self.parts
    }

    /// Brings every part's burn state up to date (`Agent::sync`): before checkpoints are written.
    pub fn sync(&mut self) {
        self.parts.iter_mut().for_each(Agent::sync);
    }

    /// Agent i of the whole as (its part, its index there): what checkpoints are written from
    /// (after `sync`).
    pub fn locate(&self, i: usize) -> (&Agent, usize) {
        let p = self.starts.partition_point(|&s| s <= i) - 1;
        (&self.parts[p], i - self.starts[p])
    }

    /// `items` (one per agent, in order) cut into each part's piece.
    fn pieces<'a, T>(&self, items: &'a [T]) -> Vec<&'a [T]> {
        let ends = self.starts[1..].iter().copied().chain([items.len()]);
        self.starts.iter().zip(ends).map(|(&s, e)| &items[s..e]).collect()
    }

    /// One update of every agent, agent i on `batches[i]`; the parts run side by side.
    pub fn update(&mut self, batches: &[Batch]) -> UpdateStats {
        self.step(batches, true).expect("asked for")
    }

    /// `update`, returning the losses only when `stats` (`Agent::step`).
    pub fn step(&mut self, batches: &[Batch], stats: bool) -> Option<UpdateStats> {
        assert_eq!(batches.len(), self.agents(), "one batch per agent");
        if self.pools.is_empty() {
            return self.parts[0].step(batches, stats);
        }
        let chunks = self.pieces(batches);
        let pools = &self.pools;
        let stats: Vec<UpdateStats> = self
            .parts
            .par_iter_mut()
            .zip(chunks)
            .enumerate()
            .map(|(p, (part, b))| pools[p].install(|| part.step(b, stats)))
            .collect::<Option<_>>()?;
        Some(UpdateStats::cat(stats))
    }

    /// Keeps `tables` on the device of a stack that trains as one part on a hand-written
    /// engine (`Agent::hold`); returns whether it does. Parts on burn's CPU engine hold none.
    pub fn hold(&mut self, tables: &[Table]) -> anyhow::Result<bool> {
        match self.parts.as_mut_slice() {
            [one] => one.hold(tables),
            _ => Ok(false),
        }
    }

    /// `step` on rows of the held tables (`Agent::step_rows`).
    pub fn step_rows(&mut self, rows: &[Rows], stats: bool) -> Option<UpdateStats> {
        assert_eq!(self.parts.len(), 1, "only a stack of one part holds tables");
        self.parts[0].step_rows(rows, stats)
    }

    /// Every agent's policy on its rows (as [`Agent::act_all`]); the parts run side by side.
    pub fn act_all(&self, rows: &[(&[f32], &[f32])], n: usize) -> Vec<Vec<f32>> {
        if self.pools.is_empty() {
            return self.parts[0].act_all(rows, n);
        }
        let chunks = self.pieces(rows);
        let outs: Vec<Vec<Vec<f32>>> = self
            .parts
            .par_iter()
            .zip(chunks)
            .enumerate()
            .map(|(p, (part, r))| self.pools[p].install(|| part.act_all(r, n)))
            .collect();
        outs.into_iter().flatten().collect()
    }
}

impl UpdateStats {
    /// The stats of consecutive parts as one, in order.
    pub fn cat(parts: Vec<UpdateStats>) -> UpdateStats {
        if parts.len() == 1 {
            return parts.into_iter().next().expect("one part");
        }
        let actor = parts.iter().all(|p| p.actor_loss.is_some());
        let (mut critic, mut q, mut actor_loss) = (Vec::new(), Vec::new(), Vec::new());
        for p in parts {
            critic.push(p.critic_loss);
            q.push(p.q_mean);
            actor_loss.extend(p.actor_loss);
        }
        UpdateStats {
            critic_loss: Tensor::cat(critic, 0),
            q_mean: Tensor::cat(q, 0),
            actor_loss: actor.then(|| Tensor::cat(actor_loss, 0)),
        }
    }
}
