//! The pickle reader on arbitrary bytes: it may refuse anything, but must never panic, hang or
//! allocate more than the input justifies. Arrays it accepts must be internally consistent.
#![no_main]

use libfuzzer_sys::fuzz_target;
use pgser::pickle::{Obj, Pickle};

fuzz_target!(|data: &[u8]| {
    if let Ok(p) = Pickle::parse(data) {
        if let Obj::Array(a) = p.get(p.root()) {
            assert_eq!(a.len() * a.dtype.size, a.data.len());
        }
    }
});
