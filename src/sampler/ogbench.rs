//! OGBench's goal-conditioned batches from a pgser table: the dict OGBench's and Horizon
//! Reduction's JAX agents (GCIQL, GCIVL, CRL, HIQL, QRL, SHARSA's flat part) train on, drawn by
//! the rules of their `GCDataset.sample` / `sample_goals` (`impls/utils/datasets.py` in OGBench,
//! `utils/datasets.py` in Horizon Reduction), so that such an agent switches to pgser by
//! replacing its dataset object with `pgser.Sampler(path, layout="ogbench")`.
//!
//! # What OGBench draws, and the same here
//! OGBench's datasets hold T − 1 transitions per episode in either of its layouts: the regular
//! one (`load_dataset`'s default) keeps (s_i, a_i, s_{i+1}) for i < T − 1; the compact one
//! (Horizon Reduction's) keeps all T states but marks the last one invalid and sets `terminals`
//! on the last two, so the "final state" of an episode is its last transition, step T − 2, in
//! both. A pgser table has T observations and T − 1 transitions per episode: the same rows. A
//! batch of `n` rows is, row by row:
//! - a transition (e, s): uniform over all the view's transitions, s in 0..T − 1;
//! - a value goal and an actor goal, each drawn apart with its own fractions (p_curgoal,
//!   p_trajgoal, p_randomgoal, geom_sample):
//!   - **current**, with probability p_curgoal: step s itself;
//!   - **trajectory**, with p_trajgoal: a later step of the same episode, clipped to its last
//!     transition L = T − 2: geometric, `min(s + k, L)` with k ~ Geometric(1 − discount) on
//!     1, 2, …; or uniform, `round(min(s + 1, L)·d + L·(1 − d))` with d uniform in [0, 1) and
//!     numpy's round-half-to-even (OGBench's own formula: its end points get half weight).
//!     For s = L either gives s itself;
//!   - **random**, with p_randomgoal: a transition uniform over the whole table. The view's
//!     [`View::random_goal`] draws over all T observations of an episode; OGBench's set is the
//!     T − 1 transitions, so a draw at step T − 1 is drawn again (rejection keeps the rest
//!     uniform: it costs T / (T − 1) draws on average).
//!
//!   OGBench decides with two uniforms: current if u₁ < p_curgoal, else trajectory if
//!   u₂ < p_trajgoal / (1 − p_curgoal), else random; with p_curgoal = 1 every goal is current.
//!   The same comparisons are made here, with the same floating-point quotient.
//! - goals are **observations** at the goal's (episode, step) (OGBench's default; `oracle_reps`
//!   datasets are not pgser tables);
//! - `successes = (goal == transition)`, compared as OGBench compares indices, by (episode, step)
//!   of the value goal: always for a current goal, for a trajectory goal when s = L, and for a
//!   random goal that lands on the row itself. `masks = 1 − successes`, `rewards = successes − 1`
//!   with `gc_negative` (else `successes`). `terminals` is 1 on an episode's last transition, as
//!   in OGBench's batch.
//!
//! The distribution is OGBench's; the numbers are not numpy's (OGBench draws from numpy's global
//! legacy generator, column by column; here each row draws in turn from pgser's own stream).
//!
//! # PGSER's swapped rows (`p_swapgoal`)
//! From a scored table or folder, a fraction `p_swapgoal` of rows (decided first, with its own
//! uniform, and only when `p_swapgoal > 0`, so other settings draw exactly as before) are PGSER's
//! prioritized swapped rows: a scored row drawn by priority gives the transition and the value
//! goal, the observation its goal was taken from; the actor goal is the same goal
//! (`swap_actor_goals`, as PGSER's TD3+BC trains actor and critic on one goal) or drawn by the
//! actor's fractions for that transition. The other rows follow OGBench's rules unchanged, so
//! the value goals' overall fractions are (1 − p_swapgoal)·p_curgoal, … and p_swapgoal. Success
//! is decided as for every goal, by (episode, step). Where the rows come from, within a budget
//! too: `swapped.rs`.
//!
//! # What is left out
//! - OGBench's `frame_stack` and `p_aug` (pixel-based tasks: stacked frames, random crops), and
//!   Horizon Reduction's `HGCDataset` (subgoal keys of the hierarchical agents).
//!
//! # Streams
//! Batch k of a stream draws from its own generator, `NpRandom::spawned(seed, [STREAM_OGBENCH,
//! k])`: its rows depend on the seed, k and its size only. The Python sampler draws batches ahead
//! at its default size and, asked for another size, draws that batch again at that size, without
//! changing any other batch (the data a pool holds also depends on the rows drawn before).

