//! A trajectory table's `pgser` footer on arbitrary JSON: a small valid table (WGCSL's
//! `info_is_success` fixture, converted once, with a passthrough column) written again with the
//! fuzzer's JSON as its footer, checksummed as pgser's writer does. The footer's own checksum
//! then holds, so what is tested is what a footer *says*: the readers that act on one (the
//! training loader, export in each format, inspect, verify) may refuse it, but must never panic,
//! hang or allocate more than the file justifies. Seeds: the footer of a converted table
//! (fuzz/seeds.sh). Inputs found to crash a reader are kept in tests/fixtures/fuzz/footer/,
//! which tests/passthrough.rs reads back.
#![no_main]

mod common;

use std::path::PathBuf;
use std::sync::OnceLock;

use arrow_array::RecordBatch;
use arrow_schema::SchemaRef;
use libfuzzer_sys::fuzz_target;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use pgser::minari::{ExportFormat, ExportOptions};

/// The base table's schema and rows, converted once per process.
fn base() -> &'static (SchemaRef, Vec<RecordBatch>) {
    static BASE: OnceLock<(SchemaRef, Vec<RecordBatch>)> = OnceLock::new();
    BASE.get_or_init(|| {
        let src = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/passthrough/wgcsl_info.pkl");
        let table = common::scratch().join("base.parquet");
        let _ = std::fs::remove_file(&table);
        let opts = pgser::trajectory::ConvertOptions {
            task: Some("FetchReach".into()),
            ..common::convert_options(src, table.clone())
        };
        pgser::convert::convert(&opts, &indicatif::ProgressBar::hidden()).expect("the base table converts");
        let builder = ParquetRecordBatchReaderBuilder::try_new(std::fs::File::open(&table).unwrap()).unwrap();
        let schema = builder.schema().clone();
        let batches = builder.build().unwrap().map(|b| b.unwrap()).collect();
        (schema, batches)
    })
}

fuzz_target!(|data: &[u8]| {
    let Ok(footer) = serde_json::from_slice::<serde_json::Value>(data) else { return };
    if !footer.is_object() {
        return;
    }
    let (schema, batches) = base();
    let p = common::scratch().join("f.parquet");
    let mut w = pgser::table::TableWriter::create(&p, schema.clone()).unwrap();
    w.write_row_groups(batches).unwrap();
    w.finish(&footer).unwrap();
    let _ = pgser::trajectory::Episodes::load(&p);
    let _ = pgser::verify::verify(&p);
    let _ = pgser::inspect::inspect(&p);
    for (format, name) in
        [(ExportFormat::Wgcsl, "e.pkl"), (ExportFormat::Minari, "e-v0"), (ExportFormat::Ogbench, "e.npz")]
    {
        let output = common::scratch().join(name);
        let opts = ExportOptions { table: p.clone(), format, output: output.clone(), drop: Vec::new() };
        if pgser::convert::export(&opts).is_ok() {
            if output.is_dir() {
                std::fs::remove_dir_all(&output).unwrap();
            } else {
                std::fs::remove_file(&output).unwrap();
            }
        }
    }
});
