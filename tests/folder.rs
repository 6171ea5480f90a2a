//! Table folders (`pgser-etl convert DIR -o OUT`): OGBench shards in Horizon Reduction's layout
//! in, a folder of Parquet shards and a manifest out. The shards are cut from a dataset file that
//! OGBench's own generator wrote (tests/fixtures/ogbench, by tests/py/make_ogbench_shards.py).

mod common;

use std::path::{Path, PathBuf};

use common::*;

const NAME: &str = "pointmaze-medium-navigate-v0";

/// A folder of shards of `per_shard` episodes each (the fixture has 4), with its `-val.npz`.
fn shards(dir: &Path, per_shard: usize, extra: &[&str]) -> PathBuf {
    let src = dir.join("src");
    let dataset = repo().join("tests/fixtures/ogbench").join(format!("{NAME}.npz"));
    let mut args = vec![dataset.to_str().unwrap(), src.to_str().unwrap()];
    let n = per_shard.to_string();
    args.push(&n);
    args.extend(extra);
    py_ok("make_ogbench_shards.py", &args);
    src
}

fn run_convert(inputs: &[&Path], out: &Path) -> std::process::Output {
    etl().arg("convert").args(inputs).arg("-o").arg(out).output().unwrap()
}

fn manifest_of(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("manifest.json")).unwrap()).unwrap()
}

/// Each shard becomes a table of its own (the same table a convert of that file alone makes),
/// listed in order with its counts and first episode; the folder's footer has the totals; the
/// validation shard is a table folder of its own in val/; verify checks every shard.
#[test]
fn a_folder_of_shards_becomes_a_table_folder() {
    let dir = tempfile::tempdir().unwrap();
    let src = shards(dir.path(), 1, &[]);
    let out = dir.path().join("table");
    let o = run_convert(&[&src], &out);
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert!(text(&o.stderr).contains("4 shards, 4 converted"), "{}", text(&o.stderr));
    let m = manifest_of(&out);
    assert_eq!(
        (m["format"].as_str(), m["rows"].as_u64(), m["episodes"].as_u64()),
        (Some("pgser-table-folder"), Some(404), Some(4))
    );
    assert_eq!((m["footer"]["rows"].as_u64(), m["footer"]["task"].as_str()), (Some(404), Some("pointmaze-medium-v0")));
    assert_eq!(m["footer"]["sources"].as_array().unwrap().len(), 4);
    for (i, s) in m["shards"].as_array().unwrap().iter().enumerate() {
        assert_eq!(s["file"].as_str().unwrap(), format!("{NAME}-{i}.parquet"));
        assert_eq!(
            (s["rows"].as_u64(), s["episodes"].as_u64(), s["first_episode"].as_u64()),
            (Some(101), Some(1), Some(i as u64))
        );
        // The same table as the shard converted alone.
        let alone = dir.path().join(format!("alone{i}.parquet"));
        let shard = src.join(format!("{NAME}-{i}.npz"));
        let o = run_convert(&[&shard], &alone);
        assert!(o.status.success(), "{}", text(&o.stderr));
        let (a, b) = (read_table(&alone).0, read_table(&out.join(s["file"].as_str().unwrap())).0);
        assert_eq!((a.schema().fields(), a.columns()), (b.schema().fields(), b.columns()), "shard {i}");
    }
    assert_eq!(m["validation"], true);
    let v = manifest_of(&out.join("val"));
    assert_eq!(
        (v["rows"].as_u64(), v["shards"][0]["file"].as_str()),
        (Some(202), Some(&*format!("{NAME}-val.parquet")))
    );
    let o = etl().arg("verify").arg(&out).output().unwrap();
    assert!(o.status.success() && text(&o.stdout).starts_with("ok "), "{}{}", text(&o.stdout), text(&o.stderr));
    assert!(!out.join(".convert.json").exists(), "the settings file outlives the convert");

    // Exported, the folder is the source folder again: every shard, the validation one too, as
    // numpy and the zip archive see it (member order, headers, bytes).
    let back = dir.path().join("back");
    let o = etl().args(["export", "--format", "ogbench"]).arg(&out).arg("-o").arg(&back).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    let mut names: Vec<String> =
        std::fs::read_dir(&src).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    let mut got: Vec<String> =
        std::fs::read_dir(&back).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    got.sort();
    assert_eq!(names, got);
    for n in &names {
        py_ok("check_ogbench.py", &["whole", src.join(n).to_str().unwrap(), back.join(n).to_str().unwrap()]);
    }
}

