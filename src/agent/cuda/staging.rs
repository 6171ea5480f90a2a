//! The host's part of a CUDA update: Adam's constants and the batch (and TD3's target noise,
//! drawn from each agent's stream in the CPU engine's order) in one staging block, written
//! straight into the pinned buffer and copied to the device in one transfer.

use rayon::prelude::*;

use crate::agent::fused::{AdamStep, adam_step};
use crate::agent::{AgentConfig, Algo, Batch};
use crate::nprandom::NpRandom;

/// Adam's per-update constants of one network kind (kernels.cu's PGSER_STEP_SIZE …).
pub(super) const CONSTS: usize = 5;

/// One array of a batch: its offset in the staging block, its width, and the batch's field.
type Field = (usize, usize, fn(&Batch) -> &[f32]);

/// The staging block of `a` agents' batches of `n` rows: Adam's constants (actor, then critics),
/// then obs, goal, next_obs, action, reward, weight, noise, each `[a, n, ·]`; offsets in f32.
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
    pub(super) len: usize,
}

impl Staged {
    pub(super) fn new(a: usize, n: usize, od: usize, gd: usize, act: usize) -> Staged {
        let mut at = 2 * CONSTS;
        let mut take = |d: usize| {
            let o = at;
            at += a * n * d;
            o
        };
        let (obs, goal, next_obs, action) = (take(od), take(gd), take(od), take(act));
        let (reward, weight, noise) = (take(1), take(1), take(act));
        Staged { a, n, od, gd, act, obs, goal, next_obs, action, reward, weight, noise, len: at }
    }

    /// This update's block: Adam's constants for the (actor, critic) `steps` and the Polyak
    /// weights `tau`, and every agent's batch. Each array is filled agent by agent across the
    /// worker threads: at 60 agents a batch is 7 MB and 123k noise draws, which one thread would
    /// take longer to write than the GPU takes to train on it.
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
        adam_consts(&mut host[..CONSTS], c.lr(), steps.0, tau);
        adam_consts(&mut host[CONSTS..2 * CONSTS], c.lr(), steps.1, tau);
        let fields: [Field; 5] = [
            (self.obs, self.od, |b| &b.obs),
            (self.goal, self.gd, |b| &b.goal),
            (self.next_obs, self.od, |b| &b.next_obs),
            (self.action, act, |b| &b.action),
            (self.reward, 1, |b| &b.reward),
        ];
        for (at, d, pick) in fields {
            host[at..at + a * n * d].par_chunks_mut(n * d).zip(batches).for_each(|(x, b)| x.copy_from_slice(pick(b)));
        }
        host[self.weight..self.weight + a * n]
            .par_chunks_mut(n)
            .zip(batches)
            .for_each(|(x, b)| if b.weight.is_empty() { x.fill(1.0) } else { x.copy_from_slice(&b.weight) });
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
