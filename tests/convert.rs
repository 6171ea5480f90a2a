//! `pgser-etl convert` round trips: pickles written by numpy (many protocols, dtypes, layouts)
//! → Parquet → pyarrow, equal to the bit, nulls exactly on the last step.

mod common;

use common::*;

fn task_args(e: &serde_json::Value) -> Vec<String> {
    let mut a = vec!["--task".to_string(), e["task"].as_str().unwrap().to_string()];
    a.extend(strings(&e["extra_args"]));
    a
}

#[test]
fn generated_corpus_round_trips_bit_exact() {
    let dir = tempfile::tempdir().unwrap();
    py_ok("make_pickles.py", &[dir.path().to_str().unwrap()]);
    let entries = manifest(dir.path());
    assert!(entries.len() >= 20, "corpus too small: {}", entries.len());
    let out = dir.path().join("out.parquet");
    for e in &entries {
        let pkl = dir.path().join(e["file"].as_str().unwrap());
        convert_ok(&[&pkl], &out, &task_args(e));
        check_roundtrip(&out, &[&pkl], &[]);
        if e["float32_ok"].as_bool().unwrap_or(true) {
            let mut args = task_args(e);
            args.push("--float32".into());
            convert_ok(&[&pkl], &out, &args);
            check_roundtrip(&out, &[&pkl], &["--float32".into()]);
        }
    }
}

#[test]
fn committed_numpy1_and_numpy2_pickles_round_trip() {
    let dir = repo().join("tests/fixtures");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.parquet");
    let entries = manifest(&dir);
    for prefix in ["np1_", "np2_"] {
        assert!(entries.iter().any(|e| e["file"].as_str().unwrap().starts_with(prefix)), "no {prefix} fixtures");
    }
    for e in &entries {
        let pkl = dir.join(e["file"].as_str().unwrap());
        convert_ok(&[&pkl], &out, &task_args(e));
        check_roundtrip(&out, &[&pkl], &[]);
    }
}

/// Real WGCSL pickles written by other people's research code (GOAT's `offline_data/`), which
/// this repository does not redistribute. Ignored by a plain `cargo test`, so it is counted as
/// not run rather than passed; `make test` runs it with `PGSER_REAL_FIXTURES` set when the files
/// are there, and says so when they are not. Given the variable, missing files fail the test.
#[test]
#[ignore = "needs real WGCSL pickles: PGSER_REAL_FIXTURES=DIR (make test sets it when they are present)"]
fn real_wgcsl_files_round_trip() {
    let root = std::env::var_os("PGSER_REAL_FIXTURES").expect("PGSER_REAL_FIXTURES is not set");
    let dir = std::path::PathBuf::from(root).join("wgcsl");
    for f in ["reach_far_expert_200.pkl", "point_reach_noise_50.pkl"] {
        assert!(dir.join(f).exists(), "{} is missing", dir.join(f).display());
    }
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out.parquet");
    let reach = dir.join("reach_far_expert_200.pkl");
    convert_ok(&[&reach], &out, &["--task".into(), "FetchReach".into()]);
    check_roundtrip(&out, &[&reach], &[]);
    let point = dir.join("point_reach_noise_50.pkl");
    convert_ok(&[&point], &out, &["--task".into(), "PointReach".into(), "--threshold".into(), "0.05".into()]);
    check_roundtrip(&out, &[&point], &[]);
    let footer = pgser::table::read_footer(&out).unwrap();
    assert_eq!(footer["obs_dim"], 2);
    assert_eq!(footer["sources"][0]["sha256"], "0ba8b8fd5053a85474cb7cd83088ba4b6d8e642886a06a5e251c67c37c2bdad2");
}

#[test]
fn episodes_flag_takes_the_first_k_of_each_input() {
    let dir = repo().join("tests/fixtures");
    let (a, b) = (dir.join("np1_p3.pkl"), dir.join("np2_p5.pkl"));
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("mix.parquet");
    let args = vec!["--task".into(), "FetchReach".into(), "--episodes".into(), "2,1".into()];
    convert_ok(&[&a, &b], &out, &args);
    check_roundtrip(&out, &[&a, &b], &["--episodes".into(), "2,1".into()]);
    let footer = pgser::table::read_footer(&out).unwrap();
    assert_eq!(footer["episodes"], 3);
    assert_eq!(footer["sources"][0]["episodes_taken"], 2);
    assert_eq!(footer["sources"][1]["episodes_taken"], 1);
}

