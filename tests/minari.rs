//! Minari datasets in and out: `convert DIR` reads the committed fixtures (recorded by Minari's
//! own DataCollector, tests/py/make_minari_fixtures.py), `export --format minari` writes a
//! dataset that Python's `minari.load_dataset` opens with the same arrays, `export --format
//! wgcsl` a pickle that `convert` turns back into the same table; bad inputs fail in one line
//! and leave nothing behind.

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type};
use arrow_array::{Array, RecordBatch};
use arrow_schema::DataType;
use common::*;

fn fixture(name: &str) -> PathBuf {
    repo().join("tests/fixtures/minari").join(name)
}

fn etl_run(args: &[&str]) -> Output {
    etl().args(args).output().unwrap()
}

fn ok(args: &[&str]) -> String {
    let o = etl_run(args);
    assert!(o.status.success(), "pgser-etl {args:?} failed: {}", text(&o.stderr));
    text(&o.stderr)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The command fails with one line naming `needles`, and `dir` (the output's folder) is left
/// exactly as it was: `before` entries.
fn fails(args: &[&str], needles: &[&str], dir: &Path, before: usize) -> String {
    let o = etl_run(args);
    let err = text(&o.stderr);
    assert!(!o.status.success(), "pgser-etl {args:?} succeeded");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    assert!(err.starts_with("pgser-etl: error: "), "{err}");
    for n in needles {
        assert!(err.contains(n), "{err:?} does not name {n:?}");
    }
    assert_eq!(std::fs::read_dir(dir).unwrap().count(), before, "{args:?} left files in {}", dir.display());
    err
}

/// Every column of two tables equal bit for bit (null rows included), and their footers' data
/// description (task, T, dimensions, threshold, float type, counts).
fn assert_same_table(a: &Path, b: &Path) {
    let ((ta, _), (tb, _)) = (read_table(a), read_table(b));
    assert_same_batches(&ta, &tb);
    let (fa, fb) = (inspect_json(a)["footer"].clone(), inspect_json(b)["footer"].clone());
    for key in [
        "task",
        "T",
        "obs_dim",
        "goal_dim",
        "act_dim",
        "goal_metric",
        "success_threshold",
        "float_type",
        "episodes",
        "rows",
    ] {
        assert_eq!(fa[key], fb[key], "footer {key}: {} vs {}", a.display(), b.display());
    }
}

fn assert_same_batches(a: &RecordBatch, b: &RecordBatch) {
    assert_eq!(a.schema().fields(), b.schema().fields());
    for (i, f) in a.schema().fields().iter().enumerate() {
        let (ca, cb) = (a.column(i), b.column(i));
        assert_eq!(ca.logical_nulls(), cb.logical_nulls(), "nulls of {}", f.name());
        let bits = |c: &dyn Array| -> Vec<u64> {
            let c = match c.data_type() {
                DataType::FixedSizeList(_, _) => c.as_fixed_size_list().values().clone(),
                _ => arrow_array::make_array(c.to_data()),
            };
            match c.data_type() {
                DataType::Float64 => c.as_primitive::<Float64Type>().values().iter().map(|v| v.to_bits()).collect(),
                DataType::Float32 => {
                    c.as_primitive::<Float32Type>().values().iter().map(|v| v.to_bits() as u64).collect()
                }
                _ => arrow_cast_ints(&c),
            }
        };
        assert_eq!(bits(ca.as_ref()), bits(cb.as_ref()), "column {}", f.name());
    }
}

fn arrow_cast_ints(c: &arrow_array::ArrayRef) -> Vec<u64> {
    match c.data_type() {
        DataType::Int64 => {
            c.as_primitive::<arrow_array::types::Int64Type>().values().iter().map(|&v| v as u64).collect()
        }
        DataType::Int32 => {
            c.as_primitive::<arrow_array::types::Int32Type>().values().iter().map(|&v| v as u64).collect()
        }
        // A Minari dataset's terminations and truncations, kept as passthrough columns.
        DataType::Boolean => c.as_boolean().iter().map(|v| u64::from(v.unwrap_or(false))).collect(),
        other => panic!("no {other} columns in a trajectory table"),
    }
}

/// A copy of a committed fixture in `dir`, to damage.
fn copy_fixture(name: &str, dir: &Path) -> PathBuf {
    fn copy(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let p = e.unwrap().path();
            let dest = to.join(p.file_name().unwrap());
            if p.is_dir() { copy(&p, &dest) } else { std::fs::copy(&p, &dest).map(|_| ()).unwrap() }
        }
    }
    let dest = dir.join(name);
    copy(&fixture(name), &dest);
    dest
}

/// A Minari fixture → table → Minari dataset, which Python's minari opens with the fixture's
/// arrays; the exported dataset converts back into the same table bit for bit.
fn round_trip(name: &str, format: &str) {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let table = d.join("t.parquet");
    ok(&["convert", s(&fixture(name)), "-o", s(&table)]);
    let f = inspect_json(&table)["footer"].clone();
    assert_eq!((f["task"].as_str(), f["T"].as_u64(), f["episodes"].as_u64()), (Some("FetchReach"), Some(50), Some(4)));
    // Observations are float64 in Fetch's spaces, actions float32: the table widens them exactly.
    assert_eq!(f["float_type"], "float64");
    let src = &f["sources"][0];
    assert_eq!((src["format"].as_str(), src["episodes_in_file"].as_u64()), (Some(format), Some(4)));
    assert_eq!(src["sha256"].as_str().unwrap().len(), 64);

    let out = d.join("exported-v0");
    ok(&["export", s(&table), "--format", "minari", "-o", s(&out)]);
    let o = py_ok("check_minari.py", &["same", s(&fixture(name)), s(&out)]);
    let seen: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((seen["episodes"].as_u64(), seen["steps"].as_u64()), (Some(4), Some(196)), "{seen}");
    assert_eq!(seen["env_id"], "FetchReach-v4");
    // Bit for bit where the types agree: observations float64 on both sides.
    assert_eq!(seen["dtypes"]["observation"], serde_json::json!(["float64", "float64"]));

    let again = d.join("again.parquet");
    ok(&["convert", s(&out), "-o", s(&again)]);
    assert_same_table(&table, &again);
    assert_eq!(inspect_json(&again)["footer"]["sources"][0]["format"], "minari-arrow");
}

#[test]
fn arrow_storage_round_trips_through_a_table() {
    round_trip("fetchreach-arrow-v0", "minari-arrow");
}

#[cfg(feature = "hdf5")]
#[test]
fn hdf5_storage_round_trips_through_a_table() {
    round_trip("fetchreach-hdf5-v0", "minari-hdf5");
}

/// The two fixtures were recorded from the same seeds and actions: both readers must give the
/// same table, and a reader's `data/` folder is as good as the dataset folder.
#[cfg(feature = "hdf5")]
#[test]
fn hdf5_and_arrow_storage_give_the_same_table() {
    let dir = tempfile::tempdir().unwrap();
    let (h, a) = (dir.path().join("h.parquet"), dir.path().join("a.parquet"));
    ok(&["convert", s(&fixture("fetchreach-hdf5-v0")), "-o", s(&h)]);
    ok(&["convert", s(&fixture("fetchreach-arrow-v0").join("data")), "-o", s(&a)]);
    assert_same_table(&h, &a);
}

#[cfg(not(feature = "hdf5"))]
#[test]
fn hdf5_storage_without_the_feature_says_how_to_get_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.parquet");
    fails(
        &["convert", s(&fixture("fetchreach-hdf5-v0")), "-o", s(&out)],
        &["HDF5 storage", "--no-default-features", "make build", "Arrow storage"],
        dir.path(),
        0,
    );
}

