//! Every bad input gets one clear line, a non-zero exit, no output file, and runs no code.

mod common;

use std::path::Path;

use common::*;

#[test]
fn every_bad_input_fails_cleanly_and_executes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    py_ok("make_bad_pickles.py", &[dir.path().to_str().unwrap()]);
    let entries = manifest(dir.path());
    assert!(entries.len() >= 20, "bad corpus too small: {}", entries.len());
    let mut failures = Vec::new();
    for (i, e) in entries.iter().enumerate() {
        let file = e["file"].as_str().unwrap();
        let pkl = dir.path().join(file);
        let out_dir = dir.path().join(format!("out{i}"));
        std::fs::create_dir(&out_dir).unwrap();
        let out = out_dir.join("traj.parquet");
        let mut args = vec!["--task".to_string(), e["task"].as_str().unwrap().to_string()];
        args.extend(strings(&e["extra_args"]));
        let o = convert(&[&pkl], &out, &args);
        let err = text(&o.stderr);
        let line = err.trim_end();
        let expect = e["expect"].as_str().unwrap();
        let problems: Vec<&str> = [
            (o.status.code() != Some(1), "exit code is not 1"),
            (line.lines().count() != 1, "not exactly one line"),
            (!line.starts_with("pgser-etl: error: "), "no error prefix"),
            (!line.contains(file), "does not name the file"),
            (!line.to_lowercase().contains(expect), "lacks the expected words"),
            (line.contains("panicked"), "panicked"),
            (std::fs::read_dir(&out_dir).unwrap().count() != 0, "left a file behind"),
            (e.get("marker").is_some_and(|m| dir.path().join(m.as_str().unwrap()).exists()), "EXECUTED CODE"),
        ]
        .into_iter()
        .filter_map(|(bad, what)| bad.then_some(what))
        .collect();
        if !problems.is_empty() {
            failures.push(format!("{file} (expect {expect:?}): {problems:?}: {line}"));
        }
    }
    assert!(failures.is_empty(), "{} bad inputs mishandled:\n{}", failures.len(), failures.join("\n"));
}

/// A failed run never touches an existing output: the old file stays byte for byte.
#[test]
fn failed_run_keeps_previous_output() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("t.parquet");
    let good = repo().join("tests/fixtures/np2_p3.pkl");
    convert_ok(&[&good], &out, &["--task".into(), "FetchReach".into()]);
    let before = std::fs::read(&out).unwrap();
    let bad = tmp.path().join("bad.pkl");
    std::fs::write(&bad, &std::fs::read(&good).unwrap()[..3000]).unwrap();
    let o = convert(&[&bad], &out, &["--task".into(), "FetchReach".into()]);
    assert!(!o.status.success());
    assert!(text(&o.stderr).contains("truncated"));
    assert_eq!(std::fs::read(&out).unwrap(), before);
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 2, "temporary file left behind");
}

#[test]
fn output_may_not_overwrite_an_input() {
    let tmp = tempfile::tempdir().unwrap();
    let pkl = tmp.path().join("in.pkl");
    std::fs::copy(repo().join("tests/fixtures/np2_p3.pkl"), &pkl).unwrap();
    let o = convert(&[&pkl], &pkl, &[]);
    assert!(!o.status.success());
    assert!(text(&o.stderr).contains("overwrite input"));
    assert_eq!(std::fs::read(&pkl).unwrap(), std::fs::read(repo().join("tests/fixtures/np2_p3.pkl")).unwrap());
}

#[test]
fn missing_input_and_output_folder_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let o = convert(&[&tmp.path().join("nope.pkl")], &tmp.path().join("o.parquet"), &[]);
    assert!(text(&o.stderr).contains("nope.pkl: cannot open"), "{}", text(&o.stderr));
    let good = repo().join("tests/fixtures/np2_p3.pkl");
    let o = convert(&[&good], &tmp.path().join("no/such/dir/o.parquet"), &[]);
    assert!(text(&o.stderr).contains("does not exist"), "{}", text(&o.stderr));
    let o = convert(&[&good, &good], &tmp.path().join("o.parquet"), &["--episodes".into(), "1".into()]);
    assert!(text(&o.stderr).contains("one count per input"), "{}", text(&o.stderr));
}

