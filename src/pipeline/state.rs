//! Step records: `OUT/.pipeline/<step>.json` = the step's key and its outputs' sha256.
//!
//! The key hashes the step's name, parameters and its inputs' *contents*, not their dates:
//! copying an out folder, touching a file or re-creating an identical output changes nothing,
//! while any changed byte upstream reruns exactly the steps that read it.
//!
//! The key also holds pgser's version (`CARGO_PKG_VERSION`), because the code is an input of
//! every step too: a new pgser may simulate, convert, train or score differently, and a record
//! written by the old one would otherwise keep its outputs forever. So after an upgrade every
//! step reruns once, and a training step starts from scratch rather than continuing a
//! checkpoint the old code wrote ([`may_resume`]). A version string is coarse (a release that
//! changes only the report reruns the training too) but honest and simple: a finer identity —
//! a hash of the sources each step depends on — would have to list those sources by hand, and
//! one missing entry would silently keep stale outputs, while a hash of the whole binary would
//! rerun days of training after any edit. The price: a developer build whose changed code
//! writes outputs differently must bump the version in `Cargo.toml` (or delete `OUT/.pipeline`).

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::SystemTime;

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use sha2::Digest;

use super::Step;
use crate::agent::{Backend, checkpoint};
use crate::output::{AtomicFile, hex};
use crate::train::TrainConfig;
use crate::trajectory::folder::MANIFEST;

/// Bump when the meaning of a key changes, so old records are not trusted (2: the key holds
/// pgser's version).
const FORMAT: u32 = 2;

/// The version every key of this build holds.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

#[derive(Serialize, Deserialize)]
pub struct Record {
    format: u32,
    pub key: String,
    /// Output path (as planned) → sha256 when the step finished.
    pub outputs: BTreeMap<String, String>,
    pub seconds: f64,
    pub pgser_version: String,
    /// How the step finished: `ran` or `resumed` (absent in records of older pgser builds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<String>,
    /// The Slurm job that ran it (the array's id for an element of the agent grid), so that
    /// `pipeline run --executor slurm --wait` tells its own runs from other runs' work.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub job: Option<String>,
}

impl Record {
    /// The sha256 recorded for `output`, a path as planned now under the out folder `out`.
    /// A record keeps each output's path as the run that wrote it planned it, relative to the
    /// folder that run was started in (`../out/x/q.ckpt` from `pipelines/`, `out/x/q.ckpt` from
    /// the repository root), so where the strings differ the output is found by its path inside
    /// the out folder: `pipeline status` and `pipeline run` give the same answer from any folder
    /// (they used to call every step of a run started elsewhere "not started" and redo it).
    pub fn output_sha(&self, out: &Path, output: &Path) -> Option<&String> {
        if let Some(sha) = self.outputs.get(&output.display().to_string()) {
            return Some(sha);
        }
        let inside = output.strip_prefix(out).ok()?;
        let mut found = self.outputs.iter().filter(|(p, _)| Path::new(p.as_str()).ends_with(inside));
        match (found.next(), found.next()) {
            (Some((_, sha)), None) => Some(sha),
            _ => None,
        }
    }
}

/// sha256 of files, computed once per run per (path, size, mtime).
#[derive(Default, Clone)]
pub struct Hashes {
    seen: HashMap<PathBuf, (u64, SystemTime, String)>,
}

impl Hashes {
    /// The digest of a file, or of a folder by its manifest (`trajectory::folder::digest`): a
    /// table folder given as β, or the scored folder the score step writes over one. None when
    /// the path is absent, and for a folder without its manifest (written last, so a score still
    /// running or killed) or a scored folder that no longer opens (a shard deleted or of another
    /// size): that output is missing, and its step rebuilds it.
    pub fn sha256(&mut self, path: &Path) -> Result<Option<String>> {
        let Ok(meta) = std::fs::metadata(path) else { return Ok(None) };
        // A folder's stamp is its manifest's: the folder's own changes with any file in it.
        let meta = if meta.is_dir() {
            match std::fs::metadata(path.join(MANIFEST)) {
                Ok(m) if m.is_file() => m,
                _ => return Ok(None),
            }
        } else {
            meta
        };
        let stamp = (meta.len(), meta.modified().with_context(|| format!("{}: no modification time", path.display()))?);
        if let Some((len, time, sha)) = self.seen.get(path)
            && (*len, *time) == stamp
        {
            return Ok(Some(sha.clone()));
        }
        if crate::score::folder::is_scored_folder(path) && crate::score::folder::ScoredFolder::open(path).is_err() {
            return Ok(None);
        }
        let sha = crate::trajectory::folder::digest(path)?;
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
        key_of(step, &inputs, VERSION).map(Some)
    }
}