/// Tables of both float types → WGCSL pickle → convert: the same table, bit for bit.
#[test]
fn table_to_wgcsl_pickle_and_back_is_the_same_table() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    for (name, extra) in [("f64", &[][..]), ("f32", &["--float32"][..])] {
        let table = d.join(format!("{name}.parquet"));
        let mut args = vec!["--task", "FetchPush", "--policy", "expert", "--episodes", "3", "--seed", "5"];
        args.extend(["--noise", "0.2", "-o", s(&table)]);
        args.extend(extra);
        collect_ok(&args, None);
        let pkl = d.join(format!("{name}.pkl"));
        ok(&["export", s(&table), "--format", "wgcsl", "-o", s(&pkl)]);
        let back = d.join(format!("{name}-back.parquet"));
        // A pickle has no task name, and FetchPush's dimensions are also PickAndPlace's and Slide's.
        let mut args = vec!["convert", s(&pkl), "-o", s(&back), "--task", "FetchPush"];
        args.extend(extra);
        ok(&args);
        assert_same_table(&table, &back);
    }
    // A table converted from Minari (float32 actions widened) goes the same way.
    let table = d.join("minari.parquet");
    ok(&["convert", s(&fixture("fetchreach-arrow-v0")), "-o", s(&table)]);
    let pkl = d.join("minari.pkl");
    ok(&["export", s(&table), "--format", "wgcsl", "-o", s(&pkl)]);
    let back = d.join("minari-back.parquet");
    ok(&["convert", s(&pkl), "-o", s(&back)]);
    assert_same_table(&table, &back);
}

