//! Reading blocks ahead of the drawing thread: the loader thread, and keeping the memory of
//! blocks that leave returnable to the system (`pool.rs` says how blocks are scheduled).

use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};

use anyhow::Result;

use super::layout::{Arrays, Block, Layout};
use super::{PoolConfig, entries};

/// glibc's mmap threshold while a pool draws: buffers of this many bytes or more are mappings of
/// their own, returned to the system when freed; smaller ones come from the heap of the thread
/// that allocates them and are reused there. Above the decoder's page buffers (Parquet pages of
/// about 1 MB, decompressed), so the loader reuses them page after page: at 1 MiB they were fresh
/// mappings, and on humanoidmaze's shape (24 MB a block) page faults were 18 % of the loader's time.
pub(super) const MMAP_THRESHOLD: usize = 2 << 20;

/// The threshold while a pool opens, when every core reads blocks at once: 1 MiB, so those
/// threads' page buffers are returned rather than left in their heaps (glibc shrinks a heap only
/// from its top; 150 MB stayed behind on humanoidmaze's shape at 2 MiB).
const OPEN_MMAP_THRESHOLD: usize = 1 << 20;

/// Makes glibc give large buffers (a block's arrays) back to the system when they are freed,
/// set for opening a pool. By default glibc raises its mmap threshold each time such a buffer is
/// freed, up to 32 MB, after which buffers of a block's size come from the heaps of the threads
/// that allocated them and stay there when freed: measured on 10M humanoidmaze-shaped rows, the
/// process then held 0.9 GB beyond a 1 GB budget, more on a larger table. A fixed threshold keeps
/// every larger buffer a mapping of its own, returned on free. A block's arrays are always at
/// least [`MMAP_THRESHOLD`] large (`Layout::read_columns` reserves it), however narrow the rows:
/// PointMaze's 500 kB arrays (62,500 rows of 2 floats) otherwise stayed in the threads' heaps,
/// where they fragmented, and peak RSS rose while drawing, from 1,162 MiB after 2,000 batches to
/// 1,326 MiB after 8,000 and 1,706 MiB after 20,000 (100M rows, 1 GB budget). A lower threshold
/// (128 KiB) fixed that too, but then every batch's wide vectors (1024 rows of 69 floats: 282 kB)
/// were fresh mappings, zeroed by the kernel: 805 → 679 batches/s on humanoidmaze's shape.
/// Process-wide; elsewhere than glibc it does nothing.
pub(super) fn keep_large_buffers_returnable() {
    set_mmap_threshold(OPEN_MMAP_THRESHOLD);
}

/// Once a pool is open: returns the free memory the opening left in every thread's heap
/// (`malloc_trim`) and sets the threshold for drawing, [`MMAP_THRESHOLD`].
pub(super) fn settle_after_open() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free pages; it is safe to call at any time.
    unsafe {
        libc::malloc_trim(0);
    }
    set_mmap_threshold(MMAP_THRESHOLD);
}

fn set_mmap_threshold(bytes: usize) {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; it is safe to call at any time.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, bytes as i32);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 2 * bytes as i32);
    }
    let _ = bytes;
}

/// Asks the kernel to back the first `floats` of `v`'s capacity with transparent huge pages
/// (2 MB) where it may (`madvise`; Linux's default THP mode honours it). A batch gathers rows at
/// random from a gigabyte of blocks and from the reservoir: with 4 kB pages nearly every row is a
/// TLB miss. Only the part that will be written is advised, since a huge page is backed whole
/// once touched: advising a 4 MB reservation of which 512 kB are used would hold 2 MB. Arrays
/// under a huge page gain nothing and are left alone; elsewhere than Linux it does nothing.
pub(super) fn advise_huge_pages(v: &mut Vec<f32>, floats: usize) {
    #[cfg(target_os = "linux")]
    {
        const HUGE: usize = 2 << 20;
        let start = v.as_mut_ptr() as usize;
        let end = start + floats.min(v.capacity()) * 4;
        let (from, to) = (start.next_multiple_of(HUGE), end / HUGE * HUGE);
        if to > from {
            // SAFETY: the range lies within `v`'s allocation and is page-aligned; MADV_HUGEPAGE
            // only changes how the kernel backs those pages, never their contents.
            unsafe {
                libc::madvise(from as *mut libc::c_void, to - from, libc::MADV_HUGEPAGE);
            }
        }
    }
}

/// The loader: entries `from` on ([`Entries`]), each block read and sent through a channel of
/// one. It stops when the pool is dropped (the send fails) or after a read error, which it sends.
///
/// It fills the arrays of blocks that left, which the pool hands back through the second channel
/// (of one, so the blocks in flight stay the plan's `IN_FLIGHT`: one sent, one being read, one
/// handed back), or fresh ones when none is waiting. Fresh arrays are mappings the kernel must
/// zero page by page as they are written: on humanoidmaze's shape (24 MB a block) page faults
/// were 18 % of the loader's time, and the loader was what batches waited for.
pub(super) fn spawn_loader(
    layout: Arc<Layout>,
    cfg: PoolConfig,
    head: usize,
    from: u64,
) -> (Receiver<Result<Block>>, SyncSender<Arrays>) {
    let (tx, rx) = sync_channel(1);
    let (back, spare) = sync_channel::<Arrays>(1);
    std::thread::Builder::new()
        .name("pgser-pool-loader".into())
        .spawn(move || {
            let mut entries = entries(&layout, &cfg, head);
            for i in from.. {
                let into = spare.try_recv().unwrap_or_default();
                let block = layout.read_columns(entries.get(i), &[true; 4], into);
                let failed = block.is_err();
                if tx.send(block).is_err() || failed {
                    return;
                }
            }
        })
        .expect("a thread starts");
    (rx, back)
}
