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
//! # What is left out
//! - OGBench's `frame_stack` and `p_aug` (pixel-based tasks: stacked frames, random crops), and
//!   Horizon Reduction's `HGCDataset` (subgoal keys of the hierarchical agents).
//! - PGSER's `p_swapgoal`: a fraction of goals from a scored table's priorities, once scored table
//!   folders exist; random goals here are OGBench's uniform ones.
//!
//! # Streams
//! Batch k of a stream draws from its own generator, `NpRandom::spawned(seed, [STREAM_OGBENCH,
//! k])`: its rows depend on the seed, k and its size only. The Python sampler draws batches ahead
//! at its default size and, asked for another size, draws that batch again at that size, without
//! changing any other batch (the data a pool holds also depends on the rows drawn before).

use std::path::Path;

use anyhow::{Result, bail};
use serde::{Deserialize, Serialize};

use super::view::{self, Budget, View};
use crate::nprandom::NpRandom;

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

/// Which of OGBench's three sources a goal came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GoalKind {
    Current,
    Trajectory,
    Random,
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
    Source(view::GoalSource),
}

/// Numpy's geometric by inversion, k = ⌈ln(1 − u) / ln(1 − p)⌉ on 1, 2, …: P(k > j) = (1 − p)^j.
fn geometric(rng: &mut NpRandom, p: f64) -> u64 {
    let k = ((-rng.random()).ln_1p() / (-p).ln_1p()).ceil();
    // u = 0 gives 0; p = 1 gives −0: both are the first trial.
    if k >= 1.0 { k.min(u64::MAX as f64) as u64 } else { 1 }
}

/// Batches of OGBench's layout from a view of a table.
pub struct OgbenchStream {
    view: Box<dyn View>,
    cfg: OgbenchConfig,
    seed: u64,
    next: u64,
}

impl OgbenchStream {
    /// A stream over `view`; refuses settings OGBench refuses and episodes without a transition.
    pub fn new(view: Box<dyn View>, cfg: OgbenchConfig, seed: u64) -> Result<OgbenchStream> {
        cfg.validate()?;
        if view.t() < 2 {
            bail!("episodes of {} step(s) hold no transition", view.t());
        }
        Ok(OgbenchStream { view, cfg, seed, next: 0 })
    }

    /// Opens a trajectory table (a file or a table folder) within `budget`.
    pub fn open(path: &Path, budget: Budget, cfg: OgbenchConfig, seed: u64) -> Result<OgbenchStream> {
        let view = view::open(path, budget, seed)?;
        Self::new(view, cfg, seed).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
    }

