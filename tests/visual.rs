//! OGBench's visual datasets in and out: uint8 image observations kept as images in the table
//! (`obs` a fixed-size binary column, the footer's `image_shape`), the goal OGBench's oracle
//! representation read from the file's state, `export` giving the file back member for member;
//! on files rendered by ogbench's own visual environments (tests/fixtures/ogbench/visual, made
//! by tests/py/make_ogbench_random_fixtures.py) and on small files written here for the faults.

mod common;

use std::io::Write;
use std::path::{Path, PathBuf};

use arrow_array::Array;
use arrow_array::cast::AsArray;
use common::*;
use pgser::dtype::Dtype;
use pgser::ogbench::npz;

fn visual(name: &str) -> PathBuf {
    repo().join("tests/fixtures/ogbench/visual").join(format!("{name}.npz"))
}

/// The rendered fixtures: (dataset, its environment).
const FIXTURES: [(&str, &str); 4] = [
    ("visual-cube-single-play-v0", "visual-cube-single-v0"),
    ("visual-puzzle-3x3-play-v0", "visual-puzzle-3x3-v0"),
    ("visual-antmaze-medium-navigate-v0", "visual-antmaze-medium-v0"),
    ("visual-scene-play-v0", "visual-scene-v0"),
];

fn convert_ok(input: &Path, out: &Path, extra: &[&str]) -> String {
    let o = etl().arg("convert").arg(input).arg("-o").arg(out).args(extra).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    text(&o.stderr)
}

/// A member's bytes, little-endian, as the file has them.
fn member(src: &Path, key: &str) -> (Vec<u8>, npz::Member) {
    npz::with_member(src, key, |r, m| {
        let mut b = Vec::new();
        r.read_to_end(&mut b)?;
        Ok((b, m.clone()))
    })
    .unwrap()
}

fn f32s(b: &[u8]) -> Vec<f32> {
    b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect()
}

/// Every visual fixture converts to a table whose `obs` rows are the file's images byte for
/// byte (a fixed-size binary column of 12,288 bytes, the footer's `image_shape` [64, 64, 3]),
/// and exports back to the same file, member for member, as numpy reads it; `verify`, `inspect`
/// and `query` read the table.
#[test]
fn visual_datasets_come_back_whole() {
    let dir = tempfile::tempdir().unwrap();
    for (name, env) in FIXTURES {
        let src = visual(name);
        let sub = dir.path().join(name);
        std::fs::create_dir_all(&sub).unwrap();
        let table = sub.join("t.parquet");
        convert_ok(&src, &table, &[]);
        let footer = pgser::table::read_footer(&table).unwrap();
        assert_eq!(footer["task"].as_str(), Some(env), "{name}");
        assert_eq!(footer["image_shape"], serde_json::json!([64, 64, 3]), "{name}");
        assert_eq!(footer["obs_dim"].as_u64(), Some(12_288), "{name}");
        let (t, _) = read_table(&table);
        let obs = t.column_by_name("obs").unwrap();
        assert_eq!(*obs.data_type(), arrow_schema::DataType::FixedSizeBinary(12_288), "{name}");
        let (images, m) = member(&src, "observations");
        assert_eq!((m.dtype, &m.shape[1..]), (Dtype::U8, &[64usize, 64, 3][..]), "{name}");
        assert_eq!(obs.as_fixed_size_binary().value_data(), &images[..], "{name}: the images are not the file's");
        let back = sub.join(format!("{name}.npz"));
        let o = etl().arg("export").arg(&table).args(["--format", "ogbench", "-o"]).arg(&back).output().unwrap();
        assert!(o.status.success(), "{name}: {}", text(&o.stderr));
        let said = py_ok("check_ogbench.py", &["whole", src.to_str().unwrap(), back.to_str().unwrap()]);
        let said = last_json(&text(&said.stdout));
        assert!(said["members"].as_array().unwrap().len() >= 5, "{name}: {said}");

        let o = etl().arg("verify").arg(&table).output().unwrap();
        assert!(o.status.success() && text(&o.stdout).starts_with("ok "), "{name}: {}", text(&o.stderr));
        let o = etl().arg("inspect").arg(&table).output().unwrap();
        assert!(o.status.success(), "{name}: {}", text(&o.stderr));
        let said = text(&o.stdout);
        assert!(said.contains("uint8 images 64×64×3") && said.contains("fixed_size_binary[12288]"), "{said}");
        let o = etl().args(["query", "SELECT COUNT(*) AS n FROM t WHERE step = 0"]).arg(&table).output().unwrap();
        assert!(o.status.success() && text(&o.stdout).ends_with("\n2\n"), "{name}: {}", text(&o.stderr));
    }
}

