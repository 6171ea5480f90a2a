//! `pgser-etl collect`: what it writes (a table, or a pickle Python loads and `convert` turns
//! into the same table), that the bytes do not depend on the thread count, that its episodes
//! are gymnasium's episodes, and how well the scripted experts do.

mod common;

use std::path::Path;

use common::*;

fn p(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// Same columns and values (footers differ: they name the command and the sources).
fn assert_same_data(a: &arrow_array::RecordBatch, b: &arrow_array::RecordBatch) {
    assert_eq!(a.schema().fields(), b.schema().fields());
    for (name, (x, y)) in a.schema().fields().iter().map(|f| f.name()).zip(a.columns().iter().zip(b.columns())) {
        assert!(x == y, "column {name} differs");
    }
}

/// The table, the pickle and the float32 table of the same run hold the same episodes, bit for
/// bit; Python's `pickle.load` reads the pickle as WGCSL arrays; `convert` turns it into the
/// very table collect wrote; and 1 or 2 threads write identical bytes.
#[test]
fn table_and_pickle_hold_the_same_episodes_for_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let (table, pkl, t32) = (dir.path().join("t.parquet"), dir.path().join("t.pkl"), dir.path().join("t32.parquet"));
    let run = ["--task", "FetchPickAndPlace", "--policy", "expert", "--noise", "0.2", "--epsilon", "0.05"];
    let run = [&run[..], &["--episodes", "60", "--seed", "11", "--row-group-rows", "500"]].concat();
    fn with<'a>(run: &[&'a str], out: &'a Path, extra: &[&'a str]) -> Vec<&'a str> {
        [run, &["-o", p(out)], extra].concat()
    }
    collect_ok(&with(&run, &table, &[]), Some(2));
    collect_ok(&with(&run, &pkl, &[]), Some(2));
    collect_ok(&with(&run, &t32, &["--float32"]), Some(2));

    // Same bytes with one thread (same output paths: the footer records the command line).
    let (table2, pkl2) = (std::fs::read(&table).unwrap(), std::fs::read(&pkl).unwrap());
    collect_ok(&with(&run, &table, &[]), Some(1));
    collect_ok(&with(&run, &pkl, &[]), Some(1));
    assert!(std::fs::read(&table).unwrap() == table2, "table bytes differ between 1 and 2 threads");
    assert!(std::fs::read(&pkl).unwrap() == pkl2, "pickle bytes differ between 1 and 2 threads");

    // numpy sees exactly the WGCSL layout.
    let script = format!(
        "import pickle, numpy as np\n\
         d = pickle.load(open({:?}, 'rb'))\n\
         assert list(d) == ['o', 'ag', 'u', 'g'], list(d)\n\
         want = dict(o=(60, 50, 25), ag=(60, 50, 3), u=(60, 49, 4), g=(60, 49, 3))\n\
         for k, a in d.items():\n\
         \x20   assert type(a) is np.ndarray and a.dtype == np.float64 and a.flags['C_CONTIGUOUS'], k\n\
         \x20   assert a.shape == want[k], (k, a.shape)\n\
         assert np.all(np.abs(d['u']) <= 1) and np.all(d['u'] == d['u'].astype(np.float32))\n\
         assert np.all(d['g'] == d['g'][:, :1])  # one goal per episode\n\
         print('ok')",
        p(&pkl)
    );
    let py = std::process::Command::new(python()).args(["-c", &script]).output().unwrap();
    assert!(py.status.success(), "{}", text(&py.stderr));

    // Both tables against the pickle, bit for bit (the float32 one against its down-cast).
    check_roundtrip(&table, &[&pkl], &["--task".into(), "FetchPickAndPlace".into()]);
    check_roundtrip(&t32, &[&pkl], &["--float32".into()]);

    // convert(pickle) is collect's table: same columns, same row groups.
    let converted = dir.path().join("c.parquet");
    convert_ok(
        &[&pkl],
        &converted,
        &["--task".into(), "FetchPickAndPlace".into(), "--row-group-rows".into(), "500".into()],
    );
    let ((a, ga), (b, gb)) = (read_table(&table), read_table(&converted));
    assert_eq!((ga, gb), (6, 6));
    assert_same_data(&a, &b);

    let footer = pgser::table::read_footer(&table).unwrap();
    assert_eq!(
        (footer["task"].as_str(), footer["policy"].as_str(), footer["seed"].as_u64()),
        (Some("FetchPickAndPlace"), Some("expert"), Some(11))
    );
    assert!(footer["command"].as_str().unwrap().contains("--noise 0.2"));
}

