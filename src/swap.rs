//! Goal swapping (PGSER Alg. 1): give a transition a goal taken from elsewhere in the dataset
//! and recompute its reward for that goal, r = R(φ(s'), g_rand).
//!
//! The goal pool is every achieved goal of every episode: those are states the data shows to be
//! reachable from somewhere, which is what makes a swapped goal plausible as a target.
//!
//! [`random_goal`] is the one definition of "draw a goal source": the trainer's on-the-fly
//! swapping (`sampler`) and the materialized swapped table (`score`, via [`swap_block`]) both
//! call it, so the two variants of the paper draw goals from the same distribution.

use crate::nprandom::NpRandom;
use crate::task::Task;
use crate::trajectory::Episodes;

/// `goal_step` of a row that keeps its transition's own desired goal (`--include-original`):
/// that goal is `desired_goal[episode, step]`, not an achieved goal, so no step of the
/// `achieved_goal` column names it. Swapped rows have `goal_step` in 0..T.
pub const ORIGINAL_GOAL_STEP: i32 = -1;

/// A random goal's source: (episode, step) of an achieved goal, uniform over all `n · t`
/// observations of a table of `n` episodes of `t` steps.
pub fn random_goal(n: usize, t: usize, rng: &mut NpRandom) -> (usize, usize) {
    let k = rng.below(n * t);
    (k / t, k % t)
}

/// The achieved goals swapped goals come from: every one of a table, `[n, t, goal_dim]` float32
/// (goal_dim floats per observation: 3 MB for 5000 Fetch episodes, but 8 GB for a billion
/// PointMaze rows and 96 GB for cube-octuple's), or a uniform sample of them (`score
/// --goal-sample N`), which bounds `score`'s memory whatever the table's size.
#[derive(Debug, Clone, PartialEq)]
pub struct GoalPool {
    pub n: usize,
    pub t: usize,
    pub goal_dim: usize,
    pub ag: Vec<f32>,
    /// A sample's (episode, step) of each goal in `ag`; empty when `ag` is the whole table's.
    pub at: Vec<(u64, u32)>,
}

impl GoalPool {
    /// A uniformly drawn goal of the pool: its (episode, step) in the table, and its value. The
    /// whole table's draws with [`random_goal`]; a sample draws one of its entries, each a
    /// uniform draw of the table's observations, so the goal is uniform over the table either way.
    pub fn draw(&self, rng: &mut NpRandom) -> (usize, usize, &[f32]) {
        let d = self.goal_dim;
        if self.at.is_empty() {
            let (e, s) = random_goal(self.n, self.t, rng);
            (e, s, &self.ag[(e * self.t + s) * d..][..d])
        } else {
            let k = rng.below(self.at.len());
            let (e, s) = self.at[k];
            (e as usize, s as usize, &self.ag[k * d..][..d])
        }
    }
}

/// Transitions with the goals they are trained on, one row per (transition, goal), as flat
/// float32 rows (`obs` holds `n · obs_dim` values, and so on): the transition table's columns
/// (docs/tables.md) but `q`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SwappedRows {
    pub n: usize,
    pub episode: Vec<i64>,
    pub step: Vec<i32>,
    pub goal_episode: Vec<i64>,
    pub goal_step: Vec<i32>,
    pub obs: Vec<f32>,
    pub action: Vec<f32>,
    pub next_obs: Vec<f32>,
    pub next_achieved_goal: Vec<f32>,
    pub goal: Vec<f32>,
    pub reward: Vec<f32>,
}