/// The goal is OGBench's oracle representation (`add_oracle_reps`), from the file's state: a
/// cube's position `(qpos[14:17] − (0.425, 0, 0)) · 10` in float64, as float32; a puzzle's
/// `button_states`; the ant's `qpos[0:2]`. Also within 1e-5 of the state observation's cube
/// position, which OGBench computes from the simulator's float64 state (the fixture's
/// `state_observations`).
#[test]
fn visual_goals_are_the_oracle_representation() {
    let dir = tempfile::tempdir().unwrap();
    let goals = |name: &str| {
        let table = dir.path().join(format!("{name}.parquet"));
        let notes = convert_ok(&visual(name), &table, &[]);
        (achieved_goals(&table), notes, pgser::table::read_footer(&table).unwrap())
    };

    let (got, notes, footer) = goals("visual-cube-single-play-v0");
    assert!(notes.contains("goal = qpos[14:17]"), "{notes}");
    assert_eq!((footer["goal_dim"].as_u64(), footer["goal_metric"].as_str()), (Some(3), Some("each_object")));
    assert_eq!(footer["success_threshold"].as_f64(), Some(0.4));
    let (qpos, m) = member(&visual("visual-cube-single-play-v0"), "qpos");
    let q = f32s(&qpos);
    let width = m.shape[1];
    let want: Vec<f32> = q
        .chunks_exact(width)
        .flat_map(|row| {
            [(row[14] as f64 - 0.425) * 10.0, (row[15] as f64) * 10.0, (row[16] as f64) * 10.0].map(|v| v as f32)
        })
        .collect();
    assert_eq!(got, want, "the cube's goal is not its oracle representation");
    if let Ok((state, sm)) = npz::with_member(&visual("visual-cube-single-play-v0"), "state_observations", |r, m| {
        let mut b = Vec::new();
        r.read_to_end(&mut b)?;
        Ok((b, m.clone()))
    }) {
        let s = f32s(&state);
        let from_state: Vec<f32> = s.chunks_exact(sm.shape[1]).flat_map(|o| o[19..22].to_vec()).collect();
        let worst = got.iter().zip(&from_state).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
        assert!(worst < 1e-5, "the goal is {worst} from the state observation's cube position");
    }

    let (got, _, footer) = goals("visual-puzzle-3x3-play-v0");
    assert_eq!((footer["goal_dim"].as_u64(), footer["goal_metric"].as_str()), (Some(9), Some("each_value")));
    let (buttons, m) = member(&visual("visual-puzzle-3x3-play-v0"), "button_states");
    assert_eq!(m.dtype, Dtype::I64);
    let want: Vec<f32> = buttons.chunks_exact(8).map(|c| i64::from_le_bytes(c.try_into().unwrap()) as f32).collect();
    assert_eq!(got, want);

    let (got, _, footer) = goals("visual-antmaze-medium-navigate-v0");
    assert_eq!((footer["goal_dim"].as_u64(), footer["success_threshold"].as_f64()), (Some(2), Some(0.5)));
    let (qpos, m) = member(&visual("visual-antmaze-medium-navigate-v0"), "qpos");
    let want: Vec<f32> = f32s(&qpos).chunks_exact(m.shape[1]).flat_map(|r| r[..2].to_vec()).collect();
    assert_eq!(got, want);
    // The ant's state observation starts with the same x, y (both float32 of the simulator's).
    let (state, sm) = member(&visual("visual-antmaze-medium-navigate-v0"), "state_observations");
    let from_state: Vec<f32> = f32s(&state).chunks_exact(sm.shape[1]).flat_map(|o| o[..2].to_vec()).collect();
    assert_eq!(got, from_state);

    // A scene: its cube from qpos (centred, scaled), its buttons' states, its drawer's and
    // window's qpos × 18 and × 15 (`add_oracle_reps`), the state scene's goal values.
    let (got, notes, footer) = goals("visual-scene-play-v0");
    assert!(notes.contains("goal = qpos[14:17] + button_states[0:2] + qpos[23:24] + [24:25]"), "{notes}");
    assert_eq!((footer["goal_dim"].as_u64(), footer["goal_metric"].as_str()), (Some(7), Some("scene")));
    let (qpos, m) = member(&visual("visual-scene-play-v0"), "qpos");
    let (buttons, _) = member(&visual("visual-scene-play-v0"), "button_states");
    let b: Vec<i64> = buttons.chunks_exact(8).map(|c| i64::from_le_bytes(c.try_into().unwrap())).collect();
    let want: Vec<f32> = f32s(&qpos)
        .chunks_exact(m.shape[1])
        .enumerate()
        .flat_map(|(r, q)| {
            let q = |j: usize| q[j] as f64;
            [
                (q(14) - 0.425) * 10.0,
                q(15) * 10.0,
                q(16) * 10.0,
                b[2 * r] as f64,
                b[2 * r + 1] as f64,
                q(23) * 18.0,
                q(24) * 15.0,
            ]
            .map(|v| v as f32)
        })
        .collect();
    assert_eq!(got, want, "the scene's goal is not its oracle representation");
    assert!(b.contains(&1) || want.chunks_exact(7).any(|g| g[5] != want[5]), "a fixture where nothing moves");
    // The state twin's observation holds the same values where the state scene's goal is.
    let (state, sm) = member(&visual("visual-scene-play-v0"), "state_observations");
    let from_state: Vec<f32> = f32s(&state)
        .chunks_exact(sm.shape[1])
        .flat_map(|o| [o[19], o[20], o[21], o[29], o[33], o[36], o[38]])
        .collect();
    let worst = got.iter().zip(&from_state).map(|(a, b)| (a - b).abs()).fold(0f32, f32::max);
    assert!(worst < 1e-5, "the scene's goal is {worst} from its state observation's");
}