/// A table pgser simulated (float32) as a Minari dataset: Python's minari sees the table's
/// arrays, the goals' rewards and the time-limit truncation.
#[test]
fn exported_dataset_holds_the_table_in_python() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let table = d.join("push.parquet");
    collect_ok(&["--task", "FetchPush", "--policy", "random", "--episodes", "3", "-o", s(&table), "--float32"], None);
    let out = d.join("push-random-v2");
    let said = ok(&["export", s(&table), "--format", "minari", "-o", s(&out)]);
    assert!(said.contains("3 episodes of FetchPush"), "{said}");
    let o = py_ok("check_minari.py", &["table", s(&table), s(&out), "0.05"]);
    let seen: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(
        (seen["env_id"].as_str(), seen["obs_dtype"].as_str()),
        (Some("FetchPush-v4"), Some("float32")),
        "{seen}"
    );
}

/// A task pgser does not know has no Gymnasium spec; the export records its name and
/// threshold, so converting the dataset back needs no flags.
#[test]
fn a_custom_task_comes_back_from_its_export() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let table = d.join("t.parquet");
    ok(&["convert", s(&fixture("fetchreach-arrow-v0")), "-o", s(&table), "--task", "MyReach", "--threshold", "0.07"]);
    let out = d.join("myreach-v1");
    ok(&["export", s(&table), "--format", "minari", "-o", s(&out)]);
    let o = py_ok("check_minari.py", &["table", s(&table), s(&out), "0.07"]);
    assert!(text(&o.stdout).contains("\"env_id\": null"), "{}", text(&o.stdout));
    let back = d.join("back.parquet");
    ok(&["convert", s(&out), "-o", s(&back)]);
    assert_same_table(&table, &back);
    assert_eq!(inspect_json(&back)["footer"]["task"], "MyReach");
}

#[test]
fn episodes_of_unequal_length_are_refused_by_episode() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("t.parquet");
    let short = fixture("fetchreach-short-arrow-v0");
    fails(
        &["convert", s(&short), "-o", s(&out)],
        &["episode 2 has 20 steps where episode 0 has 49", "--episodes 2"],
        dir.path(),
        0,
    );
    ok(&["convert", s(&short), "-o", s(&out), "--episodes", "2"]);
    assert_eq!(inspect_json(&out)["footer"]["episodes"], 2);
}

/// A dataset recorded as Python users record one, `minari.DataCollector(gym.make("FetchReach-v4"))`:
/// gymnasium-robotics' 50-step limit gives 51 observations, one more than pgser's FetchReach T.
/// convert drops each episode's last step and says so; --exact-length refuses instead.
#[test]
fn a_dataset_one_step_longer_than_its_task_loses_its_last_step() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path().join("out");
    std::fs::create_dir_all(&d).unwrap();
    let long = fixture("fetchreach-default-arrow-v0");
    let table = d.join("t.parquet");
    let err = ok(&["convert", s(&long), "-o", s(&table)]);
    let notes: Vec<&str> = err.lines().filter(|l| l.contains("dropped each episode's last step")).collect();
    assert_eq!(notes.len(), 1, "{err}");
    assert!(notes[0].contains("episodes have 50 steps") && notes[0].contains("--exact-length"), "{err}");
    let f = inspect_json(&table)["footer"].clone();
    assert_eq!((f["task"].as_str(), f["T"].as_u64(), f["episodes"].as_u64()), (Some("FetchReach"), Some(50), Some(3)));
    assert_eq!(f["sources"][0]["steps_dropped"], 1);
    // Episode 0 was recorded with the same seed and actions as episode 0 of the 49-step fixture:
    // its first 50 observations and 49 actions are that episode, bit for bit.
    let short = d.join("short.parquet");
    ok(&["convert", s(&fixture("fetchreach-arrow-v0")), "-o", s(&short)]);
    assert!(inspect_json(&short)["footer"]["sources"][0].get("steps_dropped").is_none());
    // (The 49-step fixture keeps its recorded rewards, terminations and truncations too; the
    // shortened episodes no longer end where theirs say, and leave them to the export.)
    let ((a, _), (b, _)) = (read_table(&table), read_table(&short));
    let core = [0, 1, 2, 3, 4, 5];
    assert_eq!(a.num_columns(), 6);
    assert_same_batches(&a.slice(0, 50), &b.slice(0, 50).project(&core).unwrap());
    std::fs::remove_file(&table).unwrap();
    std::fs::remove_file(&short).unwrap();
    fails(
        &["convert", s(&long), "-o", s(&table), "--exact-length"],
        &["episodes have 51 observations", "FetchReach has T = 50"],
        &d,
        0,
    );
}