    pub fn view(&self) -> &dyn View {
        self.view.as_ref()
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

    /// Batch `k` of the stream, of `n` rows (not moving the stream on): the view is refreshed
    /// for `n` draws first, so a pool's resident data follow the rows drawn.
    pub fn batch(&mut self, k: u64, n: usize) -> Result<OgbenchBatch> {
        if n == 0 {
            bail!("batch_size must be at least 1");
        }
        self.view.refresh(n)?;
        let mut rng = NpRandom::spawned(self.seed, &[STREAM_OGBENCH, k]);
        Ok(draw(self.view.as_ref(), &self.cfg, &mut rng, n))
    }
}

/// `n` rows of OGBench's layout from `view` (the module doc).
pub fn draw(view: &dyn View, cfg: &OgbenchConfig, rng: &mut NpRandom, n: usize) -> OgbenchBatch {
    let (t, od, ad) = (view.t(), view.task().obs_dim, view.task().act_dim);
    let steps = t - 1;
    let mut b = OgbenchBatch {
        n,
        obs_dim: od,
        act_dim: ad,
        observations: Vec::with_capacity(n * od),
        next_observations: Vec::with_capacity(n * od),
        actions: Vec::with_capacity(n * ad),
        value_goals: Vec::with_capacity(n * od),
        actor_goals: Vec::with_capacity(n * od),
        ..OgbenchBatch::default()
    };
    let value = (cfg.value_p_curgoal, cfg.value_p_trajgoal, cfg.value_geom_sample);
    let actor = (cfg.actor_p_curgoal, cfg.actor_p_trajgoal, cfg.actor_geom_sample);
    let offset = if cfg.gc_negative { 1.0 } else { 0.0 };
    for _ in 0..n {
        let row = rng.below(view.episodes() * steps);
        let (e, s) = (row / steps, row % steps);
        let number = view.episode_number(e);
        let vg = goal(view, cfg, rng, e, s, value);
        let ag = goal(view, cfg, rng, e, s, actor);
        b.observations.extend_from_slice(view.obs(e, s));
        b.next_observations.extend_from_slice(view.obs(e, s + 1));
        b.actions.extend_from_slice(view.action(e, s));
        b.terminals.push(if s + 2 == t { 1.0 } else { 0.0 });
        let success = if (vg.episode, vg.step) == (number, s) { 1.0 } else { 0.0 };
        b.masks.push(1.0 - success);
        b.rewards.push(success - offset);
        for (g, out, ep, st, kind) in [
            (vg, &mut b.value_goals, &mut b.value_goal_episode, &mut b.value_goal_step, &mut b.value_goal_kind),
            (ag, &mut b.actor_goals, &mut b.actor_goal_episode, &mut b.actor_goal_step, &mut b.actor_goal_kind),
        ] {
            out.extend_from_slice(match g.at {
                At::Resident(e, s) => view.obs(e, s),
                At::Source(src) => view.goal_obs(src),
            });
            ep.push(g.episode as i64);
            st.push(g.step as i64);
            kind.push(g.kind);
        }
        b.episode.push(number as i64);
        b.step.push(s as i64);
    }
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
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::sampler::view::InMemory;
    use crate::trajectory::Episodes;

    /// 20 FetchReach episodes (T = 51) whose every observation is the number e·1000 + s.
    fn coded(n: usize) -> InMemory {
        InMemory(Arc::new(Episodes::coded(0, n, |_, _| 0.0)))
    }

    fn batch(cfg: &OgbenchConfig, n: usize, seed: u64) -> (InMemory, OgbenchBatch) {
        let v = coded(20);
        let b = draw(&v, cfg, &mut NpRandom::spawned(seed, &[STREAM_OGBENCH, 0]), n);
        (v, b)
    }

    /// The (episode, step) an observation of the coded table says it is.
    fn code(x: f32) -> (i64, i64) {
        let c = x as i64;
        (c / 1000, c % 1000)
    }

    fn sigma_bound(count: usize, n: usize, p: f64) {
        let sd = (n as f64 * p * (1.0 - p)).sqrt();
        assert!((count as f64 - n as f64 * p).abs() <= 4.0 * sd + 1e-9, "{count} of {n} where p = {p}");
    }

    #[test]
    fn rows_are_transitions_and_goals_are_the_observations_they_name() {
        let (v, b) = batch(&OgbenchConfig::default(), 5000, 1);
        let (od, ad) = (b.obs_dim, b.act_dim);
        for i in 0..b.n {
            let (e, s) = (b.episode[i] as usize, b.step[i] as usize);
            assert!(s + 1 < v.t(), "row {i}: step {s}");
            assert_eq!(&b.observations[i * od..(i + 1) * od], v.obs(e, s), "row {i}");
            assert_eq!(&b.next_observations[i * od..(i + 1) * od], v.obs(e, s + 1), "row {i}");
            assert_eq!(&b.actions[i * ad..(i + 1) * ad], v.action(e, s), "row {i}");
            assert_eq!(b.terminals[i], if s == v.t() - 2 { 1.0 } else { 0.0 }, "row {i}");
            for (goals, ep, st) in [
                (&b.value_goals, &b.value_goal_episode, &b.value_goal_step),
                (&b.actor_goals, &b.actor_goal_episode, &b.actor_goal_step),
            ] {
                // A goal is a transition's observation: never an episode's last observation.
                assert!((st[i] as usize) < v.t() - 1, "row {i}: goal step {}", st[i]);
                assert_eq!(&goals[i * od..(i + 1) * od], v.obs(ep[i] as usize, st[i] as usize), "row {i}");
            }
        }
    }

    #[test]
    fn rewards_say_success_exactly_when_the_value_goal_is_the_current_observation() {
        for gc_negative in [true, false] {
            let cfg = OgbenchConfig { gc_negative, ..OgbenchConfig::default() };
            let (_, b) = batch(&cfg, 20_000, 2);
            let od = b.obs_dim;
            let mut successes = 0;
            for i in 0..b.n {
                // Observations are unique in the coded table, so equal vectors are the same index.
                let same = b.value_goals[i * od..(i + 1) * od] == b.observations[i * od..(i + 1) * od];
                assert_eq!(b.masks[i], if same { 0.0 } else { 1.0 }, "row {i}");
                let want = if same { 1.0 } else { 0.0 } - if gc_negative { 1.0 } else { 0.0 };
                assert_eq!(b.rewards[i], want, "row {i}");
                assert_eq!(code(b.value_goals[i * od]), (b.value_goal_episode[i], b.value_goal_step[i]));
                successes += same as usize;
                if b.value_goal_kind[i] == GoalKind::Current {
                    assert!(same, "row {i}: a current goal is a success");
                }
            }
            // Current goals (0.2) plus trajectory goals of last transitions and random hits.
            assert!(successes as f64 > 0.2 * b.n as f64, "{successes}");
        }
    }

    #[test]
    fn goal_kinds_come_in_their_fractions() {
        let n = 40_000;
        let (_, b) = batch(&OgbenchConfig::default(), n, 3);
        let count = |k: &[GoalKind], kind| k.iter().filter(|&&x| x == kind).count();
        sigma_bound(count(&b.value_goal_kind, GoalKind::Current), n, 0.2);
        sigma_bound(count(&b.value_goal_kind, GoalKind::Trajectory), n, 0.5);
        sigma_bound(count(&b.value_goal_kind, GoalKind::Random), n, 0.3);
        // The actor's defaults: every goal from the trajectory.
        assert_eq!(count(&b.actor_goal_kind, GoalKind::Trajectory), n);
        let cfg = OgbenchConfig {
            actor_p_curgoal: 0.1,
            actor_p_trajgoal: 0.6,
            actor_p_randomgoal: 0.3,
            value_p_curgoal: 1.0,
            value_p_trajgoal: 0.0,
            value_p_randomgoal: 0.0,
            ..OgbenchConfig::default()
        };
        let (_, b) = batch(&cfg, n, 4);
        assert_eq!(count(&b.value_goal_kind, GoalKind::Current), n);
        assert!(b.rewards.iter().all(|&r| r == 0.0) && b.masks.iter().all(|&m| m == 0.0));
        sigma_bound(count(&b.actor_goal_kind, GoalKind::Current), n, 0.1);
        sigma_bound(count(&b.actor_goal_kind, GoalKind::Trajectory), n, 0.6);
    }

    /// Trajectory goals stay in the row's episode at steps min(s + 1, L)..=L.
    fn trajectory_rows(b: &OgbenchBatch, t: usize) -> Vec<(usize, usize)> {
        let last = t - 2;
        let mut rows = Vec::new();
        for i in 0..b.n {
            if b.value_goal_kind[i] == GoalKind::Trajectory {
                let (s, g) = (b.step[i] as usize, b.value_goal_step[i] as usize);
                assert_eq!(b.value_goal_episode[i], b.episode[i], "row {i}");
                assert!(g >= (s + 1).min(last) && g <= last, "row {i}: goal step {g} for step {s}");
                rows.push((s, g));
            }
        }
        rows
    }

    /// Pearson's χ² of counts against expectations, bins of expectation < 5 pooled; and the bins.
    fn chi_square(counts: &[f64], expected: &[f64]) -> (f64, usize) {
        let (mut chi, mut bins, mut c, mut x) = (0.0, 0usize, 0.0, 0.0);
        for (k, (&o, &e)) in counts.iter().zip(expected).enumerate() {
            c += o;
            x += e;
            if x >= 5.0 || k + 1 == counts.len() {
                chi += (c - x) * (c - x) / x;
                bins += 1;
                c = 0.0;
                x = 0.0;
            }
        }
        (chi, bins)
    }

    /// χ² of the geometric offsets against Geometric(1 − discount) truncated at L − s, row by row.
    fn offsets_chi_square(rows: &[(usize, usize)], discount: f64, last: usize) -> (f64, usize) {
        let p = 1.0 - discount;
        let (mut counts, mut expected) = (vec![0.0; last + 1], vec![0.0; last + 1]);
        for &(s, g) in rows {
            counts[g - s] += 1.0;
            // P(k = j) = (1 − p)^(j − 1) p for j < L − s; the rest of the mass at L − s.
            let room = last - s;
            if room == 0 {
                expected[0] += 1.0;
                continue;
            }
            for (j, x) in expected.iter_mut().enumerate().take(room).skip(1) {
                *x += (1.0 - p).powi(j as i32 - 1) * p;
            }
            expected[room] += (1.0 - p).powi(room as i32 - 1);
        }
        chi_square(&counts, &expected)
    }

    #[test]
    fn geometric_trajectory_goals_follow_the_truncated_geometric() {
        // discount 0.9: offsets of mean 10, well inside T = 51 episodes, and the clip still hit.
        let cfg = OgbenchConfig {
            discount: 0.9,
            value_p_curgoal: 0.0,
            value_p_trajgoal: 1.0,
            value_p_randomgoal: 0.0,
            ..OgbenchConfig::default()
        };
        let (v, b) = batch(&cfg, 40_000, 5);
        let rows = trajectory_rows(&b, v.t());
        assert_eq!(rows.len(), b.n);
        let (chi, bins) = offsets_chi_square(&rows, 0.9, v.t() - 2);
        let df = (bins - 1) as f64;
        // χ²(df): mean df, sd √(2 df); 5 sd above the mean a correct sampler does not reach.
        assert!(chi < df + 5.0 * (2.0 * df).sqrt(), "χ² {chi} with {df} degrees of freedom");
        // The test has power: the same offsets against discount 0.88 are far out.
        let (wrong, _) = offsets_chi_square(&rows, 0.88, v.t() - 2);
        assert!(wrong > df + 10.0 * (2.0 * df).sqrt(), "χ² {wrong} against the wrong discount");
        // OGBench's default discount clips most offsets of steps near the end; rows of step 0
        // keep their mean min(k, 49): (1 − 0.99^49) / 0.01 = 38.9.
        let (_, b) = batch(
            &OgbenchConfig {
                value_p_curgoal: 0.0,
                value_p_trajgoal: 1.0,
                value_p_randomgoal: 0.0,
                ..OgbenchConfig::default()
            },
            40_000,
            6,
        );
        let rows = trajectory_rows(&b, v.t());
        let (chi, bins) = offsets_chi_square(&rows, 0.99, v.t() - 2);
        let df = (bins - 1) as f64;
        assert!(chi < df + 5.0 * (2.0 * df).sqrt(), "χ² {chi} with {df} degrees of freedom at discount 0.99");
    }

    #[test]
    fn uniform_trajectory_goals_are_ogbench_rounded_uniforms() {
        // The actor's default: uniform between s + 1 and L, end points at half weight.
        let (v, b) = batch(
            &OgbenchConfig {
                value_geom_sample: false,
                value_p_curgoal: 0.0,
                value_p_trajgoal: 1.0,
                value_p_randomgoal: 0.0,
                ..OgbenchConfig::default()
            },
            60_000,
            7,
        );
        let last = v.t() - 2;
        let rows = trajectory_rows(&b, v.t());
        let (mut counts, mut expected) = (vec![0.0; last + 1], vec![0.0; last + 1]);
        for &(s, g) in &rows {
            counts[g] += 1.0;
            let lo = (s + 1).min(last);
            if lo == last {
                expected[last] += 1.0;
                continue;
            }
            let width = (last - lo) as f64;
            for (j, x) in expected.iter_mut().enumerate().take(last + 1).skip(lo) {
                *x += if j == lo || j == last { 0.5 / width } else { 1.0 / width };
            }
        }
        let (chi, bins) = chi_square(&counts, &expected);
        let df = (bins - 1) as f64;
        assert!(chi < df + 5.0 * (2.0 * df).sqrt(), "χ² {chi} with {df} degrees of freedom");
        // The actor goals of the same batch (the default) are the same kind of draw.
        let a: Vec<_> = (0..b.n).map(|i| (b.step[i], b.actor_goal_step[i])).collect();
        assert!(a.iter().all(|&(s, g)| g >= (s + 1).min(last as i64) && g <= last as i64));
    }

    #[test]
    fn transitions_and_random_goals_are_uniform_over_the_table() {
        let cfg = OgbenchConfig {
            value_p_curgoal: 0.0,
            value_p_trajgoal: 0.0,
            value_p_randomgoal: 1.0,
            ..OgbenchConfig::default()
        };
        let (v, b) = batch(&cfg, 60_000, 8);
        let (episodes, steps) = (v.episodes(), v.t() - 1);
        let bound = |df: f64| df + 5.0 * (2.0 * df).sqrt();
        for (what, ep, st) in
            [("transitions", &b.episode, &b.step), ("random goals", &b.value_goal_episode, &b.value_goal_step)]
        {
            let (mut by_e, mut by_s) = (vec![0.0; episodes], vec![0.0; steps]);
            for i in 0..b.n {
                // The last observation (step T − 1) is not a transition: never drawn.
                assert!((st[i] as usize) < steps, "{what}: row {i} at step {}", st[i]);
                by_e[ep[i] as usize] += 1.0;
                by_s[st[i] as usize] += 1.0;
            }
            let (ce, _) = chi_square(&by_e, &vec![b.n as f64 / episodes as f64; episodes]);
            let (cs, _) = chi_square(&by_s, &vec![b.n as f64 / steps as f64; steps]);
            assert!(ce < bound((episodes - 1) as f64), "{what}: episodes χ² {ce}");
            assert!(cs < bound((steps - 1) as f64), "{what}: steps χ² {cs}");
        }
        // Random goals are drawn apart from their rows: about 1 in 20·50 lands on the row itself.
        let hits = (0..b.n).filter(|&i| b.rewards[i] == 0.0).count();
        sigma_bound(hits, b.n, 1.0 / (episodes * steps) as f64);
    }

    #[test]
    fn same_seed_same_bytes_and_batches_are_their_own_streams() {
        let open = || OgbenchStream::new(Box::new(coded(5)), OgbenchConfig::default(), 9).unwrap();
        let (mut a, mut b) = (open(), open());
        let a0 = a.next_batch(64).unwrap();
        assert_eq!(a0, b.next_batch(64).unwrap());
        // Batch 1 is the same whether or not batch 0 was drawn at another size first.
        let _ = b.batch(0, 7).unwrap();
        assert_eq!(a.next_batch(64).unwrap(), b.next_batch(64).unwrap());
        assert_ne!(a0, a.next_batch(64).unwrap(), "batches differ from one another");
        let mut c = OgbenchStream::new(Box::new(coded(5)), OgbenchConfig::default(), 10).unwrap();
        assert_ne!(a0, c.next_batch(64).unwrap(), "seeds differ");
    }

    #[test]
    fn settings_ogbench_refuses_are_refused() {
        let bad = [
            OgbenchConfig { value_p_randomgoal: 0.4, ..OgbenchConfig::default() },
            OgbenchConfig { actor_p_trajgoal: -0.5, actor_p_randomgoal: 1.5, ..OgbenchConfig::default() },
            OgbenchConfig { discount: 1.0, ..OgbenchConfig::default() },
        ];
        let msgs = [
            "value_p_curgoal + value_p_trajgoal + value_p_randomgoal = 1.1",
            "actor_p_trajgoal = -0.5",
            "discount = 1",
        ];
        for (cfg, msg) in bad.iter().zip(msgs) {
            let e = OgbenchStream::new(Box::new(coded(2)), cfg.clone(), 0).err().expect("refused");
            assert!(e.to_string().contains(msg), "{e}");
        }
        // Within np.isclose of 1 is accepted, as OGBench accepts it.
        let near = OgbenchConfig { value_p_randomgoal: 0.3 + 5e-6, ..OgbenchConfig::default() };
        assert!(near.validate().is_ok());
        let parsed: OgbenchConfig = serde_json::from_str(r#"{"discount": 0.999}"#).unwrap();
        assert_eq!(parsed, OgbenchConfig { discount: 0.999, ..OgbenchConfig::default() });
        assert!(serde_json::from_str::<OgbenchConfig>(r#"{"value_p_curgoa": 0.1}"#).is_err());
    }
}
