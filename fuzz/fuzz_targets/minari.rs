//! A Minari dataset folder read by `convert`, with one of its files replaced by arbitrary bytes:
//! the first input byte picks `data/metadata.json` (even) or episode 0's Arrow storage file
//! (odd), the rest is its content. The other files are the committed fixture's
//! (`tests/fixtures/minari/fetchreach-default-arrow-v0`), so the reader gets past them.
#![no_main]

mod common;

use std::path::{Path, PathBuf};

use libfuzzer_sys::fuzz_target;

fn copy(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        if e.path().is_dir() {
            copy(&e.path(), &to.join(e.file_name()));
        } else {
            std::fs::copy(e.path(), to.join(e.file_name())).unwrap();
        }
    }
}

fn dataset() -> PathBuf {
    let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/minari/fetchreach-default-arrow-v0");
    let dir = common::scratch().join("ds-v0");
    let _ = std::fs::remove_dir_all(&dir);
    copy(&fixture, &dir);
    dir
}

fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else { return };
    let dir = dataset();
    let target = if pick % 2 == 0 {
        dir.join("data/metadata.json")
    } else {
        let ep = dir.join("data/0");
        let arrow = std::fs::read_dir(&ep).unwrap().map(|e| e.unwrap().path()).find(|p| p.extension().is_some_and(|x| x == "arrow"));
        arrow.unwrap_or_else(|| ep.join("episode.arrow"))
    };
    std::fs::write(&target, rest).unwrap();
    common::convert(dir);
});
