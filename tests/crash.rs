//! Killed at any moment: a small pipeline (convert, Q pre-training, scoring, report, a stack of
//! baseline / swap / mem agents, results) is SIGKILLed at moments drawn from a seed, each run
//! continuing from what the one before left. Half the kills land at a time spread over a whole
//! run, half on entry to a `write`, `fsync` or `rename` (strace's fault injection,
//! `common/kill.rs`), where a file is half-written. After every kill:
//! - every file under `out/` that a reader opens is whole: tables read back, checkpoints load,
//!   records and metrics parse, PNGs end with their last chunk (temporary files of a killed
//!   writer are allowed until the next run);
//! - no step record claims a step whose outputs are not exactly the bytes it recorded.
//!
//! Then the pipeline runs to its end, and every output must equal an uninterrupted run's, byte
//! for byte, with no temporary file left. `make test` runs a few kills
//! (`PGSER_CRASH_KILLS`, default 6); the long run sets it to hundreds.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use common::kill::Moments;
use common::{etl, snapshot, text};
use pgser::nprandom::NpRandom;

/// The pipeline under test: the committed FetchReach sample, every step kind of a pickle-fed
/// run, checkpoints saved often so that kills land between and inside saves.
fn pipeline(dir: &Path) -> PathBuf {
    let rest = r#"[train]
batch_size = 64
eval_every = 100
eval_episodes = 2
save_every = 50
[pretrain]
updates = 300
[score]
swaps = 2
[report]
seed = 1
[agents]
variants = ["baseline", "swap", "mem"]
seeds = [0, 1]
updates = 300
"#;
    common::sample_pipeline(dir, "crash.toml", "crash", rest)
}

/// `pipeline run crash.toml` in `dir`.
fn run(dir: &Path) -> Command {
    let mut c = etl();
    c.current_dir(dir).args(["pipeline", "run", "crash.toml", "--threads", "2"]);
    c
}

fn run_to_end(dir: &Path) {
    let o = run(dir).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
}

fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() { files(&p, out) } else { out.push(p) }
    }
}

fn is_temporary(p: &Path) -> bool {
    let name = p.file_name().unwrap().to_string_lossy();
    name.starts_with('.') && name.ends_with(".tmp")
}

/// Files a run rewrites as it goes (a training's saves): they may hold an earlier complete
/// state than the uninterrupted run's last, so they are checked by loading them.
fn rewritten(name: &str) -> bool {
    [".ckpt", ".ckpt.resume", ".metrics.jsonl", ".next"].iter().any(|e| name.ends_with(e))
}

/// A training's metrics are put in place before its checkpoint (`train.rs`, `Run::save`): they
/// must be the uninterrupted run's first lines, at least up to the checkpoint's update.
fn metrics_fault(path: &Path, ckpt: &Path, want: Option<&Vec<u8>>, device: &burn::tensor::Device) -> Option<String> {
    let got = std::fs::read_to_string(path).unwrap();
    let want = String::from_utf8(want?.clone()).unwrap();
    if !want.starts_with(&got) || !(got.is_empty() || got.ends_with('\n')) {
        return Some("not the first lines of an uninterrupted run's metrics".into());
    }
    let (agent, _) = pgser::agent::checkpoint::load(ckpt, device.clone()).ok()?;
    let updates = |l: &str| serde_json::from_str::<serde_json::Value>(l).unwrap()["updates"].as_u64().unwrap();
    let needed = want.lines().filter(|l| updates(l) <= agent.updates).count();
    (got.lines().count() < needed).then(|| format!("{needed} lines due by update {}", agent.updates))
}

