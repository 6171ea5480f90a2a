//! Kill moments for the crash tests (`tests/crash.rs`). Half the kills land at a time drawn over
//! an uninterrupted run. The other half land, as SQLite's crash tests do, at an I/O call:
//! strace's fault injection SIGKILLs the process on entry to the N-th `write`, `fsync` or
//! `rename` of one of its threads, so the kill falls exactly between two writes of a file. That
//! is where a writer without the atomic rename leaves a partial file, and a kill at a random
//! time almost never lands there: the files are written in milliseconds of a run of seconds.
//! `make mutants` shows the difference: against a build that writes in place, only the kills
//! at I/O calls fail the tests.
//!
//! Without strace (or where it may not trace, e.g. a container without ptrace) every kill is
//! timed, and the test says so on stderr.

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use pgser::nprandom::NpRandom;

/// The system calls that change what is on disk.
const IO_CALLS: &str =
    "write,pwrite64,writev,pwritev,fsync,fdatasync,rename,renameat,renameat2,unlink,unlinkat,ftruncate";

/// Where the kills of a test may land: within the time of its uninterrupted reference run, or
/// at the file I/O of the run about to be killed.
pub struct Moments {
    /// How long the reference run took.
    pub whole: Duration,
}

/// One kill.
#[derive(Debug, Clone)]
pub enum Moment {
    /// SIGKILL this long after the start.
    After(Duration),
    /// SIGKILL on entry to the `n`-th call of this system call by one thread, `on` the file it
    /// reached in a run from the same state.
    AtCall { call: String, n: u64, on: String },
}

fn strace() -> Option<&'static str> {
    ["/usr/bin/strace", "/bin/strace"].into_iter().find(|p| std::path::Path::new(p).is_file())
}

/// `cmd`'s program, arguments, folder and environment, run by strace with `strace_args` first.
fn under_strace(strace: &str, cmd: &Command, strace_args: &[String]) -> Command {
    let mut c = Command::new(strace);
    // No --seccomp-bpf: with it, strace 6.1 does not inject at `when=N` (the run goes on).
    c.args(["-f", "-qq"]).args(strace_args).arg("--").arg(cmd.get_program()).args(cmd.get_args());
    if let Some(d) = cmd.get_current_dir() {
        c.current_dir(d);
    }
    for (k, v) in cmd.get_envs() {
        match v {
            Some(v) => c.env(k, v),
            None => c.env_remove(k),
        };
    }
    c.stdout(Stdio::null()).stderr(Stdio::null());
    c
}

fn copy_tree(from: &Path, to: &Path) {
    let ok = Command::new("cp").arg("-a").arg(from).arg(to).status().unwrap().success();
    assert!(ok, "cp -a {} {}", from.display(), to.display());
}

impl Moments {
    /// Runs `cmd` to its end: the reference run, which must succeed.
    pub fn measure(cmd: &mut Command, what: &str) -> Moments {
        let t0 = Instant::now();
        let o = cmd.stdout(Stdio::null()).stderr(Stdio::piped()).output().unwrap();
        assert!(o.status.success(), "{what}: the reference run failed: {}", String::from_utf8_lossy(&o.stderr));
        if strace().is_none() {
            eprintln!("{what}: no strace here: every kill is timed, none lands at an I/O call");
        }
        Moments { whole: t0.elapsed() }
    }

    fn timed(&self, rng: &mut NpRandom) -> Moment {
        Moment::After(Duration::from_secs_f64(rng.random() * self.whole.as_secs_f64()))
    }