/// A folder of visual shards (the cube fixture under two shard names) is one table folder of
/// images, which `verify` checks whole; a shard whose images are another shape is refused by
/// name, before anything is written.
#[test]
fn visual_shards_make_one_table_folder() {
    let dir = tempfile::tempdir().unwrap();
    let shards = dir.path().join("shards");
    std::fs::create_dir_all(&shards).unwrap();
    let name = "visual-cube-single-play-v0";
    for i in 0..2 {
        std::fs::copy(visual(name), shards.join(format!("{name}-{i}.npz"))).unwrap();
    }
    std::fs::copy(visual(&format!("{name}-val")), shards.join(format!("{name}-val.npz"))).unwrap();
    let out = dir.path().join("folder");
    convert_ok(&shards, &out, &[]);
    for folder in [out.clone(), out.join("val")] {
        let m: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(folder.join("manifest.json")).unwrap()).unwrap();
        assert_eq!(m["footer"]["image_shape"], serde_json::json!([64, 64, 3]), "{m}");
    }
    let o = etl().arg("verify").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));

    // The second shard's images 32 × 128 × 3: the same bytes a row, another shape.
    let other = dir.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::copy(visual(name), other.join(format!("{name}-0.npz"))).unwrap();
    let mut members = Vec::new();
    for key in ["observations", "actions", "terminals", "qpos", "qvel"] {
        let (b, m) = member(&visual(name), key);
        let shape = if key == "observations" { vec![m.shape[0], 32, 128, 3] } else { m.shape.clone() };
        members.push((key, m.dtype, shape, b));
    }
    write_npz(&other.join(format!("{name}-1.npz")), &members);
    let out = dir.path().join("bad");
    let o = etl().arg("convert").arg(&other).arg("-o").arg(&out).output().unwrap();
    let e = text(&o.stderr);
    assert!(
        !o.status.success()
            && e.contains(&format!("{name}-1.npz"))
            && e.contains("observations uint8 images 32×128×3 where")
            && e.contains("has observations uint8 images 64×64×3"),
        "{e}"
    );
    assert!(!out.exists(), "a folder was left");
}