/// The key of `step` with inputs of these sha256s, as pgser `version` computes it.
pub fn key_of(step: &Step, inputs: &[String], version: &str) -> Result<String> {
    let text = serde_json::to_string(&serde_json::json!({
        "format": FORMAT, "pgser_version": version, "step": step.name, "params": step.params, "inputs": inputs,
    }))?;
    Ok(hex(&sha2::Sha256::digest(text.as_bytes())))
}

pub fn record_path(out: &Path, step: &Step) -> PathBuf {
    out.join(".pipeline").join(format!("{}.json", step.name.replace(' ', "_")))
}

/// The step's record, if it has a readable one of this format.
pub fn read(out: &Path, step: &Step) -> Option<Record> {
    let text = std::fs::read_to_string(record_path(out, step)).ok()?;
    serde_json::from_str::<Record>(&text).ok().filter(|r| r.format == FORMAT)
}

/// Whether a training step that is not up to date may continue from the checkpoint in its out
/// folder: after a crash (no record) or a change of settings by this same pgser (`train` then
/// refuses what cannot continue), but not when the record has `key` (a finished output lost its
/// recorded bytes: rebuild it from scratch) nor when another pgser version wrote it (its
/// checkpoint is the old code's work, and continuing it would keep that).
pub fn may_resume(out: &Path, step: &Step, key: Option<&str>) -> bool {
    let Ok(text) = std::fs::read_to_string(record_path(out, step)) else { return true };
    // An unreadable or older-format record is of an older pgser.
    let Ok(r) = serde_json::from_str::<Record>(&text) else { return false };
    r.format == FORMAT && r.pgser_version == VERSION && Some(r.key.as_str()) != key
}

/// The updates a training step's checkpoint already has, when the run will continue it (as
/// `train --resume` would: same settings but for `updates`, no more updates than asked, the
/// same data); else 0.
pub fn resumes_from(out: &Path, step: &Step, f: &Forecast, cfg: &TrainConfig) -> u64 {
    let ckpt = &step.outputs[0];
    if !may_resume(out, step, f.key.as_deref()) || !checkpoint::resume_path(ckpt).exists() {
        return 0;
    }
    let Ok((agent, meta)) = Backend::Cpu.device().and_then(|d| checkpoint::load(ckpt, d)) else { return 0 };
    let saved: Option<TrainConfig> = meta.get("train").and_then(|t| serde_json::from_str(t).ok());
    let same = saved.is_some_and(|s| TrainConfig { updates: cfg.updates, ..s } == *cfg);
    let data = meta.get("data_sha256").is_some_and(|sha| f.inputs[0].as_ref() == Some(sha));
    if same && data && agent.updates <= cfg.updates { agent.updates } else { 0 }
}

/// Whether the step's record has `key` and its outputs are the bytes it wrote.
pub fn up_to_date(out: &Path, step: &Step, key: &str, hashes: &mut Hashes) -> bool {
    let Some(r) = read(out, step) else { return false };
    if r.key != key || r.outputs.len() != step.outputs.len() {
        return false;
    }
    step.outputs.iter().all(|p| {
        let want = r.output_sha(out, p);
        want.is_some() && hashes.sha256(p).ok().flatten().as_ref() == want
    })
}

/// What a run of the plan will do with one step, foreseen before any step runs.
#[derive(Debug, Clone)]
pub struct Forecast {
    /// Not up to date: the step will run.
    pub runs: bool,
    /// The sha256 each input will have when the step's turn comes (None: unknown until the
    /// step before has run, or missing).
    pub inputs: Vec<Option<String>>,
    /// The step's key then, when every input is known.
    pub key: Option<String>,
}

