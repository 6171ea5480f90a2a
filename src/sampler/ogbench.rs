//! OGBench's goal-conditioned batches from a pgser table: the dicts OGBench's and Horizon
//! Reduction's JAX agents train on, drawn by the rules of their dataset classes, so that such an
//! agent switches to pgser by replacing its dataset object with `pgser.Sampler(path,
//! layout=..., config=config)`. Whose classes a stream follows is the user's choice ([`Code`]):
//! OGBench's (`impls/utils/datasets.py`, which its GCIQL, CRL and HIQL were run on, by
//! `bench/peer_agents.py`) or Horizon Reduction's (`utils/datasets.py`: its SHARSA, double SHARSA,
//! n-step SAC+BC, hierarchical flow BC, HIQL, CRL and SAC+BC were run); `dataset_class` picks
//! `GCDataset` (this file) or `HGCDataset` (`hierarchical.rs`) within it.
//!
//! The two codes' `GCDataset`s draw alike; Horizon Reduction's takes goals from `oracle_reps`
//! where the dataset has them ([`OgbenchConfig::oracle_reps`]: the table's achieved goals),
//! loads the compact layout (its batches carry `valids`, 1 on every drawn row, and
//! `oracle_reps`), and its loader clips actions ([`OgbenchConfig::clip_actions`]).
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
//! - goals are **observations** at the goal's (episode, step), or with `oracle_reps` the
//!   table's achieved goals there;
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
//! # Pixels
//! A visual dataset's table keeps its observations as uint8 images; every observation key of a
//! batch (observations, next observations, and goals that are observations) is then a uint8
//! array [n, H, W, C], stacked by `frame_stack` to [n, H, W, K·C] and randomly cropped with
//! probability `p_aug` a batch, as OGBench's `GCDataset` does both (`images.rs`). The draws of
//! rows and goals are those of a state table; the crops' draws come after them.
//!
//! # Provenance
//! Every batch says where each row and each goal came from: `episode`, `step` (table-wide
//! episode numbers, shard order across a folder), and for each goal key `K`s (`value_goals`,
//! `high_actor_targets`, …) `K_episode`, `K_step` and `K_kind` ([`GoalKind`]), and
//! `scored_row` (the scored table's row of a swapped row, −1 for the others); in an image
//! table, `crop_y` and `crop_x`, each row's crop offsets (−1 in a batch not cropped).
//!
//! # Streams
//! Batch k of a stream draws from its own generator, `NpRandom::spawned(seed, [STREAM_OGBENCH,
//! k])`: its rows depend on the seed, k and its size only. The Python sampler draws batches ahead
//! at its default size and, asked for another size, draws that batch again at that size, without
//! changing any other batch (the data a pool holds also depends on the rows drawn before).

use std::path::Path;

use anyhow::{Result, bail};

use super::open::Beta;
use super::pool::ScoredDraw;
use super::priority::PriorityConfig;
use super::view::{Budget, View};
use crate::nprandom::NpRandom;
pub use batch::{Column, Key, OgbenchBatch};
use config::Fractions;
pub use config::{Code, DatasetClass, OgbenchConfig};
use swapped::{Source, Swapper};

mod batch;
mod config;
mod hierarchical;
mod images;
mod swapped;

/// Spawn key of OGBench-layout batches ("OGBN"), beside the batch streams' 1–4 and the pool's 5–6.
pub const STREAM_OGBENCH: u64 = 0x4f47_424e;

/// Which of OGBench's three sources, or PGSER's swapped rows, a goal came from; a subgoal
/// derived from the row's own episode (a target, a low-level goal) is `Trajectory`, or
/// `Current` where it is the row's own step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GoalKind {
    Current,
    Trajectory,
    Random,
    Swapped,
}

