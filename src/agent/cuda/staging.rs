//! The host's part of a CUDA update: Adam's constants and the batch (and TD3's target noise,
//! drawn from each agent's stream in the CPU engine's order) in one staging block, written
//! straight into the pinned buffer and copied to the device in one transfer; or, where the engine
//! holds the episodes, each row's numbers in them instead of its values.

use rayon::prelude::*;

use crate::agent::fused::{AdamStep, adam_step};
use crate::agent::{AgentConfig, Algo, Batch, Rows};
use crate::nprandom::NpRandom;

/// Adam's per-update constants of one network kind (kernels.cu's PGSER_STEP_SIZE …).
pub(super) const CONSTS: usize = 5;

/// One array of a batch: its offset in the staging block, its width, and the batch's field.
type Field = (usize, usize, fn(&Batch) -> &[f32]);

/// The staging block of `a` agents' batches of `n` rows, offsets in f32. With batches from the
/// host: Adam's constants (actor, then critics), then obs, goal, next_obs, action, reward,
/// weight, noise, each `[a, n, ·]`, all uploaded. With rows of held tables (`held`): the
/// constants, reward, weight, noise, then the row numbers `[3, a·n]` (obs, action, goal, as u32
/// bits), which is all that is uploaded; obs, goal, next_obs and action follow on the device
/// only, where `pgser_gather` writes them.
pub(super) struct Staged {
    a: usize,
    n: usize,
    od: usize,
    gd: usize,
    act: usize,
    pub(super) obs: usize,
    pub(super) goal: usize,
    pub(super) next_obs: usize,
    pub(super) action: usize,
    pub(super) reward: usize,
    pub(super) weight: usize,
    pub(super) noise: usize,
    /// Where the row numbers are, when the rows are gathered on the device.
    pub(super) index: Option<usize>,
    /// The f32 the host writes and copies each update (a prefix of the block).
    pub(super) upload: usize,
    pub(super) len: usize,
}

/// Where a stack's held tables start in the device's concatenated tables, in rows.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Base {
    pub(super) obs: u32,
    pub(super) action: u32,
    pub(super) goal: u32,
}

impl Staged {
    pub(super) fn new(a: usize, n: usize, od: usize, gd: usize, act: usize, held: bool) -> Staged {
        let mut at = 2 * CONSTS;
        let mut take = |d: usize| {
            let o = at;
            at += a * n * d;
            o
        };
        // Held: what the host sends first (reward, weight, noise, row numbers), then what
        // `pgser_gather` writes on the device. Otherwise the batch, then the rest.
        let (reward, weight, noise, index, obs, goal, next_obs, action) = if held {
            let (reward, weight, noise, index) = (take(1), take(1), take(act), take(3));
            (reward, weight, noise, Some(index), take(od), take(gd), take(od), take(act))
        } else {
            let (obs, goal, next_obs, action) = (take(od), take(gd), take(od), take(act));
            (take(1), take(1), take(act), None, obs, goal, next_obs, action)
        };
        let upload = index.map_or(at, |i| i + 3 * a * n);
        Staged { a, n, od, gd, act, obs, goal, next_obs, action, reward, weight, noise, index, upload, len: at }
    }

    /// This update's block from the host's batches: Adam's constants for the (actor, critic)
    /// `steps` and the Polyak weights `tau`, and every agent's batch. Each array is filled agent
    /// by agent across the worker threads: at 60 agents a batch is 7 MB and 123k noise draws,
    /// which one thread would take longer to write than the GPU takes to train on it.
    pub(super) fn fill(
        &self,
        host: &mut [f32],
        c: &AgentConfig,
        batches: &[Batch],
        noise_rngs: &mut [NpRandom],
        steps: (u64, u64),
        tau: Option<f64>,
    ) {
        let (a, n, act) = (self.a, self.n, self.act);
        let fields: [Field; 4] = [
            (self.obs, self.od, |b| &b.obs),
            (self.goal, self.gd, |b| &b.goal),
            (self.next_obs, self.od, |b| &b.next_obs),
            (self.action, act, |b| &b.action),
        ];
        for (at, d, pick) in fields {
            host[at..at + a * n * d].par_chunks_mut(n * d).zip(batches).for_each(|(x, b)| x.copy_from_slice(pick(b)));
        }
        let per_row: Vec<(&[f32], &[f32])> = batches.iter().map(|b| (&b.reward[..], &b.weight[..])).collect();
        self.fill_rest(host, c, &per_row, noise_rngs, steps, tau);
    }

