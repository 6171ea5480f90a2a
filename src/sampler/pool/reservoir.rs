//! The goal reservoir: the random goals (`--swap random`, OGBench's `p_randomgoal`) of a pool,
//! a uniform sample of the whole table's observations and achieved goals rather than of the
//! resident blocks (`pool.rs`, "Random goals"). Which (block, episode, step) each slot holds is
//! decided by [`Keys`] from the seed and the block sizes alone; this fills in their vectors.

use std::collections::BTreeMap;

use anyhow::Result;
use rayon::prelude::*;

use super::buffers::{Bytes, Floats};
use super::layout::{Block, IN_FLIGHT, Layout};
use super::resident::Resident;
use super::schedule::Keys;
use crate::nprandom::NpRandom;
use crate::sampler::view::RandomGoal;

pub(super) struct Reservoir {
    keys: Keys,
    /// Each slot's table-wide (episode, step), achieved goal and observation (an image table's
    /// as its bytes, in `images`).
    at: Vec<(u64, u32)>,
    ag: Floats,
    obs: Floats,
    images: Bytes,
    /// Images a slot keeps: its goal's and the `frames − 1` before it (`Layout::with_frames`).
    frames: usize,
    goal_dim: usize,
    obs_dim: usize,
}

impl Reservoir {
    /// The reservoir of `keys` (as the seed and the draws so far left them), its vectors not yet
    /// filled ([`Reservoir::fill`]).
    pub(super) fn new(layout: &Layout, keys: Keys) -> Result<Reservoir> {
        let (len, gd, od) = (keys.slots.len(), layout.task.goal_dim, layout.task.obs_dim);
        let image = layout.is_image();
        Ok(Reservoir {
            at: vec![(0, 0); len],
            ag: Floats::zeros(len * gd)?,
            obs: Floats::zeros(if image { 0 } else { len * od })?,
            images: Bytes::zeros(if image { len * od * layout.frames } else { 0 })?,
            frames: layout.frames,
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
        for &slot in slots {
            let slot = slot as usize;
            let (_, e, s) = self.keys.slots[slot];
            let (e, s) = (e as usize, s as usize);
            self.set(slot, (b.first_episode + e as u64, s as u32), b, (e, s, t));
        }
    }

    /// Block `b` enters the pool: it replaces its share of the slots, oldest first
    /// ([`Keys::feed`]), with goals of its own.
    pub(super) fn enter(&mut self, layout: &Layout, b: &Block) {
        let (t, len) = (layout.t, self.len());
        for j in self.keys.feed(layout, b.id) {
            let slot = j % len;
            let (_, e, s) = self.keys.slots[slot];
            let (e, s) = (e as usize, s as usize);
            self.set(slot, (b.first_episode + e as u64, s as u32), b, (e, s, t));
        }
    }

    /// A goal drawn uniformly from the slots: the slot is its `RandomGoal::slot`.
    pub(super) fn draw(&self, rng: &mut NpRandom) -> RandomGoal {
        let i = rng.below(self.len());
        let (episode, step) = self.at[i];
        RandomGoal { episode, step, slot: i as u64 }
    }

    pub(super) fn ag(&self, slot: u64) -> &[f32] {
        &self.ag[slot as usize * self.goal_dim..][..self.goal_dim]
    }

    /// A slot's observation (empty for an image table: [`Reservoir::image`]).
    pub(super) fn obs(&self, slot: u64) -> &[f32] {
        if self.obs.is_empty() { &[] } else { &self.obs[slot as usize * self.obs_dim..][..self.obs_dim] }
    }

    /// An image table's slot's image `back` steps before its goal (clamped to the episode's
    /// first step when the slot was filled); empty for states.
    pub(super) fn image(&self, slot: u64, back: usize) -> &[u8] {
        if self.images.is_empty() {
            return &[];
        }
        let i = slot as usize * self.frames + self.frames - 1 - back;
        &self.images[i * self.obs_dim..][..self.obs_dim]
    }

    /// Slot `slot` now holds the goal of table-wide (episode, step) `at`: (e, s) of block `b`,
    /// whose episodes have `t` steps.
    fn set(&mut self, slot: usize, at: (u64, u32), b: &Block, (e, s, t): (usize, usize, usize)) {
        let (od, gd) = (self.obs_dim, self.goal_dim);
        self.at[slot] = at;
        self.ag.as_mut_slice()[slot * gd..][..gd].copy_from_slice(b.ag(e, s, t, gd));
        if self.images.is_empty() {
            self.obs.as_mut_slice()[slot * od..][..od].copy_from_slice(b.obs(e, s, t, od));
        } else {
            // Oldest frame first, each clamped to the episode's first step.
            let k = self.frames;
            for (i, out) in self.images.as_mut_slice()[slot * k * od..][..k * od].chunks_exact_mut(od).enumerate() {
                out.copy_from_slice(b.image(e, s.saturating_sub(k - 1 - i), t, od));
            }
        }
    }
}
