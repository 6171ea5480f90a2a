//! The goal reservoir: the random goals (`--swap random`, OGBench's `p_randomgoal`) of a pool,
//! a uniform sample of the whole table's observations and achieved goals rather than of the
//! resident blocks (`pool.rs`, "Random goals"). Which (block, episode, step) each slot holds is
//! decided by [`Keys`] from the seed and the block sizes alone; this fills in their vectors.

use std::collections::BTreeMap;

use anyhow::Result;
use rayon::prelude::*;

use super::buffers::Floats;
use super::layout::{Block, IN_FLIGHT, Layout};
use super::resident::Resident;
use super::schedule::Keys;
use crate::nprandom::NpRandom;
use crate::sampler::view::GoalSource;

pub(super) struct Reservoir {
    keys: Keys,
    /// Each slot's table-wide (episode, step), achieved goal and observation.
    at: Vec<(u64, u32)>,
    ag: Floats,
    obs: Floats,
    goal_dim: usize,
    obs_dim: usize,
}

impl Reservoir {
    /// The reservoir of `keys` (as the seed and the draws so far left them), its vectors not yet
    /// filled ([`Reservoir::fill`]).
    pub(super) fn new(layout: &Layout, keys: Keys) -> Result<Reservoir> {
        let (len, gd, od) = (keys.slots.len(), layout.task.goal_dim, layout.task.obs_dim);
        Ok(Reservoir {
            at: vec![(0, 0); len],
            ag: Floats::zeros(len * gd)?,
            obs: Floats::zeros(len * od)?,
            keys,
            goal_dim: gd,
            obs_dim: od,
        })
    }

    pub(super) fn len(&self) -> usize {
        self.at.len()
    }

    pub(super) fn is_empty(&self) -> bool {
        self.at.is_empty()
    }

    /// Fills every slot's vectors from the block its key names: resident blocks from memory, the
    /// others read (observations and achieved goals only), at most `IN_FLIGHT` at a time whatever
    /// the core count (the plan sets that much aside). Each group's slots are filled as soon as
    /// its blocks are read and the blocks dropped, so nothing allocated while reading outlives
    /// it: memory is the reservoir and those blocks, never the table's columns, and long-lived
    /// allocations made between the reads (which keep the allocator from reusing what the reads
    /// freed: 215 MB more after reading the 16,000 row groups of a 1B-row table) are none.
    pub(super) fn fill(&mut self, layout: &Layout, resident: &Resident) -> Result<()> {
        // The slots in block order, so each block's are one run.
        let mut order: Vec<u32> = (0..self.len() as u32).collect();
        order.sort_unstable_by_key(|&slot| self.keys.slots[slot as usize].0);
        let block_of = |slot: u32| self.keys.slots[slot as usize].0 as usize;
        // (block, its slots), in block order.
        let runs: Vec<(usize, &[u32])> =
            order.chunk_by(|&a, &b| block_of(a) == block_of(b)).map(|run| (block_of(run[0]), run)).collect();
        let held: BTreeMap<usize, &Block> = resident.iter().map(|b| (b.id, b)).collect();
        let (here, others): (Vec<_>, Vec<_>) = runs.into_iter().partition(|(id, _)| held.contains_key(id));
        for (id, run) in here {
            self.take(held[&id], run, layout.t);
        }
        for group in others.chunks(IN_FLIGHT as usize) {
            let blocks = group
                .par_iter()
                .map(|&(id, _)| layout.read_columns(id, &[true, true, false, false], Default::default()))
                .collect::<Result<Vec<_>>>()?;
            for (&(_, run), b) in group.iter().zip(&blocks) {
                self.take(b, run, layout.t);
            }
        }
        Ok(())
    }

    /// Fills `slots`, whose keys name block `b`, from it.
    fn take(&mut self, b: &Block, slots: &[u32], t: usize) {
        let (od, gd) = (self.obs_dim, self.goal_dim);
        for &slot in slots {
            let slot = slot as usize;
            let (_, e, s) = self.keys.slots[slot];
            let (e, s) = (e as usize, s as usize);
            self.set(slot, (b.first_episode + e as u64, s as u32), b.ag(e, s, t, gd), b.obs(e, s, t, od));
        }
    }

    /// Block `b` enters the pool: it replaces its share of the slots, oldest first
    /// ([`Keys::feed`]), with goals of its own.
    pub(super) fn enter(&mut self, layout: &Layout, b: &Block) {
        let (t, od, gd, len) = (layout.t, self.obs_dim, self.goal_dim, self.len());
        for j in self.keys.feed(layout, b.id) {
            let slot = j % len;
            let (_, e, s) = self.keys.slots[slot];
            let (e, s) = (e as usize, s as usize);
            self.set(slot, (b.first_episode + e as u64, s as u32), b.ag(e, s, t, gd), b.obs(e, s, t, od));
        }
    }

    /// A goal drawn uniformly from the slots: the slot is its `GoalSource::slot`.
    pub(super) fn draw(&self, rng: &mut NpRandom) -> GoalSource {
        let i = rng.below(self.len());
        let (episode, step) = self.at[i];
        GoalSource { episode, step, slot: i as u64 }
    }

    pub(super) fn ag(&self, slot: u64) -> &[f32] {
        &self.ag[slot as usize * self.goal_dim..][..self.goal_dim]
    }

    pub(super) fn obs(&self, slot: u64) -> &[f32] {
        &self.obs[slot as usize * self.obs_dim..][..self.obs_dim]
    }

    /// Slot `slot` now holds the goal of table-wide (episode, step) `at`.
    fn set(&mut self, slot: usize, at: (u64, u32), ag: &[f32], obs: &[f32]) {
        self.at[slot] = at;
        self.ag.as_mut_slice()[slot * ag.len()..][..ag.len()].copy_from_slice(ag);
        self.obs.as_mut_slice()[slot * obs.len()..][..obs.len()].copy_from_slice(obs);
    }
}
