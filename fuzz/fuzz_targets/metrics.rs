//! The metrics lines `--resume` reads back (`.metrics.jsonl`), on arbitrary bytes.
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let p = common::file("a.ckpt.metrics.jsonl", data);
    let _ = pgser::train::read_metrics::<pgser::train::MetricsLine>(&p);
});
