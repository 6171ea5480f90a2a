//! What a `--resume` names when its settings are not the checkpoint's.

use anyhow::Result;

/// The settings in which `saved` and `given` differ, as `--flag: saved X, given Y` joined by `; `.
/// Why not both settings whole: they are some forty values each, and the one that differs is what
/// a user has to find, e.g. `--priority` when a run started before pgser 0.4 (default `q`) is
/// resumed by 0.4 (default `rank`) without `--priority q`. The settings are clap structs
/// flattened into one command line, so each leaf's name is unique and is its flag's.
pub(crate) fn differing_settings<T: serde::Serialize>(saved: &T, given: &T) -> Result<String> {
    fn walk(name: &str, a: &serde_json::Value, b: &serde_json::Value, out: &mut Vec<String>) {
        use serde_json::Value::Object;
        match (a, b) {
            (Object(x), Object(y)) => {
                let keys: std::collections::BTreeSet<&String> = x.keys().chain(y.keys()).collect();
                let null = serde_json::Value::Null;
                for k in keys {
                    walk(k, x.get(k).unwrap_or(&null), y.get(k).unwrap_or(&null), out);
                }
            }
            _ if a != b => out.push(format!("--{}: saved {a}, given {b}", name.replace('_', "-"))),
            _ => {}
        }
    }
    let mut out = Vec::new();
    walk("", &serde_json::to_value(saved)?, &serde_json::to_value(given)?, &mut out);
    Ok(out.join("; "))
}