use std::path::Path;

use anyhow::{Result, bail};
use serde::{Deserialize, Serialize};

use super::pool::{Beta, ScoredDraw};
use super::priority::PriorityConfig;
use super::view::{Budget, View};
use crate::nprandom::NpRandom;
use swapped::{Source, Swapper};

mod swapped;

/// Spawn key of OGBench-layout batches ("OGBN"), beside the batch streams' 1–4 and the pool's 5–6.
pub const STREAM_OGBENCH: u64 = 0x4f47_424e;

/// OGBench's dataset settings, under the names and defaults of its agents' configs (GCIQL's,
/// GCIVL's and HIQL's defaults; CRL's, QRL's and GCBC's differ only in these values).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OgbenchConfig {
    /// The geometric offsets' parameter is 1 − discount.
    pub discount: f64,
    pub value_p_curgoal: f64,
    pub value_p_trajgoal: f64,
    pub value_p_randomgoal: f64,
    /// Geometric (true) or uniform (false) trajectory value goals.
    pub value_geom_sample: bool,
    pub actor_p_curgoal: f64,
    pub actor_p_trajgoal: f64,
    pub actor_p_randomgoal: f64,
    pub actor_geom_sample: bool,
    /// Rewards 0 at the goal and −1 elsewhere (true), or 1 and 0 (false).
    pub gc_negative: bool,
    /// PGSER's prioritized swapped rows, a fraction of each batch (needs a scored table).
    pub p_swapgoal: f64,
    /// A swapped row's actor goal is its swapped goal (true) or drawn by the actor's fractions.
    pub swap_actor_goals: bool,
}

impl Default for OgbenchConfig {
    fn default() -> Self {
        OgbenchConfig {
            discount: 0.99,
            value_p_curgoal: 0.2,
            value_p_trajgoal: 0.5,
            value_p_randomgoal: 0.3,
            value_geom_sample: true,
            actor_p_curgoal: 0.0,
            actor_p_trajgoal: 1.0,
            actor_p_randomgoal: 0.0,
            actor_geom_sample: false,
            gc_negative: true,
            p_swapgoal: 0.0,
            swap_actor_goals: true,
        }
    }
}

impl OgbenchConfig {
    /// Refuses what OGBench refuses (fractions that do not sum to 1, by `np.isclose`) and what its
    /// numpy calls would (a discount outside [0, 1) gives `geometric` a p outside (0, 1]).
    pub fn validate(&self) -> Result<()> {
        if !(0.0..1.0).contains(&self.discount) {
            bail!("discount = {}: must be in [0, 1) (geometric goal offsets take p = 1 − discount)", self.discount);
        }
        if !(0.0..=1.0).contains(&self.p_swapgoal) {
            bail!("p_swapgoal = {}: must be in [0, 1]", self.p_swapgoal);
        }
        for (who, [cur, traj, random]) in [
            ("value", [self.value_p_curgoal, self.value_p_trajgoal, self.value_p_randomgoal]),
            ("actor", [self.actor_p_curgoal, self.actor_p_trajgoal, self.actor_p_randomgoal]),
        ] {
            for (name, p) in [("p_curgoal", cur), ("p_trajgoal", traj), ("p_randomgoal", random)] {
                if !(0.0..=1.0).contains(&p) {
                    bail!("{who}_{name} = {p}: must be in [0, 1]");
                }
            }
            let sum = cur + traj + random;
            // np.isclose(sum, 1.0): |sum − 1| ≤ 1e-8 + 1e-5.
            if (sum - 1.0).abs() > 1e-8 + 1e-5 {
                bail!("{who}_p_curgoal + {who}_p_trajgoal + {who}_p_randomgoal = {sum}: must be 1");
            }
        }
        Ok(())
    }
}