impl GoalKind {
    /// The uint8 code a Python batch gives a kind (`pgser.GOAL_KINDS` names them in order).
    pub fn code(self) -> u8 {
        match self {
            GoalKind::Current => 0,
            GoalKind::Trajectory => 1,
            GoalKind::Random => 2,
            GoalKind::Swapped => 3,
        }
    }
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
    Source(super::view::RandomGoal),
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
        cfg.check_table(source.view())?;
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
        let source = Source::open(path, budget, &cfg, priority, seed)?;
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

    /// Draws the batches from here on with `cfg` (a Python agent that sets a config key after
    /// its dataset was made, as Horizon Reduction's double SHARSA sets `low_discount`); refused,
    /// and the stream unchanged, if this table or the open stream cannot take it.
    pub fn reconfigure(&mut self, cfg: OgbenchConfig) -> Result<()> {
        let fixed = |c: &OgbenchConfig| (c.code, c.oracle_reps, c.p_swapgoal > 0.0, c.frame_stack);
        if fixed(&cfg) != fixed(&self.cfg) {
            bail!("a config change of layout, oracle_reps, frame_stack or p_swapgoal's use needs a new sampler");
        }
        cfg.check_table(self.source.view())?;
        self.cfg = cfg;
        Ok(())
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
    pub fn would_rotate(&self, n: usize) -> bool {
        self.source.pool().is_some_and(|p| p.rotates_within(n))
    }

    /// Readies the block the next rotation takes in, waiting for the loader (a no-op for β held
    /// whole): see `Pool::stage`.
    pub fn stage(&mut self) {
        if let Some(p) = self.source.pool_mut() {
            p.stage();
        }
    }

    /// Forgets `rows` draws of batches drawn ahead and dropped, none of which took a block in
    /// ([`OgbenchStream::would_rotate`]): the next batch is drawn from the pool as it was before them.
    pub fn drop_ahead(&mut self, rows: usize) {
        if let Some(p) = self.source.pool_mut() {
            p.unrefresh(rows);
        }
    }

    /// Batch `k` of the stream, of `n` rows (not moving the stream on): the view is refreshed
    /// for `n` draws first, so a pool's resident data follow the rows drawn.
    pub fn batch(&mut self, k: u64, n: usize) -> Result<OgbenchBatch> {
        self.batch_for(k, n, false)
    }

    /// [`OgbenchStream::batch`], as an `evaluation` batch when asked (OGBench's
    /// `sample(..., evaluation=True)`: never cropped; everything else drawn alike).
    pub fn batch_for(&mut self, k: u64, n: usize, evaluation: bool) -> Result<OgbenchBatch> {
        if n == 0 {
            bail!("batch_size must be at least 1");
        }
        self.source.refresh(n)?;
        let mut rng = NpRandom::spawned(self.seed, &[STREAM_OGBENCH, k]);
        let ctx = Ctx { view: self.source.view(), swap: self.source.swapper(), cfg: &self.cfg, augment: !evaluation };
        Ok(match self.cfg.dataset_class {
            DatasetClass::GCDataset => draw(&ctx, &mut rng, n),
            DatasetClass::HGCDataset => hierarchical::draw(&ctx, &mut rng, n),
        })
    }
}

/// What a batch is drawn from, and with which settings.
struct Ctx<'a> {
    view: &'a dyn View,
    swap: Option<&'a dyn Swapper>,
    cfg: &'a OgbenchConfig,
    /// Whether images may be cropped (not in an evaluation batch).
    augment: bool,
}

/// Which vector of a point a key reads.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Read {
    /// Its observation.
    Obs,
    /// Its goal representation: the achieved goal with `oracle_reps`, else the observation.
    Rep,
}