/// Alg. 1 over a block of whole episodes: `block` holds episodes `first_episode ..` of a table
/// (so episode `i` of the block is episode `first_episode + i` of the table). For every
/// transition (s_t, a_t, s_{t+1}), t < T − 1, in table order, emit `include_original` the row
/// with its own desired goal (goal_episode = episode, goal_step = [`ORIGINAL_GOAL_STEP`]; needs
/// `block.g`), then `swaps` rows whose goals are achieved goals drawn from `pool` with
/// [`random_goal`], in that order from `rng`. Rewards come from one batched `task.rewards` call.
pub fn swap_block(
    block: &Episodes,
    first_episode: usize,
    pool: &GoalPool,
    task: &Task,
    swaps: usize,
    include_original: bool,
    rng: &mut NpRandom,
) -> SwappedRows {
    let per = swaps + include_original as usize;
    let n = block.transitions() * per;
    let (od, gd, ad) = (task.obs_dim, task.goal_dim, task.act_dim);
    let mut r = SwappedRows {
        n,
        episode: Vec::with_capacity(n),
        step: Vec::with_capacity(n),
        goal_episode: Vec::with_capacity(n),
        goal_step: Vec::with_capacity(n),
        obs: Vec::with_capacity(n * od),
        action: Vec::with_capacity(n * ad),
        next_obs: Vec::with_capacity(n * od),
        next_achieved_goal: Vec::with_capacity(n * gd),
        goal: Vec::with_capacity(n * gd),
        reward: vec![0.0; n],
    };
    for i in 0..block.transitions() {
        let (e, t) = block.transition(i);
        let episode = (first_episode + e) as i64;
        let (obs, action, next_obs, next_ag) =
            (block.obs(e, t), block.action(e, t), block.obs(e, t + 1), block.ag(e, t + 1));
        for j in 0..per {
            let (ge, gt, goal) = if include_original && j == 0 {
                (episode, ORIGINAL_GOAL_STEP, block.goal(e, t))
            } else {
                let (ge, gt, goal) = pool.draw(rng);
                (ge as i64, gt as i32, goal)
            };
            r.episode.push(episode);
            r.step.push(t as i32);
            r.goal_episode.push(ge);
            r.goal_step.push(gt);
            r.obs.extend_from_slice(obs);
            r.action.extend_from_slice(action);
            r.next_obs.extend_from_slice(next_obs);
            r.next_achieved_goal.extend_from_slice(next_ag);
            r.goal.extend_from_slice(goal);
        }
    }
    task.rewards(&r.next_achieved_goal, &r.goal, &mut r.reward);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Episodes whose values encode where they are (see `Episodes::coded`).
    fn block(first: usize, n: usize) -> Episodes {
        Episodes::coded(first, n, |e, s| -(((e * 1000) + s) as f32))
    }

    #[test]
    fn rows_are_transitions_in_order_with_pool_goals_and_rewards() {
        let whole = block(0, 30);
        let pool = GoalPool { n: 30, t: whole.t, goal_dim: 3, ag: whole.ag.clone(), at: Vec::new() };
        let part = block(10, 5);
        let task = whole.task.clone();
        let r = swap_block(&part, 10, &pool, &task, 3, true, &mut NpRandom::new(1));
        assert_eq!(r.n, 5 * 49 * 4);
        for i in 0..r.n {
            let (e, t) = ((10 + (i / 4) / 49) as i64, ((i / 4) % 49) as i32);
            assert_eq!((r.episode[i], r.step[i]), (e, t), "row {i}");
            assert_eq!(r.obs[i * 10], (e * 1000 + t as i64) as f32);
            assert_eq!(r.next_obs[i * 10], (e * 1000 + t as i64 + 1) as f32);
            let goal = &r.goal[i * 3..][..3];
            if i % 4 == 0 {
                assert_eq!((r.goal_episode[i], r.goal_step[i]), (e, ORIGINAL_GOAL_STEP));
                assert_eq!(goal[0], -((e * 1000 + t as i64) as f32));
            } else {
                let (ge, gt) = (r.goal_episode[i] as usize, r.goal_step[i] as usize);
                assert!(ge < 30 && gt < 50);
                assert_eq!(goal, &whole.ag[(ge * whole.t + gt) * 3..][..3]);
            }
            assert_eq!(r.reward[i], task.reward(&r.next_achieved_goal[i * 3..][..3], goal));
        }
        let again = swap_block(&part, 10, &pool, &task, 3, true, &mut NpRandom::new(1));
        assert_eq!(again, r, "same stream, same rows");
    }

    #[test]
    fn draws_follow_the_shared_goal_source() {
        // swap_block draws exactly what random_goal draws, in row order.
        let whole = block(0, 7);
        let pool = GoalPool { n: 7, t: whole.t, goal_dim: 3, ag: whole.ag.clone(), at: Vec::new() };
        let r = swap_block(&whole, 0, &pool, &whole.task, 2, false, &mut NpRandom::new(9));
        let mut rng = NpRandom::new(9);
        for i in 0..r.n {
            let (ge, gt) = random_goal(7, whole.t, &mut rng);
            assert_eq!((r.goal_episode[i], r.goal_step[i]), (ge as i64, gt as i32));
        }
    }
}