/// Writes an .npz of `members` (key, dtype, shape, little-endian bytes) with pgser's writer.
fn write_npz(path: &Path, members: &[(&str, Dtype, Vec<usize>, Vec<u8>)]) {
    let mut w = npz::NpzWriter::new(std::fs::File::create(path).unwrap(), true);
    for (k, dt, shape, data) in members {
        w.start(k, *dt, shape).unwrap();
        w.write(data).unwrap();
    }
    w.finish().unwrap();
}

/// A small visual dataset: `episodes` of `rows` 4 × 4 × 3 images (each byte its row and place),
/// float32 actions, terminals, and a cube scene's qpos (21 values, the cube at row / 100).
fn small_visual(episodes: usize, rows: usize) -> Vec<(&'static str, Dtype, Vec<usize>, Vec<u8>)> {
    let n = episodes * rows;
    let images: Vec<u8> = (0..n * 48).map(|i| (i % 251) as u8).collect();
    let actions = vec![0u8; n * 5 * 4];
    let terminals: Vec<u8> = (0..n).map(|r| u8::from(r % rows == rows - 1)).collect();
    let qpos: Vec<u8> =
        (0..n).flat_map(|r| (0..21).map(move |i| (r * 21 + i) as f32 / 100.0)).flat_map(f32::to_le_bytes).collect();
    vec![
        ("observations", Dtype::U8, vec![n, 4, 4, 3], images),
        ("actions", Dtype::F32, vec![n, 5], actions),
        ("terminals", Dtype::BOOL, vec![n], terminals),
        ("qpos", Dtype::F32, vec![n, 21], qpos),
    ]
}

/// An .npz whose members are written raw (a .npy header then `data`, however short), for the
/// files no writer of numpy's makes.
fn write_raw_npz(path: &Path, members: &[(&str, &str, &str, &[u8])]) {
    let mut z = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    for (key, descr, shape, data) in members {
        let mut header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
        while (10 + header.len() + 1) % 64 != 0 {
            header.push(' ');
        }
        header.push('\n');
        z.start_file(format!("{key}.npy"), zip::write::FileOptions::default()).unwrap();
        z.write_all(b"\x93NUMPY\x01\x00").unwrap();
        z.write_all(&(header.len() as u16).to_le_bytes()).unwrap();
        z.write_all(header.as_bytes()).unwrap();
        z.write_all(data).unwrap();
    }
    z.finish().unwrap();
}

/// Each fault in one line naming the file, and nothing written: a cut-short image member,
/// float "images", `--full-goal`, a visual scene without its button states, a visual cube file
/// without its qpos; and an image table given to what reads observations as floats
/// (`pgser-train`, with and without a memory budget, and export to Minari).
#[test]
fn bad_visual_input_fails_in_one_line_and_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.parquet");
    let fails = |input: &Path, extra: &[&str], want: &str| convert_fails(input, &out, extra, want);
    let good = dir.path().join("visual-cube-single-play-v0.npz");
    write_npz(&good, &small_visual(3, 5));
    convert_ok(&good, &out, &[]);
    std::fs::remove_file(&out).unwrap();

    // The images cut short: 15 rows promised, 10 given.
    let m = small_visual(3, 5);
    let single = |tag: &str| {
        let sub = dir.path().join(tag);
        std::fs::create_dir_all(&sub).unwrap();
        sub.join("visual-cube-single-play-v0.npz")
    };
    let cut = single("cut");
    write_raw_npz(
        &cut,
        &[
            ("observations", "|u1", "(15, 4, 4, 3)", &m[0].3[..10 * 48]),
            ("actions", "<f4", "(15, 5)", &m[1].3),
            ("terminals", "|b1", "(15,)", &m[2].3),
            ("qpos", "<f4", "(15, 21)", &m[3].3),
        ],
    );
    fails(&cut, &[], "observations: 608 bytes, less than the 720 bytes of its [15, 4, 4, 3] uint8 array");
    // Float images: neither float rows nor uint8 images.
    let mut floats = small_visual(3, 5);
    floats[0] = ("observations", Dtype::F32, vec![15, 4, 2, 3], vec![0u8; 15 * 24 * 4]);
    let f = single("floats");
    write_npz(&f, &floats);
    fails(&f, &[], "pgser reads float rows [N, dim], or uint8 images [N, H, W, C]");
    fails(&good, &["--full-goal", "--threshold", "1"], "--full-goal: observations are images");
    let scene = dir.path().join("visual-scene-play-v0.npz");
    write_npz(&scene, &small_visual(3, 5));
    fails(
        &scene,
        &[],
        "visual-scene-v0's goal is its button_states (OGBench's oracle representation), and the file has none",
    );
    let no_qpos = single("no_qpos");
    write_npz(&no_qpos, &small_visual(3, 5)[..3]);
    fails(&no_qpos, &[], "goal is its qpos");

    // Readers of float observations refuse an image table by name.
    let table = dir.path().join("images.parquet");
    convert_ok(&good, &table, &[]);
    let refused = |o: std::process::Output, what: &str| {
        let e = text(&o.stderr);
        assert!(!o.status.success() && e.contains("images.parquet") && e.contains("4×4×3 uint8 images"), "{what}: {e}");
        assert_eq!(e.trim().lines().count(), 1, "{what}: {e}");
    };
    let ckpt = dir.path().join("a.ckpt");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", table.to_str().unwrap(), "-o", ckpt.to_str().unwrap(), "--updates", "2"])
        .output()
        .unwrap();
    refused(o, "pgser-train");
    assert!(!ckpt.exists());
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", table.to_str().unwrap(), "-o", ckpt.to_str().unwrap(), "--updates", "2"])
        .args(["--memory-budget", "50M"])
        .output()
        .unwrap();
    refused(o, "pgser-train --memory-budget");
    let minari = dir.path().join("visual-cube-v0");
    let o = etl()
        .arg("export")
        .arg(&table)
        .args(["--format", "minari", "--drop", "last_action", "-o"])
        .arg(&minari)
        .output()
        .unwrap();
    refused(o, "export --format minari");
    assert!(!minari.exists());
}