impl Ctx<'_> {
    /// A row's transition (resident episode, step), and its swapped goal and scored row when it
    /// is one of PGSER's rows: decided first, with its own uniform, and only when
    /// `p_swapgoal > 0`, so other settings draw exactly as without.
    fn pick(&self, rng: &mut NpRandom) -> (usize, usize, Option<(Goal, u64)>) {
        if let Some(swap) = self.swap.filter(|_| self.cfg.p_swapgoal > 0.0 && rng.random() < self.cfg.p_swapgoal) {
            let (e, s, vg, row) = swap.pick(rng);
            return (e, s, Some((vg, row)));
        }
        let steps = self.view.t() - 1;
        let row = rng.below(self.view.episodes() * steps);
        (row / steps, row % steps, None)
    }

    /// The last transition's step, L = T − 2: OGBench's "final state" of every episode.
    fn last(&self) -> usize {
        self.view.t() - 2
    }

    /// Point (e, step) of resident episode `e`, a subgoal derived from row (e, s).
    fn point(&self, e: usize, s: usize, step: usize) -> Goal {
        let kind = if step == s { GoalKind::Current } else { GoalKind::Trajectory };
        Goal { kind, episode: self.view.episode_number(e), step, at: At::Resident(e, step) }
    }

    /// Whether goal `g` is the row's own step: OGBench's `idxs == goal_idxs`.
    fn reaches(&self, e: usize, s: usize, g: &Goal) -> bool {
        (g.episode, g.step) == (self.view.episode_number(e), s)
    }

    fn read(&self, g: &Goal, read: Read) -> &[f32] {
        let rep = read == Read::Rep && self.cfg.oracle_reps;
        match g.at {
            At::Resident(e, s) if rep => self.view.ag(e, s),
            At::Resident(e, s) => self.view.obs(e, s),
            At::Source(src) if rep => self.view.goal_ag(src),
            At::Source(src) => self.view.goal_obs(src),
            // The scored row's stored goal: its achieved goal, which is the observation it was
            // taken from where goals are whole observations (checked at open) and the oracle
            // representation with `oracle_reps`.
            At::Scored(d) => self.swap.expect("a scored goal comes from the swapper").scored_goal(&d),
        }
    }

    /// Whether a key of `read` holds observations (images, in an image table), not oracle
    /// representations.
    fn is_obs(&self, read: Read) -> bool {
        read == Read::Obs || !self.cfg.oracle_reps
    }

    /// The image `back` steps before goal `g` in its stack (`images.rs`).
    fn frame(&self, g: &Goal, back: usize) -> &[u8] {
        match g.at {
            At::Resident(e, s) => self.view.image(e, images::stack_step(s, back, self.view.t())),
            At::Source(src) => self.view.goal_image(src, back),
            // Image tables are never scored (scoring reads states), so no swapped goal is an image.
            At::Scored(_) => &[],
        }
    }

    fn width(&self, read: Read) -> usize {
        let task = self.view.task();
        if read == Read::Rep && self.cfg.oracle_reps { task.goal_dim } else { task.obs_dim }
    }

    /// The batch's keys every class has: the transitions (observations, next_observations,
    /// actions clipped by `clip_actions`, terminals; Horizon Reduction's compact datasets'
    /// `valids` too), then the keys of `points`, the class's `scalars`, and the provenance. The vectors are copied in
    /// parallel, in chunks of rows (copying is most of a batch's time on wide observations, and
    /// it does not touch the generator, so the batch is the same at any thread count). In an
    /// image table the observation keys are images, stacked and cropped by `images.rs`, whose
    /// crops are drawn here, after the rows.
    fn batch(
        &self,
        rng: &mut NpRandom,
        rows: &[(usize, usize)],
        scored: Vec<i64>,
        points: Vec<(&str, Read, Vec<Goal>)>,
        scalars: Vec<(String, Column)>,
    ) -> OgbenchBatch {
        let (view, n) = (self.view, rows.len());
        let (od, ad) = (view.task().obs_dim, view.task().act_dim);
        let mut b = OgbenchBatch { n, keys: Vec::new() };
        let floats = |dim, values| Column::F32 { dim: Some(dim), values };
        let shape = view.image_shape();
        let image =
            (!shape.is_empty()).then(|| images::Geometry::of(shape, self.cfg.frame_stack.unwrap_or(1) as usize));
        let crops = image.and_then(|_| images::crops(rng, self.cfg.p_aug, self.augment, n));
        let pixels = |goals: &[Goal], g: images::Geometry| Column::U8 {
            shape: g.shape(),
            values: images::gather(goals, g, crops.as_deref(), |goal, j| self.frame(goal, g.stack - 1 - j)),
        };
        match image {
            Some(g) => {
                let at = |next: usize| -> Vec<Goal> {
                    rows.iter().map(|&(e, s)| self.point(e, s + next, s + next)).collect()
                };
                b.push("observations", pixels(&at(0), g));
                b.push("next_observations", pixels(&at(1), g));
            }
            None => {
                b.push("observations", floats(od, super::gather_rows(rows, od, |r| view.obs(r.0, r.1))));
                b.push("next_observations", floats(od, super::gather_rows(rows, od, |r| view.obs(r.0, r.1 + 1))));
            }
        }
        let mut actions = super::gather_rows(rows, ad, |r| view.action(r.0, r.1));
        if let Some(eps) = self.cfg.clip_actions {
            // np.clip(float32, −1 + eps, 1 − eps): the bounds as float32, NaN kept.
            let (lo, hi) = ((-1.0 + eps) as f32, (1.0 - eps) as f32);
            actions.iter_mut().for_each(|a| *a = a.clamp(lo, hi));
        }
        b.push("actions", floats(ad, actions));
        let t = view.t();
        let terminals = rows.iter().map(|&(_, s)| if s + 2 == t { 1.0 } else { 0.0 }).collect();
        b.push("terminals", Column::F32 { dim: None, values: terminals });
        if self.cfg.code == Code::HorizonReduction {
            b.push("valids", Column::F32 { dim: None, values: vec![1.0; n] });
            if self.cfg.oracle_reps {
                let gd = view.task().goal_dim;
                b.push("oracle_reps", floats(gd, super::gather_rows(rows, gd, |r| view.ag(r.0, r.1))));
            }
        }
        for (name, read, goals) in &points {
            if let Some(g) = image.filter(|_| self.is_obs(*read)) {
                b.push(name, pixels(goals, g));
                continue;
            }
            let dim = self.width(*read);
            b.push(name, floats(dim, super::gather_rows(goals, dim, |g| self.read(g, *read))));
        }
        for (name, column) in scalars {
            b.push(&name, column);
        }
        b.push_provenance("episode", Column::I64(rows.iter().map(|r| view.episode_number(r.0) as i64).collect()));
        b.push_provenance("step", Column::I64(rows.iter().map(|r| r.1 as i64).collect()));
        for (name, _, goals) in &points {
            // value_goals → value_goal_episode, high_actor_targets → high_actor_target_step.
            let stem = name.strip_suffix('s').unwrap_or(name);
            b.push_provenance(
                &format!("{stem}_episode"),
                Column::I64(goals.iter().map(|g| g.episode as i64).collect()),
            );
            b.push_provenance(&format!("{stem}_step"), Column::I64(goals.iter().map(|g| g.step as i64).collect()));
            b.push_provenance(&format!("{stem}_kind"), Column::Kind(goals.iter().map(|g| g.kind).collect()));
        }
        b.push_provenance("scored_row", Column::I64(scored));
        if image.is_some() {
            // Each row's crop offsets, −1 in a batch not cropped.
            for (name, axis) in [("crop_y", 0), ("crop_x", 1)] {
                let at = |i: usize| crops.as_ref().map_or(-1, |c| i64::from(if axis == 0 { c[i].0 } else { c[i].1 }));
                b.push_provenance(name, Column::I64((0..n).map(at).collect()));
            }
        }
        b
    }
}

