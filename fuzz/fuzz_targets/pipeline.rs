//! A pipeline file (TOML) on arbitrary bytes: loaded, checked and planned, never run. Seeds:
//! `pipelines/*.toml`.
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let p = common::file("p.toml", data);
    if let Ok(pipeline) = pgser::pipeline::Pipeline::load(&p) {
        let _ = pgser::pipeline::plan(&pipeline);
    }
});