#[test]
fn bad_datasets_fail_in_one_line_and_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (d, work) = (dir.path().join("out"), dir.path().join("work"));
    std::fs::create_dir_all(&d).unwrap();
    let out = d.join("t.parquet");
    let convert = |input: &Path, needles: &[&str]| fails(&["convert", s(input), "-o", s(&out)], needles, &d, 0);

    // An episode folder missing from an Arrow dataset.
    let missing = copy_fixture("fetchreach-arrow-v0", &work);
    std::fs::remove_dir_all(missing.join("data/2")).unwrap();
    convert(&missing, &["fetchreach-arrow-v0/data", "episode 2 is missing", "total_episodes 4"]);
    // An episode file that is not Arrow.
    let corrupt = copy_fixture("fetchreach-short-arrow-v0", &work);
    let file = corrupt.join("data/1/part-0.arrow");
    let bytes = std::fs::read(&file).unwrap();
    std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
    convert(&corrupt, &["data/1/part-0.arrow (episode 1)", "not an Arrow IPC file"]);
    // A plain Box observation: no goals.
    convert(
        &fixture("pendulum-hdf5-v0"),
        &["pendulum-hdf5-v0/data/metadata.json", "is a Box of shape [3]", "not a goal-conditioned"],
    );
    // A folder that is no dataset (before, `convert DIR` said "No such device (os error 19)").
    let empty = work.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    convert(
        &empty,
        &["empty: a folder, but not a Minari dataset", "nor OGBench shards", "OGBench .npz files and folders"],
    );
    // A dataset among pickles.
    let pkl = repo().join("data/fetch_reach_expert_50.pkl");
    fails(&["convert", s(&pkl), s(&missing), "-o", s(&out)], &["a folder (a Minari dataset) among 2 inputs"], &d, 0);

    #[cfg(feature = "hdf5")]
    {
        // An HDF5 dataset whose metadata promises an episode the file lacks.
        let missing = copy_fixture("fetchreach-hdf5-v0", &work.join("h"));
        let meta = missing.join("data/metadata.json");
        let text = std::fs::read_to_string(&meta).unwrap().replace("\"total_episodes\": 4", "\"total_episodes\": 5");
        std::fs::write(&meta, text).unwrap();
        convert(&missing, &["main_data.hdf5", "episode 4 is missing: no group episode_4", "total_episodes 5"]);
        // A truncated HDF5 file.
        let corrupt = copy_fixture("fetchreach-hdf5-v0", &work.join("h2"));
        let file = corrupt.join("data/main_data.hdf5");
        let bytes = std::fs::read(&file).unwrap();
        std::fs::write(&file, &bytes[..bytes.len() / 3]).unwrap();
        convert(&corrupt, &["main_data.hdf5"]);
    }
}

#[test]
fn export_never_overwrites_and_names_datasets_by_id() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let table = d.join("t.parquet");
    ok(&["convert", s(&fixture("fetchreach-arrow-v0")), "-o", s(&table)]);
    let out = d.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let taken_pkl = out.join("taken.pkl");
    std::fs::write(&taken_pkl, b"mine").unwrap();
    let taken_dir = out.join("taken-v0");
    std::fs::create_dir_all(&taken_dir).unwrap();
    for (format, path) in [("wgcsl", &taken_pkl), ("minari", &taken_dir)] {
        fails(
            &["export", s(&table), "--format", format, "-o", s(path)],
            &["already exists", "never overwrites"],
            &out,
            2,
        );
    }
    assert_eq!(std::fs::read(&taken_pkl).unwrap(), b"mine");
    assert_eq!(std::fs::read_dir(&taken_dir).unwrap().count(), 0);
    fails(&["export", s(&table), "--format", "minari", "-o", s(&out.join("no_version"))], &["NAME-vN"], &out, 2);
    // Not a trajectory table: nothing is written either.
    let pkl = repo().join("data/fetch_reach_expert_50.pkl");
    fails(
        &["export", s(&pkl), "--format", "minari", "-o", s(&out.join("x-v0"))],
        &["fetch_reach_expert_50.pkl"],
        &out,
        2,
    );
}