/// `n` rows of the flat class, `GCDataset.sample` (OGBench's, and Horizon Reduction's, which
/// reads oracle representations as goals where the dataset has them): the module doc.
fn draw(ctx: &Ctx, rng: &mut NpRandom, n: usize) -> OgbenchBatch {
    let cfg = ctx.cfg;
    let (value, actor) = (cfg.value(), cfg.actor());
    let (mut rows, mut scored) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let (mut value_goals, mut actor_goals) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for _ in 0..n {
        let (e, s, swapped) = ctx.pick(rng);
        let (vg, ag) = match swapped {
            Some((vg, row)) => {
                scored.push(row as i64);
                (vg, if cfg.swap_actor_goals { vg } else { goal(ctx, rng, e, s, actor) })
            }
            None => {
                scored.push(-1);
                let vg = goal(ctx, rng, e, s, value);
                (vg, goal(ctx, rng, e, s, actor))
            }
        };
        rows.push((e, s));
        value_goals.push(vg);
        actor_goals.push(ag);
    }
    let offset = if cfg.gc_negative { 1.0 } else { 0.0 };
    let successes = successes(ctx, &rows, &value_goals);
    ctx.batch(
        rng,
        &rows,
        scored,
        vec![("value_goals", Read::Rep, value_goals), ("actor_goals", Read::Rep, actor_goals)],
        rewards_and_masks("", &successes, offset),
    )
}

