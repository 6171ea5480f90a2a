//! The resident blocks and the index of their episodes: which block and which of its episodes
//! a resident episode number names (`pool.rs` draws by resident episode numbers).

use std::collections::VecDeque;
use std::ops::Deref;

use super::layout::Block;

/// The resident blocks, oldest first, and their episodes in that order. Blocks leave oldest first
/// and enter last, so a rotation pops the leaving block's episodes off the front of the index and
/// pushes the new one's at the back: its cost is the two blocks' episodes, not the resident
/// ones', and resident episode numbers are those a rebuilt index would give.
pub(super) struct Resident {
    blocks: VecDeque<Block>,
    /// Every block that enters gets the next sequence number (wrapping); the oldest's.
    front_seq: u32,
    /// Resident episode → (its block's sequence number, episode within the block).
    index: VecDeque<(u32, u32)>,
    /// Each resident block's first episode, counted over every episode that ever entered.
    starts: VecDeque<u64>,
    /// Episodes that ever entered.
    entered: u64,
}

impl Resident {
    pub(super) fn new(slots: usize) -> Resident {
        Resident {
            blocks: VecDeque::with_capacity(slots),
            front_seq: 0,
            index: VecDeque::new(),
            starts: VecDeque::with_capacity(slots),
            entered: 0,
        }
    }

    /// Places `b` after the resident blocks, its episodes after theirs.
    pub(super) fn enter(&mut self, b: Block) {
        let seq = self.front_seq.wrapping_add(self.blocks.len() as u32);
        self.index.extend((0..b.n as u32).map(|e| (seq, e)));
        self.starts.push_back(self.entered);
        self.entered += b.n as u64;
        self.blocks.push_back(b);
    }

    /// Takes the oldest block out, and its episodes.
    pub(super) fn leave(&mut self) -> Block {
        let b = self.blocks.pop_front().expect("a pool holds blocks");
        self.index.drain(..b.n);
        self.starts.pop_front();
        self.front_seq = self.front_seq.wrapping_add(1);
        b
    }

    /// Resident episodes.
    pub(super) fn episodes(&self) -> usize {
        self.index.len()
    }

    /// Resident episode `e`'s position in the blocks, and its block's first resident episode.
    pub(super) fn slot_of(&self, e: usize) -> (usize, usize) {
        let slot = self.index[e].0.wrapping_sub(self.front_seq) as usize;
        (slot, (self.starts[slot] - self.starts[0]) as usize)
    }

    /// Resident episode `e`'s block, and the episode within it.
    pub(super) fn episode(&self, e: usize) -> (&Block, usize) {
        let (seq, local) = self.index[e];
        (&self.blocks[seq.wrapping_sub(self.front_seq) as usize], local as usize)
    }
}

/// The blocks, to read (they change only through `enter` and `leave`).
impl Deref for Resident {
    type Target = VecDeque<Block>;
    fn deref(&self) -> &VecDeque<Block> {
        &self.blocks
    }
}
