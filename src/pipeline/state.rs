//! Step records: `OUT/.pipeline/<step>.json` = the step's key and its outputs' sha256.
//!
//! The key hashes the step's name, parameters and its inputs' *contents*, not their dates:
//! copying an out folder, touching a file or re-creating an identical output changes nothing,
//! while any changed byte upstream reruns exactly the steps that read it.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use sha2::Digest;

use super::Step;
use crate::output::{AtomicFile, hex, sha256_file};

/// Bump when the meaning of a key changes, so old records are not trusted.
const FORMAT: u32 = 1;

#[derive(Serialize, Deserialize)]
struct Record {
    format: u32,
    key: String,
    /// Output path (as planned) → sha256 when the step finished.
    outputs: BTreeMap<String, String>,
    seconds: f64,
    pgser_version: String,
}

/// sha256 of files, computed once per run per (path, size, mtime).
#[derive(Default)]
pub struct Hashes {
    seen: HashMap<PathBuf, (u64, SystemTime, String)>,
}

impl Hashes {
    pub fn sha256(&mut self, path: &Path) -> Result<Option<String>> {
        let Ok(meta) = std::fs::metadata(path) else { return Ok(None) };
        let stamp = (meta.len(), meta.modified().with_context(|| format!("{}: no modification time", path.display()))?);
        if let Some((len, time, sha)) = self.seen.get(path)
            && (*len, *time) == stamp
        {
            return Ok(Some(sha.clone()));
        }
        let sha = sha256_file(path)?;
        self.seen.insert(path.to_path_buf(), (stamp.0, stamp.1, sha.clone()));
        Ok(Some(sha))
    }

    /// The step's key, or None while one of its inputs does not exist (yet).
    pub fn key(&mut self, step: &Step) -> Result<Option<String>> {
        let mut inputs = Vec::new();
        for p in &step.inputs {
            match self.sha256(p)? {
                Some(sha) => inputs.push(sha),
                None => return Ok(None),
            }
        }
        let text = serde_json::to_string(&serde_json::json!({
            "format": FORMAT, "step": step.name, "params": step.params, "inputs": inputs,
        }))?;
        Ok(Some(hex(&sha2::Sha256::digest(text.as_bytes()))))
    }
}

fn record_path(out: &Path, step: &Step) -> PathBuf {
    out.join(".pipeline").join(format!("{}.json", step.name.replace(' ', "_")))
}

/// The key in the step's record, if it has one.
pub fn recorded_key(out: &Path, step: &Step) -> Option<String> {
    let text = std::fs::read_to_string(record_path(out, step)).ok()?;
    serde_json::from_str::<Record>(&text).ok().map(|r| r.key)
}

/// Whether the step's record has `key` and its outputs are the bytes it wrote.
pub fn up_to_date(out: &Path, step: &Step, key: &str, hashes: &mut Hashes) -> bool {
    let Ok(text) = std::fs::read_to_string(record_path(out, step)) else { return false };
    let Ok(r) = serde_json::from_str::<Record>(&text) else { return false };
    if r.format != FORMAT || r.key != key || r.outputs.len() != step.outputs.len() {
        return false;
    }
    step.outputs.iter().all(|p| {
        let want = r.outputs.get(&p.display().to_string());
        want.is_some() && hashes.sha256(p).ok().flatten().as_ref() == want
    })
}

/// Writes the step's record once it has finished (atomically, like every output).
pub fn record(out: &Path, step: &Step, key: &str, seconds: f64, hashes: &mut Hashes) -> Result<()> {
    let mut outputs = BTreeMap::new();
    for p in &step.outputs {
        let sha = hashes.sha256(p)?.with_context(|| format!("{}: step {} did not write it", p.display(), step.name))?;
        outputs.insert(p.display().to_string(), sha);
    }
    let r = Record {
        format: FORMAT,
        key: key.to_string(),
        outputs,
        seconds,
        pgser_version: env!("CARGO_PKG_VERSION").to_string(),
    };
    let path = record_path(out, step);
    std::fs::create_dir_all(path.parent().expect("has a folder"))
        .with_context(|| format!("{}: cannot create", out.join(".pipeline").display()))?;
    let f = AtomicFile::create(&path)?;
    std::io::Write::write_all(&mut f.handle()?, serde_json::to_string_pretty(&r)?.as_bytes())
        .with_context(|| format!("{}: write failed", path.display()))?;
    f.commit()
}