/// 1 where a row's goal is its own step (OGBench's `idxs == goal_idxs`), else 0.
fn successes(ctx: &Ctx, rows: &[(usize, usize)], goals: &[Goal]) -> Vec<f64> {
    rows.iter().zip(goals).map(|(&(e, s), g)| if ctx.reaches(e, s, g) { 1.0 } else { 0.0 }).collect()
}

/// `{prefix}rewards` and `{prefix}masks` of one-step successes: `successes − 1` with
/// `gc_negative` (`offset` 1), else `successes`; masks `1 − successes`. Float64, as numpy's
/// `.astype(float)` gives them.
fn rewards_and_masks(prefix: &str, successes: &[f64], offset: f64) -> Vec<(String, Column)> {
    vec![
        (format!("{prefix}rewards"), Column::F64(successes.iter().map(|x| x - offset).collect())),
        (format!("{prefix}masks"), Column::F64(successes.iter().map(|x| 1.0 - x).collect())),
    ]
}

/// One goal for transition (e, s) by OGBench's `sample_goals` (the module doc).
fn goal(ctx: &Ctx, rng: &mut NpRandom, e: usize, s: usize, p: Fractions) -> Goal {
    let (p_cur, p_traj, geom, discount) = p;
    let view = ctx.view;
    if p_cur == 1.0 || rng.random() < p_cur {
        return ctx.point(e, s, s);
    }
    if rng.random() < p_traj / (1.0 - p_cur) {
        let step = trajectory_step(ctx, rng, s, geom, discount);
        return Goal { kind: GoalKind::Trajectory, ..ctx.point(e, s, step) };
    }
    random_goal(view, rng)
}

/// A later step of the row's episode: geometric, `min(s + k, L)`, or OGBench's rounded uniform
/// between `min(s + 1, L)` and L.
fn trajectory_step(ctx: &Ctx, rng: &mut NpRandom, s: usize, geom: bool, discount: f64) -> usize {
    let last = ctx.last();
    if geom {
        let k = geometric(rng, 1.0 - discount);
        (s as u64).saturating_add(k).min(last as u64) as usize
    } else {
        let d = rng.random();
        let near = (s + 1).min(last) as f64;
        (near * d + last as f64 * (1.0 - d)).round_ties_even() as usize
    }
}

/// A transition uniform over the whole table (OGBench's `get_random_idxs`): the view draws over
/// all T observations of an episode, so a draw of step T − 1 is drawn again.
fn random_goal(view: &dyn View, rng: &mut NpRandom) -> Goal {
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
