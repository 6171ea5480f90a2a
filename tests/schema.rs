//! `schemas/*.json` are the machine-readable contract; what the code writes must match them.

mod common;

use std::fs::File;
use std::path::Path;

use arrow_schema::DataType;
use common::*;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use serde_json::Value;

fn json_type_ok(v: &Value, ty: &str) -> bool {
    match ty {
        "integer" => v.is_u64() || v.is_i64(),
        "number" => v.is_number(),
        "string" => v.is_string(),
        "array" => v.is_array(),
        "object" => v.is_object(),
        "boolean" => v.is_boolean(),
        other => panic!("schema names unknown JSON type {other}"),
    }
}

/// Check a written table against a schema file: columns in order, types, nullability, footer.
pub fn check_table_against_schema(table: &Path, schema_file: &Path) {
    let spec: Value = serde_json::from_str(&std::fs::read_to_string(schema_file).unwrap()).unwrap();
    let footer = pgser::table::read_footer(table).unwrap();
    let builder = ParquetRecordBatchReaderBuilder::try_new(File::open(table).unwrap()).unwrap();
    let schema = builder.schema();
    let cols = spec["columns"].as_array().unwrap();
    let names: Vec<&str> = schema.fields().iter().map(|f| f.name().as_str()).collect();
    let mut want: Vec<&str> = cols.iter().map(|c| c["name"].as_str().unwrap()).collect();
    // Passthrough columns follow, as the footer lists them (nullable, the schema's types).
    let passthrough = footer["passthrough"].as_array().cloned().unwrap_or_default();
    want.extend(passthrough.iter().map(|p| p["column"].as_str().unwrap()));
    assert_eq!(names, want, "column names/order");
    if !passthrough.is_empty() {
        let fields =
            spec["footer"]["passthrough_fields"].as_object().expect("the schema describes passthrough entries");
        for (p, field) in passthrough.iter().zip(schema.fields().iter().skip(cols.len())) {
            assert!(field.is_nullable(), "{} must be nullable", field.name());
            for (key, ty) in fields {
                assert!(json_type_ok(&p[key], ty.as_str().unwrap()), "passthrough {key} missing or not {ty}");
            }
        }
    }
    let float = footer["float_type"].as_str().unwrap_or("float32");
    for (field, col) in schema.fields().iter().zip(cols) {
        let name = field.name();
        assert_eq!(field.is_nullable(), col["nullable"].as_bool().unwrap(), "{name} nullability");
        match col["type"].as_str().unwrap() {
            "fixed_size_list" => {
                let DataType::FixedSizeList(item, n) = field.data_type() else {
                    panic!("{name} is {}", field.data_type())
                };
                let size_key = col["size"].as_str().unwrap();
                assert_eq!(*n as u64, footer[size_key].as_u64().unwrap(), "{name} size vs footer {size_key}");
                let want_item = match col["item"].as_str().unwrap() {
                    "float" => float.to_string(),
                    other => other.to_string(),
                };
                assert_eq!(item.data_type().to_string().to_lowercase(), want_item, "{name} item type");
                assert!(!item.is_nullable(), "{name} items must not be nullable");
            }
            scalar => assert_eq!(field.data_type().to_string().to_lowercase(), scalar, "{name} type"),
        }
    }
    let f = &spec["footer"];
    assert_eq!(footer["kind"], f["kind"]);
    assert_eq!(footer["schema_version"], spec["schema_version"]);
    for (key, ty) in f["required"].as_object().unwrap() {
        assert!(json_type_ok(&footer[key], ty.as_str().unwrap()), "footer {key} missing or not {ty}");
    }
    let known: Vec<&String> =
        f["required"].as_object().unwrap().keys().chain(f["optional"].as_object().unwrap().keys()).collect();
    for key in footer.as_object().unwrap().keys() {
        assert!(known.contains(&key), "footer key {key} is not in {}", schema_file.display());
    }
    // Footer values that are objects: their own required fields.
    for (key, fields) in f.get("object_fields").and_then(|o| o.as_object()).into_iter().flatten() {
        for (field, ty) in fields.as_object().unwrap() {
            assert!(
                json_type_ok(&footer[key][field], ty.as_str().unwrap()),
                "footer {key}.{field} missing or not {ty}"
            );
        }
    }
    let optional = f.get("optional_source_fields").and_then(|s| s.as_object());
    if let Some(fields) = f.get("source_fields").and_then(|s| s.as_object()) {
        for source in footer["sources"].as_array().into_iter().flatten() {
            for (key, ty) in fields {
                assert!(json_type_ok(&source[key], ty.as_str().unwrap()), "source {key} missing or not {ty}");
            }
            for key in source.as_object().unwrap().keys() {
                let ty = fields.get(key).or_else(|| optional.and_then(|o| o.get(key)));
                let ty = ty.unwrap_or_else(|| panic!("source key {key} is not in {}", schema_file.display()));
                assert!(json_type_ok(&source[key], ty.as_str().unwrap()), "source {key} is not {ty}");
            }
        }
    }
}

