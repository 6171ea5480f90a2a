//! Reading blocks ahead of the drawing thread: the loader thread (`pool.rs` says how blocks are
//! scheduled, `buffers.rs` whose memory they fill).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;

use anyhow::{Result, anyhow};

use super::layout::{Arrays, Block, Layout};
use super::{PoolConfig, entries};

/// The loader thread: reads entries `from` on ([`Entries`]), each block checked and decoded on
/// this one thread, and sends them through a channel of one. It owns its thread: dropping it
/// closes both channels and joins the thread, so a closed pool leaves nothing reading.
///
/// The loader never uses rayon. The pool is drawn from inside the global pool's workers
/// (`pgser-train` draws each cell's batch in a `par_iter_mut`), and a draw that waits for a block
/// holds its worker: a loader that checked its chunks with `par_iter` could then wait for a
/// worker that waits for it, a hang with one thread or a stack whose cells all wait at once.
///
/// It fills the arrays of blocks that left, which the pool hands back whole (their scored rows
/// are dropped here, off the drawing thread): fresh arrays are mappings the kernel must zero page
/// by page as they are written (on humanoidmaze's shape, 24 MB a block, page faults were 18 % of
/// the loader's time). Only its first two reads take fresh arrays; from the third on, read `n`
/// (from 0) waits for the block that left when the pool took block `n − 2`, which has been
/// taken, since the channel of one let block `n − 1` in, and is handed back right after. So the
/// wait is a handover, never a stall, and the blocks in flight are the plan's `IN_FLIGHT`: one
/// sent, one being read, one handed back. The way back holds two, for a pool that takes block
/// `n − 1` too before read `n` starts (a loader behind the draws); a third never comes, as
/// block `n` is not yet sent.
pub(super) struct Loader {
    blocks: Option<Receiver<Result<Block>>>,
    back: Option<SyncSender<Block>>,
    thread: Option<JoinHandle<()>>,
}

impl Loader {
    pub(super) fn spawn(layout: Arc<Layout>, cfg: PoolConfig, head: usize, from: u64) -> Loader {
        let (tx, blocks) = sync_channel(1);
        let (back, returned) = sync_channel::<Block>(2);
        let thread = std::thread::Builder::new()
            .name("pgser-pool-loader".into())
            .spawn(move || {
                let mut entries = entries(&layout, &cfg, head);
                for (k, i) in (from..).enumerate() {
                    let into = if k < 2 {
                        Arrays::default()
                    } else {
                        match returned.recv() {
                            Ok(mut b) => b.take_arrays(),
                            // The pool was dropped.
                            Err(_) => return,
                        }
                    };
                    let id = entries.get(i);
                    let block = catch_unwind(AssertUnwindSafe(|| layout.read_columns(id, &[true; 4], into)))
                        .unwrap_or_else(|p| Err(anyhow!("{}: the reader panicked: {}", layout.at(id), panic_text(&p))));
                    let failed = block.is_err();
                    if tx.send(block).is_err() || failed {
                        return;
                    }
                }
            })
            .expect("a thread starts");
        Loader { blocks: Some(blocks), back: Some(back), thread: Some(thread) }
    }

    /// The next block, if it is ready now.
    pub(super) fn ready(&mut self) -> Option<Result<Block>> {
        self.blocks.as_ref()?.try_recv().ok()
    }

    /// The next block, waiting for it. A loader that stopped without sending one (it panicked
    /// outside a read, or was closed) is reported, its panic's message with it.
    pub(super) fn wait(&mut self) -> Result<Block> {
        if let Some(b) = self.blocks.as_ref().and_then(|rx| rx.recv().ok()) {
            return b;
        }
        let why = match self.thread.take().map(JoinHandle::join) {
            Some(Err(p)) => format!(": it panicked: {}", panic_text(&p)),
            _ => String::new(),
        };
        Err(anyhow!("the pool's loader stopped{why}"))
    }

    /// Hands a leaving block back, for its arrays to be filled again.
    pub(super) fn give_back(&mut self, b: Block) {
        // Full only if the loader failed or stopped: then nothing needs the arrays.
        if let Some(back) = &self.back {
            let _ = back.try_send(b);
        }
    }
}

impl Drop for Loader {
    /// Closes both channels, so the thread stops at its next send or wait (after the block it
    /// is reading, at most), and joins it.
    fn drop(&mut self) {
        self.blocks = None;
        self.back = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

fn panic_text(p: &(dyn std::any::Any + Send)) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "(no message)".into())
}