#[test]
fn a_closed_stdout_ends_the_command_quietly() {
    // `pgser-etl inspect t | head -1`: the reader goes away; no panic, no backtrace.
    let dir = tempfile::tempdir().unwrap();
    let table = dir.path().join("t.parquet");
    let data = repo().join("data");
    convert_ok(&[&data.join("fetch_reach_expert_50.pkl")], &table, &[]);
    let mut child = etl()
        .args(["inspect", "--per-dim"])
        .arg(&table)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = text(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
}

/// A full disk or a file-size limit mid-write: under `ulimit -f` (RLIMIT_FSIZE) every writer
/// gets EFBIG instead of being killed by SIGXFSZ, says so in one line naming the file, leaves no
/// temporary file, and keeps the previous complete output; with the limit lifted the same
/// command writes the bytes an unlimited run writes.
#[test]
fn a_file_size_limit_mid_write_fails_in_one_line_and_keeps_the_old_output() {
    let dir = tempfile::tempdir().unwrap();
    let s = |x: &Path| x.display().to_string();
    // Inputs for the writers that read pgser's own files: a table and a small critic.
    let inputs = dir.path().join("inputs");
    std::fs::create_dir(&inputs).unwrap();
    let pkl = repo().join("data/fetch_reach_random_200.pkl");
    let traj = inputs.join("traj.parquet");
    convert_ok(&[&pkl], &traj, &["--task".into(), "FetchReach".into()]);
    let q = inputs.join("q.ckpt");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", &s(&traj), "-o", &s(&q), "--updates", "20", "--hidden", "32", "--batch-size", "32"])
        .args(["--eval-episodes", "0"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));

    // Training's saves (checkpoint, resume state, metrics) under the limit: one line naming the
    // file, nothing left beside them.
    let train_dir = dir.path().join("train");
    std::fs::create_dir(&train_dir).unwrap();
    let o = std::process::Command::new("bash")
        .arg("-c")
        .arg("ulimit -f 64; exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", &s(&traj), "-o", &s(&train_dir.join("run.ckpt")), "--updates", "20", "--eval-episodes", "0"])
        .output()
        .unwrap();
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "pgser-train: {:?}: {err}", o.status);
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    assert!(err.contains("run.ckpt") && err.contains("File too large"), "{err}");
    assert_eq!(std::fs::read_dir(&train_dir).unwrap().count(), 0, "pgser-train left files: {err}");

    let collect = ["collect", "--task", "FetchReach", "--policy", "random", "--episodes", "200", "--seed", "0"];
    // (output, arguments); `export` never overwrites, so its "previous output" is no file at all.
    let cases: Vec<(&str, Vec<String>)> = vec![
        ("traj.parquet", vec!["convert".into(), s(&pkl), "--task".into(), "FetchReach".into()]),
        ("random.pkl", collect.map(String::from).to_vec()),
        ("random.parquet", collect.map(String::from).to_vec()),
        ("scored.parquet", ["score", "--q", &s(&q), "--data", &s(&traj), "--swaps", "2"].map(String::from).to_vec()),
        ("export.pkl", ["export", &s(&traj), "--format", "wgcsl"].map(String::from).to_vec()),
    ];
    let exe = env!("CARGO_BIN_EXE_pgser-etl");
    for (name, args) in cases {
        let out_dir = dir.path().join(name.replace('.', "_"));
        std::fs::create_dir(&out_dir).unwrap();
        let out = out_dir.join(name);
        let run = |limit_kib: Option<u64>| {
            // 1 KiB blocks as bash's ulimit counts them.
            let limit = limit_kib.map_or("unlimited".to_string(), |k| k.to_string());
            std::process::Command::new("bash")
                .arg("-c")
                .arg(format!("ulimit -f {limit}; exec \"$0\" \"$@\""))
                .arg(exe)
                .args(&args)
                .arg("-o")
                .arg(&out)
                .output()
                .unwrap()
        };
        // The previous complete output: a first run without a limit.
        let o = run(None);
        assert!(o.status.success(), "{name}: {}", text(&o.stderr));
        let old = std::fs::read(&out).unwrap();
        assert!(old.len() > 64 * 1024, "{name}: {} bytes is too small to cross the limit", old.len());
        let overwrites = args[0] != "export";
        if overwrites {
            std::fs::write(&out, b"previous complete output").unwrap();
        } else {
            std::fs::remove_file(&out).unwrap();
        }

        let o = run(Some(64));
        let err = text(&o.stderr);
        let line = err.trim_end();
        assert_eq!(o.status.code(), Some(1), "{name}: killed or wrong exit ({:?}): {line}", o.status);
        assert_eq!(line.lines().count(), 1, "{name}: {err}");
        assert!(line.starts_with("pgser-etl: error: ") && line.contains(name), "{name}: {line}");
        assert!(line.contains("File too large"), "{name}: {line}");
        let left: Vec<String> = std::fs::read_dir(&out_dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        if overwrites {
            assert_eq!(left, [name.to_string()], "{name}: temporary files left behind");
            assert_eq!(std::fs::read(&out).unwrap(), b"previous complete output", "{name}: the old output was touched");
            std::fs::remove_file(&out).unwrap();
        } else {
            assert!(left.is_empty(), "{name}: files left behind: {left:?}");
        }

        // Space back: the same bytes as the first, unlimited run.
        let o = run(None);
        assert!(o.status.success(), "{name}: {}", text(&o.stderr));
        assert!(std::fs::read(&out).unwrap() == old, "{name}: a rerun wrote other bytes");
    }
}

