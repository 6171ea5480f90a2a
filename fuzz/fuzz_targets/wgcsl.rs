//! A WGCSL pickle, as `pgser-etl export --format wgcsl` writes it and `convert` reads it back,
//! on arbitrary bytes: the whole conversion (the pickle reader, the arrays' shapes, the task
//! inference), not only the parser of `pickle.rs`. Seeds: `data/*.pkl`, exported pickles.
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let input = common::file("e.pkl", data);
    common::convert(input);
});
