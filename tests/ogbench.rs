//! OGBench datasets in and out (`pgser-etl convert DATASET.npz`, `export --format ogbench`), on
//! files written by OGBench's own code (tests/fixtures/ogbench, made by
//! tests/py/make_ogbench_fixtures.py in ogbench 1.2.2's PointMaze with its data generator's
//! oracle): the distributed layout, and what `ogbench.load_dataset` returns regular and compact.

mod common;

use std::path::{Path, PathBuf};

use common::*;
use pgser::dtype::Dtype;

fn fixture(rel: &str) -> PathBuf {
    repo().join("tests/fixtures/ogbench").join(rel)
}

fn convert_ok(input: &Path, out: &Path, extra: &[&str]) -> String {
    let o = etl().arg("convert").arg(input).arg("-o").arg(out).args(extra).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    text(&o.stderr)
}

/// The three layouts of one dataset make one table: T = 101 observations per episode, the goal
/// the point's x, y, each transition's desired goal its episode's last position, and the rows
/// those of the file (observations all; actions all, each episode's last kept on its last step
/// where the file has it: not in the regular layout, whose rows are transitions). Each keeps its
/// file's other arrays beside them (tests/passthrough.rs).
#[test]
fn every_layout_of_a_dataset_makes_the_same_table() {
    let dir = tempfile::tempdir().unwrap();
    let tables: Vec<_> = [
        "pointmaze-medium-navigate-v0.npz",
        "compact/pointmaze-medium-navigate-v0.npz",
        "regular/pointmaze-medium-navigate-v0.npz",
    ]
    .iter()
    .enumerate()
    .map(|(i, f)| {
        let out = dir.path().join(format!("t{i}.parquet"));
        let notes = convert_ok(&fixture(f), &out, &[]);
        assert!(notes.contains("environment pointmaze-medium-v0") && notes.contains("success within 1"), "{notes}");
        read_table(&out)
    })
    .collect();
    let (t, _) = &tables[0];
    assert_eq!(t.num_rows(), 404);
    let (compact, regular) = (&tables[1].0, &tables[2].0);
    // episode, step, obs, achieved_goal, desired_goal: the same; action: the same where both
    // layouts have it.
    for other in [compact, regular] {
        assert_eq!(other.columns()[..5], t.columns()[..5], "a layout converts to other values");
    }
    assert_eq!(compact.column(5), t.column(5), "the compact layout's actions");
    let transitions: Vec<u32> = (0..404u32).filter(|r| r % 101 != 100).collect();
    let rows = arrow_array::UInt32Array::from(transitions);
    let pick = |b: &arrow_array::RecordBatch| arrow_select::take::take(b.column(5), &rows, None).unwrap();
    use arrow_array::Array;
    assert_eq!(pick(regular).to_data(), pick(t).to_data(), "the regular layout's actions");
    let footer = pgser::table::read_footer(&dir.path().join("t0.parquet")).unwrap();
    assert_eq!(
        (footer["task"].as_str(), footer["T"].as_u64(), footer["success_threshold"].as_f64()),
        (Some("pointmaze-medium-v0"), Some(101), Some(1.0))
    );
    assert_eq!(footer["sources"][0]["format"], "ogbench-npz");

    // Against the file itself, read by the .npz reader.
    let read = |key: &str| -> Vec<f32> {
        pgser::ogbench::npz::with_member(&fixture("pointmaze-medium-navigate-v0.npz"), key, |r, _| {
            let mut b = Vec::new();
            r.read_to_end(&mut b)?;
            Ok(b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect())
        })
        .unwrap()
    };
    let (obs, act) = (read("observations"), read("actions"));
    let col = |name: &str, row: usize| -> Option<Vec<f32>> {
        use arrow_array::Array;
        use arrow_array::cast::AsArray;
        let list = t.column_by_name(name).unwrap().as_fixed_size_list();
        (!list.is_null(row))
            .then(|| list.value(row).as_primitive::<arrow_array::types::Float32Type>().values().to_vec())
    };
    for row in [0, 57, 100, 101, 250, 403] {
        let (e, s) = (row / 101, row % 101);
        assert_eq!(col("obs", row).unwrap(), obs[row * 2..row * 2 + 2], "row {row}");
        assert_eq!(col("achieved_goal", row).unwrap(), obs[row * 2..row * 2 + 2], "row {row}");
        if s < 100 {
            assert_eq!(col("action", row).unwrap(), act[row * 2..row * 2 + 2], "row {row}");
            let last = e * 101 + 100;
            assert_eq!(col("desired_goal", row).unwrap(), obs[last * 2..last * 2 + 2], "row {row}");
        } else {
            // The file's last action of the episode, kept for export; no goal after the last step.
            assert_eq!(col("action", row).unwrap(), act[row * 2..row * 2 + 2], "row {row}");
            assert_eq!(col("desired_goal", row), None, "row {row}: the last observation's");
        }
    }
}

