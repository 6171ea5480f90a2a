//! The scored table reader (footer, checksums, the keys the sampler reads) on arbitrary bytes.
//! Seeds: `pgser-etl score` outputs.
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let p = common::file("s.parquet", data);
    let _ = pgser::score::ScoredTable::open(&p);
});