/// An export killed mid-write (SIGKILL runs no destructor) leaves its staging folder
/// `.NAME.XXXXXX` beside the dataset; the next export of that dataset removes it, unless a live
/// writer still holds it (its flock), and finishes with the same dataset as an undisturbed run.
#[test]
fn a_killed_exports_staging_folder_is_swept_and_a_live_ones_kept() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let table = d.join("t.parquet");
    ok(&["convert", s(&fixture("fetchreach-default-arrow-v0")), "-o", s(&table)]);
    let clean = d.join("clean");
    std::fs::create_dir(&clean).unwrap();
    ok(&["export", s(&table), "--format", "minari", "-o", s(&clean.join("ds-v0"))]);

    // What a killed export leaves: a half-written staging folder nobody holds.
    let dead = d.join(".ds-v0.k1LLed");
    std::fs::create_dir_all(dead.join("data/0")).unwrap();
    std::fs::write(dead.join("data/0/observation.arrow"), b"half").unwrap();
    // A live writer's: held by this process.
    let live = d.join(".ds-v0.L1veOn");
    std::fs::create_dir(&live).unwrap();
    let held = std::fs::File::open(&live).unwrap();
    assert_eq!(unsafe { libc::flock(std::os::fd::AsRawFd::as_raw_fd(&held), libc::LOCK_EX | libc::LOCK_NB) }, 0);
    // Not ours: other names, and a file with a staging folder's name.
    let other = d.join(".ds-v1.k1LLed");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(d.join(".ds-v0.fi1eXX"), b"not a folder").unwrap();

    ok(&["export", s(&table), "--format", "minari", "-o", s(&d.join("ds-v0"))]);
    assert!(!dead.exists(), "the killed export's staging folder is swept");
    assert!(live.is_dir() && other.is_dir() && d.join(".ds-v0.fi1eXX").is_file(), "only stale folders of ds-v0 go");
    let (a, b) = (d.join("a.parquet"), d.join("b.parquet"));
    ok(&["convert", s(&d.join("ds-v0")), "-o", s(&a)]);
    ok(&["convert", s(&clean.join("ds-v0")), "-o", s(&b)]);
    assert_same_table(&a, &b);
    drop(held);
}