/// An image table's row groups hold whole episodes, at most 32 MiB of images (at least one
/// episode): OGBench's 64 × 64 × 3 images at 1001 steps are two episodes a group, where a
/// state table's 65,536 rows would be 65 episodes (805 MB).
#[test]
fn image_row_groups_are_bounded_by_bytes() {
    let dir = tempfile::tempdir().unwrap();
    // 12 episodes of 3 steps of 1 MiB images: 3 MiB an episode, so 10 episodes a group.
    let (episodes, rows, side) = (12usize, 3usize, 512usize);
    let n = episodes * rows;
    let bytes = side * side * 4;
    let images: Vec<u8> = (0..n * bytes).map(|i| (i % 253) as u8).collect();
    let terminals: Vec<u8> = (0..n).map(|r| u8::from(r % rows == rows - 1)).collect();
    let src = dir.path().join("visual-cube-single-play-v0.npz");
    write_npz(
        &src,
        &[
            ("observations", Dtype::U8, vec![n, side, side, 4], images.clone()),
            ("actions", Dtype::F32, vec![n, 5], vec![0u8; n * 20]),
            ("terminals", Dtype::BOOL, vec![n], terminals),
            ("qpos", Dtype::F32, vec![n, 21], vec![0u8; n * 21 * 4]),
        ],
    );
    let table = dir.path().join("t.parquet");
    convert_ok(&src, &table, &[]);
    let (t, groups) = read_table(&table);
    assert_eq!(groups, 2, "10 episodes, then 2");
    assert_eq!(t.column_by_name("obs").unwrap().as_fixed_size_binary().value_data(), &images[..]);
    let table = dir.path().join("small.parquet");
    convert_ok(&src, &table, &["--row-group-rows", "6"]);
    assert_eq!(read_table(&table).1, 6, "--row-group-rows still counts where it is the smaller");
}

/// A visual cube dataset of `episodes` of `rows` steps of `side` × `side` × 3 images whose bytes
/// are pseudo-random (every image its own), with actions, terminals and qpos.
fn random_visual(
    episodes: usize,
    rows: usize,
    side: usize,
    seed: u64,
) -> Vec<(&'static str, Dtype, Vec<usize>, Vec<u8>)> {
    let mut m = small_visual(episodes, rows);
    let n = episodes * rows;
    let mut x = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
    let images: Vec<u8> = (0..n * side * side * 3)
        .map(|_| {
            x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (x >> 56) as u8
        })
        .collect();
    m[0] = ("observations", Dtype::U8, vec![n, side, side, 3], images);
    m
}

