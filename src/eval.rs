//! Evaluation: the deterministic policy in the task's MuJoCo environment (docs/domain.md).
//!
//! Episodes run in lockstep so the policy sees one batch of all live episodes per step (one
//! forward pass instead of E), while the environments step in parallel on rayon's pool; at most
//! 64 environments live at once (waves, see `run`), so memory does not grow with the stack. Episode
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

/// Whether a task is scored by its success rate in percent, as OGBench scores its datasets
/// (`pointmaze-medium-navigate-v0`), rather than by the paper's score: a maze episode ends at
/// its goal, so T + return would count the steps it took, not whether it arrived.
pub fn scored_by_success(task: &str) -> bool {
    env::pointmaze::resolve(task).is_some()
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    pub episodes: usize,
    pub return_mean: f64,
    pub return_std: f64,
    /// Fraction of episodes whose final step reached the goal (gymnasium's `is_success`).
    pub success_rate: f64,
    /// T + return_mean: the paper's score, in [0, T].
    pub paper_score: f64,
    /// Environments with fixed evaluation tasks (OGBench's mazes: 5): each task's success rate,
    /// task 1 first, as OGBench reports them beside their mean. Empty for the other tasks.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub task_success: Vec<f64>,
}

impl EvalReport {
    /// One line for a terminal: "50 episodes of FetchReach: return …, success …, paper score …"
    /// (and each fixed task's success, where the environment has them).
    pub fn summary(&self, task: &str) -> String {
        let tasks = if self.task_success.is_empty() {
            String::new()
        } else {
            let each: Vec<String> = self.task_success.iter().map(|s| format!("{s:.3}")).collect();
            format!("; success per task (1–{}): {}", each.len(), each.join(" "))
        };
        format!(
            "{} episodes of {task}: return {:.2} ± {:.2}, success {:.3}, paper score {:.2}{tasks}",
            self.episodes, self.return_mean, self.return_std, self.success_rate, self.paper_score
        )
    }
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
    pub rng: std::sync::Mutex<crate::nprandom::NpRandom>,
}

impl RandomPolicy {
    pub fn new(act_dim: usize, seed: u64) -> RandomPolicy {
        RandomPolicy { act_dim, rng: std::sync::Mutex::new(crate::nprandom::NpRandom::new(seed)) }
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
pub fn evaluate_stack(agents: &crate::agent::Shards, episodes: usize, seed: u64) -> Result<Vec<EvalReport>> {
    run(&agents.task().name, agents.agents(), episodes, seed, &|rows, n| agents.act_all(rows, n))
}

/// Agent i's policy on rows[i] = (observations, desired goals) of n rows each.
type StackPolicy<'a> = dyn Fn(&[(&[f32], &[f32])], usize) -> Vec<Vec<f32>> + 'a;

/// Environments alive at once. Each holds MuJoCo's buffers (~20 MB for Fetch and the hand
/// tasks), so evaluating a stack of 9 agents on 50 episodes all at once held 9 GB; episodes now
/// run in waves of at most this many environments, which are reused from wave to wave.
const MAX_ENVS: usize = 64;

/// `members` policies × `episodes` episodes, in waves. A wave is a group of members × a block
/// of episodes, stepped in lockstep; member m's episode i is reset with seed `seed + i`.
///
/// The block size depends on `episodes` alone, never on `members`, and every member's rows go
/// through the policy in blocks of that size: an agent evaluated inside a stack sees the same
/// batches, hence the same bits, as evaluated alone. Members outside the wave's group get a
/// copy of some group member's rows, whose actions are dropped.
fn run(task_name: &str, members: usize, episodes: usize, seed: u64, act: &StackPolicy) -> Result<Vec<EvalReport>> {
    let block = episodes.min(MAX_ENVS);
    let group = (MAX_ENVS / block.max(1)).clamp(1, members.max(1));
    let mut envs: Vec<Box<dyn GoalEnv + Send>> =
        (0..(group * block).min(members * episodes)).map(|_| env::make(task_name)).collect::<Result<_>>()?;
    let task = envs.first().map(|e| e.task().clone());
    let Some(task) = task else {
        let empty = EvalReport {
            episodes: 0,
            return_mean: 0.0,
            return_std: 0.0,
            success_rate: 0.0,
            paper_score: 0.0,
            task_success: vec![],
        };
        return Ok(vec![empty; members]);
    };
    let mut returns = vec![0.0f64; members * episodes];
    let mut success = vec![false; members * episodes];
    // Episode i's evaluation task (1…K), where the environment has them.
    let mut task_of: Vec<Option<usize>> = vec![None; episodes];
    for g0 in (0..members).step_by(group) {
        let gm = group.min(members - g0);
        for e0 in (0..episodes).step_by(block) {
            let n = block.min(episodes - e0);
            // Environment k of the wave is member g0 + k / n's episode e0 + k % n.
            let live = &mut envs[..gm * n];
            let mut obs: Vec<Obs> =
                live.par_iter_mut().enumerate().map(|(k, e)| e.restart(seed + (e0 + k % n) as u64)).collect();
            for (k, e) in live[..n].iter().enumerate() {
                task_of[e0 + k] = e.eval_task();
            }
            // Episodes that ended at their success (OGBench's mazes): stepped no further.
            let mut done = vec![false; live.len()];
            for _ in 0..task.t {
                let flat = |f: fn(&Obs) -> &Vec<f64>| {
                    obs.iter().flat_map(|o| f(o).iter().map(|&x| x as f32)).collect::<Vec<f32>>()
                };
                let (o, g) = (flat(|o| &o.observation), flat(|o| &o.desired_goal));
                let (od, gd) = (task.obs_dim * n, task.goal_dim * n);
                let rows: Vec<(&[f32], &[f32])> = (0..members)
                    .map(|m| {
                        let k = if (g0..g0 + gm).contains(&m) { m - g0 } else { 0 };
                        (&o[k * od..(k + 1) * od], &g[k * gd..(k + 1) * gd])
                    })
                    .collect();
                let out = act(&rows, n);
                let actions: Vec<f32> = out[g0..g0 + gm].concat();
                let steps: Vec<_> = live
                    .par_iter_mut()
                    .zip(actions.par_chunks(task.act_dim))
                    .zip(done.par_iter())
                    .map(|((e, a), &d)| (!d).then(|| e.step(&a.iter().map(|&x| x as f64).collect::<Vec<f64>>())))
                    .collect();
                for (k, s) in steps.into_iter().enumerate() {
                    let Some(s) = s else { continue };
                    let j = (g0 + k / n) * episodes + e0 + k % n;
                    returns[j] += s.reward;
                    success[j] = s.success;
                    done[k] = s.success && live[k].ends_at_success();
                    obs[k] = s.obs;
                }
                if done.iter().all(|&d| d) {
                    break;
                }
            }
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
                task_success: per_task(&task_of, success),
            }
        })
        .collect())
}

/// Each task's success rate (task 1 first) from the episodes' tasks; empty when the environment
/// has no fixed tasks. A task no episode drew (fewer episodes than tasks) is NaN.
fn per_task(task_of: &[Option<usize>], success: &[bool]) -> Vec<f64> {
    let Some(k) = task_of.iter().flatten().max() else { return vec![] };
    (1..=*k)
        .map(|t| {
            let runs: Vec<bool> =
                task_of.iter().zip(success).filter(|(x, _)| **x == Some(t)).map(|(_, &s)| s).collect();
            runs.iter().filter(|&&s| s).count() as f64 / runs.len() as f64
        })
        .collect()
}
