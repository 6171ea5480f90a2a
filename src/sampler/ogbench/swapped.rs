//! PGSER's prioritized swapped rows in OGBench's layout (`p_swapgoal`): where they come from, and
//! opening a scored table for them.
//!
//! A swapped row is a scored row drawn by priority: its transition and its goal come together,
//! as in PGSER's `-mem` batches, so the transitions of swapped rows lean towards those the critic
//! finds a reachable goal for. OGBench's goals are observations, so the goal of a swapped row is
//! the observation at the scored row's (`goal_episode`, `goal_step`), not the achieved goal the
//! scored table stores:
//! - **β held whole**: priorities over the whole scored table in a sum tree (4.25 bytes a row)
//!   and every row's keys (16 bytes a row); the goal is read from β.
//! - **β within a budget** (a pool, or a shard window): each block carries its own scored rows and
//!   their goals' (episode, step) (`pool.rs`, "PGSER within a budget"); the goal's observation is
//!   usually not resident, so the stored goal is used, which is the observation only when the
//!   task's goals are its whole observations (PointMaze), and the goal itself with `oracle_reps`
//!   (whose goals are the achieved goals the scored table stores). Other tasks are refused within
//!   a budget.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Context, Result, bail};

use super::{At, Goal, GoalKind, OgbenchConfig};
use crate::nprandom::NpRandom;
use crate::sampler::RowKey;
use crate::sampler::open::{self, Beta, Observations, Opened, Scoring};
use crate::sampler::pool::{Pool, Position};
use crate::sampler::priority::{PriorityConfig, SumTree};
use crate::sampler::view::{Budget, View};
use crate::score::ScoredTable;
use crate::trajectory::Episodes;

/// A source of prioritized swapped rows for OGBench's layout.
pub(super) trait Swapper: Sync {
    /// A scored row drawn by priority: its transition (resident episode, step), its goal, and
    /// its row in the scored table.
    fn pick(&self, rng: &mut NpRandom) -> (usize, usize, Goal, u64);
    /// The stored goal of an `At::Scored` goal `pick` returned: the achieved goal it was scored
    /// with (the observation where goals are whole observations).
    fn scored_goal(&self, d: &crate::sampler::pool::ScoredDraw) -> &[f32];
}

/// β held whole: priorities over every scored row, and every row's keys.
pub(super) struct WholeRows {
    tree: SumTree,
    keys: Vec<RowKey>,
}

impl Swapper for WholeRows {
    fn pick(&self, rng: &mut NpRandom) -> (usize, usize, Goal, u64) {
        let r = self.tree.find(rng.random() * self.tree.total());
        let k = self.keys[r];
        let (ge, gs) = (k.goal_episode as usize, k.goal_step as usize);
        let goal = Goal { kind: GoalKind::Swapped, episode: ge as u64, step: gs, at: At::Resident(ge, gs) };
        (k.episode as usize, k.step as usize, goal, r as u64)
    }
    fn scored_goal(&self, _: &crate::sampler::pool::ScoredDraw) -> &[f32] {
        unreachable!("rows of β held whole name their goal's place in β")
    }
}

impl Swapper for Pool {
    fn pick(&self, rng: &mut NpRandom) -> (usize, usize, Goal, u64) {
        let d = self.draw_scored(1, rng)[0];
        let (ge, gs) = self.scored_goal_source(&d).expect("the layout keeps the goals' sources");
        let goal = Goal { kind: GoalKind::Swapped, episode: ge, step: gs, at: At::Scored(d) };
        (d.e, d.step, goal, self.scored_row(&d))
    }
    fn scored_goal(&self, d: &crate::sampler::pool::ScoredDraw) -> &[f32] {
        Pool::scored_goal(self, d)
    }
}

/// β and, when swapped rows are drawn, where they come from.
pub(super) enum Source {
    Plain(Beta),
    Whole { data: Arc<Episodes>, rows: WholeRows },
    Pool(Box<Pool>),
}

impl Source {
    pub(super) fn view(&self) -> &dyn View {
        match self {
            Source::Plain(b) => b.view(),
            Source::Whole { data, .. } => data.as_ref(),
            Source::Pool(p) => p.as_ref(),
        }
    }

    /// Readies a pool for the next `rows` draws (`View::refresh`); β held whole has nothing to do.
    pub(super) fn refresh(&mut self, rows: usize) -> Result<()> {
        match self {
            Source::Plain(Beta::Pool(p)) | Source::Pool(p) => p.refresh(rows),
            Source::Plain(Beta::Whole(_)) | Source::Whole { .. } => Ok(()),
        }
    }

