//! pgser's tables in other tools: Python polars and DuckDB read every table pgser writes (a
//! trajectory table, a scored transition table, a results CSV) and see the values pgser reads,
//! bit for bit; and pgser reads a trajectory table that polars wrote as it reads its own.

mod common;

use std::path::Path;

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Float64Type, Int32Type, Int64Type};
use arrow_array::{Array, ArrayRef};
use arrow_schema::DataType;
use common::*;
use pgser::trajectory::Episodes;

/// A column as flat float64 (vectors row-major, NaN on null rows) and its null rows: the form
/// check_interop.py dumps each reader's view in.
fn flatten(col: &ArrayRef) -> (Vec<f64>, Vec<u8>) {
    let nulls: Vec<u8> = (0..col.len()).map(|i| u8::from(col.is_null(i))).collect();
    let scalars = |a: &ArrayRef| -> Vec<f64> {
        match a.data_type() {
            DataType::Float64 => a.as_primitive::<Float64Type>().values().to_vec(),
            DataType::Float32 => a.as_primitive::<Float32Type>().values().iter().map(|&v| f64::from(v)).collect(),
            DataType::Int64 => a.as_primitive::<Int64Type>().values().iter().map(|&v| v as f64).collect(),
            DataType::Int32 => a.as_primitive::<Int32Type>().values().iter().map(|&v| f64::from(v)).collect(),
            other => panic!("no such column type in pgser's tables: {other}"),
        }
    };
    let mut flat = match col.data_type() {
        DataType::FixedSizeList(_, _) => scalars(col.as_fixed_size_list().values()),
        _ => scalars(col),
    };
    let dim = flat.len() / col.len().max(1);
    for (r, &n) in nulls.iter().enumerate() {
        if n == 1 {
            flat[r * dim..(r + 1) * dim].fill(f64::NAN);
        }
    }
    (flat, nulls)
}

fn f64_file(path: &Path) -> Vec<f64> {
    let b = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    b.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect()
}

fn json_file(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Equal as bits, except that any NaN equals any NaN (a null row is NaN on both sides).
fn same_values(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
}

#[test]
fn polars_and_duckdb_read_every_table_pgser_writes() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (traj, scored) = reach_tables(d);
    let results = results_table(d);
    let dump = d.join("dump");
    std::fs::create_dir(&dump).unwrap();
    let arg = |name: &str, p: &Path| format!("{name}={}", p.display());
    py_ok(
        "check_interop.py",
        &[
            "dump",
            dump.to_str().unwrap(),
            &arg("trajectory", &traj),
            &arg("scored", &scored),
            &arg("results", &results.csv),
        ],
    );
    for (name, path) in [("trajectory", &traj), ("scored", &scored)] {
        let (b, _) = read_table(path);
        let names: Vec<&str> = b.schema_ref().fields().iter().map(|f| f.name().as_str()).collect();
        for reader in ["polars", "duckdb"] {
            let meta = json_file(&dump.join(format!("{name}.{reader}.json")));
            assert_eq!(meta["rows"], b.num_rows(), "{name} by {reader}");
            assert_eq!(meta["columns"], serde_json::json!(names), "{name} by {reader}");
            for (field, col) in b.schema_ref().fields().iter().zip(b.columns()) {
                let c = field.name();
                let (want, want_nulls) = flatten(col);
                let got = f64_file(&dump.join(format!("{name}.{reader}.{c}.f64")));
                let got_nulls = std::fs::read(dump.join(format!("{name}.{reader}.{c}.nulls"))).unwrap();
                assert_eq!(got_nulls, want_nulls, "{name}.{c}: null rows by {reader}");
                assert!(same_values(&got, &want), "{name}.{c}: values by {reader} differ from pgser's");
            }
        }
    }
    // The results CSV: every cell as pgser computed it (NaN std of one seed, empty p as null).
    for reader in ["polars", "duckdb"] {
        let rows = json_file(&dump.join(format!("results.{reader}.json")));
        let rows = rows.as_array().unwrap();
        assert_eq!(rows.len(), results.rows.len(), "{reader}");
        for (got, r) in rows.iter().zip(&results.rows) {
            let f = |x: f64| if x.is_nan() { serde_json::json!("NaN") } else { serde_json::json!(x) };
            let o = |x: Option<f64>| x.map_or(serde_json::Value::Null, f);
            let want = serde_json::json!({
                "task": r.task, "algo": r.algo, "variant": r.variant, "seeds": r.seeds,
                "paper_score_mean": f(r.paper_score_mean), "paper_score_std": f(r.paper_score_std),
                "success_mean": f(r.success_mean), "p_vs_baseline": o(r.p_vs_baseline), "p_vs_swap": o(r.p_vs_swap),
                "p_one_sided_vs_baseline": o(r.p_one_sided_vs_baseline), "p_one_sided_vs_swap": o(r.p_one_sided_vs_swap),
                "episodes": r.episodes, "paper_score_std_episodes": o(r.paper_score_std_episodes),
                "p_episodes_vs_baseline": o(r.p_episodes_vs_baseline), "p_episodes_vs_swap": o(r.p_episodes_vs_swap),
            });
            assert_eq!(got, &want, "results.csv by {reader}");
        }
    }
}

/// A trajectory table written by polars (its own Parquet writer, the `pgser` footer carried
/// over) loads as pgser's own does, and inspect sees the same table.
#[test]
fn pgser_reads_a_trajectory_table_polars_wrote() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let traj = d.join("reach.parquet");
    let data = repo().join("data");
    convert_ok(&[&data.join("fetch_reach_expert_50.pkl")], &traj, &[]);
    let by_polars = d.join("by_polars.parquet");
    py_ok("check_interop.py", &["write-traj", traj.to_str().unwrap(), by_polars.to_str().unwrap()]);
    assert_ne!(std::fs::read(&traj).unwrap(), std::fs::read(&by_polars).unwrap(), "another writer's bytes");

    let (ours, theirs) = (Episodes::load(&traj).unwrap(), Episodes::load(&by_polars).unwrap());
    assert_eq!((theirs.n, theirs.t), (50, 50));
    assert_eq!(theirs.footer, ours.footer);
    assert_eq!((&theirs.obs, &theirs.ag, &theirs.g, &theirs.u), (&ours.obs, &ours.ag, &ours.g, &ours.u));

    let (a, b) = (inspect_json(&traj), inspect_json(&by_polars));
    for k in ["rows", "episodes", "final_success", "success_rate", "footer"] {
        assert_eq!(a[k], b[k], "{k}");
    }
    for (x, y) in a["columns"].as_array().unwrap().iter().zip(b["columns"].as_array().unwrap()) {
        assert_eq!((&x["name"], &x["nulls"], &x["all"]["count"]), (&y["name"], &y["nulls"], &y["all"]["count"]));
        assert_eq!((&x["all"]["min"], &x["all"]["max"]), (&y["all"]["min"], &y["all"]["max"]), "{}", x["name"]);
    }
}