/// Which of `steps` a run will run. A step reads the outputs of earlier ones, so its key is
/// computed with the bytes they will have: those of an up-to-date step now; those recorded for a
/// step that reruns with its recorded key (every step is deterministic, so a lost output comes
/// back byte for byte); unknown for one that reruns with another key, which makes the steps
/// reading it run too.
pub fn forecast(out: &Path, steps: &[Step], hashes: &mut Hashes) -> Result<Vec<Forecast>> {
    let mut will_be: HashMap<PathBuf, Option<String>> = HashMap::new();
    let mut all = Vec::with_capacity(steps.len());
    for step in steps {
        let inputs = step
            .inputs
            .iter()
            .map(|p| match will_be.get(p) {
                Some(sha) => Ok(sha.clone()),
                None => hashes.sha256(p),
            })
            .collect::<Result<Vec<_>>>()?;
        let key = match inputs.iter().cloned().collect::<Option<Vec<String>>>() {
            Some(shas) => Some(key_of(step, &shas, VERSION)?),
            None => None,
        };
        let runs = !key.as_deref().is_some_and(|k| up_to_date(out, step, k, hashes));
        let record = read(out, step).filter(|r| Some(&r.key) == key.as_ref());
        for o in &step.outputs {
            let sha = match (runs, &record) {
                (false, _) => hashes.sha256(o)?,
                (true, Some(r)) => r.output_sha(out, o).cloned(),
                (true, None) => None,
            };
            will_be.insert(o.clone(), sha);
        }
        all.push(Forecast { runs, inputs, key });
    }
    Ok(all)
}

/// Writes the step's record once it has finished `how` (`ran`, `resumed`), atomically like
/// every output.
pub fn record(out: &Path, step: &Step, key: &str, seconds: f64, how: &str, hashes: &mut Hashes) -> Result<()> {
    write_record(out, step, key, seconds, hashes, VERSION, how)
}

/// The Slurm job this process runs in: the array's id for an element of a job array.
pub fn slurm_job() -> Option<String> {
    std::env::var("SLURM_ARRAY_JOB_ID").or_else(|_| std::env::var("SLURM_JOB_ID")).ok()
}

fn write_record(
    out: &Path,
    step: &Step,
    key: &str,
    seconds: f64,
    hashes: &mut Hashes,
    version: &str,
    how: &str,
) -> Result<()> {
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
        pgser_version: version.to_string(),
        status: Some(how.to_string()),
        job: slurm_job(),
    };
    let path = record_path(out, step);
    std::fs::create_dir_all(path.parent().expect("has a folder"))
        .with_context(|| format!("{}: cannot create", out.join(".pipeline").display()))?;
    let f = AtomicFile::create(&path)?;
    std::io::Write::write_all(&mut f.handle()?, serde_json::to_string_pretty(&r)?.as_bytes())
        .with_context(|| format!("{}: write failed", path.display()))?;
    f.commit()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::Action;

    #[test]
    fn another_pgser_version_makes_a_finished_step_stale() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path();
        let (input, output) = (out.join("in.txt"), out.join("out.txt"));
        std::fs::write(&input, "x").unwrap();
        std::fs::write(&output, "y").unwrap();
        let step = Step {
            name: "s".into(),
            inputs: vec![input.clone()],
            outputs: vec![output],
            params: serde_json::json!({"a": 1}),
            action: Action::Results(vec![]),
        };
        let mut h = Hashes::default();
        let inputs = [h.sha256(&input).unwrap().unwrap()];
        assert_eq!(h.key(&step).unwrap().unwrap(), key_of(&step, &inputs, VERSION).unwrap());

        // Finished by an older pgser: up to date for that version only, and not to be resumed.
        let old = key_of(&step, &inputs, "0.0.1-old").unwrap();
        let new = key_of(&step, &inputs, VERSION).unwrap();
        assert_ne!(old, new);
        write_record(out, &step, &old, 1.0, &mut h, "0.0.1-old", "ran").unwrap();
        assert!(up_to_date(out, &step, &old, &mut h));
        assert!(!up_to_date(out, &step, &new, &mut h));
        assert!(!may_resume(out, &step, Some(&new)));

        // Finished by this pgser: up to date; other settings may continue its checkpoint.
        record(out, &step, &new, 1.0, "ran", &mut h).unwrap();
        assert!(up_to_date(out, &step, &new, &mut h));
        assert!(!may_resume(out, &step, Some(&new)));
        assert!(may_resume(out, &step, Some("another key")));
        std::fs::remove_file(record_path(out, &step)).unwrap();
        assert!(may_resume(out, &step, Some(&new)), "no record: a crash, continue");
    }
}