/// A FIFO or a symlink loop given where a file is read: every command refuses it at once in one
/// line naming it (a FIFO used to block the open forever), and writes nothing. An output inside
/// an input folder (a Minari dataset) is refused too: it would become part of the dataset.
#[test]
fn fifos_symlink_loops_and_outputs_inside_inputs_are_refused() {
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let fifo = d.join("fifo.parquet");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    std::os::unix::fs::symlink(d.join("loop_b"), d.join("loop_a")).unwrap();
    std::os::unix::fs::symlink(d.join("loop_a"), d.join("loop_b")).unwrap();
    let out = d.join("out");
    std::fs::create_dir(&out).unwrap();
    let o = |n: &str| out.join(n).to_str().unwrap().to_string();
    let train = env!("CARGO_BIN_EXE_pgser-train");
    let etl_bin = env!("CARGO_BIN_EXE_pgser-etl");
    for (bad, why) in [(fifo.clone(), "not a regular file"), (d.join("loop_a"), "symbolic links")] {
        let b = bad.to_str().unwrap().to_string();
        let runs: Vec<(&str, Vec<String>)> = vec![
            (etl_bin, vec!["convert".into(), b.clone(), "-o".into(), o("t.parquet")]),
            (train, vec!["--data".into(), b.clone(), "-o".into(), o("a.ckpt")]),
            (train, vec!["eval".into(), "--ckpt".into(), b.clone()]),
            (
                etl_bin,
                vec!["score".into(), "--q".into(), b.clone(), "--data".into(), b.clone(), "-o".into(), o("s.parquet")],
            ),
            (etl_bin, vec!["inspect".into(), b.clone()]),
            (etl_bin, vec!["export".into(), b.clone(), "--format".into(), "wgcsl".into(), "-o".into(), o("x.pkl")]),
            (etl_bin, vec!["pipeline".into(), "run".into(), b.clone()]),
        ];
        for (bin, args) in runs {
            let mut child = std::process::Command::new(bin)
                .args(&args)
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap();
            // A hang is the fault this guards against: give it 20 s, then fail the test.
            let started = std::time::Instant::now();
            while child.try_wait().unwrap().is_none() {
                if started.elapsed() > std::time::Duration::from_secs(20) {
                    child.kill().unwrap();
                    panic!("{args:?} hung on {why}");
                }
                std::thread::sleep(std::time::Duration::from_millis(20));
            }
            let r = child.wait_with_output().unwrap();
            let err = text(&r.stderr);
            assert!(!r.status.success(), "{args:?} succeeded");
            assert!(err.contains(&b) && err.contains(why), "{args:?}: {err}");
            assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
        }
    }
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "a refused command wrote something");
    // An output inside the Minari dataset folder being converted.
    let ds = d.join("ds");
    let src = repo().join("tests/fixtures/minari/fetchreach-arrow-v0");
    let copied = std::process::Command::new("cp").arg("-r").arg(&src).arg(&ds).status().unwrap();
    assert!(copied.success());
    let before = pgser::minari::sha256_folder(&ds).unwrap();
    let inside = ds.join("data/t.parquet");
    let r = etl().arg("convert").arg(&ds).arg("-o").arg(&inside).output().unwrap();
    let err = text(&r.stderr);
    assert!(!r.status.success() && err.contains("output inside input folder"), "{err}");
    assert_eq!(pgser::minari::sha256_folder(&ds).unwrap(), before, "the dataset changed");
}