/// A table exported as an OGBench file loads in ogbench as the original does: every array of
/// the train and val datasets, regular and compact (but the compact actions of each episode's
/// last row, which a table does not hold), equal value for value.
#[test]
fn an_exported_file_loads_in_ogbench_as_the_original() {
    let dir = tempfile::tempdir().unwrap();
    let (exported, original) = (dir.path().join("ours"), dir.path().join("theirs"));
    for d in [&exported, &original] {
        std::fs::create_dir(d).unwrap();
    }
    for split in ["", "-val"] {
        let name = format!("pointmaze-medium-navigate-v0{split}.npz");
        std::fs::copy(fixture(&name), original.join(&name)).unwrap();
        let table = dir.path().join(format!("t{split}.parquet"));
        convert_ok(&fixture(&name), &table, &[]);
        let o = etl()
            .args(["export"])
            .arg(&table)
            .args(["--format", "ogbench", "-o"])
            .arg(exported.join(&name))
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        // Converted back, the same table.
        let back = dir.path().join(format!("back{split}.parquet"));
        convert_ok(&exported.join(&name), &back, &[]);
        assert_eq!(read_table(&back).0.columns(), read_table(&table).0.columns());
    }
    let file = |d: &Path| d.join("pointmaze-medium-navigate-v0.npz").display().to_string();
    let o = py_ok("check_ogbench.py", &["same", "pointmaze-medium-navigate-v0", &file(&original), &file(&exported)]);
    let out = text(&o.stdout);
    for k in ["train/observations", "val/next_observations", "train/valids/compact", "train/actions/compact"] {
        assert!(out.contains(k), "{out}");
    }
}

/// Bad inputs: one line naming the file and the fault, and no output file.
#[test]
fn bad_files_fail_in_one_line_and_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.parquet");
    let fails = |input: &Path, extra: &[&str], want: &str| convert_fails(input, &out, extra, want);
    let bytes = std::fs::read(fixture("pointmaze-medium-navigate-v0.npz")).unwrap();
    // Not a zip archive at all.
    let junk = dir.path().join("pointmaze-medium-navigate-v0.npz");
    std::fs::write(&junk, b"not a zip").unwrap();
    fails(&junk, &[], "not a .npz file");
    // Cut short: the archive's directory is at its end.
    std::fs::write(&junk, &bytes[..bytes.len() / 2]).unwrap();
    fails(&junk, &[], "not a .npz file");
    // A name that says no environment, then the same file with --task.
    let odd = dir.path().join("mydata.npz");
    std::fs::write(&odd, &bytes).unwrap();
    fails(&odd, &[], "names no environment: give it with --task");
    convert_ok(&odd, &out, &["--task", "pointmaze-medium-v0"]);
    std::fs::remove_file(&out).unwrap();
    // A pointmaze file under a cube dataset's name: its observations are no cube scene's.
    let cube = dir.path().join("cube-single-play-v0.npz");
    std::fs::write(&cube, &bytes).unwrap();
    fails(&cube, &[], "cube-single-v0: observations have 2 values; a cube scene's have 19 + 9 per cube");
    // Episodes of two lengths, and a missing key: written with the npz writer.
    let write = |path: &Path, keys: &[(&str, Dtype, Vec<usize>, Vec<u8>)]| {
        let mut w = npz::NpzWriter::new(std::fs::File::create(path).unwrap(), true);
        for (k, dt, shape, data) in keys {
            w.start(k, *dt, shape).unwrap();
            w.write(data).unwrap();
        }
        w.finish().unwrap();
    };
    use pgser::ogbench::npz;
    let f32s = |n: usize| vec![0u8; n * 4];
    let uneven = dir.path().join("pointmaze-large-navigate-v0.npz");
    let mut term = vec![0u8; 7];
    term[2] = 1;
    term[6] = 1;
    write(
        &uneven,
        &[
            ("observations", Dtype::F32, vec![7, 2], f32s(14)),
            ("actions", Dtype::F32, vec![7, 2], f32s(14)),
            ("terminals", Dtype::BOOL, vec![7], term.clone()),
        ],
    );
    fails(&uneven, &[], "episode 1 has 4 rows where episode 0 has 3");
    write(&uneven, &[("observations", Dtype::F32, vec![7, 2], f32s(14)), ("terminals", Dtype::BOOL, vec![7], term)]);
    fails(&uneven, &[], "no actions array");
    let open = vec![0u8; 6];
    write(
        &uneven,
        &[
            ("observations", Dtype::F32, vec![6, 2], f32s(12)),
            ("actions", Dtype::F32, vec![6, 2], f32s(12)),
            ("terminals", Dtype::BOOL, vec![6], open),
        ],
    );
    fails(&uneven, &[], "the last row (5) ends no episode");
    // A NaN is named by the key as the file names it (not pgser's internal `o` or `u`).
    let mut term = vec![0u8; 6];
    term[2] = 1;
    term[5] = 1;
    let mut acts = f32s(12);
    acts[4 * 9..4 * 10].copy_from_slice(&f32::NAN.to_le_bytes()); // row 4, index 1
    write(
        &uneven,
        &[
            ("observations", Dtype::F32, vec![6, 2], f32s(12)),
            ("actions", Dtype::F32, vec![6, 2], acts),
            ("terminals", Dtype::BOOL, vec![6], term),
        ],
    );
    fails(&uneven, &[], "non-finite value NaN in key 'actions' at episode 1, step 1, index 1");
    // Export: not a .npz name.
    let table = dir.path().join("t.parquet");
    convert_ok(&fixture("pointmaze-medium-navigate-v0.npz"), &table, &[]);
    let o = etl()
        .arg("export")
        .arg(&table)
        .args(["--format", "ogbench", "-o"])
        .arg(dir.path().join("x.pkl"))
        .output()
        .unwrap();
    assert!(
        !o.status.success() && text(&o.stderr).contains("is a .npz file named after the dataset"),
        "{}",
        text(&o.stderr)
    );
    assert!(!dir.path().join("x.pkl").exists());
}