/// A convert killed part way (a shard missing, no manifest), run again, converts only what is
/// missing and ends with the same folder; one with other settings converts every shard again.
#[test]
fn a_convert_run_again_redoes_only_unfinished_shards() {
    let dir = tempfile::tempdir().unwrap();
    let src = shards(dir.path(), 2, &[]);
    let out = dir.path().join("table");
    assert!(run_convert(&[&src], &out).status.success());
    let before = manifest_of(&out);
    // What a convert killed before its last shard leaves: its settings file, no manifest.
    std::fs::remove_file(out.join(format!("{NAME}-1.parquet"))).unwrap();
    std::fs::remove_file(out.join("manifest.json")).unwrap();
    std::fs::write(out.join(".convert.json"), before["settings"].to_string()).unwrap();
    let e = etl().arg("inspect").arg(&out).output().unwrap();
    assert!(!e.status.success());
    let o = run_convert(&[&src], &out);
    assert!(text(&o.stderr).contains("2 shards, 1 converted, 1 kept"), "{}", text(&o.stderr));
    let after = manifest_of(&out);
    assert_eq!(before["shards"], after["shards"], "the folder differs after a resumed convert");
    let o = etl().arg("convert").arg(&src).arg("-o").arg(&out).arg("--float32").output().unwrap();
    assert!(text(&o.stderr).contains("2 shards, 2 converted, 0 kept"), "{}", text(&o.stderr));
}

/// Shards that disagree are refused by name before any output; a folder holding other files is
/// refused; a shard changed after the convert is named by open and verify.
#[test]
fn disagreeing_shards_and_changed_folders_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let src = shards(dir.path(), 1, &["--float64", "2"]);
    let out = dir.path().join("table");
    let o = run_convert(&[&src], &out);
    let e = text(&o.stderr);
    assert!(!o.status.success() && e.contains(&format!("{NAME}-2.npz")) && e.contains("float64 where"), "{e}");
    assert!(!out.exists(), "a refused convert left {}", out.display());
    // A validation shard that disagrees with the training shards: refused before any shard is
    // written (it was once found after the training table was converted).
    let src = shards(&dir.path().join("val64"), 1, &["--val-float64"]);
    let o = run_convert(&[&src], &out);
    let e = text(&o.stderr);
    assert!(!o.status.success() && e.contains(&format!("{NAME}-val.npz")), "{e}");
    assert!(e.contains("the validation shards must agree with the training shards"), "{e}");
    assert!(!out.exists(), "a refused convert left {}", out.display());

    let src = shards(&dir.path().join("ok"), 1, &[]);
    let busy = dir.path().join("busy");
    std::fs::create_dir(&busy).unwrap();
    std::fs::write(busy.join("notes.txt"), "mine").unwrap();
    let e = text(&run_convert(&[&src], &busy).stderr);
    assert!(e.contains("holds notes.txt"), "{e}");

    assert!(run_convert(&[&src], &out).status.success());
    // One shard replaced by another: its size or footer no longer matches the manifest.
    std::fs::copy(out.join(format!("{NAME}-0.parquet")), out.join(format!("{NAME}-3.parquet"))).unwrap();
    let o = etl().arg("verify").arg(&out).output().unwrap();
    let e = text(&o.stdout);
    assert!(!o.status.success() && e.contains(&format!("{NAME}-3.parquet")), "{e}");
    // A flipped byte in a shard: the manifest's SHA-256 names it.
    assert!(run_convert(&[&src], &dir.path().join("t2")).status.success());
    let shard = dir.path().join("t2").join(format!("{NAME}-1.parquet"));
    let mut bytes = std::fs::read(&shard).unwrap();
    bytes[100] ^= 1;
    std::fs::write(&shard, bytes).unwrap();
    let o = etl().arg("verify").arg(dir.path().join("t2")).output().unwrap();
    let e = text(&o.stdout);
    assert!(!o.status.success() && e.contains(&format!("{NAME}-1.parquet")) && e.contains("SHA-256"), "{e}");
}

