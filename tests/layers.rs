//! The library's modules are layered, and imports run one way: down. This test reads `src/` and
//! fails on any `crate::X` (in code or doc comments) that names a module in the same or a higher
//! layer than the file's own module, and on a module missing from the table, so a new module
//! gets a place before it gets imports. The table is the one in `src/lib.rs`'s doc comment and
//! the README's module table; the binaries (`src/bin/`) sit above everything and are not checked.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Bottom layer first. A module may import only modules of lower layers.
const LAYERS: &[&[&str]] = &[
    &["dtype", "install"],
    &["cli", "nprandom", "output", "pickle", "progress", "task"],
    &["env", "table"],
    &["agent", "trajectory"],
    &["eval", "minari", "ogbench", "query", "swap", "verify"],
    &["collect", "convert", "score"],
    &["inspect", "sampler"],
    &["train"],
    &["report"],
    &["pipeline"],
];

fn layer_of() -> BTreeMap<&'static str, usize> {
    LAYERS.iter().enumerate().flat_map(|(i, ms)| ms.iter().map(move |m| (*m, i))).collect()
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module a file belongs to (`src/agent/td3.rs` → `agent`, `src/eval.rs` → `eval`).
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).unwrap();
    let first = rel.components().next()?.as_os_str().to_str()?.to_string();
    match first.as_str() {
        "bin" | "lib.rs" => None,
        _ => Some(first.trim_end_matches(".rs").to_string()),
    }
}

/// Every module named after `crate::` on a line: `crate::a::b` gives `a`, `crate::{a, b::c}` gives
/// `a` and `b`.
fn crate_refs(line: &str) -> Vec<String> {
    let mut found = Vec::new();
    let mut rest = line;
    while let Some(i) = rest.find("crate::") {
        let after = &rest[i + "crate::".len()..];
        if let Some(group) = after.strip_prefix('{') {
            let inner = group.split('}').next().unwrap_or("");
            found.extend(inner.split(',').map(|p| head(p.trim())).filter(|h| !h.is_empty()));
        } else {
            found.push(head(after));
        }
        rest = after;
    }
    found.retain(|m| !m.is_empty() && m.chars().next().is_some_and(|c| c.is_ascii_lowercase()));
    found
}

fn head(path: &str) -> String {
    path.chars().take_while(|c| c.is_ascii_alphanumeric() || *c == '_').collect()
}

#[test]
fn every_import_runs_down_the_layers() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let layers = layer_of();
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    files.sort();
    let (mut upward, mut unplaced) = (Vec::new(), std::collections::BTreeSet::new());
    for file in &files {
        let Some(module) = module_of(&src, file) else { continue };
        let Some(&own) = layers.get(module.as_str()) else {
            unplaced.insert(module);
            continue;
        };
        for (n, line) in std::fs::read_to_string(file).unwrap().lines().enumerate() {
            for used in crate_refs(line) {
                if used == module {
                    continue;
                }
                match layers.get(used.as_str()) {
                    Some(&l) if l < own => {}
                    Some(&l) => upward.push(format!(
                        "{}:{}: {module} (layer {own}) names crate::{used} (layer {l})",
                        file.strip_prefix(&src).unwrap().display(),
                        n + 1
                    )),
                    None => {
                        unplaced.insert(used);
                    }
                }
            }
        }
    }
    assert!(unplaced.is_empty(), "modules with no layer in tests/layers.rs (place them): {unplaced:?}");
    assert!(upward.is_empty(), "imports that run up or across the layers:\n{}", upward.join("\n"));
}

#[test]
fn the_reference_finder_reads_paths_and_groups() {
    assert_eq!(crate_refs("use crate::agent::HostActor;"), ["agent"]);
    assert_eq!(crate_refs("use crate::{collect, convert::check, report};"), ["collect", "convert", "report"]);
    assert_eq!(crate_refs("/// see [`crate::minari`] and crate::Trait"), ["minari"]);
    assert_eq!(crate_refs("let x = 1;"), Vec::<String>::new());
}
