//! `Episodes::load`: trajectory tables round-trip into memory as f32, and bad tables are refused
//! with one line naming the file and where.

mod common;

use std::path::Path;
use std::sync::Arc;

use arrow_array::{ArrayRef, FixedSizeListArray, Float32Array, Int32Array, Int64Array, RecordBatch};
use arrow_buffer::NullBuffer;
use arrow_schema::{DataType, Field, Schema};
use parquet::arrow::ArrowWriter;
use parquet::file::metadata::KeyValue;
use pgser::table::FOOTER_KEY;
use pgser::task::Task;
use pgser::trajectory::{
    EpisodeArrays, Episodes, FloatArray, FloatType, Footer, TrajectoryWriter, WriterOptions, vector_field,
};

const T: usize = 4;

/// T = 4, obs 3, goal 2, act 1.
fn task() -> Task {
    Task::custom("Tiny", T, 3, 2, 1, 0.1)
}

/// A value unique to (WGCSL key, episode, step, index) that float32 cannot hold exactly.
fn value(key: usize, e: usize, s: usize, i: usize) -> f64 {
    key as f64 * 1000.0 + e as f64 * 10.0 + s as f64 + i as f64 * 0.1 + 1.0 / 3.0
}

/// The WGCSL arrays o, ag, u, g of `n` episodes as little-endian bytes of `size` (4 or 8).
fn source(n: usize, size: usize, tweak: impl Fn(usize, usize, usize, usize) -> Option<f64>) -> [Vec<u8>; 4] {
    let shape = [(T, 3), (T, 2), (T - 1, 1), (T - 1, 2)];
    std::array::from_fn(|k| {
        let (steps, dim) = shape[k];
        let mut bytes = Vec::new();
        for (e, s, i) in (0..n).flat_map(|e| (0..steps).flat_map(move |s| (0..dim).map(move |i| (e, s, i)))) {
            let v = tweak(k, e, s, i).unwrap_or(value(k, e, s, i));
            if size == 8 { bytes.extend(v.to_le_bytes()) } else { bytes.extend((v as f32).to_le_bytes()) }
        }
        bytes
    })
}

/// Write `data` (episodes of element `size`) as a table of `float` with the crate's writer.
fn write(path: &Path, data: &[Vec<u8>; 4], size: usize, float: FloatType, nonfinite: bool) {
    let shape = [(T, 3), (T, 2), (T - 1, 1), (T - 1, 2)];
    let n = data[0].len() / (T * 3 * size);
    let arrays = std::array::from_fn(|k| FloatArray { data: &data[k], size, steps: shape[k].0, dim: shape[k].1 });
    let src =
        EpisodeArrays { origin: "test".into(), keys: pgser::trajectory::KEYS, arrays, episodes: n, extras: Vec::new() };
    // 7 episodes per row group: groups and the reader's 64-episode batches fall out of step.
    let options = WriterOptions { allow_nonfinite: nonfinite, ..WriterOptions::new(7 * T) };
    let mut w = TrajectoryWriter::create(path, &task(), float, options).unwrap();
    w.append(&src, 0, n).unwrap();
    w.finish(&Footer::new(&task(), float, n, "test".into())).unwrap();
}

fn check_values(eps: &Episodes, n: usize, want: impl Fn(usize, usize, usize, usize) -> f32) {
    assert_eq!((eps.n, eps.t, eps.transitions()), (n, T, n * (T - 1)));
    assert_eq!((eps.obs.len(), eps.ag.len(), eps.g.len(), eps.u.len()), (n * T * 3, n * T * 2, n * 6, n * 3));
    assert_eq!(eps.task, task());
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for e in 0..n {
        for s in 0..T {
            assert_eq!(bits(eps.obs(e, s)), (0..3).map(|i| want(0, e, s, i).to_bits()).collect::<Vec<_>>());
            assert_eq!(bits(eps.ag(e, s)), (0..2).map(|i| want(1, e, s, i).to_bits()).collect::<Vec<_>>());
            if s < T - 1 {
                assert_eq!(bits(eps.action(e, s)), [want(2, e, s, 0).to_bits()]);
                assert_eq!(bits(eps.goal(e, s)), (0..2).map(|i| want(3, e, s, i).to_bits()).collect::<Vec<_>>());
            }
        }
    }
    let i = 5 * (T - 1) + 2;
    assert_eq!(eps.transition(i), (5, 2));
}