    /// Kill `k`'s moment for `cmd`, which works in `state` (the folder it reads and writes).
    /// Odd kills, and every kill without strace, land at a time within the reference run's.
    /// Even kills land at a file I/O call (kills 0, 4, 8… at a write of an output; the first
    /// kills, which find the most left to do): `cmd` runs once from a copy of `state` under strace,
    /// which lists its writes, fsyncs, renames and unlinks of files in `state` by thread; one is
    /// drawn and `state` is put back, so the killed run, from the same state, makes the same
    /// calls and dies on entry to the one drawn.
    pub fn draw(&self, k: usize, rng: &mut NpRandom, state: &Path, cmd: &Command) -> Moment {
        let Some(s) = strace().filter(|_| k.is_multiple_of(2)) else { return self.timed(rng) };
        let saved = tempfile::Builder::new().prefix(".state").tempdir_in(state.parent().unwrap()).unwrap();
        if state.exists() {
            copy_tree(state, &saved.path().join("s"));
        }
        let log = tempfile::NamedTempFile::new().unwrap();
        let args =
            ["-y", "-o", &log.path().display().to_string(), "-e", &format!("trace={IO_CALLS}")].map(String::from);
        under_strace(s, cmd, &args).status().unwrap();
        if state.exists() {
            std::fs::remove_dir_all(state).unwrap();
        }
        if saved.path().join("s").exists() {
            std::fs::rename(saved.path().join("s"), state).unwrap();
        }
        // Each call's rank among its thread's calls of that system call: what `when=` counts.
        let trace = std::fs::read_to_string(log.path()).unwrap_or_default();
        let within = state.display().to_string();
        let mut seen: BTreeMap<(String, String), u64> = BTreeMap::new();
        let mut on_files = Vec::new();
        for line in trace.lines() {
            // "PID  call(args…) = result", the PID padded to a width.
            let Some((tid, rest)) = line.split_once(' ') else { continue };
            let Some((call, what)) = rest.trim_start().split_once('(') else { continue };
            let n = seen.entry((tid.to_string(), call.to_string())).or_default();
            *n += 1;
            if let Some(at) = what.find(&within) {
                let file = what[at + within.len()..].split(['>', '"']).next().unwrap_or_default();
                on_files.push((call.to_string(), *n, file.trim_start_matches('/').to_string()));
            }
        }
        // Every other one of these kills lands at a write of an output's data, where a file is
        // half-written; the rest at any of the calls (a step lock's note, an fsync, a rename:
        // between a file's commit and its companion's).
        if k.is_multiple_of(4) {
            on_files.retain(|(call, _, file)| call.contains("write") && !file.contains("/locks/"));
        }
        if on_files.is_empty() {
            // Nothing left to write: the run would end at once.
            return self.timed(rng);
        }
        let (call, n, on) = on_files.swap_remove((rng.random() * on_files.len() as f64) as usize);
        Moment::AtCall { call, n, on }
    }
}

impl Moment {
    /// Runs `cmd` and SIGKILLs it at this moment; false if it ended first (a run that continues
    /// another skips what is done, so a late moment may find it finished).
    pub fn kill(&self, cmd: &mut Command) -> bool {
        match self {
            Moment::After(at) => {
                let mut child = cmd.stdout(Stdio::null()).stderr(Stdio::null()).spawn().unwrap();
                std::thread::sleep(*at);
                if child.try_wait().unwrap().is_some() {
                    return false;
                }
                // SAFETY: a plain kill(2) of our own child.
                unsafe { libc::kill(child.id() as i32, libc::SIGKILL) };
                child.wait().unwrap();
                true
            }
            Moment::AtCall { call, n, .. } => {
                let args = ["-o".into(), "/dev/null".into(), "-e".into(), format!("trace={call}"), "-e".into()]
                    .into_iter()
                    .chain([format!("inject={call}:signal=KILL:when={n}")])
                    .collect::<Vec<String>>();
                let o = under_strace(strace().unwrap(), cmd, &args).stderr(Stdio::piped()).output().unwrap();
                let status = o.status;
                // strace ends as its tracee did: by SIGKILL (or 128 + 9).
                let killed = std::os::unix::process::ExitStatusExt::signal(&status) == Some(libc::SIGKILL)
                    || status.code() == Some(137);
                assert!(
                    killed,
                    "the run was not killed at {self} ({status}): the harness is not doing its job: {}",
                    String::from_utf8_lossy(&o.stderr)
                );
                true
            }
        }
    }
}

impl std::fmt::Display for Moment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Moment::After(at) => write!(f, "{:.2} s", at.as_secs_f64()),
            Moment::AtCall { call, n, on } => write!(f, "{call} #{n} ({on})"),
        }
    }
}
