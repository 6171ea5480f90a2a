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