#[test]
fn float32_table_round_trips_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f32.parquet");
    write(&path, &source(150, 4, |_, _, _, _| None), 4, FloatType::Float32, false);
    let eps = Episodes::load(&path).unwrap();
    check_values(&eps, 150, |k, e, s, i| value(k, e, s, i) as f32);
    // Episode-major layout: obs of episode 2, step 1 start at (2·T + 1)·obs_dim.
    assert_eq!(eps.obs((2 * T + 1) / T, 1)[0], eps.obs[(2 * T + 1) * 3]);
}

#[test]
fn float64_table_loads_as_f32_by_cast() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f64.parquet");
    write(&path, &source(9, 8, |_, _, _, _| None), 8, FloatType::Float64, false);
    let eps = Episodes::load(&path).unwrap();
    assert_eq!(eps.footer.float_type, FloatType::Float64);
    check_values(&eps, 9, |k, e, s, i| value(k, e, s, i) as f32);
}

/// A committed numpy pickle through `pgser-etl convert`, as float64 and as `--float32`: both
/// load to the same f32 bits (the converter's down-cast is `as f32` too), in the pickle's shape.
#[test]
fn converted_pickles_load_alike_at_either_float_type() {
    let dir = tempfile::tempdir().unwrap();
    let pkl = common::repo().join("tests/fixtures/np2_p4.pkl");
    let (f64_table, f32_table) = (dir.path().join("f64.parquet"), dir.path().join("f32.parquet"));
    let task = ["--task".to_string(), "FetchReach".to_string()];
    common::convert_ok(&[&pkl], &f64_table, &task);
    common::convert_ok(&[&pkl], &f32_table, &[task[0].clone(), task[1].clone(), "--float32".into()]);
    let (a, b) = (Episodes::load(&f64_table).unwrap(), Episodes::load(&f32_table).unwrap());
    assert_eq!((a.n, a.t, a.task.name.as_str(), a.footer.float_type), (3, 50, "FetchReach", FloatType::Float64));
    assert_eq!((b.footer.float_type, a.obs.len(), a.g.len(), a.u.len()), (FloatType::Float32, 1500, 441, 588));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    for (x, y) in [(&a.obs, &b.obs), (&a.ag, &b.ag), (&a.g, &b.g), (&a.u, &b.u)] {
        assert_eq!(bits(x), bits(y));
    }
}

/// Load `path`, which must fail with one line naming the file; returns the message.
fn load_err(path: &Path) -> String {
    let e = Episodes::load(path).unwrap_err().to_string();
    assert!(!e.contains('\n') && e.starts_with(&path.display().to_string()), "{e}");
    e
}

#[test]
fn non_finite_values_are_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.parquet");
    let nan = |k, e, s, i| (k == 1 && e == 3 && s == 2 && i == 1).then_some(f64::NAN);
    write(&path, &source(5, 8, nan), 8, FloatType::Float64, true);
    let e = load_err(&path);
    assert!(e.contains("episode 3, step 2") && e.contains("`achieved_goal`[1]") && e.contains("NaN"), "{e}");

    let huge = |k, e, s, i| (k == 0 && e == 1 && s == 3 && i == 0).then_some(1e39);
    write(&path, &source(5, 8, huge), 8, FloatType::Float64, true);
    let e = load_err(&path);
    assert!(e.contains("row 7 (episode 1, step 3)") && e.contains("1e39 overflows float32") && e.contains("`obs`"));
}

/// Columns of a hand-made Float32 table with the given (episode, step) rows; desired_goal and
/// action null on step T − 1.
fn columns(keys: &[(i64, i32)]) -> Vec<(Field, ArrayRef)> {
    let n = keys.len();
    let not_last: Vec<bool> = keys.iter().map(|k| k.1 as usize != T - 1).collect();
    let mut cols: Vec<(Field, ArrayRef)> = vec![
        (
            Field::new("episode", DataType::Int64, false),
            Arc::new(Int64Array::from_iter_values(keys.iter().map(|k| k.0))),
        ),
        (Field::new("step", DataType::Int32, false), Arc::new(Int32Array::from_iter_values(keys.iter().map(|k| k.1)))),
    ];
    for (name, dim, nullable) in
        [("obs", 3, false), ("achieved_goal", 2, false), ("desired_goal", 2, true), ("action", 1, true)]
    {
        cols.push(list(name, dim, n, nullable.then(|| not_last.clone())));
    }
    cols
}

fn list(name: &str, dim: usize, rows: usize, valid: Option<Vec<bool>>) -> (Field, ArrayRef) {
    let values = Arc::new(Float32Array::from_iter_values((0..rows * dim).map(|i| i as f32 * 0.5)));
    let item = Arc::new(Field::new("item", DataType::Float32, false));
    let field = vector_field(name, FloatType::Float32, dim, valid.is_some());
    (field, Arc::new(FixedSizeListArray::new(item, dim as i32, values, valid.map(NullBuffer::from))))
}

