//! The trajectory table reader (footer, checksums, columns, episode layout) on arbitrary bytes:
//! it may refuse anything, but must never panic, hang or allocate more than the file justifies.
//! Seeds: any table `pgser-etl convert` writes (`data/`, `tests/fixtures/`).
#![no_main]

mod common;

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let p = common::file("t.parquet", data);
    if let Ok(e) = pgser::trajectory::Episodes::load(&p) {
        // What it accepts is consistent: every array holds whole episodes.
        assert_eq!(e.obs.len(), e.n * e.t * e.task.obs_dim);
        assert_eq!(e.u.len(), e.n * (e.t - 1) * e.task.act_dim);
    }
    let _ = pgser::verify::verify(&p);
});
