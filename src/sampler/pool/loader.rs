//! Reading blocks ahead of the drawing thread: the loader thread, and keeping the memory of
//! blocks that leave returnable to the system (`pool.rs` says how blocks are scheduled).

use std::sync::Arc;
use std::sync::mpsc::{Receiver, sync_channel};

use anyhow::Result;

use super::layout::{Block, Layout};
use super::{PoolConfig, entries};

/// glibc's mmap threshold while a pool lives: buffers of this many bytes or more are mappings of
/// their own, returned to the system when freed.
pub(super) const MMAP_THRESHOLD: usize = 1 << 20;

/// Makes glibc give large buffers (a block's arrays, a row group's decoded pages) back to the
/// system when they are freed. By default glibc raises its mmap threshold each time such a
/// buffer is freed, up to 32 MB, after which buffers of a block's size come from the heaps of the
/// threads that allocated them and stay there when freed: measured on 10M humanoidmaze-shaped
/// rows, the process then held 0.9 GB beyond a 1 GB budget, more on a larger table. A fixed
/// threshold keeps every buffer over 1 MiB a mapping of its own, returned on free. A block's
/// arrays are always at least that large (`Layout::read_columns` reserves it), however narrow the rows:
/// PointMaze's 500 kB arrays (62,500 rows of 2 floats) otherwise stayed in the threads' heaps,
/// where they fragmented, and peak RSS rose while drawing, from 1,162 MiB after 2,000 batches to
/// 1,326 MiB after 8,000 and 1,706 MiB after 20,000 (100M rows, 1 GB budget). A lower threshold
/// (128 KiB) fixed that too, but then every batch's wide vectors (1024 rows of 69 floats: 282 kB)
/// were fresh mappings, zeroed by the kernel: 805 → 679 batches/s on humanoidmaze's shape.
/// Process-wide and idempotent; elsewhere than glibc it does nothing.
pub(super) fn keep_large_buffers_returnable() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets an allocator parameter; it is safe to call at any time.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD as i32);
    }
}

/// The loader: entries `from` on ([`Entries`]), each block read and sent through a channel of
/// one. It stops when the pool is dropped (the send fails) or after a read error, which it sends.
pub(super) fn spawn_loader(layout: Arc<Layout>, cfg: PoolConfig, head: usize, from: u64) -> Receiver<Result<Block>> {
    let (tx, rx) = sync_channel(1);
    std::thread::Builder::new()
        .name("pgser-pool-loader".into())
        .spawn(move || {
            let mut entries = entries(&layout, &cfg, head);
            for i in from.. {
                let block = layout.read(entries.get(i));
                let failed = block.is_err();
                if tx.send(block).is_err() || failed {
                    return;
                }
            }
        })
        .expect("a thread starts");
    rx
}