    /// The pool, mutably, when β is one.
    pub(super) fn pool_mut(&mut self) -> Option<&mut Pool> {
        match self {
            Source::Plain(Beta::Pool(p)) | Source::Pool(p) => Some(p),
            _ => None,
        }
    }

    /// The pool, when β is one.
    pub(super) fn pool(&self) -> Option<&Pool> {
        match self {
            Source::Plain(Beta::Pool(p)) | Source::Pool(p) => Some(p),
            _ => None,
        }
    }

    pub(super) fn swapper(&self) -> Option<&dyn Swapper> {
        match self {
            Source::Plain(_) => None,
            Source::Whole { rows, .. } => Some(rows),
            Source::Pool(p) => Some(p.as_ref()),
        }
    }

    /// Opens `path` within `budget`: a trajectory table (no swapped rows: `p_swapgoal` must be 0),
    /// or a scored table and its original data, with its rows' priorities by `priority`.
    pub(super) fn open(
        path: &Path,
        budget: Budget,
        cfg: &OgbenchConfig,
        priority: &PriorityConfig,
        seed: u64,
    ) -> Result<Source> {
        let (at, p_swapgoal) = (path.display(), cfg.p_swapgoal);
        let Some(table) = ScoredTable::open_if_scored(path)? else {
            if p_swapgoal > 0.0 {
                bail!(
                    "{at}: p_swapgoal = {p_swapgoal} draws swapped goals by priority from a scored table (pgser-etl \
                     score), and this is a trajectory table; give its scored table or folder, or p_swapgoal = 0"
                );
            }
            return Ok(Source::Plain(
                open::plan(
                    path,
                    budget,
                    None,
                    Observations::StatesOrImages { frames: cfg.frame_stack.unwrap_or(1) as usize },
                )?
                .open(seed, Position::START)?
                .data,
            ));
        };
        let source = open::checked_source(&table)?;
        if p_swapgoal == 0.0 {
            // Its original data alone: no scored rows held for nothing.
            return Ok(Source::Plain(
                open::plan(
                    &source,
                    budget,
                    None,
                    Observations::StatesOrImages { frames: cfg.frame_stack.unwrap_or(1) as usize },
                )?
                .open(seed, Position::START)?
                .data,
            ));
        }
        priority.validate()?;
        if let Some(b) = priority.is_beta {
            bail!("is_beta = {b}: OGBench's batches carry no importance weights; leave it unset");
        }
        if table.footer.include_original {
            bail!(
                "{at}: scored with --include-original: its rows that keep a transition's own desired goal name no \
                 observation, which OGBench's goals are; score without it"
            );
        }
        let task = table.task.clone();
        let scoring = Scoring { table, priority: priority.clone(), goal_sources: true };
        let planned = open::plan(
            &source,
            budget,
            Some(scoring),
            Observations::StatesOrImages { frames: cfg.frame_stack.unwrap_or(1) as usize },
        )?;
        // Within a budget the stored goal stands for the goal vector: the achieved goal, which
        // is what `oracle_reps` reads; for observation goals, refused unless the task's goals are
        // its whole observations (the width here, before the pool reads anything; the values once
        // its first blocks are in).
        let refuse = |bytes: u64| {
            anyhow::anyhow!(
                "{at}: p_swapgoal within a memory budget needs goals that are whole observations (a block keeps the \
                 goals its rows were scored with, not the observations they were taken from); {}'s goals are {} of \
                 its {} observation values. Hold the data in memory (no memory_budget, or one of {} or more), or \
                 use layout=\"pgser\"",
                task.name,
                task.goal_dim,
                task.obs_dim,
                crate::progress::bytes(bytes)
            )
        };
        let bytes = planned.pool_bytes();
        if let Some(b) = bytes
            && !cfg.oracle_reps
            && task.goal_dim != task.obs_dim
        {
            return Err(refuse(b));
        }
        match planned.open(seed, Position::START)? {
            Opened { data: Beta::Whole(data), scored: Some(table) } => {
                table.check_whole()?;
                let q = table.read_q()?;
                let tree = SumTree::new(priority.priorities(q, table.gamma).with_context(|| format!("{at}"))?);
                let keys = table.read_keys(&data)?;
                Ok(Source::Whole { data, rows: WholeRows { tree, keys } })
            }
            Opened { data: Beta::Pool(pool), .. } => {
                if !cfg.oracle_reps && !pool.goals_are_observations() {
                    return Err(refuse(bytes.expect("a pool was planned")));
                }
                Ok(Source::Pool(pool))
            }
            Opened { data: Beta::Whole(_), scored: None } => {
                unreachable!("a scored table held whole is opened with it")
            }
        }
    }
}