/// Every reader takes a table folder as the one table it is: `inspect`, `query`, the trainer's
/// batches and Python's `read_table` give what they give for the single file of the same
/// episodes, with episodes numbered across the folder.
#[test]
fn readers_take_a_folder_as_the_single_table_of_its_episodes() {
    let dir = tempfile::tempdir().unwrap();
    let src = shards(dir.path(), 1, &[]);
    let folder = dir.path().join("folder");
    let o = run_convert(&[&src], &folder);
    assert!(o.status.success(), "{}", text(&o.stderr));
    let dataset = repo().join("tests/fixtures/ogbench").join(format!("{NAME}.npz"));
    let single = dir.path().join(format!("{NAME}.parquet"));
    let o = run_convert(&[&dataset], &single);
    assert!(o.status.success(), "{}", text(&o.stderr));

    // inspect: the same counts, success and statistics; the folder says it is one.
    let (f, s) = (inspect_json(&folder), inspect_json(&single));
    assert_eq!(f["shards"], 4);
    for key in ["rows", "episodes", "final_success"] {
        assert_eq!(f[key], s[key], "{key}");
    }
    for (a, b) in f["columns"].as_array().unwrap().iter().zip(s["columns"].as_array().unwrap()) {
        assert_eq!(a["name"], b["name"]);
        for (x, y) in a["per_dim"].as_array().unwrap().iter().zip(b["per_dim"].as_array().unwrap()) {
            let (x, y) = (x["mean"].as_f64().unwrap(), y["mean"].as_f64().unwrap());
            assert!((x - y).abs() <= 1e-9 * (1.0 + y.abs()), "{}: mean {x} vs {y}", a["name"]);
        }
    }

    // query: the same rows, episodes numbered across the folder.
    let query = |table: &Path| {
        let sql = "SELECT episode, step, obs, action FROM t ORDER BY episode, step";
        let o = etl().args(["query", "--json", sql]).arg(format!("t={}", table.display())).output().unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        o.stdout
    };
    assert_eq!(query(&folder), query(&single));

    // The trainer's batches: number for number.
    let batches = |table: &Path, out: &str| {
        let path = dir.path().join(out);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
            .args(["batches", "--data"])
            .arg(table)
            .args(["--count", "20", "--batch-size", "64", "--swap", "random", "-o"])
            .arg(&path)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        read_table(&path).0.columns().to_vec()
    };
    assert!(batches(&folder, "f.parquet") == batches(&single, "s.parquet"), "other batches from the folder");

    // A shard that changed is named by every reader.
    let shard = folder.join(format!("{NAME}-2.parquet"));
    let mut bytes = std::fs::read(&shard).unwrap();
    bytes.push(0);
    std::fs::write(&shard, &bytes).unwrap();
    let o = etl().arg("inspect").arg(&folder).output().unwrap();
    assert!(!o.status.success() && text(&o.stderr).contains(&format!("{NAME}-2.parquet")), "{}", text(&o.stderr));
    let o = etl().args(["query", "SELECT COUNT(*) FROM t"]).arg(format!("t={}", folder.display())).output().unwrap();
    assert!(!o.status.success() && text(&o.stderr).contains("manifest says"), "{}", text(&o.stderr));
}
