//! `[data] table`: a pipeline over an existing trajectory table folder (`common::reach_folder`,
//! three FetchReach shards). β is read where it is (no convert), the score step writes a scored
//! folder with one shard per β shard under β's shard names, the -mem agents train on it and the
//! report reads its first shard; a rerun repeats nothing, and a lost scored shard is scored again
//! into the same bytes with nothing after it rerun. The table cannot be combined with the keys
//! that make data.

mod common;

use std::collections::BTreeMap;
use std::path::Path;

use common::{etl, folder_pipeline, snapshot, step_statuses, text};

/// Runs the pipeline; returns step name → status.
fn run(file: &Path, extra: &[&str]) -> BTreeMap<String, String> {
    let out = etl()
        .args(["pipeline", "run"])
        .arg(file)
        .args(["--json", "--threads", "2", "--no-measure"])
        .args(extra)
        .output()
        .unwrap();
    assert!(out.status.success(), "pipeline failed: {}", text(&out.stderr));
    step_statuses(&out)
}

fn ran(s: &BTreeMap<String, String>) -> Vec<&str> {
    s.iter().filter(|(_, v)| v.as_str() != "up to date").map(|(k, _)| k.as_str()).collect()
}

#[test]
fn a_table_folder_runs_end_to_end_into_a_scored_folder_and_reruns_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let file = folder_pipeline(dir.path(), 20);
    let out = dir.path().join("out");
    let beta = dir.path().join("reach");
    let beta_before = snapshot(&beta);

    let first = run(&file, &[]);
    let mut want: Vec<String> = ["pretrain", "score", "report", "results"].map(String::from).to_vec();
    for v in ["baseline", "swap", "mem"] {
        want.extend((0..2).map(|s| format!("agent td3bc_{v}_s{s}")));
    }
    want.sort();
    assert_eq!(first.keys().collect::<Vec<_>>(), want.iter().collect::<Vec<_>>(), "no convert: {first:?}");
    assert!(first.values().all(|s| s == "ran"), "{first:?}");
    assert!(!out.join("traj.parquet").exists() && !out.join("scored.parquet").exists());
    assert!(snapshot(&beta) == beta_before, "β was written to");

    // The scored folder: β's shard names, each a transition table naming β, and the manifest.
    let scored = out.join("scored");
    let mut names: Vec<String> =
        std::fs::read_dir(&scored).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["manifest.json", "reach-0.parquet", "reach-1.parquet", "reach-2.parquet"]);
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(scored.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(manifest["format"], "pgser-scored-folder");
    // 28 episodes × 49 transitions × 2 swaps.
    assert_eq!(manifest["rows"], 28 * 49 * 2, "{manifest}");
    for f in ["results.md", "results.csv", "curves_FetchReach.png", "report/table1.json", "report/fig5_q_hist.png"] {
        assert!(out.join(f).exists(), "{f} missing");
    }
    let table1: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report/table1.json")).unwrap()).unwrap();
    assert_eq!(table1["positive_episodes"], 8, "the first shard's episodes: {table1}");
    let results = std::fs::read_to_string(out.join("results.md")).unwrap();
    for v in ["baseline", "swap", "mem"] {
        assert!(results.contains(v), "{results}");
    }

    // A clean second run repeats nothing.
    let again = run(&file, &[]);
    assert!(ran(&again).is_empty(), "{again:?}");

    // A lost scored shard: the score step scores it again, into the same bytes (and the same
    // manifest), so nothing that reads the scored folder reruns.
    let before = snapshot(&out);
    std::fs::remove_file(scored.join("reach-1.parquet")).unwrap();
    let rebuilt = run(&file, &[]);
    assert_eq!(ran(&rebuilt), ["score"], "{rebuilt:?}");
    assert!(snapshot(&out) == before, "the scored folder was not rebuilt byte for byte");

    // Another shard of β (a changed table): every step reads β, so every step runs again.
    let shard = beta.join("reach-2.parquet");
    common::convert_ok(
        &[&common::repo().join("data/fetch_reach_random_200.pkl")],
        &shard,
        &["--task".into(), "FetchReach".into(), "--episodes".into(), "10".into()],
    );
    let files: Vec<String> = (0..3).map(|i| format!("reach-{i}.parquet")).collect();
    pgser::trajectory::folder::Manifest::of_shards(&beta, &files, "test", false, None).unwrap().write(&beta).unwrap();
    let changed = run(&file, &[]);
    assert!(changed.values().all(|s| s == "ran"), "{changed:?}");
}

#[test]
fn a_table_with_the_keys_that_make_data_is_refused_by_name_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let file = folder_pipeline(dir.path(), 20);
    let good = std::fs::read_to_string(&file).unwrap();
    for (with, says) in [
        ("episodes = [12, 24]", "`episodes`"),
        ("pickles = [\"a.pkl\"]", "`pickles`"),
        ("expert = 5\nrandom = 5", "`expert`, `random`"),
        ("oracle = 10", "`oracle`"),
    ] {
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, good.replace("table = \"reach\"", &format!("table = \"reach\"\n{with}"))).unwrap();
        let out = etl().args(["pipeline", "run"]).arg(&bad).output().unwrap();
        let err = text(&out.stderr);
        assert!(!out.status.success(), "{with}: accepted");
        assert!(err.contains("bad.toml") && err.contains("[data] table") && err.contains(says), "{says}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{err}");
        assert!(!dir.path().join("out").exists(), "{says}: wrote outputs");
    }
    // A folder that is not a table folder, and a table of another task: named before any step.
    std::fs::create_dir_all(dir.path().join("empty")).unwrap();
    let empty = dir.path().join("empty.toml");
    std::fs::write(&empty, good.replace("table = \"reach\"", "table = \"empty\"")).unwrap();
    let out = etl().args(["pipeline", "run"]).arg(&empty).output().unwrap();
    let err = text(&out.stderr);
    assert!(!out.status.success() && err.contains("[data] table") && err.contains("manifest.json"), "{err}");
    let push = dir.path().join("push.toml");
    std::fs::write(&push, good.replace("task = \"FetchReach\"", "task = \"FetchPush\"")).unwrap();
    let out = etl().args(["pipeline", "run"]).arg(&push).output().unwrap();
    let err = text(&out.stderr);
    assert!(
        !out.status.success() && err.contains("a table of FetchReach, not of the pipeline's task FetchPush"),
        "{err}"
    );
    assert!(!dir.path().join("out").exists(), "wrote outputs");

    // --shard is for the score step over a folder.
    let out = etl().args(["pipeline", "step"]).arg(&file).args(["pretrain", "--shard", "0"]).output().unwrap();
    assert!(text(&out.stderr).contains("--shard is for the score step"), "{}", text(&out.stderr));
    let out = etl().args(["pipeline", "step"]).arg(&file).args(["score", "--shard", "3"]).output().unwrap();
    assert!(text(&out.stderr).contains("--shard 3: β has 3 shards (0 to 2)"), "{}", text(&out.stderr));
}