    /// This update's block from rows of the held tables starting at `bases` (per table): the
    /// constants, rewards, weights and noise as `fill` writes them, and each row's numbers in the
    /// device's tables.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn fill_rows(
        &self,
        host: &mut [f32],
        c: &AgentConfig,
        rows: &[Rows],
        bases: &[Base],
        noise_rngs: &mut [NpRandom],
        steps: (u64, u64),
        tau: Option<f64>,
    ) {
        let (an, n) = (self.a * self.n, self.n);
        let index = self.index.expect("a block laid out for rows");
        let per_row: Vec<(&[f32], &[f32])> = rows.iter().map(|r| (&r.reward[..], &r.weight[..])).collect();
        self.fill_rest(host, c, &per_row, noise_rngs, steps, tau);
        let numbers = &mut host[index..index + 3 * an];
        let columns: [fn(&Rows) -> &[u32]; 3] = [|r| &r.obs, |r| &r.action, |r| &r.goal];
        let base: [fn(&Base) -> u32; 3] = [|b| b.obs, |b| b.action, |b| b.goal];
        for ((out, pick), base) in numbers.chunks_mut(an).zip(columns).zip(base) {
            out.par_chunks_mut(n).zip(rows).for_each(|(x, r)| {
                let b = base(&bases[r.table]);
                for (v, &i) in x.iter_mut().zip(pick(r)) {
                    *v = f32::from_bits(b + i);
                }
            });
        }
    }

    /// Adam's constants, rewards, weights (1 where a batch has none) and TD3's target noise.
    fn fill_rest(
        &self,
        host: &mut [f32],
        c: &AgentConfig,
        per_row: &[(&[f32], &[f32])],
        noise_rngs: &mut [NpRandom],
        steps: (u64, u64),
        tau: Option<f64>,
    ) {
        let (a, n, act) = (self.a, self.n, self.act);
        adam_consts(&mut host[..CONSTS], c.lr(), steps.0, tau);
        adam_consts(&mut host[CONSTS..2 * CONSTS], c.lr(), steps.1, tau);
        host[self.reward..self.reward + a * n]
            .par_chunks_mut(n)
            .zip(per_row)
            .for_each(|(x, (r, _))| x.copy_from_slice(r));
        host[self.weight..self.weight + a * n]
            .par_chunks_mut(n)
            .zip(per_row)
            .for_each(|(x, (_, w))| if w.is_empty() { x.fill(1.0) } else { x.copy_from_slice(w) });
        if c.algo != Algo::Ddpg {
            let noise = &mut host[self.noise..self.noise + a * n * act];
            noise.par_chunks_mut(n * act).zip(noise_rngs.par_iter_mut()).for_each(|(x, rng)| {
                for v in x {
                    *v = (rng.standard_normal() * c.policy_noise).clamp(-c.noise_clip, c.noise_clip) as f32;
                }
            });
        }
    }
}

/// Adam's constants for step `step` (the CPU engine's), and the Polyak weights when the targets
/// move, in kernels.cu's PGSER_STEP_SIZE … order. Step 0 (a network that has not moved yet and
/// does not move now) gets step 1's, which no kernel reads.
fn adam_consts(out: &mut [f32], lr: f64, step: u64, tau: Option<f64>) {
    let AdamStep { step_size, bc2_sqrt, keep, take } = adam_step(lr, step.max(1), tau);
    out.copy_from_slice(&[step_size, bc2_sqrt, keep, take, if tau.is_some() { 1.0 } else { 0.0 }]);
}