/// Row groups are encoded in parallel but appended in order: bytes never depend on threads.
#[test]
fn output_bytes_do_not_depend_on_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    py_ok("make_pickles.py", &[tmp.path().to_str().unwrap()]);
    let pkl = tmp.path().join("fetchpush_p4_f64_C_n7.pkl");
    assert!(pkl.exists(), "corpus lacks {}", pkl.display());
    let mut files = Vec::new();
    for threads in ["1", "2", "3"] {
        // Same path every time: the footer records the command line.
        let out = tmp.path().join("t.parquet");
        let o = etl()
            .env("RAYON_NUM_THREADS", threads)
            .args(["convert", pkl.to_str().unwrap(), "-o", out.to_str().unwrap(), "--task", "FetchPush"])
            .args(["--row-group-rows", "50"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        files.push(std::fs::read(&out).unwrap());
    }
    assert!(files.windows(2).all(|w| w[0] == w[1]), "bytes differ across thread counts");
}

#[test]
fn task_is_inferred_only_when_unambiguous() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("o.parquet");
    let reach = repo().join("tests/fixtures/np2_p3.pkl");
    convert_ok(&[&reach], &out, &[]);
    assert_eq!(pgser::table::read_footer(&out).unwrap()["task"], "FetchReach");

    py_ok("make_pickles.py", &[tmp.path().to_str().unwrap()]);
    let push = tmp.path().join("fetchpush_p4_f64_C_n7.pkl");
    let o = convert(&[&push], &tmp.path().join("p.parquet"), &[]);
    assert!(!o.status.success());
    let err = text(&o.stderr);
    assert!(err.contains("FetchPush") && err.contains("FetchSlide") && err.contains("--task"), "{err}");
}

/// inspect's success rate and statistics agree with numpy on the source arrays.
#[test]
fn inspect_agrees_with_numpy() {
    let tmp = tempfile::tempdir().unwrap();
    py_ok("make_pickles.py", &[tmp.path().to_str().unwrap()]);
    let pkl = tmp.path().join("fetchpush_p4_f64_C_n7.pkl");
    let out = tmp.path().join("o.parquet");
    convert_ok(&[&pkl], &out, &["--task".into(), "FetchPush".into()]);
    let o = etl().args(["inspect", "--json", out.to_str().unwrap()]).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let s: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let script = format!(
        "import pickle, numpy as np, json; d = pickle.load(open({:?}, 'rb'));\n\
         ok = np.linalg.norm(d['ag'][:, -1] - d['g'][:, -1], axis=-1) < 0.05\n\
         print(json.dumps(dict(n=len(ok), ok=int(ok.sum()), mean=float(d['o'].mean()), std=float(d['o'].std()),\n\
              min=float(d['o'].min()), max=float(d['o'].max()), umean=float(d['u'].mean()))))",
        pkl.display().to_string()
    );
    let py = std::process::Command::new(python()).args(["-c", &script]).output().unwrap();
    assert!(py.status.success(), "{}", text(&py.stderr));
    let want: serde_json::Value = serde_json::from_slice(&py.stdout).unwrap();
    assert_eq!(s["episodes"], want["n"]);
    assert_eq!(s["final_success"], want["ok"]);
    let col = |name: &str| s["columns"].as_array().unwrap().iter().find(|c| c["name"] == name).unwrap().clone();
    let (obs, act) = (col("obs"), col("action"));
    let close = |a: &serde_json::Value, b: &serde_json::Value| {
        let (a, b) = (a.as_f64().unwrap(), b.as_f64().unwrap());
        (a - b).abs() <= 1e-9 * (1.0 + b.abs())
    };
    assert!(close(&obs["all"]["mean"], &want["mean"]), "{} vs {}", obs["all"]["mean"], want["mean"]);
    assert!(close(&obs["std"], &want["std"]));
    assert_eq!(obs["all"]["min"], want["min"]);
    assert_eq!(obs["all"]["max"], want["max"]);
    assert!(close(&act["all"]["mean"], &want["umean"]), "nulls must be skipped in stats");
    assert_eq!(act["nulls"].as_u64().unwrap(), want["n"].as_u64().unwrap());
}

#[test]
fn help_shows_examples() {
    let o = etl().args(["convert", "--help"]).output().unwrap();
    assert!(o.status.success());
    assert!(text(&o.stdout).contains("Examples:"));
}
