//! `HGCDataset.sample`: the batches of the hierarchical agents, by the rules of the code the
//! stream follows. OGBench's (HIQL) and Horizon Reduction's (SHARSA, double SHARSA, n-step
//! SAC+BC, hierarchical flow BC, its HIQL) are different classes with different keys.
//!
//! Every row is a transition (e, s) drawn as the flat class draws it. L = T − 2 is the episode's
//! last transition, OGBench's "final state". Every subgoal and target lies in the row's own
//! episode, at most L, so it is resident wherever the row is. Steps are compared as OGBench
//! compares its flat indices, by (table-wide episode, step).
//!
//! # OGBench's (`impls/utils/datasets.py`)
//! - `value_goals`: a goal by the value fractions (`sample_goals`); `masks`, `rewards` as the
//!   flat class gives them.
//! - `low_actor_goals`: the observation at min(s + subgoal_steps, L).
//! - `high_actor_goals` / `high_actor_targets`: with probability `actor_p_randomgoal`, a random
//!   transition of the table, target min(s + subgoal_steps, L); otherwise a trajectory step g
//!   (geometric or uniform by `actor_geom_sample`, as `sample_goals` draws one), target
//!   min(s + subgoal_steps, g). `actor_p_curgoal` is not read here, as OGBench does not read it.
//!
//! # Horizon Reduction's (`utils/datasets.py`)
//! With V = `value_subgoal_steps` (else `subgoal_steps`) and A = `actor_subgoal_steps` (else
//! `subgoal_steps`), and a subgoal step of goal g from row s clipped twice: to the episode's end,
//! k = min(steps, L − s), then to the goal, k = g − s where g is in the row's episode with
//! 0 ≤ g − s < k (`compute_high_next_idxs`):
//! - `high_value_goals`: a goal by the value fractions; its subgoal k, `high_value_actions` (the
//!   representation at s + k), `high_value_next_observations` (the observation there),
//!   `high_value_subgoal_steps` = k, `high_value_offsets` = g − s as a flat index difference
//!   ((goal episode − episode)·T + goal step − s, Horizon Reduction's compact arrays holding T
//!   rows an episode), `high_value_masks` = 1 − [k < V], `high_value_rewards` =
//!   −(1 − γ^k)/(1 − γ) with `gc_negative`, else γ^k·[k < V]; `high_value_reps` the row's own
//!   representation.
//! - `low_value_goals`, `low_value_masks`, `low_value_rewards`, when the config has a
//!   `low_discount` key: a goal by the value fractions, geometric, with offsets' discount
//!   `low_discount` (the config's `discount` while it is None, as their `sample_goals` falls
//!   back), and one-step masks and rewards.
//! - `masks`, `rewards`: one-step, of the high-level value goal.
//! - `high_actor_goals`: a goal by the actor fractions (`actor_p_curgoal` included); its subgoal
//!   by A gives `high_actor_actions` and `high_actor_next_observations`.
//! - `low_actor_goals`: the representation at min(s + A, L).
//!
//! Representations are the table's achieved goals with `oracle_reps` (OGBench's oracle
//! representations), and the observations otherwise, where Horizon Reduction reads
//! `oracle_reps` or falls back to observations.
//!
//! # PGSER's swapped rows (`p_swapgoal`)
//! A swapped row's transition and goal come from the scored row drawn by priority, as in the
//! flat class. The swapped goal is a high-level goal: the value goal (OGBench's `value_goals`,
//! Horizon Reduction's `high_value_goals`, with the subgoal steps, masks and rewards it implies),
//! and, with `swap_actor_goals`, the high-level actor goal too (a target of OGBench's is then
//! min(s + subgoal_steps, L), as for a random goal). The low-level goals stay the rules' own:
//! they are within the row's episode, a few steps ahead, where a goal from another episode has
//! no meaning.

use super::{Code, Column, Ctx, Goal, GoalKind, OgbenchBatch, Read, goal, random_goal, rewards_and_masks};
use super::{successes, trajectory_step};
use crate::nprandom::NpRandom;

/// `n` rows of `HGCDataset.sample`, OGBench's or Horizon Reduction's by `ctx.cfg.code`.
pub(super) fn draw(ctx: &Ctx, rng: &mut NpRandom, n: usize) -> OgbenchBatch {
    match ctx.cfg.code {
        Code::Ogbench => ogbench(ctx, rng, n),
        Code::HorizonReduction => horizon_reduction(ctx, rng, n),
    }
}

/// The swapped goal of a swapped row, as its scored row drawn, and the row recorded.
fn swapped_value_goal(
    ctx: &Ctx,
    rng: &mut NpRandom,
    e: usize,
    s: usize,
    swapped: Option<(Goal, u64)>,
    scored: &mut Vec<i64>,
) -> (Goal, bool) {
    match swapped {
        Some((g, row)) => {
            scored.push(row as i64);
            (g, true)
        }
        None => {
            scored.push(-1);
            (goal(ctx, rng, e, s, ctx.cfg.value()), false)
        }
    }
}

