//! A Minari dataset's folder as a whole: where its `data/` folder is, what its `metadata.json`
//! says (the storage, the episode count, the spaces, the environment), and the sha256 a table's
//! footer records of it.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use super::Spaces;
use crate::task::GoalMetric;

/// The two storages Minari writes and pgser reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    Hdf5,
    Arrow,
}

impl Storage {
    /// The name in a footer's `sources[].format`.
    pub fn format_name(self) -> &'static str {
        match self {
            Storage::Hdf5 => "minari-hdf5",
            Storage::Arrow => "minari-arrow",
        }
    }
}

/// What pgser uses of a dataset's `metadata.json`.
#[derive(Debug, Clone)]
pub struct Metadata {
    /// The `data/` folder holding `metadata.json`.
    pub data: PathBuf,
    pub storage: Storage,
    pub total_episodes: usize,
    pub spaces: Spaces,
    /// The Dict observation's other keys (an image beside the goals), each with its subspace as
    /// metadata.json's text has it: kept as passthrough columns `observations/KEY`.
    pub extra_obs: Vec<(String, String)>,
    /// The Gymnasium id of `env_spec` (`FetchReach-v4`), when the dataset names one.
    pub env_id: Option<String>,
    /// What pgser's own export recorded about the task (`pgser` key): name, threshold, metric.
    pub pgser_task: Option<(String, f64, GoalMetric)>,
}

/// The `data/` folder of a dataset given as `ID/` (as under MINARI_DATASETS_PATH) or as `ID/data/`.
pub fn data_folder(dir: &Path) -> Result<PathBuf> {
    for d in [dir.join("data"), dir.to_path_buf()] {
        if d.join("metadata.json").is_file() {
            return Ok(d);
        }
    }
    bail!(
        "{}: a folder, but not a Minari dataset: neither data/metadata.json nor metadata.json is in it, nor OGBench \
         shards (.npz files) (convert reads WGCSL pickles, OGBench .npz files and folders of them, and Minari \
         dataset folders)",
        dir.display()
    )
}

/// Read and check `metadata.json`: the storage, the episode count and a goal-conditioned Dict
/// observation with float Box spaces.
pub fn read_metadata(dir: &Path) -> Result<Metadata> {
    let data = data_folder(dir)?;
    let path = data.join("metadata.json");
    let at = path.display().to_string();
    let text = crate::output::read_input_text(&path)?;
    let json: serde_json::Value =
        serde_json::from_str(&text).map_err(|e| anyhow::anyhow!("{at}: not valid JSON ({e})"))?;
    let string = |key: &str| json.get(key).and_then(|v| v.as_str());
    let storage = match string("data_format") {
        Some("hdf5") => Storage::Hdf5,
        Some("arrow") => Storage::Arrow,
        Some(other) => bail!("{at}: data_format '{other}'; pgser reads Minari's 'hdf5' and 'arrow' storages"),
        None => bail!("{at}: no data_format (a Minari dataset names its storage, 'hdf5' or 'arrow')"),
    };
    let total_episodes =
        json.get("total_episodes").and_then(|v| v.as_u64()).with_context(|| format!("{at}: no total_episodes count"))?
            as usize;
    let obs = string("observation_space").with_context(|| format!("{at}: no observation_space"))?;
    let act = string("action_space").with_context(|| format!("{at}: no action_space"))?;
    let (spaces, extra_obs) = Spaces::parse(&at, obs, act)?;
    // env_spec is Gymnasium's EnvSpec as a JSON string; only its id matters here.
    let env_id = string("env_spec")
        .and_then(|s| serde_json::from_str::<serde_json::Value>(s).ok())
        .and_then(|v| v.get("id").and_then(|id| id.as_str()).map(str::to_string));
    let pgser_task = json.get("pgser").and_then(|p| {
        let name = p.get("task")?.as_str()?.to_string();
        let threshold = p.get("success_threshold")?.as_f64()?;
        let metric = serde_json::from_value(p.get("goal_metric")?.clone()).ok()?;
        Some((name, threshold, metric))
    });
    Ok(Metadata { data, storage, total_episodes, spaces, extra_obs, env_id, pgser_task })
}

/// The sha256 recorded for a dataset folder: over its files in sorted path order, each as its
/// path relative to the folder, a NUL byte, its length (u64 little-endian) and its bytes. A
/// folder has no bytes of its own; this changes when any file is added, removed or edited.
pub fn sha256_folder(dir: &Path) -> Result<String> {
    use sha2::{Digest, Sha256};
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for entry in std::fs::read_dir(&d).with_context(|| format!("{}: cannot list", d.display()))? {
            let path = entry.with_context(|| format!("{}: cannot list", d.display()))?.path();
            if path.is_dir() { stack.push(path) } else { files.push(path) }
        }
    }
    files.sort();
    let mut h = Sha256::new();
    for f in &files {
        let cannot = || format!("{}: cannot read", f.display());
        let file = std::fs::File::open(f).with_context(cannot)?;
        let len = file.metadata().with_context(cannot)?.len();
        h.update(f.strip_prefix(dir).unwrap_or(f).to_string_lossy().as_bytes());
        h.update([0]);
        h.update(len.to_le_bytes());
        let read = crate::output::feed_file(&mut h, file, f)?;
        if read != len {
            bail!("{}: changed while it was read ({len} bytes, then {read})", f.display());
        }
    }
    Ok(crate::output::hex(&h.finalize()))
}