/// A folder of `shards` visual shards, converted with `--row-group-rows rows_per_group`.
fn visual_folder(dir: &Path, shards: usize, (episodes, rows, side): (usize, usize, usize), group: usize) -> PathBuf {
    let src = dir.join("shards");
    std::fs::create_dir_all(&src).unwrap();
    for i in 0..shards {
        write_npz(
            &src.join(format!("visual-cube-single-play-v0-{i}.npz")),
            &random_visual(episodes, rows, side, i as u64),
        );
    }
    let out = dir.join("folder");
    convert_ok(&src, &out, &["--row-group-rows", &group.to_string()]);
    out
}

mod batches {
    //! pgser's visual batches against OGBench's rules, re-implemented here from
    //! `impls/utils/datasets.py` on flat indices: the compact layout's `terminals` (1 on an
    //! episode's last two steps), `initial_locs`, `get_stacked_observations` and
    //! `random_crop` (3 pixels of edge padding, then a cut at the row's offsets).

    use super::*;
    use pgser::sampler::ogbench::{Code, DatasetClass, OgbenchBatch, OgbenchConfig, OgbenchStream};
    use pgser::sampler::priority::PriorityConfig;
    use pgser::sampler::view::Budget;
    use pgser::trajectory::Episodes;

    /// OGBench's frames of the stack at flat index `idx` (oldest first), in a table of episodes
    /// of `t` steps, by its compact layout's trajectory starts.
    fn stack_indices(idx: usize, t: usize, episodes: usize, k: usize) -> Vec<usize> {
        let terminals: Vec<usize> = (0..episodes * t).filter(|i| i % t == t - 1 || i % t == t - 2).collect();
        let mut initial = vec![0];
        initial.extend(terminals[..terminals.len() - 1].iter().map(|i| i + 1));
        // initial_locs[np.searchsorted(initial_locs, idx, side='right') - 1]
        let start = initial[initial.partition_point(|&i| i <= idx) - 1];
        (0..k).rev().map(|i| idx.saturating_sub(i).max(start)).collect()
    }

    /// `random_crop` of an h × w × c image at (dy, dx): np.pad by 3 in edge mode, then the cut.
    fn crop(img: &[u8], [h, w, c]: [usize; 3], (dy, dx): (usize, usize)) -> Vec<u8> {
        let mut out = Vec::with_capacity(h * w * c);
        for y in 0..h {
            for x in 0..w {
                let sy = (y + dy).saturating_sub(3).min(h - 1);
                let sx = (x + dx).saturating_sub(3).min(w - 1);
                out.extend_from_slice(&img[(sy * w + sx) * c..][..c]);
            }
        }
        out
    }

    /// The image key `key` of batch `b` row by row, against the re-implementation from the
    /// table's images (`data`), at its provenance's (episode, step) (`at`), with the row's crop.
    fn check_key(b: &OgbenchBatch, data: &Episodes, key: &str, at: (&str, &str), next: usize, k: usize) {
        let [h, w, c] = [data.footer.image_shape[0], data.footer.image_shape[1], data.footer.image_shape[2]];
        let (values, shape) = b.u8(key).unwrap_or_else(|| panic!("{key} is not an image key"));
        assert_eq!(shape, &[h, w, c * k], "{key}");
        let (eps, steps) = (b.i64(at.0).unwrap(), b.i64(at.1).unwrap());
        let (cy, cx) = (b.i64("crop_y").unwrap(), b.i64("crop_x").unwrap());
        let row = h * w * c * k;
        for i in 0..b.n {
            let idx = eps[i] as usize * data.t + steps[i] as usize + next;
            let frames: Vec<&[u8]> =
                stack_indices(idx, data.t, data.n, k).into_iter().map(|j| data.image(j / data.t, j % data.t)).collect();
            // np.concatenate(frames, axis=-1)
            let mut stacked = Vec::with_capacity(row);
            for p in 0..h * w {
                for f in &frames {
                    stacked.extend_from_slice(&f[p * c..][..c]);
                }
            }
            let want =
                if cy[i] < 0 { stacked } else { crop(&stacked, [h, w, c * k], (cy[i] as usize, cx[i] as usize)) };
            assert_eq!(&values[i * row..][..row], &want[..], "{key}, row {i} (episode {}, step {})", eps[i], steps[i]);
        }
    }