/// Inputs the Minari fuzzer found to crash `convert` (`tests/fixtures/fuzz/minari/`, each the
/// fuzz target's input: a first byte picking `data/metadata.json` (even) or episode 0's Arrow
/// file (odd), then that file's bytes, put into the fixture dataset). The first: a record
/// batch whose buffer offset lies far past its body, which arrow-ipc's reader asserts on. Each
/// now fails in one line naming the file, and writes nothing.
#[test]
fn datasets_the_fuzzer_found_fail_in_one_line() {
    let found = std::fs::read_dir(repo().join("tests/fixtures/fuzz/minari")).unwrap();
    let mut n = 0;
    for entry in found {
        let input = std::fs::read(entry.unwrap().path()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let (d, out) = (dir.path().join("out"), dir.path().join("out/t.parquet"));
        std::fs::create_dir_all(&d).unwrap();
        let ds = copy_fixture("fetchreach-default-arrow-v0", dir.path());
        let target = if input[0] % 2 == 0 {
            ds.join("data/metadata.json")
        } else {
            let ep = ds.join("data/0");
            std::fs::read_dir(&ep)
                .unwrap()
                .map(|e| e.unwrap().path())
                .find(|p| p.extension().is_some_and(|x| x == "arrow"))
                .unwrap()
        };
        std::fs::write(&target, &input[1..]).unwrap();
        let name = target.file_name().unwrap().to_string_lossy().into_owned();
        let err = fails(&["convert", s(&ds), "-o", s(&out)], &[&name], &d, 0);
        assert!(err.contains("corrupt") || err.contains("not"), "{err}");
        n += 1;
    }
    assert!(n > 0, "no inputs in tests/fixtures/fuzz/minari");
}

/// `check_minari.py edit`: one episode of a copied fixture changed in place, in either storage.
fn edit(dataset: &Path, episode: usize, column: &str, action: &str) {
    py_ok("check_minari.py", &["edit", s(dataset), &episode.to_string(), column, action]);
}

/// convert fails in one line naming `needles` and suggesting a `--drop X`; convert with that
/// very flag then succeeds and says it left X out. Returns X.
fn the_suggested_drop_is_accepted(input: &Path, out_dir: &Path, needles: &[&str]) -> String {
    let out = out_dir.join("t.parquet");
    let before = std::fs::read_dir(out_dir).unwrap().count();
    let err = fails(&["convert", s(input), "-o", s(&out)], needles, out_dir, before);
    let at = err.find("--drop ").unwrap_or_else(|| panic!("no --drop suggested: {err}"));
    let column: String = err[at + 7..].chars().take_while(|c| !c.is_whitespace() && !",;)".contains(*c)).collect();
    let said = ok(&["convert", s(input), "-o", s(&out), "--drop", &column]);
    assert!(said.contains("left out") && said.contains(&column), "{said}");
    std::fs::remove_file(&out).unwrap();
    column
}

/// Every episode holds the same infos keys, checked both ways (as WGCSL's inputs are): a key
/// only a later episode holds was lost without a word before; one a later episode lacks is
/// refused too. Each refusal names the episode and the key, and its `--drop` is accepted, though
/// episode 0 lacks the key.
#[test]
fn an_infos_key_of_some_episodes_only_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let storages: &[&str] = if cfg!(feature = "hdf5") { &["arrow", "hdf5"] } else { &["arrow"] };
    for storage in storages {
        let name = format!("fetchreach-infos-{storage}-v0");
        let late = copy_fixture(&name, &dir.path().join(format!("late-{storage}")));
        edit(&late, 2, "infos/late", "add");
        let col = the_suggested_drop_is_accepted(&late, &out, &["episode 2 has `infos/late`, which episode 0 lacks"]);
        assert_eq!(col, "infos/late");
        let gone = copy_fixture(&name, &dir.path().join(format!("gone-{storage}")));
        edit(&gone, 1, "infos/distance", "remove");
        let col = the_suggested_drop_is_accepted(&gone, &out, &["episode 1's `infos/distance` is missing"]);
        assert_eq!(col, "infos/distance");
        // A --drop no episode holds is refused, after every episode is read.
        fails(
            &["convert", s(&fixture(&name)), "-o", s(&out.join("t.parquet")), "--drop", "infos/late"],
            &["--drop infos/late", "in the 3 episodes taken"],
            &out,
            0,
        );
    }
}

/// What no column can keep (a string `rewards`, a string infos key) is refused under the name
/// `--drop` takes, and that `--drop` converts: before, an Arrow dataset's refusal named
/// `infos.rewards` and suggested `--drop infos/rewards`, itself refused, and in both storages the
/// refused column was read (and refused again) whatever `--drop` said. After a dropped last
/// step, `--drop rewards` failed with "has no infos key".
#[test]
fn every_suggested_drop_is_one_convert_accepts() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let storages: &[&str] = if cfg!(feature = "hdf5") { &["arrow", "hdf5"] } else { &["arrow"] };
    for storage in storages {
        let rewards = copy_fixture(&format!("fetchreach-{storage}-v0"), &dir.path().join(format!("r-{storage}")));
        edit(&rewards, 0, "rewards", "string");
        let col = the_suggested_drop_is_accepted(&rewards, &out, &["rewards", "which a table column cannot keep"]);
        assert_eq!(col, "rewards");
        let info = copy_fixture(&format!("fetchreach-infos-{storage}-v0"), &dir.path().join(format!("i-{storage}")));
        edit(&info, 0, "infos/distance", "string");
        let col = the_suggested_drop_is_accepted(&info, &out, &["distance", "which a table column cannot keep"]);
        assert_eq!(col, "infos/distance");
    }
    // The recorded outcomes of a dataset whose last step is dropped are left out anyway; a
    // --drop of them is accepted all the same.
    let said = ok(&[
        "convert",
        s(&fixture("fetchreach-default-arrow-v0")),
        "-o",
        s(&out.join("t.parquet")),
        "--drop",
        "rewards",
    ]);
    assert!(said.contains("dropped each episode's last step"), "{said}");
}
