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

/// `pgser-etl convert INPUT` with default settings, its output removed: what both the Minari and
/// the WGCSL targets put their input through.
#[allow(dead_code)] // only the targets that read through convert use it
pub fn convert(input: PathBuf) {
    let out = scratch().join("converted.parquet");
    let _ = pgser::convert::convert(&convert_options(input, out.clone()), &indicatif::ProgressBar::hidden());
    let _ = std::fs::remove_file(&out);
}

/// `pgser-etl convert INPUT -o OUTPUT`'s settings, with every flag at its default.
#[allow(dead_code)] // only the targets that read through convert use it
pub fn convert_options(input: PathBuf, output: PathBuf) -> pgser::trajectory::ConvertOptions {
    pgser::trajectory::ConvertOptions {
        inputs: vec![input],
        output,
        task: None,
        threshold: None,
        episodes: None,
        float32: false,
        allow_nonfinite: false,
        exact_length: false,
        row_group_rows: 65_536,
        full_goal: false,
        drop: Vec::new(),
        command: String::new(),
    }
}