/// pgser's evaluation in its PointMaze equals OGBench's: OGBench's oracle agent (the BFS
/// direction plus N(0, 1) noise from `default_rng(seed)`, computed from the float32 observation a
/// pgser policy sees) run by `pgser::eval::evaluate` on seeds 0–9 (tasks 1–5 twice: consecutive
/// seeds cycle through OGBench's five tasks) and by ogbench's own environment (episodes ending at
/// success) succeed on the same episodes after the same number of steps.
#[test]
fn evaluation_in_pointmaze_equals_ogbenchs() {
    use pgser::env::pointmaze::oracle_subgoal;
    use pgser::nprandom::NpRandom;
    use std::cell::RefCell;

    struct Oracle {
        noise: RefCell<Vec<NpRandom>>,
    }
    impl pgser::eval::Policy for Oracle {
        fn act(&self, obs: &[f32], goal: &[f32], n: usize) -> Vec<f32> {
            let mut noise = self.noise.borrow_mut();
            let mut out = Vec::with_capacity(2 * n);
            for k in 0..n {
                let xy = [f64::from(obs[2 * k]), f64::from(obs[2 * k + 1])];
                let g = [f64::from(goal[2 * k]), f64::from(goal[2 * k + 1])];
                let sub = oracle_subgoal("pointmaze-medium-v0", xy, g).unwrap();
                let d = [sub[0] - xy[0], sub[1] - xy[1]];
                let norm = (d[0] * d[0] + d[1] * d[1]).sqrt() + 1e-6;
                let z = pgser::nprandom::ziggurat::tables().unwrap();
                let e = [z.standard_normal(&mut noise[k]), z.standard_normal(&mut noise[k])];
                out.extend((0..2).map(|i| (d[i] / norm + e[i]).clamp(-1.0, 1.0) as f32));
            }
            out
        }
    }
    let seeds: Vec<u64> = (0..10).collect();
    let o =
        py_ok("env_parity.py", &["pointmaze-eval", "--maze", "pointmaze-medium-v0", "--seeds", "0,1,2,3,4,5,6,7,8,9"]);
    let theirs: serde_json::Value = serde_json::from_str(&text(&o.stdout)).unwrap();
    let policy = Oracle { noise: RefCell::new(seeds.iter().map(|&s| NpRandom::new(s)).collect()) };
    let ours = pgser::eval::evaluate("pointmaze-medium-v0", &policy, seeds.len(), 0).unwrap();
    let runs = theirs.as_array().unwrap();
    let successes = runs.iter().filter(|r| r["success"] == true).count();
    // Reward −1 a step until the step that reaches the goal (0), which ends the episode.
    let returns: f64 = runs
        .iter()
        .map(|r| if r["success"] == true { -(r["steps"].as_f64().unwrap() - 1.0) } else { -1000.0 })
        .sum::<f64>()
        / runs.len() as f64;
    assert_eq!(ours.success_rate, successes as f64 / runs.len() as f64, "{ours:?} vs {theirs}");
    assert_eq!(ours.return_mean, returns, "{ours:?} vs {theirs}");
    assert!(successes > 0, "the oracle reached no goal: the test checks no early end");
    // Per task, as OGBench reports: seed i ran task i % 5 + 1.
    let per_task: Vec<f64> = (0..5)
        .map(|t| {
            let of: Vec<_> =
                runs.iter().enumerate().filter(|(i, _)| i % 5 == t).map(|(_, r)| r["success"] == true).collect();
            of.iter().filter(|&&s| s).count() as f64 / of.len() as f64
        })
        .collect();
    assert_eq!(ours.task_success, per_task, "{ours:?} vs {theirs}");
    assert!(pgser::eval::evaluate("FetchReach", &policy_fetch(), 2, 0).unwrap().task_success.is_empty());
}

/// Zero actions in FetchReach: a task without fixed evaluation tasks.
fn policy_fetch() -> impl pgser::eval::Policy {
    struct Still;
    impl pgser::eval::Policy for Still {
        fn act(&self, _obs: &[f32], _goal: &[f32], n: usize) -> Vec<f32> {
            vec![0.0; 4 * n]
        }
    }
    Still
}

