//! The order blocks enter the pool in, and which observations the goal reservoir holds: what the
//! pool's random numbers decide alone, before any data is read, so a resumed pool can replay them.

use super::layout::Layout;
use crate::nprandom::NpRandom;

/// Spawn keys of the pool's generators: the loader's permutations (with the pass number) and the
/// reservoir's draws. The batch streams use 1–4 and OGBench's layout its own.
pub(super) const KEY_PERMUTATION: u64 = 5;
pub(super) const KEY_RESERVOIR: u64 = 6;
/// The order blocks enter in, as one sequence over the passes: entry i is block
/// `permutation(.., i / B)[i % B]`. Computed, never stored beyond the current pass, so both the
/// loader and a resumed pool can find entry i without reading anything.
pub(super) struct Entries {
    /// A shard window's entries: the blocks in table order, over and over.
    pub(super) in_order: bool,
    pub(super) blocks: usize,
    pub(super) head: usize,
    pub(super) seed: u64,
    pub(super) pass: u64,
    pub(super) order: Vec<usize>,
}

impl Entries {
    pub(super) fn new(blocks: usize, head: usize, seed: u64) -> Entries {
        Entries { in_order: false, blocks, head, seed, pass: 0, order: permutation(blocks, head, seed, 0) }
    }

    /// Block after block in table order (a shard window).
    pub(super) fn in_order(blocks: usize) -> Entries {
        Entries { in_order: true, blocks, head: 0, seed: 0, pass: 0, order: Vec::new() }
    }

    pub(super) fn get(&mut self, i: u64) -> usize {
        if self.in_order {
            return (i % self.blocks as u64) as usize;
        }
        let pass = i / self.blocks as u64;
        if pass != self.pass {
            self.order = permutation(self.blocks, self.head, self.seed, pass);
            self.pass = pass;
        }
        self.order[(i % self.blocks as u64) as usize]
    }
}

/// The reservoir's entries as (block, episode in it, step): what the pool's random numbers decide
/// alone, before any data is read. Vectors are filled in from the blocks afterwards
/// (`Pool::materialize`, `Pool::rotate`).
pub(super) struct Keys {
    pub(super) slots: Vec<(u32, u32, u32)>,
    /// Next slot to replace (the oldest).
    pub(super) next: usize,
    /// The fraction of an entry owed to the next block.
    pub(super) carry: f64,
    pub(super) rng: NpRandom,
}

impl Keys {
    /// The first fill: every block gives its share of entries (carry-rounded, so they sum to
    /// `len`), uniform over its observations, each block's from a generator of its own; then the
    /// entries are put in a random order, since they are replaced oldest first and in block order
    /// the first shards' entries would all go before any of the last ones'.
    pub(super) fn first(layout: &Layout, len: usize, seed: u64) -> Keys {
        let mut slots = Vec::with_capacity(len);
        let mut carry = 0.0;
        for (id, b) in layout.blocks.iter().enumerate() {
            carry += len as f64 * b.episodes as f64 / layout.episodes as f64;
            let mut k = carry.floor() as usize;
            carry -= k as f64;
            if id + 1 == layout.blocks.len() {
                k = len - slots.len();
            }
            let mut rng = NpRandom::spawned(seed, &[KEY_RESERVOIR, 1 + id as u64]);
            for _ in 0..k {
                slots.push((id as u32, rng.below(b.episodes) as u32, rng.below(layout.t) as u32));
            }
        }
        let mut rng = NpRandom::spawned(seed, &[KEY_RESERVOIR]);
        for i in (1..slots.len()).rev() {
            slots.swap(i, rng.below(i + 1));
        }
        Keys { slots, next: 0, carry: 0.0, rng }
    }

    /// Block `id` enters: it replaces its share of entries, `R · r / N` for its `r` observations
    /// (the fraction carried), oldest first. Returns the slots it wrote.
    pub(super) fn feed(&mut self, layout: &Layout, id: usize) -> std::ops::Range<usize> {
        let b = layout.blocks[id];
        let len = self.slots.len();
        if len == 0 {
            return 0..0;
        }
        self.carry += len as f64 * b.episodes as f64 / layout.episodes as f64;
        let k = (self.carry.floor() as usize).min(len);
        self.carry -= k as f64;
        let from = self.next;
        for j in 0..k {
            let (e, s) = (self.rng.below(b.episodes), self.rng.below(layout.t));
            self.slots[(from + j) % len] = (id as u32, e as u32, s as u32);
        }
        self.next = (from + k) % len;
        from..from + k
    }
}

/// The order blocks enter in pass `pass`: every block once. Pass 0 is a seeded permutation;
/// every later pass starts with the same `head` blocks (pass 0's first ones, the first fill) and
/// shuffles the rest afresh.
///
/// Why the fixed head: a block is resident for `S` rotations. The first fill's block k leaves at rotation
/// k + 1, having had k + 1 of its S turns; as the pass ends, the same block enters again as the
/// next pass's k-th and has S − 1 − k turns before the pass's last rotation. So within every pass of
/// draws each block is resident for exactly S turns, and each shard's share of the draws is its
/// share of the rows, up to sampling noise, with no block half-drawn at a pass's edges.
pub(super) fn permutation(blocks: usize, head: usize, seed: u64, pass: u64) -> Vec<usize> {
    let shuffle = |p: &mut [usize], pass: u64| {
        let mut rng = NpRandom::spawned(seed, &[KEY_PERMUTATION, pass]);
        for i in (1..p.len()).rev() {
            p.swap(i, rng.below(i + 1));
        }
    };
    let mut p: Vec<usize> = (0..blocks).collect();
    shuffle(&mut p, 0);
    if pass > 0 {
        shuffle(&mut p[head..], pass);
    }
    p
}