/// What is wrong with `out` after a kill, one line per fault. Every output written once must
/// be the bytes of the uninterrupted run's (`want`, by path under `out`); every file is checked
/// by reading it as its kind too.
fn faults(out: &Path, want: &BTreeMap<PathBuf, Vec<u8>>) -> Vec<String> {
    let mut all = Vec::new();
    files(out, &mut all);
    let mut bad = Vec::new();
    let device = pgser::agent::Backend::Cpu.device().unwrap();
    for p in all.iter().filter(|p| !is_temporary(p)) {
        let rel = p.strip_prefix(out).unwrap();
        let at = rel.display().to_string();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if !rel.starts_with(".pipeline") && !rewritten(&name) && want.get(rel) != Some(&std::fs::read(p).unwrap()) {
            bad.push(format!("{at}: not the bytes an uninterrupted run writes there"));
        }
        let fault = if let Some(ckpt) = name.strip_suffix(".metrics.jsonl") {
            metrics_fault(p, &p.with_file_name(ckpt), want.get(rel), &device)
        } else if name.ends_with(".parquet") {
            let o = etl().args(["inspect", "--json"]).arg(p).output().unwrap();
            (!o.status.success()).then(|| text(&o.stderr))
        } else if name.ends_with(".ckpt") {
            pgser::agent::checkpoint::load(p, device.clone()).err().map(|e| format!("{e:#}"))
        } else if name.ends_with(".resume") || name.ends_with(".next") {
            // A resume state, or a save's companion waiting beside its place: whole on its own.
            pgser::verify::verify(p).err().map(|e| format!("{e:#}"))
        } else if name.ends_with(".json") {
            serde_json::from_slice::<serde_json::Value>(&std::fs::read(p).unwrap()).err().map(|e| e.to_string())
        } else if name.ends_with(".jsonl") {
            let t = String::from_utf8_lossy(&std::fs::read(p).unwrap()).into_owned();
            t.lines().find(|l| serde_json::from_str::<serde_json::Value>(l).is_err()).map(|l| format!("bad line {l:?}"))
        } else if name.ends_with(".png") {
            let b = std::fs::read(p).unwrap();
            (!(b.starts_with(b"\x89PNG") && b.len() > 12 && &b[b.len() - 8..b.len() - 4] == b"IEND"))
                .then(|| "not a whole PNG".to_string())
        } else {
            None
        };
        if let Some(f) = fault {
            bad.push(format!("{at}: {}", f.trim()));
        }
    }
    // A record may only name outputs that are exactly the bytes it recorded.
    for p in all.iter().filter(|p| p.parent().unwrap().ends_with(".pipeline") && !is_temporary(p)) {
        let Ok(r) = serde_json::from_slice::<serde_json::Value>(&std::fs::read(p).unwrap()) else { continue };
        for (file, sha) in r["outputs"].as_object().into_iter().flatten() {
            let got = std::fs::read(out.parent().unwrap().join(file)).ok().map(|b| sha256_hex(&b));
            if got.as_deref() != sha.as_str() {
                bad.push(format!("record {} claims {file}, which is not the recorded bytes", p.display()));
            }
        }
    }
    bad
}

fn sha256_hex(b: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(b).iter().map(|x| format!("{x:02x}")).collect()
}