fn collect_ok(task: &str, episodes: usize, seed: u64, out: &Path, extra: &[&str]) -> String {
    let o = etl()
        .args(["collect", "--task", task, "--policy", "oracle", "--episodes", &episodes.to_string()])
        .args(["--seed", &seed.to_string(), "-o"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    text(&o.stderr)
}

/// `collect --policy oracle` is OGBench's data generator, episode for episode: its files equal,
/// array for array (all but each episode's first qvel row, a random velocity OGBench's reset
/// leaves and its first step zeroes), what the generator's loop writes run in ogbench's own
/// environment with numpy seeded S + i per episode (tests/py/make_ogbench_fixtures.py
/// --seed-per-episode): navigate with its goal switches and walls, and stitch in the teleport
/// maze with its teleports, train and val files.
#[test]
fn oracle_data_equal_ogbenchs_generator_run_in_ogbench() {
    let dir = tempfile::tempdir().unwrap();
    for (maze, kind, episodes, rows) in [("medium", "navigate", 3, 1001), ("teleport", "stitch", 20, 201)] {
        let name = format!("pointmaze-{maze}-{kind}-v0");
        let (ours, theirs) = (dir.path().join(format!("ours-{maze}")), dir.path().join(format!("theirs-{maze}")));
        std::fs::create_dir(&ours).unwrap();
        let file = ours.join(format!("{name}.npz"));
        let said = collect_ok(&name, episodes, 7, &file, &[]);
        assert!(said.contains(&format!("{episodes} episodes of pointmaze-{maze}-v0")), "{said}");
        let val = (episodes / 10).max(1).to_string();
        py_ok(
            "make_ogbench_fixtures.py",
            &[
                theirs.to_str().unwrap(),
                "--maze",
                maze,
                "--dataset-type",
                kind,
                "--train-episodes",
                &episodes.to_string(),
                "--val-episodes",
                &val,
                "--steps",
                &rows.to_string(),
                "--seed",
                "7",
                "--seed-per-episode",
            ],
        );
        let want = theirs.join(format!("{name}.npz"));
        let o = py_ok("check_ogbench.py", &["collected", want.to_str().unwrap(), file.to_str().unwrap()]);
        assert!(text(&o.stdout).contains("-val/qvel"), "{}", text(&o.stdout));
    }
}

/// In distribution, the oracle data are OGBench's: state coverage per cell, the actions' mean,
/// spread and clipping, step lengths, wall contacts and how far episodes go, each within 5
/// standard errors of the statistics of OGBench's own `generate_locomaze.py` (run unmodified,
/// unseeded, with the flags of its commands.sh: tests/fixtures/ogbench/generator_stats.json, made
/// by tests/py/ogbench_generator_stats.py reference), on as many episodes.
#[test]
fn oracle_data_match_ogbenchs_generator_in_distribution() {
    let dir = tempfile::tempdir().unwrap();
    let reference = fixture("generator_stats.json");
    for (name, episodes) in [
        ("pointmaze-medium-navigate-v0", 200),
        ("pointmaze-medium-stitch-v0", 1000),
        ("pointmaze-large-stitch-v0", 1000),
    ] {
        let file = dir.path().join(format!("{name}.npz"));
        collect_ok(name, episodes, 1000, &file, &[]);
        let o = py_ok(
            "ogbench_generator_stats.py",
            &["compare", reference.to_str().unwrap(), name, file.to_str().unwrap()],
        );
        let r: serde_json::Value = serde_json::from_str(&text(&o.stdout)).unwrap();
        assert!(r["statistics"].as_u64().unwrap() >= 30, "{r}");
    }
    // The comparison has power: a tenth less noise than OGBench's is caught.
    let file = dir.path().join("pointmaze-medium-stitch-v0.npz");
    collect_ok("pointmaze-medium-stitch-v0", 1000, 1000, &file, &["--noise", "0.4"]);
    let o = std::process::Command::new(python())
        .arg(repo().join("tests/py/ogbench_generator_stats.py"))
        .args(["compare", reference.to_str().unwrap(), "pointmaze-medium-stitch-v0", file.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!o.status.success() && text(&o.stderr).contains("action_clipped"), "{}", text(&o.stderr));
}

/// A `.parquet` from the oracle is the table `convert` makes of its `.npz`; the task is the
/// maze's with T = the recipe's rows, and the footer names the recipe and the seed.
#[test]
fn oracle_table_is_the_converted_npz() {
    let dir = tempfile::tempdir().unwrap();
    let (npz, direct, converted) =
        (dir.path().join("pointmaze-large-stitch-v0.npz"), dir.path().join("d.parquet"), dir.path().join("c.parquet"));
    collect_ok("pointmaze-large-stitch-v0", 30, 5, &npz, &[]);
    collect_ok("pointmaze-large-stitch-v0", 30, 5, &direct, &["--row-group-rows", "65536"]);
    convert_ok(&npz, &converted, &[]);
    assert_eq!(read_table(&direct).0.columns(), read_table(&converted).0.columns());
    let footer = pgser::table::read_footer(&direct).unwrap();
    assert_eq!((footer["task"].as_str(), footer["T"].as_u64()), (Some("pointmaze-large-v0"), Some(201)));
    assert_eq!(
        (footer["policy"].as_str(), footer["seed"].as_u64()),
        (Some("oracle:pointmaze-large-stitch-v0 noise 0.5"), Some(5))
    );
    // Bad requests: one line, no file.
    let fails = |task: &str, out: &Path, extra: &[&str], want: &str| {
        let o = etl()
            .args(["collect", "--task", task, "--policy", "oracle", "--episodes", "3", "-o"])
            .arg(out)
            .args(extra)
            .output()
            .unwrap();
        let e = text(&o.stderr);
        assert!(!o.status.success() && e.contains(want) && e.trim().lines().count() == 1, "{e}");
        assert!(!out.exists());
    };
    let out = dir.path().join("x.npz");
    fails("pointmaze-medium-v0", &out, &[], "name one, pointmaze-<maze>-navigate-v0");
    fails("FetchPush", &out, &[], "OGBench's PointMaze datasets");
    fails("pointmaze-medium-stitch-v0", &dir.path().join("x.pkl"), &[], "name it .npz");
    fails("pointmaze-medium-stitch-v0", &out, &["--epsilon", "0.1"], "--epsilon");
    fails("pointmaze-medium-stitch-v0", &out, &["--seed", "4294967295"], "below 2^32");
}

/// A fixture's `oracle_reps` member (float32, what ogbench's own environment computed).
fn oracle_reps(src: &Path) -> Vec<f32> {
    pgser::ogbench::npz::with_member(src, "oracle_reps", |r, _| {
        let mut b = Vec::new();
        r.read_to_end(&mut b)?;
        Ok(b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect())
    })
    .unwrap()
}

/// Cube datasets (tests/fixtures/ogbench/cube, from ogbench's own cube scenes by
/// tests/py/make_ogbench_random_fixtures.py): the goal is each cube's position, exactly what
/// OGBench's oracle representation holds row for row (`oracle_reps`, kept in the fixture), reached
/// when every cube is within 0.4 (0.04 m in the observation's ×10 units); and an exported file
/// loads in ogbench as the original.
#[test]
fn cube_goals_are_the_cubes_positions() {
    let dir = tempfile::tempdir().unwrap();
    for (scene, cubes) in [("single", 1usize), ("double", 2)] {
        let name = format!("cube-{scene}-play-v0");
        let src = fixture(&format!("cube/{name}.npz"));
        let table = dir.path().join(format!("{scene}.parquet"));
        let notes = convert_ok(&src, &table, &[]);
        assert!(notes.contains("for every cube"), "{notes}");
        let footer = pgser::table::read_footer(&table).unwrap();
        assert_eq!(
            (footer["task"].as_str(), footer["goal_dim"].as_u64(), footer["goal_metric"].as_str()),
            (Some(format!("cube-{scene}-v0").as_str()), Some(3 * cubes as u64), Some("each_object"))
        );
        assert_eq!((footer["success_threshold"].as_f64(), footer["T"].as_u64()), (Some(0.4), Some(21)));
        assert_eq!(
            achieved_goals(&table),
            oracle_reps(&src),
            "{name}: the goal is not OGBench's oracle representation"
        );

        let out = dir.path().join(format!("ours-{scene}"));
        std::fs::create_dir(&out).unwrap();
        for split in ["", "-val"] {
            let file = format!("{name}{split}.npz");
            let t = dir.path().join(format!("{scene}{split}.parquet"));
            convert_ok(&fixture(&format!("cube/{file}")), &t, &[]);
            let o =
                etl().arg("export").arg(&t).args(["--format", "ogbench", "-o"]).arg(out.join(&file)).output().unwrap();
            assert!(o.status.success(), "{}", text(&o.stderr));
        }
        let (ours, theirs) = (out.join(format!("{name}.npz")), src.clone());
        py_ok("check_ogbench.py", &["same", &name, theirs.to_str().unwrap(), ours.to_str().unwrap()]);
    }
    // A puzzle without its button states, and observations that are no cube scene's.
    let bad = dir.path().join("puzzle-3x3-play-v0.npz");
    std::fs::copy(fixture("cube/cube-single-play-v0.npz"), &bad).unwrap();
    let o = etl().arg("convert").arg(&bad).arg("-o").arg(dir.path().join("p.parquet")).output().unwrap();
    let said = text(&o.stderr);
    assert!(!o.status.success() && said.contains("puzzle-3x3-v0's goal is its button_states"), "{said}");
    assert!(!dir.path().join("p.parquet").exists());
    let o = etl()
        .arg("convert")
        .arg(fixture("cube/cube-single-play-v0.npz"))
        .args(["--task", "cube-double-v0", "-o"])
        .arg(dir.path().join("q.parquet"))
        .output()
        .unwrap();
    assert!(!o.status.success() && text(&o.stderr).contains("a scene of 2 cubes has 37"), "{}", text(&o.stderr));
}

/// A puzzle dataset (tests/fixtures/ogbench/puzzle, from ogbench's own puzzle-3x3 scene by
/// tests/py/make_ogbench_random_fixtures.py): the goal is the buttons' states, the file's int64
/// `button_states` as floats, exactly OGBench's oracle representation (`oracle_reps`, kept in the
/// fixture, and `add_oracle_reps`), reached when every button is in its target state; the file
/// comes back whole; and a file whose goal cannot be read is refused, leaving nothing.
#[test]
fn puzzle_goals_are_the_button_states() {
    let dir = tempfile::tempdir().unwrap();
    let src = fixture("puzzle/puzzle-3x3-play-v0.npz");
    let table = dir.path().join("p.parquet");
    let notes = convert_ok(&src, &table, &[]);
    assert!(notes.contains("goal = button_states[0:9]") && notes.contains("for every value"), "{notes}");
    let footer = pgser::table::read_footer(&table).unwrap();
    assert_eq!(
        (footer["task"].as_str(), footer["goal_dim"].as_u64(), footer["goal_metric"].as_str()),
        (Some("puzzle-3x3-v0"), Some(9), Some("each_value"))
    );
    assert_eq!(footer["success_threshold"].as_f64(), Some(0.5));
    let got = achieved_goals(&table);
    assert_eq!(got, oracle_reps(&src), "the goal is not OGBench's oracle representation");
    assert!(got.contains(&1.0) && got.contains(&0.0));
    let (back, _) = through_a_table(&src, dir.path(), "puzzle");
    same_file(&src, &back);

    // The regular layout (load_dataset's) has no button states for each episode's last state,
    // and a goal cannot be dropped.
    let fails = |input: &Path, extra: &[&str], want: &str| {
        let out = dir.path().join("bad.parquet");
        let o = etl().arg("convert").arg(input).args(extra).arg("-o").arg(&out).output().unwrap();
        let said = text(&o.stderr);
        assert!(!o.status.success() && said.contains(want), "{said}");
        assert!(!out.exists());
    };
    fails(&src, &["--drop", "button_states"], "--drop button_states: puzzle-3x3-v0's goal is its button_states");
    let regular = dir.path().join("regular").join("puzzle-3x3-play-v0.npz");
    std::fs::create_dir_all(regular.parent().unwrap()).unwrap();
    py_ok("check_ogbench.py", &["regular", src.to_str().unwrap(), regular.to_str().unwrap()]);
    fails(&regular, &[], "the regular layout (load_dataset's) holds for transitions only");
}

/// A scene dataset (tests/fixtures/ogbench/scene, from ogbench's own scene by
/// tests/py/make_ogbench_random_fixtures.py): the goal is OGBench's oracle representation row for
/// row (the cube's position, both buttons' states, the drawer's and the window's positions; the
/// fixture's `oracle_reps`, what `compute_oracle_observation` gave), read from the observation, so
/// the regular layout (no button states for an episode's last state) gives the same goals; each
/// part within its own tolerance; the file comes back whole.
#[test]
fn scene_goals_are_the_oracle_representation() {
    let dir = tempfile::tempdir().unwrap();
    let src = fixture("scene/scene-play-v0.npz");
    let table = dir.path().join("s.parquet");
    let notes = convert_ok(&src, &table, &[]);
    assert!(notes.contains("goal = observations[19:22] + [29:30] + [33:34] + [36:37] + [38:39]"), "{notes}");
    assert!(notes.contains("for every part"), "{notes}");
    let footer = pgser::table::read_footer(&table).unwrap();
    assert_eq!(
        (footer["task"].as_str(), footer["goal_dim"].as_u64(), footer["goal_metric"].as_str()),
        (Some("scene-v0"), Some(7), Some("scene"))
    );
    assert_eq!(footer["success_threshold"].as_f64(), Some(1.0));
    let got = achieved_goals(&table);
    assert_eq!(got, oracle_reps(&src), "the goal is not OGBench's oracle representation");
    // Both button states occur in the fixture, so the buttons' values are the states, not zeros.
    assert!(got.chunks(7).any(|g| g[3] == 1.0) && got.chunks(7).any(|g| g[3] == 0.0));
    let (back, _) = through_a_table(&src, dir.path(), "scene");
    same_file(&src, &back);

    let regular = dir.path().join("regular").join("scene-play-v0.npz");
    std::fs::create_dir_all(regular.parent().unwrap()).unwrap();
    py_ok("check_ogbench.py", &["regular", src.to_str().unwrap(), regular.to_str().unwrap()]);
    let from_regular = dir.path().join("r.parquet");
    convert_ok(&regular, &from_regular, &[]);
    assert_eq!(achieved_goals(&from_regular), got, "the regular layout's goals differ");

    // Observations of no scene's width are refused, naming the widths, and leave nothing.
    let out = dir.path().join("bad.parquet");
    let o = etl()
        .arg("convert")
        .arg(fixture("cube/cube-single-play-v0.npz"))
        .args(["--task", "scene-v0", "-o"])
        .arg(&out)
        .output()
        .unwrap();
    let said = text(&o.stderr);
    assert!(!o.status.success() && said.contains("(40 with one cube)"), "{said}");
    assert!(!out.exists());
}

/// `pgser-train eval` of several checkpoints: one JSON line each, naming it, with OGBench's five
/// tasks' success rates; each line what that checkpoint's evaluation alone gives.
#[test]
fn eval_reports_each_checkpoint_and_each_task() {
    let dir = tempfile::tempdir().unwrap();
    let table = dir.path().join("t.parquet");
    collect_ok("pointmaze-medium-stitch-v0", 20, 0, &table, &[]);
    let ckpt = dir.path().join("a.ckpt");
    let train = |args: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train")).args(args).output().unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout)
    };
    train(&[
        "--data",
        table.to_str().unwrap(),
        "-o",
        ckpt.to_str().unwrap(),
        "--updates",
        "20",
        "--batch-size",
        "16",
        "--eval-episodes",
        "0",
        "--seeds",
        "0",
        "1",
    ]);
    let (a, b) = (ckpt.join("s0.ckpt"), ckpt.join("s1.ckpt"));
    let both = train(&["eval", "--ckpt", a.to_str().unwrap(), b.to_str().unwrap(), "--episodes", "10", "--json"]);
    let lines: Vec<serde_json::Value> = both.lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(lines.len(), 2, "{both}");
    for (line, c) in lines.iter().zip([&a, &b]) {
        assert_eq!(line["checkpoint"].as_str(), c.to_str(), "{line}");
        assert_eq!(line["task_success"].as_array().unwrap().len(), 5, "{line}");
        let alone = train(&["eval", "--ckpt", c.to_str().unwrap(), "--episodes", "10", "--json"]);
        assert_eq!(&serde_json::from_str::<serde_json::Value>(&alone).unwrap(), line);
    }
}

/// OGBench's protocol scores a scripted oracle (the BFS direction without noise, and the goal
/// itself once in its cell) at 100 % on every task of the medium and large mazes: 5 tasks × 10
/// episodes, per task as OGBench reports.
#[test]
fn the_oracle_scores_full_marks_under_the_protocol() {
    use pgser::env::pointmaze::oracle_subgoal;
    struct Oracle(&'static str);
    impl pgser::eval::Policy for Oracle {
        fn act(&self, obs: &[f32], goal: &[f32], n: usize) -> Vec<f32> {
            (0..n)
                .flat_map(|k| {
                    let xy = [f64::from(obs[2 * k]), f64::from(obs[2 * k + 1])];
                    let g = [f64::from(goal[2 * k]), f64::from(goal[2 * k + 1])];
                    // In the goal's cell the oracle steers to the cell's centre; the goal itself
                    // may lie up to √2 from it, so there it heads for the goal.
                    let centre = oracle_subgoal(self.0, g, g).unwrap();
                    let home = (xy[0] - centre[0]).abs() <= 2.0 && (xy[1] - centre[1]).abs() <= 2.0;
                    let sub = if home { g } else { oracle_subgoal(self.0, xy, g).unwrap() };
                    let d = [sub[0] - xy[0], sub[1] - xy[1]];
                    let norm = (d[0] * d[0] + d[1] * d[1]).sqrt() + 1e-6;
                    [(d[0] / norm) as f32, (d[1] / norm) as f32]
                })
                .collect()
        }
    }
    for maze in ["pointmaze-medium-v0", "pointmaze-large-v0"] {
        let r = pgser::eval::evaluate(maze, &Oracle(maze), 50, 0).unwrap();
        assert_eq!((r.success_rate, r.task_success.clone()), (1.0, vec![1.0; 5]), "{maze}: {r:?}");
    }
}

/// `convert --full-goal`: the whole observation is the goal (OGBench's evaluation goals), with
/// the threshold the user gives; without one, and for a file that is not OGBench's, one line.
#[test]
fn full_observation_goals_on_request() {
    let dir = tempfile::tempdir().unwrap();
    let src = fixture("antmaze/antmaze-medium-navigate-v0.npz");
    let table = dir.path().join("full.parquet");
    let notes = convert_ok(&src, &table, &["--full-goal", "--threshold", "0.5"]);
    assert!(notes.contains("goal = observations[0:29], success within 0.5"), "{notes}");
    let footer = pgser::table::read_footer(&table).unwrap();
    assert_eq!((footer["goal_dim"].as_u64(), footer["goal_metric"].as_str()), (Some(29), Some("euclidean")));
    let (t, _) = read_table(&table);
    assert_eq!(t.column_by_name("achieved_goal").unwrap().to_data(), t.column_by_name("obs").unwrap().to_data());
    // By default the ant's goal is its x, y.
    let xy = dir.path().join("xy.parquet");
    convert_ok(&src, &xy, &[]);
    assert_eq!(pgser::table::read_footer(&xy).unwrap()["goal_dim"].as_u64(), Some(2));
    let fails = |input: &Path, extra: &[&str], want: &str| {
        let out = dir.path().join("bad.parquet");
        let o = etl().arg("convert").arg(input).arg("-o").arg(&out).args(extra).output().unwrap();
        let e = text(&o.stderr);
        assert!(!o.status.success() && e.contains(want) && e.trim().lines().count() == 1, "{want}: {e}");
        assert!(!out.exists());
    };
    fails(&src, &["--full-goal"], "--full-goal: give --threshold");
    fails(&repo().join("data/fetch_reach_expert_50.pkl"), &["--full-goal"], "OGBench files only");
}

/// `convert` then `export --format ogbench`, in a folder of its own under `dir`; returns the
/// exported file (named as the source) and convert's notes.
fn through_a_table(src: &Path, dir: &Path, tag: &str) -> (PathBuf, String) {
    let sub = dir.join(tag);
    std::fs::create_dir_all(&sub).unwrap();
    let table = sub.join("t.parquet");
    let notes = convert_ok(src, &table, &[]);
    let back = sub.join(src.file_name().unwrap());
    let o = etl().arg("export").arg(&table).args(["--format", "ogbench", "-o"]).arg(&back).output().unwrap();
    assert!(o.status.success(), "{tag}: {}", text(&o.stderr));
    (back, notes)
}

/// The file as numpy sees it, against the source: every member in the zip's order, its .npy
/// header (descr with its byte order, fortran_order, shape) and the bytes after it, and np.load's
/// arrays (tests/py/check_ogbench.py whole).
fn same_file(want: &Path, got: &Path) -> serde_json::Value {
    let o = py_ok("check_ogbench.py", &["whole", want.to_str().unwrap(), got.to_str().unwrap()]);
    last_json(&text(&o.stdout))
}

/// Written by OGBench's generator (terminals, qpos, qvel, oracle_reps) and by its loader
/// (compact: valids; regular: next_observations): every member comes back in its place, with its
/// header and its bytes, each episode's last action included.
#[test]
fn ogbench_files_of_every_layout_come_back_whole() {
    let dir = tempfile::tempdir().unwrap();
    for rel in [
        "pointmaze-medium-navigate-v0.npz",
        "antmaze/antmaze-medium-navigate-v0.npz",
        "cube/cube-double-play-v0.npz",
        "compact/pointmaze-medium-navigate-v0.npz",
        "regular/pointmaze-medium-navigate-v0.npz",
    ] {
        let src = fixture(rel);
        let (back, _) = through_a_table(&src, dir.path(), &rel.replace('/', "_"));
        let said = same_file(&src, &back);
        assert!(said["members"].as_array().unwrap().len() >= 5, "{rel}: {said}");
    }
}

/// A regular-layout file whose next_observations are not the observations shifted by a row (one
/// row moved by 0.25; before, it came back as the following observation without a word): kept
/// whole as a passthrough column, said in a note, and exported as it was.
#[test]
fn a_regular_files_own_next_observations_come_back() {
    let dir = tempfile::tempdir().unwrap();
    let src = dir.path().join("pointmaze-medium-navigate-v0.npz");
    let regular = fixture("regular/pointmaze-medium-navigate-v0.npz");
    py_ok(
        "check_ogbench.py",
        &["edit", regular.to_str().unwrap(), src.to_str().unwrap(), "next_observations[105]+=0.25"],
    );
    let (back, notes) = through_a_table(&src, dir.path(), "shifted");
    assert!(notes.contains("next_observations are more than the observations shifted"), "{notes}");
    assert!(notes.contains("episode 1's row 5 is not the observation after it"), "{notes}");
    same_file(&src, &back);
    let footer = pgser::table::read_footer(&dir.path().join("shifted/t.parquet")).unwrap();
    let cols: Vec<&str> =
        footer["passthrough"].as_array().unwrap().iter().map(|p| p["column"].as_str().unwrap()).collect();
    assert_eq!(cols, ["terminals", "qpos", "qvel", "next_observations"]);
    // The unedited file keeps none: its next observations are the observations.
    through_a_table(&regular, dir.path(), "plain");
    let footer = pgser::table::read_footer(&dir.path().join("plain/t.parquet")).unwrap();
    assert!(!footer["passthrough"].to_string().contains("next_observations"), "{footer}");
}

/// Observations and actions of two float types (and a float64 qpos beside float32 observations)
/// come back each in its own: before, both came back float64 where either was.
#[test]
fn each_array_comes_back_in_its_own_float_type() {
    let dir = tempfile::tempdir().unwrap();
    for (rel, changes) in [
        ("pointmaze-medium-navigate-v0.npz", &["actions=float64"][..]),
        ("pointmaze-medium-navigate-v0.npz", &["observations=float64"][..]),
        ("pointmaze-medium-navigate-v0.npz", &["qpos=float64"][..]),
        ("regular/pointmaze-medium-navigate-v0.npz", &["actions=float64"][..]),
        ("regular/pointmaze-medium-navigate-v0.npz", &["observations=float64", "next_observations=float64"][..]),
    ] {
        let tag = format!("{}-{}", rel.replace('/', "_"), changes.join("-"));
        let sub = dir.path().join(&tag);
        std::fs::create_dir_all(&sub).unwrap();
        let src = sub.join("pointmaze-medium-navigate-v0.npz");
        let from = fixture(rel);
        let mut args = vec!["edit", from.to_str().unwrap(), src.to_str().unwrap()];
        args.extend(changes);
        py_ok("check_ogbench.py", &args);
        let (back, _) = through_a_table(&src, &sub, "out");
        let said = same_file(&src, &back);
        let footer = pgser::table::read_footer(&sub.join("out/t.parquet")).unwrap();
        let float_bytes = &footer["sources"][0]["float_bytes"];
        if changes == ["actions=float64"] {
            assert_eq!(float_bytes, &serde_json::json!([4, 4, 4, 8]), "{tag}: {said}");
        }
    }
}
