//! What every file-reading target shares: the fuzzer's bytes written to a file of this
//! process's own scratch folder, which the reader under test then opens by path as users do.

use std::path::PathBuf;

/// This process's scratch folder (one per fuzzing process, reused for every input).
pub fn scratch() -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pgser-fuzz-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// `data` as the file `name` in the scratch folder.
#[allow(dead_code)] // not every target reads a single file
pub fn file(name: &str, data: &[u8]) -> PathBuf {
    let p = scratch().join(name);
    std::fs::write(&p, data).unwrap();
    p
}