/// Chunks of simulated episodes do not show: 260 episodes with one per row group cross the
/// 256-episode chunk boundary and still give `convert`'s row groups.
#[test]
fn chunks_line_up_with_converts_row_groups() {
    let dir = tempfile::tempdir().unwrap();
    let (table, pkl, converted) =
        (dir.path().join("r.parquet"), dir.path().join("r.pkl"), dir.path().join("c.parquet"));
    let run =
        ["--task", "FetchReach", "--policy", "random", "--episodes", "260", "--seed", "3", "--row-group-rows", "50"];
    collect_ok(&[&run[..], &["-o", p(&table)]].concat(), None);
    collect_ok(&[&run[..], &["-o", p(&pkl)]].concat(), None);
    convert_ok(&[&pkl], &converted, &["--task".into(), "FetchReach".into(), "--row-group-rows".into(), "50".into()]);
    let ((a, ga), (b, gb)) = (read_table(&table), read_table(&converted));
    assert_eq!((ga, gb), (260, 260));
    assert_same_data(&a, &b);
    check_roundtrip(&table, &[&pkl], &[]);
}

/// Episode i of a collected table is what gymnasium-robotics does after `reset(seed=S+i)` with
/// the recorded actions, and random actions are numpy's spawned stream (replay_collect.py).
#[test]
fn episodes_replay_in_gymnasium() {
    let dir = tempfile::tempdir().unwrap();
    for (task, policy) in [("FetchPush", "expert"), ("FetchPickAndPlace", "expert"), ("FetchSlide", "random")] {
        let table = dir.path().join(format!("{task}.parquet"));
        let run = ["--task", task, "--policy", policy, "--episodes", "12", "--seed", "123"];
        let run = [&run[..], if policy == "expert" { &["--noise", "0.1"][..] } else { &[][..] }].concat();
        collect_ok(&[&run[..], &["-o", p(&table)]].concat(), None);
        let out = py_ok("replay_collect.py", &[p(&table), "--episodes", "0,5,11", "--tol", "1e-6"]);
        println!("{task}: {}", text(&out.stdout).trim());
    }
}

/// Final-step success over 100 episodes (seeds 0–99) through `collect` and `inspect`: each
/// expert above its target, the random policy far below. Deterministic (fixed seeds), so the
/// thresholds are exact checks of these 100 episodes, not estimates with a margin.
#[test]
fn experts_beat_their_targets_and_random_does_not() {
    let dir = tempfile::tempdir().unwrap();
    let mut report = Vec::new();
    for (task, target) in [("FetchReach", 0.95), ("FetchPush", 0.8), ("FetchPickAndPlace", 0.7), ("FetchSlide", 0.3)] {
        let mut rates = Vec::new();
        for policy in ["expert", "random"] {
            let table = dir.path().join(format!("{task}-{policy}.parquet"));
            let run = ["--task", task, "--policy", policy, "--episodes", "100", "--seed", "0", "-o", p(&table)];
            collect_ok(&run, None);
            let s = inspect_json(&table);
            assert_eq!(s["episodes"], 100);
            rates.push(s["success_rate"].as_f64().unwrap());
        }
        report.push(format!("{task:<18} expert {:.2} (target {target}), random {:.2}", rates[0], rates[1]));
        assert!(rates[0] >= target, "{task}: expert success {} < {target}", rates[0]);
        assert!(rates[1] < 0.2, "{task}: random success {} is suspiciously high", rates[1]);
    }
    println!("{}", report.join("\n"));
}

/// Every bad request: exit 1, one line naming the fault, no file left behind.
#[test]
fn bad_requests_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let base = ["--task", "FetchReach", "--policy", "expert", "--episodes", "2"];
    let cases: [(&[&str], &str, &str); 8] = [
        (&base, "out.csv", ".parquet"),
        (&[&base[..], &["--float32"]].concat(), "out.pkl", "float64"),
        (
            &["--task", "FetchReach", "--policy", "random", "--episodes", "2", "--noise", "0.1"],
            "o.pkl",
            "random policy",
        ),
        (&["--task", "FetchFoo", "--policy", "expert", "--episodes", "2"], "o.pkl", "fetchfoo"),
        (
            &["--task", "HandManipulateBlockRotZ", "--policy", "random", "--episodes", "2"],
            "o.pkl",
            "did you mean HandManipulateBlockRotateZ?",
        ),
        (&["--task", "FetchReach", "--policy", "expert", "--episodes", "0"], "o.pkl", "at least 1"),
        (&[&base[..], &["--epsilon", "2"]].concat(), "o.parquet", "epsilon"),
        (&[&base[..], &["--seed", "18446744073709551615"]].concat(), "o.parquet", "overflows"),
    ];
    for (args, out, expect) in cases {
        let o = collect(&[args, &["-o", p(&dir.path().join(out))]].concat(), None);
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(
            err.starts_with("pgser-etl: error: ") && err.to_lowercase().contains(&expect.to_lowercase()),
            "{args:?}: {err}"
        );
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "{args:?} left a file");
    }
    let missing = dir.path().join("no/such/dir/x.parquet");
    let o = collect(&[&base[..], &["-o", p(&missing)]].concat(), None);
    assert!(text(&o.stderr).contains("does not exist"), "{}", text(&o.stderr));
}