/// Which of OGBench's three sources, or PGSER's swapped rows, a goal came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GoalKind {
    Current,
    Trajectory,
    Random,
    Swapped,
}

/// One batch, as flat row-major arrays (`n` rows; vectors of `obs_dim` or `act_dim` floats).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OgbenchBatch {
    pub n: usize,
    pub obs_dim: usize,
    pub act_dim: usize,
    pub observations: Vec<f32>,
    pub next_observations: Vec<f32>,
    pub actions: Vec<f32>,
    /// 1 on an episode's last transition (OGBench's regular `terminals`).
    pub terminals: Vec<f32>,
    pub rewards: Vec<f32>,
    pub masks: Vec<f32>,
    pub value_goals: Vec<f32>,
    pub actor_goals: Vec<f32>,
    /// The transition's table-wide episode number (shard order across a folder) and step.
    pub episode: Vec<i64>,
    pub step: Vec<i64>,
    /// Where each goal is: table-wide episode and step of the observation it is.
    pub value_goal_episode: Vec<i64>,
    pub value_goal_step: Vec<i64>,
    pub actor_goal_episode: Vec<i64>,
    pub actor_goal_step: Vec<i64>,
    pub value_goal_kind: Vec<GoalKind>,
    pub actor_goal_kind: Vec<GoalKind>,
    /// The scored table's row of a swapped row; −1 for rows drawn by OGBench's rules.
    pub scored_row: Vec<i64>,
}

/// A goal drawn for row (e, s): its kind, table-wide (episode, step), and where to read it.
#[derive(Debug, Clone, Copy)]
struct Goal {
    kind: GoalKind,
    episode: u64,
    step: usize,
    at: At,
}

#[derive(Debug, Clone, Copy)]
enum At {
    /// A resident episode's step.
    Resident(usize, usize),
    /// A `random_goal` source.
    Source(super::view::GoalSource),
    /// A scored row's stored goal, in a pool's block.
    Scored(ScoredDraw),
}

/// Numpy's geometric by inversion, k = ⌈ln(1 − u) / ln(1 − p)⌉ on 1, 2, …: P(k > j) = (1 − p)^j.
fn geometric(rng: &mut NpRandom, p: f64) -> u64 {
    let k = ((-rng.random()).ln_1p() / (-p).ln_1p()).ceil();
    // u = 0 gives 0; p = 1 gives −0: both are the first trial.
    if k >= 1.0 { k.min(u64::MAX as f64) as u64 } else { 1 }
}

/// Batches of OGBench's layout from a table.
pub struct OgbenchStream {
    source: Source,
    cfg: OgbenchConfig,
    seed: u64,
    next: u64,
}

impl OgbenchStream {
    /// A stream over β without swapped rows; refuses settings OGBench refuses, `p_swapgoal`
    /// (which needs a scored table) and episodes without a transition.
    pub fn new(beta: Beta, cfg: OgbenchConfig, seed: u64) -> Result<OgbenchStream> {
        if cfg.p_swapgoal > 0.0 {
            bail!("p_swapgoal = {}: swapped rows come from a scored table; open one", cfg.p_swapgoal);
        }
        Self::of(Source::Plain(beta), cfg, seed)
    }

    fn of(source: Source, cfg: OgbenchConfig, seed: u64) -> Result<OgbenchStream> {
        cfg.validate()?;
        if source.view().t() < 2 {
            bail!("episodes of {} step(s) hold no transition", source.view().t());
        }
        Ok(OgbenchStream { source, cfg, seed, next: 0 })
    }

