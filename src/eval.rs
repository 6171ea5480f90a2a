//! Evaluation: the deterministic policy in the task's MuJoCo environment (docs/domain.md).
//!
//! Episodes run in lockstep so the policy sees one batch of all live episodes per step (one
//! forward pass instead of E), while the environments step in parallel on rayon's pool. Episode
//! i is reset with seed `seed + i`, so a report is a function of (policy, seed, episodes).
//!
//! An episode is T environment steps (gymnasium's `max_episode_steps`, 50 for Fetch), so the
//! return, the sum of the paper's eq. 2 rewards, lies in [−T, 0] and `paper_score` = T + return
//! is the paper's Table 2 number (the sum of {0, 1} rewards). WGCSL data holds T observations
//! and T − 1 actions per episode; evaluation follows the environment and the paper, not the
//! data's length.

use anyhow::Result;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::env::{self, GoalEnv, Obs};

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub episodes: usize,
    pub return_mean: f64,
    pub return_std: f64,
    /// Fraction of episodes whose final step reached the goal (gymnasium's `is_success`).
    pub success_rate: f64,
    /// T + return_mean: the paper's score, in [0, T].
    pub paper_score: f64,
}

/// A batched policy: `n` rows of observations and desired goals in, `n` actions out.
pub trait Policy {
    fn act(&self, obs: &[f32], goal: &[f32], n: usize) -> Vec<f32>;
}

impl Policy for crate::agent::Agent {
    fn act(&self, obs: &[f32], goal: &[f32], n: usize) -> Vec<f32> {
        crate::agent::Agent::act(self, obs, goal, n)
    }
}

/// Uniform random actions in [−1, 1]: the floor every learned policy is compared with.
/// Seeded, and drawn from one stream in episode order, so its report is reproducible.
pub struct RandomPolicy {
    pub act_dim: usize,
    pub rng: std::sync::Mutex<crate::env::rng::NpRandom>,
}

impl RandomPolicy {
    pub fn new(act_dim: usize, seed: u64) -> RandomPolicy {
        RandomPolicy { act_dim, rng: std::sync::Mutex::new(crate::env::rng::NpRandom::new(seed)) }
    }
}

impl Policy for RandomPolicy {
    fn act(&self, _obs: &[f32], _goal: &[f32], n: usize) -> Vec<f32> {
        let mut rng = self.rng.lock().expect("not poisoned");
        (0..n * self.act_dim).map(|_| rng.uniform(-1.0, 1.0) as f32).collect()
    }
}

/// Runs `episodes` episodes of `policy` in `task_name` with seeds `seed`, `seed + 1`, ...
pub fn evaluate(task_name: &str, policy: &dyn Policy, episodes: usize, seed: u64) -> Result<EvalReport> {
    let act = |rows: &[(&[f32], &[f32])], n: usize| vec![policy.act(rows[0].0, rows[0].1, n)];
    Ok(run(task_name, 1, episodes, seed, &act)?.remove(0))
}

/// Every agent of a stack on the same `episodes` episodes (seeds `seed`, `seed + 1`, ...): one
/// report per agent, each what `evaluate` gives that agent alone, with one forward pass of the
/// whole stack per environment step.
pub fn evaluate_stack(agent: &crate::agent::Agent, episodes: usize, seed: u64) -> Result<Vec<EvalReport>> {
    run(&agent.task.name, agent.agents(), episodes, seed, &|rows, n| agent.act_all(rows, n))
}

/// Agent i's policy on rows[i] = (observations, desired goals) of n rows each.
type StackPolicy<'a> = dyn Fn(&[(&[f32], &[f32])], usize) -> Vec<Vec<f32>> + 'a;

/// `members` policies × `episodes` episodes in lockstep; environment `m·episodes + i` is member
/// m's episode i, reset with seed `seed + i`.
fn run(task_name: &str, members: usize, episodes: usize, seed: u64, act: &StackPolicy) -> Result<Vec<EvalReport>> {
    let total = members * episodes;
    let mut envs: Vec<Box<dyn GoalEnv + Send>> = (0..total).map(|_| env::make(task_name)).collect::<Result<_>>()?;
    let task = envs.first().map(|e| e.task().clone());
    let Some(task) = task else {
        let empty = EvalReport { episodes: 0, return_mean: 0.0, return_std: 0.0, success_rate: 0.0, paper_score: 0.0 };
        return Ok(vec![empty; members]);
    };
    let mut obs: Vec<Obs> =
        envs.par_iter_mut().enumerate().map(|(j, e)| e.reset(Some(seed + (j % episodes) as u64))).collect();
    let mut returns = vec![0.0f64; total];
    let mut success = vec![false; total];
    for _ in 0..task.t {
        let flat =
            |f: fn(&Obs) -> &Vec<f64>| obs.iter().flat_map(|o| f(o).iter().map(|&x| x as f32)).collect::<Vec<f32>>();
        let (o, g) = (flat(|o| &o.observation), flat(|o| &o.desired_goal));
        let rows: Vec<(&[f32], &[f32])> = (0..members)
            .map(|m| {
                let (od, gd) = (task.obs_dim * episodes, task.goal_dim * episodes);
                (&o[m * od..(m + 1) * od], &g[m * gd..(m + 1) * gd])
            })
            .collect();
        let actions: Vec<f32> = act(&rows, episodes).concat();
        let steps: Vec<_> = envs
            .par_iter_mut()
            .zip(actions.par_chunks(task.act_dim))
            .map(|(e, a)| e.step(&a.iter().map(|&x| x as f64).collect::<Vec<f64>>()))
            .collect();
        for (j, s) in steps.into_iter().enumerate() {
            returns[j] += s.reward;
            success[j] = s.success;
            obs[j] = s.obs;
        }
    }
    Ok(returns
        .chunks(episodes)
        .zip(success.chunks(episodes))
        .map(|(returns, success)| {
            let n = episodes as f64;
            let mean = returns.iter().sum::<f64>() / n;
            let std = (returns.iter().map(|r| (r - mean) * (r - mean)).sum::<f64>() / n).sqrt();
            EvalReport {
                episodes,
                return_mean: mean,
                return_std: std,
                success_rate: success.iter().filter(|&&s| s).count() as f64 / n,
                paper_score: task.t as f64 + mean,
            }
        })
        .collect())
}