#[test]
fn killed_at_any_moment_nothing_is_partial_and_the_rerun_is_byte_identical() {
    let kills: usize = std::env::var("PGSER_CRASH_KILLS").ok().and_then(|v| v.parse().ok()).unwrap_or(6);
    let seed: u64 = std::env::var("PGSER_CRASH_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(0);

    // The reference: one uninterrupted run, how long it takes and what I/O it makes.
    let reference = tempfile::tempdir().unwrap();
    pipeline(reference.path());
    let moments = Moments::measure(&mut run(reference.path()), "pipeline");
    let want = snapshot(&reference.path().join("out"));

    let dir = tempfile::tempdir().unwrap();
    pipeline(dir.path());
    let out = dir.path().join("out");
    let mut rng = NpRandom::new(seed);
    let (mut report, mut rounds, mut k, mut checked) = (Vec::new(), 0, 0, 0);
    while k < kills {
        let at = moments.draw(k, &mut rng, &out, &run(dir.path()));
        if !at.kill(&mut run(dir.path())) {
            // The run reached its end before the moment: this round of kills is over, and the
            // next starts from nothing, so that every kill lands in a live run.
            same_as_uninterrupted(&out, &want, &report);
            std::fs::remove_dir_all(&out).unwrap();
            (rounds, report) = (rounds + 1, Vec::new());
            continue;
        }
        if out.exists() {
            let f = faults(&out, &want);
            assert!(f.is_empty(), "kill {k} at {at}:\n{}", f.join("\n"));
            let mut all = Vec::new();
            files(&out, &mut all);
            checked += all.iter().filter(|p| !is_temporary(p)).count();
        }
        report.push(at.to_string());
        k += 1;
        if k % 25 == 0 {
            eprintln!("{k} kills in {} round(s), {checked} files checked: nothing partial", rounds + 1);
        }
    }
    run_to_end(dir.path());
    same_as_uninterrupted(&out, &want, &report);
    eprintln!(
        "{kills} kills of a {:?} run in {} round(s), {checked} files checked after them (the last round's kills at \
         {report:?}): nothing partial, every round's rerun byte-identical",
        moments.whole,
        rounds + 1
    );
}

/// After a round of kills the pipeline ran to its end: every output is the uninterrupted run's,
/// and nothing else is left (no temporary file).
fn same_as_uninterrupted(out: &Path, want: &BTreeMap<PathBuf, Vec<u8>>, kills: &[String]) {
    let got = snapshot(out);
    let extra: Vec<_> = got.keys().filter(|p| !want.contains_key(*p)).collect();
    assert!(extra.is_empty(), "left behind after kills at {kills:?}: {extra:?}");
    for (p, bytes) in want {
        assert!(
            got.get(p) == Some(bytes),
            "{}: differs from an uninterrupted run after kills at {kills:?}",
            p.display()
        );
    }
}

/// The harness would see a partial file: a table cut short, or an empty results file, is caught
/// by the check above.
#[test]
fn the_checks_catch_a_cut_table_and_a_false_record() {
    let dir = tempfile::tempdir().unwrap();
    pipeline(dir.path());
    run_to_end(dir.path());
    let out = dir.path().join("out");
    let want = snapshot(&out);
    assert!(faults(&out, &want).is_empty());
    let traj = out.join("traj.parquet");
    let bytes = std::fs::read(&traj).unwrap();
    std::fs::write(&traj, &bytes[..bytes.len() / 2]).unwrap();
    let f = faults(&out, &want);
    assert!(f.iter().any(|l| l.starts_with("traj.parquet:")), "{f:?}");
    assert!(f.iter().any(|l| l.contains("claims") && l.contains("traj.parquet")), "{f:?}");
    // What a writer without the rename leaves when killed at its one write: an empty file.
    std::fs::write(out.join("results.md"), "").unwrap();
    let f = faults(&out, &want);
    assert!(f.iter().any(|l| l.starts_with("results.md: not the bytes")), "{f:?}");
}

/// `score` and `collect` on their own, SIGKILLed at moments drawn from a seed over an
/// uninterrupted run's time (`PGSER_CRASH_KILLS` of them each): after every kill the output is
/// absent or whole, and the next run writes the reference bytes and sweeps the temporary files
/// the killed runs left (a killed writer runs no destructor; `output::sweep_stale`).
#[test]
fn killed_score_and_collect_leave_nothing_a_rerun_keeps() {
    let kills: usize = std::env::var("PGSER_CRASH_KILLS").ok().and_then(|v| v.parse().ok()).unwrap_or(6);
    let seed: u64 = std::env::var("PGSER_CRASH_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
    let inputs = tempfile::tempdir().unwrap();
    let (table, _) = common::reach_tables(inputs.path());
    let ckpt = inputs.path().join("reach.ckpt");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let commands: [(&str, Vec<String>); 2] = [
        (
            "scored.parquet",
            ["score", "--q", &s(&ckpt), "--data", &s(&table), "--swaps", "24"].map(String::from).to_vec(),
        ),
        (
            "push.parquet",
            ["collect", "--task", "FetchPush", "--policy", "expert", "--episodes", "150", "--seed", "3"]
                .map(String::from)
                .to_vec(),
        ),
    ];
    let mut rng = NpRandom::new(seed);
    for (name, args) in commands {
        let run = |dir: &Path| {
            let mut c = etl();
            c.current_dir(dir).args(&args).args(["-o", name]).env("RAYON_NUM_THREADS", "2");
            c.stdout(Stdio::null()).stderr(Stdio::null());
            c
        };
        let reference = tempfile::tempdir().unwrap();
        let moments = Moments::measure(&mut run(reference.path()), name);
        let want = std::fs::read(reference.path().join(name)).unwrap();

        let dir = tempfile::tempdir().unwrap();
        let mut left = 0;
        for k in 0..kills {
            let at = moments.draw(k, &mut rng, dir.path(), &run(dir.path()));
            at.kill(&mut run(dir.path()));
            let mut all = Vec::new();
            files(dir.path(), &mut all);
            left += all.iter().filter(|p| is_temporary(p)).count();
            let out = dir.path().join(name);
            assert!(
                !out.exists() || std::fs::read(&out).unwrap() == want,
                "{name}: kill {k} at {at} left a partial output"
            );
            std::fs::remove_file(&out).ok();
        }
        assert!(run(dir.path()).status().unwrap().success(), "{name}: the rerun failed");
        let mut all = Vec::new();
        files(dir.path(), &mut all);
        assert_eq!(all, [dir.path().join(name)], "{name}: left behind after {kills} kills");
        assert!(std::fs::read(dir.path().join(name)).unwrap() == want, "{name}: the rerun's bytes differ");
        eprintln!(
            "{name}: {kills} kills over a {:?} run, {left} temporary files left by them, all swept",
            moments.whole
        );
    }
}

/// Everything a training run's files hold, as numbers: the checkpoint's networks and
/// normalizer, the resume state's targets, Adam moments and steps and noise stream, and the
/// metrics lines with their timings dropped. The files themselves also record the command line,
/// which differs once `--resume` is added.
fn training_state(ckpt: &Path) -> (Vec<Vec<f32>>, String) {
    let device = pgser::agent::Backend::Cpu.device().unwrap();
    let (mut agent, _) = pgser::agent::checkpoint::load(ckpt, device).unwrap();
    pgser::agent::checkpoint::load_resume(&mut agent, &pgser::agent::checkpoint::resume_path(ckpt)).unwrap();
    let mut nets = Vec::new();
    for net in [&agent.actor, &agent.critics, &agent.actor_target, &agent.critics_target] {
        nets.extend(net.tensors().into_iter().map(|(_, v)| v));
    }
    let (m, v) = agent.critics_opt.member(0);
    nets.extend(m.into_iter().chain(v).flat_map(|(w, b)| [w, b]));
    let mut metrics = String::new();
    let path = format!("{}.metrics.jsonl", ckpt.display());
    for line in std::fs::read_to_string(path).unwrap_or_default().lines() {
        let mut v: serde_json::Value = serde_json::from_str(line).unwrap();
        if let Some(o) = v.as_object_mut() {
            o.retain(|k, _| !k.contains("sec") && !k.contains("per_s"));
        }
        metrics.push_str(&v.to_string());
    }
    let about = format!(
        "updates {} steps {}/{} noise {:?} norm {:?}\n{metrics}",
        agent.updates,
        agent.actor_opt.step,
        agent.critics_opt.step,
        agent.noise_rngs[0].words(),
        agent.norms[0]
    );
    (nets, about)
}

/// `pgser-train --resume` and `pgser-train online --resume` on their own, SIGKILLed at moments
/// drawn from a seed over an uninterrupted run's time: after every kill, a checkpoint in place
/// loads with its resume state (or there is none yet); each run continues from what the killed
/// one saved, and the last one ends with an uninterrupted run's networks, targets, Adam state,
/// streams and metrics, with no temporary file left.
#[test]
fn killed_training_resumes_to_the_uninterrupted_state() {
    let kills: usize = std::env::var("PGSER_CRASH_KILLS").ok().and_then(|v| v.parse().ok()).unwrap_or(6);
    let seed: u64 = std::env::var("PGSER_CRASH_SEED").ok().and_then(|v| v.parse().ok()).unwrap_or(0);
    let inputs = tempfile::tempdir().unwrap();
    let (table, _) = common::reach_tables(inputs.path());
    let table = table.to_str().unwrap().to_string();
    let offline: Vec<String> = ["--data", &table, "--updates", "400", "--save-every", "50", "--batch-size", "64"]
        .into_iter()
        .chain(["--eval-every", "100", "--eval-episodes", "2", "--hidden", "64", "--seed", "3"])
        .map(String::from)
        .collect();
    let online: Vec<String> = ["online", "--task", "FetchReach", "--epochs", "8", "--cycles", "2"]
        .into_iter()
        .chain(["--episodes-per-cycle", "2", "--updates-per-cycle", "10", "--batch-size", "64", "--hidden", "64"])
        .chain(["--eval-episodes", "2", "--seed", "3"])
        .map(String::from)
        .collect();
    let mut rng = NpRandom::new(seed);
    for (what, args) in [("train", offline), ("online", online)] {
        let run = |dir: &Path, resume: bool| {
            let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"));
            c.current_dir(dir).args(&args).args(["-o", "a.ckpt", "--threads", "2"]);
            if resume {
                c.arg("--resume");
            }
            c.stdout(Stdio::null()).stderr(Stdio::null());
            c
        };
        let reference = tempfile::tempdir().unwrap();
        let moments = Moments::measure(&mut run(reference.path(), false), what);
        let want = training_state(&reference.path().join("a.ckpt"));

        let dir = tempfile::tempdir().unwrap();
        let ckpt = dir.path().join("a.ckpt");
        // Where a round of kills ends (the run reached its last update): the uninterrupted
        // run's state, and no temporary file.
        let same = |round: usize| {
            let got = training_state(&ckpt);
            assert!(got.0 == want.0, "{what}: the weights after round {round} differ from an uninterrupted run's");
            assert_eq!(got.1, want.1, "{what}: counters, streams or metrics differ after round {round}");
            let mut all = Vec::new();
            files(dir.path(), &mut all);
            assert!(all.iter().all(|p| !is_temporary(p)), "{what}: temporary files left: {all:?}");
        };
        let (mut k, mut rounds) = (0, 0);
        while k < kills {
            let at = moments.draw(k, &mut rng, dir.path(), &run(dir.path(), ckpt.exists()));
            if !at.kill(&mut run(dir.path(), ckpt.exists())) {
                same(rounds);
                for e in std::fs::read_dir(dir.path()).unwrap() {
                    std::fs::remove_file(e.unwrap().path()).unwrap();
                }
                rounds += 1;
                continue;
            }
            if ckpt.exists() {
                // Loads, with a resume state of the same update (training_state checks both).
                let loaded = std::panic::catch_unwind(|| training_state(&ckpt));
                assert!(loaded.is_ok(), "{what}: kill {k} at {at} left a checkpoint that does not load");
            }
            k += 1;
        }
        assert!(run(dir.path(), ckpt.exists()).status().unwrap().success(), "{what}: the last run failed");
        same(rounds);
        eprintln!(
            "{what}: {kills} kills of a {:?} run in {} round(s), each resumed to the uninterrupted state",
            moments.whole,
            rounds + 1
        );
    }
}
