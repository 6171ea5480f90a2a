//! What the binaries share: the one-line error report and the recorded command line.

use std::process::ExitCode;
use std::sync::LazyLock;

/// `--version` text: our version and the MuJoCo library actually loaded at run time.
pub static LONG_VERSION: LazyLock<String> =
    LazyLock::new(|| format!("{} (MuJoCo {})", env!("CARGO_PKG_VERSION"), mujoco_rs::mujoco_version()));

/// Run a command's body; print any error as one line `PROGRAM: error: …` and exit 1.
pub fn main_with(program: &str, body: impl FnOnce() -> anyhow::Result<()>) -> ExitCode {
    // Rust ignores SIGPIPE, so `println!` into a closed pipe (`pgser-etl inspect f | head`)
    // panics with a backtrace; like other Unix tools we want to just stop.
    #[cfg(unix)]
    // SAFETY: called before any thread exists; SIG_DFL is a valid action for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    // A write past the file-size limit (`ulimit -f`, a quota'd batch system's RLIMIT_FSIZE)
    // raises SIGXFSZ, whose default action kills the process at once: no message, exit 153, and
    // the atomic output's temporary file left behind. Ignored, the write fails with EFBIG
    // instead, which the writer reports in one line naming the file, and the temporary file is
    // removed as on any other error.
    #[cfg(unix)]
    // SAFETY: as above; SIG_IGN is a valid action for SIGXFSZ.
    unsafe {
        libc::signal(libc::SIGXFSZ, libc::SIG_IGN);
    }
    // Training allocates and frees tensors of a few MB many times per update. glibc serves those
    // with mmap and gives them back on free, so every update paid for page faults and zeroing
    // of fresh pages (15 % of a stacked update's time in a profile). Kept on the heap, freed
    // blocks are reused instead. One arena for all threads: a thread's own arena lives in heaps
    // of at most 64 MB that glibc unmaps as soon as they are empty, whatever the trim threshold,
    // so a stack updated on a second thread (agent/shards.rs) faulted in its buffers afresh
    // every update (450k page faults in 30 updates of 10 agents; 51.8 -> 68-77 agent-updates/s
    // with one arena). The lock is taken once per tensor-sized block, not per element.
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets allocator parameters; called before any thread exists.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
    match body() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            let line = format!("{e:#}").replace('\n', " ");
            eprintln!("{program}: error: {line}");
            ExitCode::FAILURE
        }
    }
}

/// The command line as typed (shell-quoted where needed), for footers.
pub fn command_line() -> String {
    std::env::args()
        .map(|a| {
            if !a.is_empty() && a.chars().all(|c| c.is_ascii_alphanumeric() || "-_./=,:+@".contains(c)) {
                a
            } else {
                format!("'{}'", a.replace('\'', r"'\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}