    /// Opens a trajectory table (a file or a table folder) within `budget`; or a scored table or
    /// folder, whose original data is β and whose rows, by `priority`, are the swapped rows
    /// (`p_swapgoal`).
    pub fn open(
        path: &Path,
        budget: Budget,
        cfg: OgbenchConfig,
        priority: &PriorityConfig,
        seed: u64,
    ) -> Result<OgbenchStream> {
        cfg.validate()?;
        let source = Source::open(path, budget, cfg.p_swapgoal, priority, seed)?;
        Self::of(source, cfg, seed).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    pub fn view(&self) -> &dyn View {
        self.source.view()
    }

    /// What the pool's disk reads have cost so far; None while β is held whole.
    pub fn pool_stats(&self) -> Option<super::pool::PoolStats> {
        self.source.pool().map(|p| p.stats())
    }

    /// Whether batches mix in PGSER's swapped rows.
    pub fn is_scored(&self) -> bool {
        self.source.swapper().is_some()
    }

    pub fn config(&self) -> &OgbenchConfig {
        &self.cfg
    }

    /// The index of the batch `next_batch` draws next.
    pub fn position(&self) -> u64 {
        self.next
    }

    /// The next batch, of `n` rows.
    pub fn next_batch(&mut self, n: usize) -> Result<OgbenchBatch> {
        let b = self.batch(self.next, n)?;
        self.next += 1;
        Ok(b)
    }

    /// Whether drawing `n` rows now would take a block into the pool (never for β held whole).
    pub fn would_swap(&self, n: usize) -> bool {
        self.source.pool().is_some_and(|p| p.swaps_within(n))
    }

    /// Readies the block the next swap takes in, waiting for the loader (a no-op for β held
    /// whole): see `Pool::stage`.
    pub fn stage(&mut self) {
        if let Some(p) = self.source.pool_mut() {
            p.stage();
        }
    }

    /// Forgets `rows` draws of batches drawn ahead and dropped, none of which took a block in
    /// ([`OgbenchStream::would_swap`]): the next batch is drawn from the pool as it was before them.
    pub fn drop_ahead(&mut self, rows: usize) {
        if let Some(p) = self.source.pool_mut() {
            p.unrefresh(rows);
        }
    }

    /// Batch `k` of the stream, of `n` rows (not moving the stream on): the view is refreshed
    /// for `n` draws first, so a pool's resident data follow the rows drawn.
    pub fn batch(&mut self, k: u64, n: usize) -> Result<OgbenchBatch> {
        if n == 0 {
            bail!("batch_size must be at least 1");
        }
        self.source.refresh(n)?;
        let mut rng = NpRandom::spawned(self.seed, &[STREAM_OGBENCH, k]);
        Ok(draw(self.source.view(), self.source.swapper(), &self.cfg, &mut rng, n))
    }
}

/// `n` rows of OGBench's layout from `view`, with swapped rows from `swap` (the module doc).
/// The rows and goals are drawn in turn from `rng`; their vectors are then copied in parallel, in
/// chunks of rows (copying is most of a batch's time on wide observations, and it does not touch
/// the generator, so the batch is the same at any thread count).
fn draw(
    view: &dyn View,
    swap: Option<&dyn Swapper>,
    cfg: &OgbenchConfig,
    rng: &mut NpRandom,
    n: usize,
) -> OgbenchBatch {
    let (t, od, ad) = (view.t(), view.task().obs_dim, view.task().act_dim);
    let steps = t - 1;
    let value = (cfg.value_p_curgoal, cfg.value_p_trajgoal, cfg.value_geom_sample);
    let actor = (cfg.actor_p_curgoal, cfg.actor_p_trajgoal, cfg.actor_geom_sample);
    let offset = if cfg.gc_negative { 1.0 } else { 0.0 };
    let mut scored_rows = Vec::with_capacity(n);
    let rows: Vec<(usize, usize, Goal, Goal)> = (0..n)
        .map(|_| {
            if let Some(swap) = swap.filter(|_| cfg.p_swapgoal > 0.0 && rng.random() < cfg.p_swapgoal) {
                let (e, s, vg, row) = swap.pick(rng);
                let ag = if cfg.swap_actor_goals { vg } else { goal(view, cfg, rng, e, s, actor) };
                scored_rows.push(row as i64);
                return (e, s, vg, ag);
            }
            let row = rng.below(view.episodes() * steps);
            let (e, s) = (row / steps, row % steps);
            let vg = goal(view, cfg, rng, e, s, value);
            let ag = goal(view, cfg, rng, e, s, actor);
            scored_rows.push(-1);
            (e, s, vg, ag)
        })
        .collect();
    let mut b = OgbenchBatch { n, obs_dim: od, act_dim: ad, scored_row: scored_rows, ..OgbenchBatch::default() };
    for &(e, s, vg, ag) in &rows {
        let number = view.episode_number(e);
        b.terminals.push(if s + 2 == t { 1.0 } else { 0.0 });
        let success = if (vg.episode, vg.step) == (number, s) { 1.0 } else { 0.0 };
        b.masks.push(1.0 - success);
        b.rewards.push(success - offset);
        for (g, ep, st, kind) in [
            (vg, &mut b.value_goal_episode, &mut b.value_goal_step, &mut b.value_goal_kind),
            (ag, &mut b.actor_goal_episode, &mut b.actor_goal_step, &mut b.actor_goal_kind),
        ] {
            ep.push(g.episode as i64);
            st.push(g.step as i64);
            kind.push(g.kind);
        }
        b.episode.push(number as i64);
        b.step.push(s as i64);
    }
    let goal_obs = |g: &Goal| match g.at {
        At::Resident(e, s) => view.obs(e, s),
        At::Source(src) => view.goal_obs(src),
        At::Scored(d) => swap.expect("a scored goal comes from the swapper").scored_obs(&d),
    };
    b.observations = super::gather_rows(&rows, od, |r| view.obs(r.0, r.1));
    b.next_observations = super::gather_rows(&rows, od, |r| view.obs(r.0, r.1 + 1));
    b.actions = super::gather_rows(&rows, ad, |r| view.action(r.0, r.1));
    b.value_goals = super::gather_rows(&rows, od, |r| goal_obs(&r.2));
    b.actor_goals = super::gather_rows(&rows, od, |r| goal_obs(&r.3));
    b
}

/// One goal for transition (e, s) by OGBench's `sample_goals` (the module doc).
fn goal(view: &dyn View, cfg: &OgbenchConfig, rng: &mut NpRandom, e: usize, s: usize, p: (f64, f64, bool)) -> Goal {
    let (p_cur, p_traj, geom) = p;
    let number = view.episode_number(e);
    let current = Goal { kind: GoalKind::Current, episode: number, step: s, at: At::Resident(e, s) };
    if p_cur == 1.0 || rng.random() < p_cur {
        return current;
    }
    if rng.random() < p_traj / (1.0 - p_cur) {
        let last = view.t() - 2;
        let step = if geom {
            let k = geometric(rng, 1.0 - cfg.discount);
            (s as u64).saturating_add(k).min(last as u64) as usize
        } else {
            let d = rng.random();
            let near = (s + 1).min(last) as f64;
            (near * d + last as f64 * (1.0 - d)).round_ties_even() as usize
        };
        return Goal { kind: GoalKind::Trajectory, episode: number, step, at: At::Resident(e, step) };
    }
    let last_obs = view.t() - 1;
    loop {
        let g = view.random_goal(rng);
        if g.step as usize != last_obs {
            return Goal { kind: GoalKind::Random, episode: g.episode, step: g.step as usize, at: At::Source(g) };
        }
    }
}

#[cfg(test)]
mod tests;
