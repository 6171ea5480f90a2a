//! One lock per step, `OUT/.pipeline/locks/<step>.lock`, so that two runs of one pipeline — two
//! submissions to Slurm, a submission while its jobs still run, a local run beside either — never
//! run the same step at once nor interleave its outputs. The runner takes a step's lock, then
//! decides whether the step is up to date: the second of two runs waits for the first to finish
//! the step and then finds it up to date, so every step runs once.
//!
//! `flock(2)` rather than a lock *file* created with `O_EXCL`: the kernel (or the NFS server)
//! drops the lock when its holder dies, even by SIGKILL at the end of a Slurm time limit, so no
//! stale lock ever needs a human to delete it. Linux's NFS client implements `flock` with byte-
//! range locks the server sees, so it holds across the nodes of a cluster; Lustre does only when
//! mounted with `-o flock` (docs/pipelines.md says so). The file also says who holds it, for
//! the message of the run that waits.

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};

/// A held step lock; dropped, it is released (closing the file releases the `flock`).
pub struct StepLock {
    _file: File,
}

/// The lock file of step `name` of the pipeline whose outputs are under `out`.
pub fn path(out: &Path, name: &str) -> PathBuf {
    out.join(".pipeline/locks").join(format!("{}.lock", name.replace(' ', "_")))
}

fn flock(file: &File, op: libc::c_int) -> std::io::Result<()> {
    loop {
        // SAFETY: flock only reads the descriptor, which `file` keeps open for the call.
        if unsafe { libc::flock(file.as_raw_fd(), op) } == 0 {
            return Ok(());
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
}

impl StepLock {
    /// Takes the lock of step `name`, waiting while another process holds it; `waiting` is
    /// called once, with the holder's description, when it has to wait.
    pub fn acquire(out: &Path, name: &str, waiting: &dyn Fn(&str)) -> Result<StepLock> {
        let at = path(out, name);
        let dir = at.parent().expect("in the locks folder");
        std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&at)
            .with_context(|| format!("{}: cannot open the lock of step {name}", at.display()))?;
        if let Err(e) = flock(&file, libc::LOCK_EX | libc::LOCK_NB) {
            if e.raw_os_error() != Some(libc::EWOULDBLOCK) {
                return Err(e).with_context(|| format!("{}: cannot lock step {name}", at.display()));
            }
            let mut holder = String::new();
            let _ = file.read_to_string(&mut holder);
            waiting(holder.trim());
            flock(&file, libc::LOCK_EX).with_context(|| format!("{}: cannot lock step {name}", at.display()))?;
        }
        // Say who holds it (for the message above); a failure here does not weaken the lock.
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
        let job = std::env::var("SLURM_JOB_ID").map(|j| format!(", Slurm job {j}")).unwrap_or_default();
        let _ = file.set_len(0).and_then(|()| file.rewind());
        let _ = write!(file, "process {} on {}{job}", std::process::id(), host.trim());
        Ok(StepLock { _file: file })
    }
}

/// Who holds the lock of step `name` now (None: nobody), without waiting: what `pipeline status`
/// says of a step running anywhere, locally or in a job.
pub fn holder(out: &Path, name: &str) -> Option<String> {
    let mut file = File::open(path(out, name)).ok()?;
    match flock(&file, libc::LOCK_SH | libc::LOCK_NB) {
        Ok(()) => None, // released when `file` closes
        Err(e) if e.raw_os_error() == Some(libc::EWOULDBLOCK) => {
            let mut who = String::new();
            let _ = file.read_to_string(&mut who);
            Some(who.trim().to_string())
        }
        Err(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_second_holder_waits_for_the_first() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        let first = StepLock::acquire(out, "agent a", &|_| panic!("nobody holds it yet")).unwrap();
        let released = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let flag = released.clone();
        let out2 = out.to_path_buf();
        let waiter = std::thread::spawn(move || {
            let waited = std::sync::atomic::AtomicBool::new(false);
            let _l = StepLock::acquire(&out2, "agent a", &|who| {
                assert!(who.contains(&std::process::id().to_string()), "{who}");
                waited.store(true, std::sync::atomic::Ordering::SeqCst);
            })
            .unwrap();
            assert!(flag.load(std::sync::atomic::Ordering::SeqCst), "got the lock while it was held");
            waited.load(std::sync::atomic::Ordering::SeqCst)
        });
        std::thread::sleep(std::time::Duration::from_millis(200));
        assert!(holder(out, "agent a").is_some_and(|h| h.contains("process")), "the holder is not seen");
        assert_eq!(holder(out, "agent c"), None);
        // Another step's lock is independent.
        drop(StepLock::acquire(out, "agent b", &|_| panic!("another step's lock")).unwrap());
        released.store(true, std::sync::atomic::Ordering::SeqCst);
        drop(first);
        assert!(waiter.join().unwrap(), "the second holder did not wait");
    }
}