    fn keys(class: DatasetClass) -> Vec<(&'static str, (&'static str, &'static str), usize)> {
        let goal = |k: &'static str, e: &'static str, s: &'static str| (k, (e, s), 0);
        let mut v = vec![("observations", ("episode", "step"), 0), ("next_observations", ("episode", "step"), 1)];
        match class {
            DatasetClass::GCDataset => v.extend([
                goal("value_goals", "value_goal_episode", "value_goal_step"),
                goal("actor_goals", "actor_goal_episode", "actor_goal_step"),
            ]),
            DatasetClass::HGCDataset => v.extend([
                goal("value_goals", "value_goal_episode", "value_goal_step"),
                goal("low_actor_goals", "low_actor_goal_episode", "low_actor_goal_step"),
                goal("high_actor_goals", "high_actor_goal_episode", "high_actor_goal_step"),
                goal("high_actor_targets", "high_actor_target_episode", "high_actor_target_step"),
            ]),
        }
        v
    }

    /// Every image key of both of OGBench's classes is the re-implementation's, byte for byte,
    /// stacked (3 frames, and 1) and cropped: held whole, and within a budget three fifths of the
    /// folder's (random goals' frames from the pool's reservoir); random goals are drawn, and
    /// batches come cropped and not.
    #[test]
    fn every_image_key_is_ogbench_stacked_and_cropped_whole_and_within_a_budget() {
        let dir = tempfile::tempdir().unwrap();
        let folder = visual_folder(dir.path(), 4, (6, 12, 8), 12);
        let data = Episodes::load_with_images(&folder).unwrap();
        assert_eq!((data.n, data.t, data.images.len()), (24, 12, 24 * 12 * 192));
        let whole = pgser::sampler::pool::Layout::open(&folder).unwrap().bytes();
        for class in [DatasetClass::GCDataset, DatasetClass::HGCDataset] {
            for k in [1usize, 3] {
                for budget in [Budget::Unbounded, Budget::bytes(whole * 3 / 5)] {
                    let cfg = OgbenchConfig {
                        dataset_class: class,
                        subgoal_steps: (class == DatasetClass::HGCDataset).then_some(4),
                        actor_p_randomgoal: 0.3,
                        actor_p_trajgoal: 0.7,
                        frame_stack: (k > 1).then_some(k as u64),
                        p_aug: 0.5,
                        ..OgbenchConfig::default()
                    };
                    let mut s = OgbenchStream::open(&folder, budget, cfg, &PriorityConfig::default(), 3).unwrap();
                    assert_eq!(s.pool_stats().is_some(), budget != Budget::Unbounded, "a pool within {budget:?}");
                    let (mut cropped, mut plain, mut random) = (0, 0, 0);
                    for _ in 0..12 {
                        let b = s.next_batch(64).unwrap();
                        for (key, at, next) in keys(class) {
                            check_key(&b, &data, key, at, next, k);
                        }
                        let cy = b.i64("crop_y").unwrap();
                        assert!(cy.iter().all(|&v| v >= 0) || cy.iter().all(|&v| v < 0), "one decision a batch");
                        if cy[0] >= 0 {
                            cropped += 1
                        } else {
                            plain += 1
                        }
                        random += b
                            .kinds("value_goal_kind")
                            .unwrap()
                            .iter()
                            .filter(|k| **k == pgser::sampler::ogbench::GoalKind::Random)
                            .count();
                    }
                    assert!(
                        cropped > 0 && plain > 0 && random > 0,
                        "{class:?} k={k} {budget:?}: {cropped} {plain} {random}"
                    );
                }
            }
        }
    }

