//! A WGCSL pickle, as `pgser-etl export --format wgcsl` writes it and `convert` reads it back,
//! on arbitrary bytes: the whole conversion (the pickle reader, the arrays' shapes, the task
//! inference), not only the parser of `pickle.rs`. Seeds: `data/*.pkl`, exported pickles.
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let input = common::file("e.pkl", data);
    let out = common::scratch().join("w.parquet");
    let opts = pgser::trajectory::ConvertOptions {
        inputs: vec![input],
        output: out.clone(),
        task: None,
        threshold: None,
        episodes: None,
        float32: false,
        allow_nonfinite: false,
        exact_length: false,
        row_group_rows: 65_536,
        command: String::new(),
    };
    let _ = pgser::convert::convert(&opts, &indicatif::ProgressBar::hidden());
    let _ = std::fs::remove_file(&out);
});
