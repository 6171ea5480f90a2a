//! SIGTERM during training: save, then stop. Slurm ends a job at its time limit or on preemption
//! with SIGTERM, then SIGKILL after a grace period (`KillWait`, 30 s by default); a training step
//! killed outright loses every update since its last scheduled checkpoint, which may be hours.
//! With the handler installed (`install`: a process-wide handler, so only the binaries call it, in
//! their `main` for the commands that train), SIGTERM only sets a flag;
//! the training loop checks it once per update — one relaxed atomic load, nothing when no signal
//! comes — and at the next update boundary saves every cell's checkpoint, resume state and
//! metrics exactly as a scheduled save would, then fails with [`Interrupted`]. The requeued or
//! resubmitted job continues from there to the weights of a run that was never stopped.
//!
//! Outside training (converting, scoring, a report) there is nothing to save, and waiting for
//! the SIGKILL would only hold the node: the handler then ends the process at once, as the
//! default action would (exit status 128 + 15). Every output is written atomically, so an
//! interrupted step leaves no partial file.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Set by the handler while training runs.
static REQUESTED: AtomicBool = AtomicBool::new(false);
/// Training loops now running in this process (several with `pipeline run --jobs`).
static TRAINING: AtomicUsize = AtomicUsize::new(0);

extern "C" fn on_term(_: libc::c_int) {
    if TRAINING.load(Ordering::SeqCst) > 0 {
        REQUESTED.store(true, Ordering::SeqCst);
    } else {
        // SAFETY: _exit is async-signal-safe.
        unsafe { libc::_exit(128 + libc::SIGTERM) }
    }
}

/// Installs the SIGTERM handler (idempotent). Call before training starts.
pub fn install() -> anyhow::Result<()> {
    let handler = on_term as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: the handler only touches atomics and calls _exit, both async-signal-safe.
    if unsafe { libc::signal(libc::SIGTERM, handler) } == libc::SIG_ERR {
        anyhow::bail!("cannot install the SIGTERM handler: {}", std::io::Error::last_os_error());
    }
    Ok(())
}

/// Whether SIGTERM asked the training to stop.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::Relaxed)
}

/// Marks a training loop as running while it lives: a SIGTERM then waits for its save.
pub struct Training(());

impl Training {
    pub fn start() -> Training {
        TRAINING.fetch_add(1, Ordering::SeqCst);
        Training(())
    }
}

impl Drop for Training {
    fn drop(&mut self) {
        TRAINING.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A training stopped by SIGTERM after saving at `updates` (of `of`).
#[derive(Debug, thiserror::Error)]
#[error("stopped by SIGTERM at update {updates} of {of}; its checkpoint is saved there, run again to continue")]
pub struct Interrupted {
    pub updates: u64,
    pub of: u64,
}