    /// An evaluation batch is the training batch of the same index uncropped; the crop offsets
    /// are uniform on 0..=6 on both axes, one decision of `p_aug` a batch; the same seed gives the
    /// same bytes on 1 and 4 threads.
    #[test]
    fn crops_are_uniform_evaluation_batches_are_not_cropped_and_threads_change_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let folder = visual_folder(dir.path(), 2, (4, 10, 8), 20);
        let cfg = OgbenchConfig { p_aug: 0.5, frame_stack: Some(2), ..OgbenchConfig::default() };
        let open =
            || OgbenchStream::open(&folder, Budget::Unbounded, cfg.clone(), &PriorityConfig::default(), 5).unwrap();
        let mut s = open();
        let mut counts = [[0u64; 7]; 2];
        let mut cropped = 0;
        let batches = 400;
        for k in 0..batches {
            let b = s.batch_for(k, 32, false).unwrap();
            let e = s.batch_for(k, 32, true).unwrap();
            assert!(e.i64("crop_y").unwrap().iter().all(|&v| v == -1), "an evaluation batch is never cropped");
            for key in ["episode", "step", "value_goal_episode", "value_goal_step", "actor_goal_step"] {
                assert_eq!(b.i64(key), e.i64(key), "{key}: the same rows");
            }
            let (cy, cx) = (b.i64("crop_y").unwrap(), b.i64("crop_x").unwrap());
            if cy[0] >= 0 {
                cropped += 1;
                for i in 0..b.n {
                    counts[0][cy[i] as usize] += 1;
                    counts[1][cx[i] as usize] += 1;
                }
            } else {
                assert_eq!(b.u8("observations"), e.u8("observations"), "an uncropped batch is its evaluation batch");
            }
        }
        // Binomial(400, 0.5): 200 ± 5σ (σ = 10).
        assert!((cropped as i64 - 200).abs() < 50, "{cropped} of {batches} batches cropped");
        for axis in counts {
            let (stat, crit) = common::coded::chi_square(&axis);
            assert!(stat < crit, "offsets {axis:?}: χ² {stat} ≥ {crit}");
        }
        let at = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let mut s = open();
                (0..6).map(|_| s.next_batch(256).unwrap()).collect::<Vec<_>>()
            })
        };
        assert_eq!(at(1), at(4));
    }

    /// Bad pixel settings are refused in one line naming the value: p_aug outside [0, 1], a
    /// stack of 0 frames or longer than an episode, crops or stacks of a state table, and
    /// either with Horizon Reduction's classes, which read neither.
    #[test]
    fn bad_pixel_settings_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let folder = visual_folder(dir.path(), 1, (3, 6, 4), 12);
        let states = common::coded::folder(&dir.path().join("states"));
        let open = |path: &Path, cfg: OgbenchConfig| {
            OgbenchStream::open(path, Budget::Unbounded, cfg, &PriorityConfig::default(), 0)
                .err()
                .map(|e| format!("{e:#}"))
                .unwrap_or_else(|| panic!("taken: {path:?}"))
        };
        let og = OgbenchConfig::default();
        let hr = OgbenchConfig { code: Code::HorizonReduction, ..OgbenchConfig::default() };
        for (path, cfg, want) in [
            (&folder, OgbenchConfig { p_aug: 1.5, ..og.clone() }, "p_aug = 1.5: must be in [0, 1]"),
            (&folder, OgbenchConfig { frame_stack: Some(0), ..og.clone() }, "frame_stack = 0"),
            (
                &folder,
                OgbenchConfig { frame_stack: Some(7), ..og.clone() },
                "frame_stack = 7: longer than this table's episodes (6 observations each)",
            ),
            (
                &states,
                OgbenchConfig { p_aug: 0.5, ..og.clone() },
                "p_aug = 0.5: random crops are of images, and this table's observations are states",
            ),
            (
                &states,
                OgbenchConfig { frame_stack: Some(3), ..og.clone() },
                "frame_stack = 3: frames stacked are images",
            ),
            (
                &folder,
                OgbenchConfig { p_aug: 0.5, ..hr.clone() },
                "p_aug = 0.5: a key of OGBench's dataset classes, which Horizon Reduction's do not read",
            ),
            (&folder, OgbenchConfig { frame_stack: Some(2), ..hr }, "frame_stack = 2: a key of OGBench's"),
        ] {
            let e = open(path, cfg);
            assert!(e.contains(want) && e.lines().count() == 1, "{e}");
        }
        assert!(
            OgbenchStream::open(
                &folder,
                Budget::Unbounded,
                OgbenchConfig { frame_stack: Some(6), ..og },
                &PriorityConfig::default(),
                0
            )
            .is_ok()
        );
    }
}