#[test]
fn passthrough_columns_follow_the_trajectory_schema() {
    // A WGCSL buffer's extra arrays and an OGBench file's qpos, qvel, terminals and last actions.
    let tmp = tempfile::tempdir().unwrap();
    for (input, args) in [
        ("tests/fixtures/passthrough/wgcsl_mixed.pkl", vec!["--task", "FetchReach"]),
        ("tests/fixtures/ogbench/antmaze/antmaze-medium-navigate-v0.npz", vec![]),
    ] {
        let out = tmp.path().join("t.parquet");
        let _ = std::fs::remove_file(&out);
        let o = etl().arg("convert").arg(repo().join(input)).arg("-o").arg(&out).args(args).output().unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        check_table_against_schema(&out, &repo().join("schemas/trajectory.json"));
    }
}

#[test]
fn convert_writes_the_trajectory_schema() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("t.parquet");
    let pkl = repo().join("tests/fixtures/np1_p4.pkl");
    for extra in [vec![], vec!["--float32".to_string()]] {
        let mut args = vec!["--task".to_string(), "FetchReach".to_string()];
        args.extend(extra);
        convert_ok(&[&pkl], &out, &args);
        check_table_against_schema(&out, &repo().join("schemas/trajectory.json"));
    }
}

#[test]
fn collect_writes_the_trajectory_schema() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("c.parquet");
    for extra in [&[][..], &["--float32"][..]] {
        let args =
            [&["--task", "FetchPush", "--policy", "random", "--episodes", "3", "-o", out.to_str().unwrap()][..], extra]
                .concat();
        collect_ok(&args, None);
        check_table_against_schema(&out, &repo().join("schemas/trajectory.json"));
    }
}

#[test]
fn score_writes_the_transition_schema() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, ckpt) = (tmp.path().join("t.parquet"), tmp.path().join("c.ckpt"));
    let pkl = repo().join("data/fetch_reach_expert_50.pkl");
    convert_ok(&[&pkl], &table, &["--task".to_string(), "FetchReach".to_string()]);
    let trained = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .args(["--data", table.to_str().unwrap(), "-o", ckpt.to_str().unwrap(), "--updates", "5", "--hidden", "16"])
        .args(["--batch-size", "32", "--eval-episodes", "0"])
        .output()
        .unwrap();
    assert!(trained.status.success(), "{}", text(&trained.stderr));
    let out = tmp.path().join("s.parquet");
    for extra in [&[][..], &["--include-original"][..]] {
        let o = etl()
            .args(["score", "--q", ckpt.to_str().unwrap(), "--data", table.to_str().unwrap()])
            .args(["-o", out.to_str().unwrap(), "--swaps", "2"])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        check_table_against_schema(&out, &repo().join("schemas/transition.json"));
    }
}

#[test]
fn batches_writes_the_batches_schema() {
    let tmp = tempfile::tempdir().unwrap();
    let (table, scored) = reach_tables(tmp.path());
    let out = tmp.path().join("b.parquet");
    for (data, extra) in [(&table, &["--swap", "random"][..]), (&scored, &["--is-beta", "0.4"][..])] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
            .args(["batches", "--data", data.to_str().unwrap(), "--count", "3", "--batch-size", "16", "-o"])
            .arg(&out)
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", text(&o.stderr));
        check_table_against_schema(&out, &repo().join("schemas/batches.json"));
    }
}

#[test]
fn a_minari_conversion_with_a_dropped_step_writes_the_trajectory_schema() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("m.parquet");
    let o = etl()
        .arg("convert")
        .arg(repo().join("tests/fixtures/minari/fetchreach-default-arrow-v0"))
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", text(&o.stderr));
    assert_eq!(pgser::table::read_footer(&out).unwrap()["sources"][0]["steps_dropped"], 1);
    check_table_against_schema(&out, &repo().join("schemas/trajectory.json"));
}
