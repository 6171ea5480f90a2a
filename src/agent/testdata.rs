//! Batches and normalizers the engines' tests share (`fused/tests.rs`, `cuda/tests.rs`): random
//! rows with both reward values and priority weights, and per-agent normalizers that differ, so
//! that an agent's rows reaching another agent's networks would show.

use super::{Batch, Normalizer};
use crate::nprandom::NpRandom;
use crate::task::Task;

pub fn batch(task: &Task, n: usize, seed: u64, weighted: bool) -> Batch {
    let mut rng = NpRandom::new(seed);
    let mut u = |k: usize| (0..k).map(|_| rng.uniform(-1.0, 1.0) as f32).collect::<Vec<_>>();
    Batch {
        n,
        obs: u(n * task.obs_dim),
        goal: u(n * task.goal_dim),
        action: u(n * task.act_dim).into_iter().map(|a| 0.9 * a).collect(),
        reward: u(n).into_iter().map(|x| if x < 0.0 { -1.0 } else { 0.0 }).collect(),
        next_obs: u(n * task.obs_dim),
        weight: if weighted { u(n).into_iter().map(|x| 0.75 + 0.5 * x).collect() } else { vec![] },
    }
}

pub fn norms(task: &Task, a: usize) -> Vec<Normalizer> {
    (0..a)
        .map(|i| {
            let mut n = Normalizer::identity(task, 5.0);
            n.obs_mean.iter_mut().for_each(|m| *m = 0.1 * i as f32);
            n.goal_std.iter_mut().for_each(|s| *s = 0.5 + i as f32);
            n
        })
        .collect()
}