#[test]
fn help_shows_examples() {
    let o = etl().args(["collect", "--help"]).output().unwrap();
    assert!(o.status.success());
    let h = text(&o.stdout);
    assert!(h.contains("Examples:") && h.contains("reset(seed=S+i)"), "{h}");
}

/// `pgser-train` on `table` (a few tiny updates), for a checkpoint to collect with.
fn tiny_checkpoint(table: &Path, out: &Path) {
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", p(table), "-o", p(out), "--updates", "20", "--batch-size", "32", "--hidden", "16"])
        .args(["--eval-episodes", "0", "--log-every", "10", "--seed", "1"])
        .output()
        .unwrap();
    assert!(o.status.success(), "pgser-train failed: {}", text(&o.stderr));
}

/// `--policy checkpoint:FILE`: a trained actor (here a tiny one) collects in its own task, Fetch
/// or hand; its recorded actions are what `Agent::act` gives on the recorded observations; a
/// checkpoint of another task is refused in one line and leaves no file.
#[test]
fn a_trained_actor_collects_in_its_task_and_only_there() {
    let dir = tempfile::tempdir().unwrap();
    for (task, policy) in [("FetchReach", "expert"), ("HandManipulateEggRotate", "random")] {
        let data = dir.path().join(format!("{task}-data.parquet"));
        collect_ok(&["--task", task, "--policy", policy, "--episodes", "4", "--seed", "3", "-o", p(&data)], None);
        let ckpt = dir.path().join(format!("{task}.ckpt"));
        tiny_checkpoint(&data, &ckpt);
        let policy = format!("checkpoint:{}", p(&ckpt));
        let table = dir.path().join(format!("{task}-trained.parquet"));
        let run = ["--task", task, "--policy", &policy, "--episodes", "3", "--seed", "50"];
        collect_ok(&[&run[..], &["-o", p(&table)]].concat(), Some(2));
        let again = dir.path().join(format!("{task}-trained-1.parquet"));
        collect_ok(&[&run[..], &["-o", p(&again)]].concat(), Some(1));
        assert_same_data(&read_table(&table).0, &read_table(&again).0); // 2 threads vs 1
        let footer = &inspect_json(&table)["footer"];
        assert_eq!(footer["policy"], serde_json::json!(policy));
        let metric = if task.starts_with("Hand") { "quat_angle" } else { "euclidean" };
        assert_eq!(footer["goal_metric"], serde_json::json!(metric), "{task}: the footer's goal metric");
        // `pgser-train eval` runs the checkpoint in its task's environment.
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
            .args(["eval", "--ckpt", p(&ckpt), "--episodes", "2", "--json"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{task}: eval failed: {}", text(&o.stderr));
        let report: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        assert_eq!(report["episodes"], 2, "{task}: {report}");

        // The actions are the actor's (clipped and rounded as applied), up to float round-off.
        let (agent, _) = pgser::agent::checkpoint::load(&ckpt, burn::tensor::Device::flex()).unwrap();
        let (batch, _) = read_table(&table);
        let col = |name: &str| -> Vec<f32> {
            let a =
                batch.column_by_name(name).unwrap().as_any().downcast_ref::<arrow_array::FixedSizeListArray>().unwrap();
            let v = a.values().as_any().downcast_ref::<arrow_array::Float64Array>().unwrap();
            v.values().iter().map(|&x| x as f32).collect()
        };
        let (obs, goal, act) = (col("obs"), col("desired_goal"), col("action"));
        let t = agent.task.clone();
        let rows = t.t - 1; // episode 0's steps with an action
        let want = agent.act(&obs[..rows * t.obs_dim], &goal[..rows * t.goal_dim], rows);
        let worst = want.iter().zip(&act[..rows * t.act_dim]).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "{task}: recorded actions differ from Agent::act by {worst}");
    }
    // A checkpoint of FetchReach given to another task: one line, no file.
    let reach = format!("checkpoint:{}", p(&dir.path().join("FetchReach.ckpt")));
    let out = dir.path().join("wrong.parquet");
    let o = collect(&["--task", "FetchPush", "--policy", &reach, "--episodes", "2", "-o", p(&out)], None);
    let err = text(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.trim_end().lines().count() == 1 && err.contains("trained on FetchReach, not FetchPush"), "{err}");
    assert!(!out.exists());
    let o = collect(
        &["--task", "FetchReach", "--policy", "checkpoint:/no/such.ckpt", "--episodes", "2", "-o", p(&out)],
        None,
    );
    assert!(text(&o.stderr).contains("/no/such.ckpt") && !out.exists(), "{}", text(&o.stderr));
}