/// The last two writers under a file-size limit: `export --format minari` (a dataset folder of
/// one Arrow file per episode, staged and renamed into place) and `report` (a PNG and two table
/// files). Each fails in one line naming the file, leaves nothing partial, and a rerun without
/// the limit writes what an undisturbed run writes.
#[test]
fn a_file_size_limit_in_report_and_minari_export_fails_cleanly() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, scored) = reach_tables(tmp.path());
    let limited = |limit_kib: u64, args: &[&str]| {
        std::process::Command::new("bash")
            .arg("-c")
            .arg(format!("ulimit -f {limit_kib}; exec \"$0\" \"$@\""))
            .arg(env!("CARGO_BIN_EXE_pgser-etl"))
            .args(args)
            .output()
            .unwrap()
    };
    let one_line = |o: &std::process::Output, names: &str| {
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{:?}: {err}", o.status);
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.contains(names) && err.contains("File too large"), "{err}");
    };
    // Minari export: an episode file is ~10 KiB, so 4 KiB stops it at episode 0.
    let parent = tmp.path().join("datasets");
    std::fs::create_dir(&parent).unwrap();
    let ds = parent.join("reach-mix-v0");
    let args = ["export", table.to_str().unwrap(), "--format", "minari", "-o", ds.to_str().unwrap()];
    one_line(&limited(4, &args), "reach-mix-v0");
    assert_eq!(std::fs::read_dir(&parent).unwrap().count(), 0, "export left a partial dataset");
    let o = etl().args(args).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let back = tmp.path().join("back.parquet");
    let o = etl().args(["convert", ds.to_str().unwrap(), "-o", back.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    // The dataset's episodes, and its rewards, terminations and truncations kept beside them.
    let (back, table) = (read_table(&back).0, read_table(&table).0);
    assert!(back.columns()[..6] == table.columns()[..6], "the rerun's dataset differs");
    let schema = back.schema();
    let extra: Vec<&str> = schema.fields()[6..].iter().map(|f| f.name().as_str()).collect();
    assert_eq!(extra, ["rewards", "terminations", "truncations"]);

    // report: its previous complete output stays as it was.
    let rep = tmp.path().join("report");
    let args = ["report", scored.to_str().unwrap(), "-o", rep.to_str().unwrap(), "--positive-episodes", "50"];
    // Small samples: the classifiers' time is not what is tested here.
    let args = [&args[..], &["--max-samples", "1000", "--svm-max-train", "200"]].concat();
    let o = etl().args(&args).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let before = snapshot(&rep);
    std::fs::remove_file(rep.join("fig5_q_hist.png")).unwrap();
    std::fs::write(rep.join("table1.md"), "previous complete output").unwrap();
    one_line(&limited(16, &args), "fig5_q_hist.png");
    assert_eq!(std::fs::read_to_string(rep.join("table1.md")).unwrap(), "previous complete output");
    let left: Vec<_> = std::fs::read_dir(&rep).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(left.len(), 2, "report left a partial or temporary file: {left:?}");
    let o = etl().args(&args).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(snapshot(&rep), before, "the rerun's report differs from an undisturbed run's");
}

/// The WGCSL fuzzer's inputs (`fuzz/wgcsl`, tests/fixtures/fuzz/wgcsl/): pickles that made
/// `convert` fail on a path that once left a thread behind. Each fails in one line naming the
/// file, with nothing written.
#[test]
fn pickles_the_fuzzer_found_fail_in_one_line() {
    let found = std::fs::read_dir(repo().join("tests/fixtures/fuzz/wgcsl")).unwrap();
    let mut n = 0;
    for entry in found {
        let pkl = entry.unwrap().path();
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("t.parquet");
        let o = convert(&[&pkl], &out, &[]);
        let line = text(&o.stderr);
        let line = line.trim_end();
        assert_eq!(o.status.code(), Some(1), "{}: {line}", pkl.display());
        assert_eq!(line.lines().count(), 1, "{line}");
        assert!(line.starts_with("pgser-etl: error: ") && line.contains(&*pkl.to_string_lossy()), "{line}");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "left a file behind");
        n += 1;
    }
    assert!(n > 0, "no inputs in tests/fixtures/fuzz/wgcsl");
}