fn ogbench(ctx: &Ctx, rng: &mut NpRandom, n: usize) -> OgbenchBatch {
    let cfg = ctx.cfg;
    let steps = cfg.subgoal_steps.expect("validated: OGBench's HGCDataset has subgoal_steps") as usize;
    let last = ctx.last();
    let (mut rows, mut scored) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let [mut value, mut low, mut high, mut targets] = std::array::from_fn(|_| Vec::with_capacity(n));
    for _ in 0..n {
        let (e, s, swapped) = ctx.pick(rng);
        let (vg, is_swapped) = swapped_value_goal(ctx, rng, e, s, swapped, &mut scored);
        let ahead = (s + steps).min(last);
        let (hg, target) = if is_swapped && cfg.swap_actor_goals {
            (vg, ahead)
        } else if rng.random() < cfg.actor_p_randomgoal {
            (random_goal(ctx.view, rng), ahead)
        } else {
            let g = trajectory_step(ctx, rng, s, cfg.actor_geom_sample, cfg.discount);
            (Goal { kind: GoalKind::Trajectory, ..ctx.point(e, s, g) }, (s + steps).min(g))
        };
        rows.push((e, s));
        value.push(vg);
        low.push(ctx.point(e, s, ahead));
        high.push(hg);
        targets.push(ctx.point(e, s, target));
    }
    let successes = successes(ctx, &rows, &value);
    let offset = if cfg.gc_negative { 1.0 } else { 0.0 };
    ctx.batch(
        rng,
        &rows,
        scored,
        vec![
            ("value_goals", Read::Rep, value),
            ("low_actor_goals", Read::Rep, low),
            ("high_actor_goals", Read::Rep, high),
            ("high_actor_targets", Read::Rep, targets),
        ],
        rewards_and_masks("", &successes, offset),
    )
}

/// Horizon Reduction's `compute_high_next_idxs`: the subgoal step k of goal `g` from row (e, s),
/// `steps` clipped to the episode's end, then to the goal where it lies within them.
fn subgoal(ctx: &Ctx, e: usize, s: usize, g: &Goal, steps: usize) -> usize {
    let k = steps.min(ctx.last() - s);
    let same_episode = g.episode == ctx.view.episode_number(e);
    if same_episode && g.step >= s && g.step - s < k { g.step - s } else { k }
}

fn horizon_reduction(ctx: &Ctx, rng: &mut NpRandom, n: usize) -> OgbenchBatch {
    let cfg = ctx.cfg;
    let (value_steps, actor_steps) = cfg.subgoal_steps_of().expect("validated");
    let (value_steps, actor_steps) = (value_steps as usize, actor_steps as usize);
    let t = ctx.view.t() as i64;
    let low_fractions = (cfg.value_p_curgoal, cfg.value_p_trajgoal, true, cfg.low_discount.unwrap_or(cfg.discount));
    let (mut rows, mut scored) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let [mut reps, mut hv_goals, mut hv_next, mut low_goals, mut ha_goals, mut ha_next, mut low_actor] =
        std::array::from_fn(|_| Vec::with_capacity(n));
    let (mut offsets, mut hv_steps) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for _ in 0..n {
        let (e, s, swapped) = ctx.pick(rng);
        let (hvg, is_swapped) = swapped_value_goal(ctx, rng, e, s, swapped, &mut scored);
        let k = subgoal(ctx, e, s, &hvg, value_steps);
        if cfg.low_value_goals {
            low_goals.push(goal(ctx, rng, e, s, low_fractions));
        }
        let hag = if is_swapped && cfg.swap_actor_goals { hvg } else { goal(ctx, rng, e, s, cfg.actor()) };
        let ka = subgoal(ctx, e, s, &hag, actor_steps);
        let number = ctx.view.episode_number(e) as i64;
        offsets.push((hvg.episode as i64 - number) * t + hvg.step as i64 - s as i64);
        hv_steps.push(k as i64);
        rows.push((e, s));
        reps.push(ctx.point(e, s, s));
        hv_goals.push(hvg);
        hv_next.push(ctx.point(e, s, s + k));
        ha_goals.push(hag);
        ha_next.push(ctx.point(e, s, s + ka));
        low_actor.push(ctx.point(e, s, (s + actor_steps).min(ctx.last())));
    }
    let offset = if cfg.gc_negative { 1.0 } else { 0.0 };
    let gamma = cfg.discount;
    let reached: Vec<f64> = hv_steps.iter().map(|&k| if (k as usize) < value_steps { 1.0 } else { 0.0 }).collect();
    // Their `discount ** steps`: C's pow on float64 (`powf`, glibc's, correctly rounded);
    // numpy's SIMD power on an AVX-512 CPU may differ from it in the last bit.
    let rewards = hv_steps
        .iter()
        .zip(&reached)
        .map(|(&k, &r)| {
            let p = gamma.powf(k as f64);
            if cfg.gc_negative { -(1.0 - p) / (1.0 - gamma) } else { p * r }
        })
        .collect();
    let mut scalars = vec![
        ("high_value_offsets".to_string(), Column::I64(offsets)),
        ("high_value_subgoal_steps".to_string(), Column::I64(hv_steps)),
        ("high_value_masks".to_string(), Column::F64(reached.iter().map(|r| 1.0 - r).collect())),
        ("high_value_rewards".to_string(), Column::F64(rewards)),
    ];
    let mut points = vec![
        ("high_value_reps", Read::Rep, reps),
        ("high_value_goals", Read::Rep, hv_goals.clone()),
        ("high_value_actions", Read::Rep, hv_next.clone()),
        ("high_value_next_observations", Read::Obs, hv_next),
    ];
    if cfg.low_value_goals {
        scalars.extend(rewards_and_masks("low_value_", &successes(ctx, &rows, &low_goals), offset));
        points.push(("low_value_goals", Read::Rep, low_goals));
    }
    scalars.extend(rewards_and_masks("", &successes(ctx, &rows, &hv_goals), offset));
    points.extend([
        ("high_actor_goals", Read::Rep, ha_goals),
        ("high_actor_actions", Read::Rep, ha_next.clone()),
        ("high_actor_next_observations", Read::Obs, ha_next),
        ("low_actor_goals", Read::Rep, low_actor),
    ]);
    ctx.batch(rng, &rows, scored, points, scalars)
}

#[cfg(test)]
mod tests;