fn dense(episodes: usize) -> Vec<(i64, i32)> {
    (0..episodes * T).map(|r| ((r / T) as i64, (r % T) as i32)).collect()
}

fn footer(episodes: usize) -> serde_json::Value {
    serde_json::to_value(Footer::new(&task(), FloatType::Float32, episodes, "test".into())).unwrap()
}

fn write_hand(path: &Path, cols: Vec<(Field, ArrayRef)>, footer: Option<serde_json::Value>) {
    let (fields, arrays): (Vec<Field>, Vec<ArrayRef>) = cols.into_iter().unzip();
    let batch = RecordBatch::try_new(Arc::new(Schema::new(fields)), arrays).unwrap();
    let mut w = ArrowWriter::try_new(std::fs::File::create(path).unwrap(), batch.schema(), None).unwrap();
    w.write(&batch).unwrap();
    if let Some(f) = footer {
        w.append_key_value_metadata(KeyValue::new(FOOTER_KEY.to_string(), f.to_string()));
    }
    w.close().unwrap();
}

#[test]
fn a_hand_made_table_loads() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("ok.parquet");
    write_hand(&path, columns(&dense(3)), Some(footer(3)));
    let eps = Episodes::load(&path).unwrap();
    assert_eq!((eps.n, eps.transitions()), (3, 9));
    assert_eq!(eps.goal(1, 0), [4.0, 4.5]); // row 4: list values 8 and 9, times 0.5
    assert_eq!(eps.action(2, 2), [10.0 * 0.5]);
}

#[test]
fn tables_of_another_kind_or_none_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    let mut f = footer(2);
    f["kind"] = "transition".into();
    write_hand(&path, columns(&dense(2)), Some(f));
    let e = load_err(&path);
    assert!(e.contains("a transition table, not a trajectory table") && e.contains("pgser-etl convert"), "{e}");

    write_hand(&path, columns(&dense(2)), None);
    assert!(load_err(&path).contains("no `pgser` footer"));
}

#[test]
fn episodes_must_be_dense_and_steps_ordered() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    let mut keys = dense(3);
    keys.iter_mut().skip(T).for_each(|k| k.0 += 1); // 0, 2, 3
    write_hand(&path, columns(&keys), Some(footer(3)));
    let e = load_err(&path);
    assert!(e.contains("row 4: episode 2 (step 0) where episode 1 was expected") && e.contains("dense"), "{e}");

    let mut keys = dense(2);
    keys.swap(5, 6); // episode 1: steps 0, 2, 1, 3
    write_hand(&path, columns(&keys), Some(footer(2)));
    let e = load_err(&path);
    assert!(e.contains("row 5 (episode 1): step 2 where 1 was expected"), "{e}");

    let keys: Vec<_> = dense(3).into_iter().filter(|&(e, s)| !(e == 1 && s == 3)).chain([(3, 0)]).collect();
    write_hand(&path, columns(&keys), Some(footer(3)));
    let e = load_err(&path);
    assert!(e.contains("row 7: episode 1 ends after 3 steps"), "{e}");
}

#[test]
fn a_null_action_before_the_last_step_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    let mut cols = columns(&dense(2));
    let mut valid: Vec<bool> = (0..2 * T).map(|r| r % T != T - 1).collect();
    valid[5] = false;
    cols[5] = list("action", 1, 2 * T, Some(valid));
    write_hand(&path, cols, Some(footer(2)));
    let e = load_err(&path);
    assert!(e.contains("row 5 (episode 1, step 1): `action` is null; only the last step"), "{e}");
}

#[test]
fn columns_must_match_the_footer() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("t.parquet");
    let mut cols = columns(&dense(2));
    cols[2] = list("obs", 4, 2 * T, None);
    write_hand(&path, cols, Some(footer(2)));
    let e = load_err(&path);
    assert!(e.contains("`obs` holds lists of 4 values but the footer says obs_dim = 3"), "{e}");

    let mut cols = columns(&dense(2));
    cols.remove(4);
    write_hand(&path, cols, Some(footer(2)));
    assert!(load_err(&path).contains("no `desired_goal` column"));

    write_hand(&path, columns(&dense(2)), Some(footer(3)));
    let e = load_err(&path);
    assert!(e.contains("the file holds 8 rows but its footer says 12 (3 episodes × T = 4)"), "{e}");
}
