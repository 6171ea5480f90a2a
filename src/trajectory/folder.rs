//! A table folder: one trajectory table stored as Parquet shards plus one manifest.
//!
//! Why a folder: OGBench's and Horizon Reduction's largest datasets (100M–1B transitions) come
//! as folders of `.npz` shards (`humanoidmaze-giant-navigate-v0-{0..249}.npz`), hundreds of GB
//! that no one converts, copies or checks in one piece. Kept as shards, a convert can run them
//! in parallel and resume after a kill, a cluster can score one shard per array task, and every
//! shard stays an ordinary pgser table that polars, DuckDB and pyarrow read on its own.
//!
//! The folder holds the shards (`NAME-i.parquet`, one per source shard, each written atomically)
//! and `manifest.json`, written last and atomically, so a folder without a manifest is a convert
//! still running or killed, never a table. The manifest lists the shards in order with their
//! rows, episodes, bytes and SHA-256, and the footer every shard shares (task, T, dimensions,
//! float type, passthrough columns) with the folder's totals. Episodes are numbered across the
//! folder in shard order: a shard's episode `e` is the folder's `first_episode + e`. A
//! validation set (OGBench's `-val.npz`) is a table folder of its own, `val/` inside it.
//!
//! [`TableFolder::open`] is where a folder becomes one table: it refuses a manifest whose shards
//! are missing, of another size, or whose footers disagree with it or with each other, naming the
//! shard and the field. Reading a shard's footer costs a few KB, so opening a 1000-shard folder
//! reads no data.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

use super::Footer;
use crate::table::ShardFile;

/// The manifest's file name inside a table folder.
pub const MANIFEST: &str = "manifest.json";
/// The manifest's `format`.
pub const FORMAT: &str = "pgser-table-folder";
/// Bumped when the manifest changes meaning.
pub const VERSION: u32 = 1;
/// The validation table's folder inside a table folder.
pub const VALIDATION: &str = "val";

/// One shard as the manifest lists it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Shard {
    /// The shard's file name inside the folder.
    pub file: String,
    pub rows: usize,
    pub episodes: usize,
    /// The folder's number of this shard's episode 0.
    pub first_episode: usize,
    pub bytes: u64,
    pub sha256: String,
}

/// `manifest.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    pub rows: usize,
    pub episodes: usize,
    /// What every shard's footer says, with the folder's totals (`episodes`, `rows`), every
    /// shard's sources in order, and the command that made the folder.
    pub footer: Footer,
    pub shards: Vec<Shard>,
    /// Whether `val/` holds the validation table.
    #[serde(default)]
    pub validation: bool,
    /// The settings of the convert that made the folder (what decides a shard's bytes besides
    /// its source), by which a later convert into it knows which shards it may keep.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub settings: Option<serde_json::Value>,
}

/// A table folder, opened and checked.
#[derive(Debug, Clone)]
pub struct TableFolder {
    pub dir: PathBuf,
    pub manifest: Manifest,
}

/// Whether `path` is a table folder (a folder with a manifest).
pub fn is_folder(path: &Path) -> bool {
    path.is_dir() && path.join(MANIFEST).is_file()
}

/// The fields of a footer every shard of one table shares: the footer less its counts, sources
/// and command, and less each passthrough column's source files.
fn shared(f: &Footer) -> Footer {
    let mut s = f.clone();
    s.episodes = 0;
    s.rows = 0;
    s.sources.clear();
    s.command.clear();
    s.pgser_version.clear();
    s.policy = None;
    s.seed = None;
    for p in &mut s.passthrough {
        p.files.clear();
    }
    s
}

/// The first field in which shard footer `b` differs from `a` (both as [`shared`] gives them),
/// in words, or None.
fn difference(a: &Footer, b: &Footer) -> Option<String> {
    let (a, b) = (shared(a), shared(b));
    if a == b {
        return None;
    }
    let checks: [(&str, String, String); 10] = [
        ("task", a.task.clone(), b.task.clone()),
        ("T", a.t.to_string(), b.t.to_string()),
        ("obs_dim", a.obs_dim.to_string(), b.obs_dim.to_string()),
        ("goal_dim", a.goal_dim.to_string(), b.goal_dim.to_string()),
        ("act_dim", a.act_dim.to_string(), b.act_dim.to_string()),
        ("float_type", format!("{:?}", a.float_type), format!("{:?}", b.float_type)),
        ("image_shape", format!("{:?}", a.image_shape), format!("{:?}", b.image_shape)),
        ("success_threshold", a.success_threshold.to_string(), b.success_threshold.to_string()),
        ("goal_metric", format!("{:?}", a.goal_metric), format!("{:?}", b.goal_metric)),
        ("last_action", a.last_action.to_string(), b.last_action.to_string()),
    ];
    for (what, x, y) in checks {
        if x != y {
            return Some(format!("{what} {y} where the first shard has {x}"));
        }
    }
    let cols = |f: &Footer| {
        f.passthrough.iter().map(|p| format!("{} ({} {:?} per {:?})", p.column, p.dtype, p.shape, p.per)).collect()
    };
    let (x, y): (Vec<String>, Vec<String>) = (cols(&a), cols(&b));
    if x != y {
        return Some(format!("passthrough columns [{}] where the first shard has [{}]", y.join(", "), x.join(", ")));
    }
    Some("a footer that differs from the first shard's".into())
}

/// The digest a run records of its data (checkpoints, batch tables, scored footers, pipelines'
/// content keys): a file's SHA-256, or for a table folder the SHA-256 of its manifest once the
/// folder opens (the manifest holds every shard's SHA-256 and size, and opening checks the sizes
/// and footers). Hashing every shard again is `pgser-etl verify`'s job: a 1B-transition folder is
/// hundreds of GB, which no training run should read twice before it starts.
pub fn digest(path: &Path) -> Result<String> {
    if is_folder(path) {
        // Other folders with a manifest (a scored folder) are checked by their own readers.
        let manifest = path.join(MANIFEST);
        let format = std::fs::read_to_string(&manifest)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .map(|j| j["format"].clone());
        if format.is_none_or(|f| f == FORMAT) {
            TableFolder::open(path)?;
        }
        crate::output::sha256_file(&manifest)
    } else {
        crate::output::sha256_file(path)
    }
}

/// The trajectory footer of a table: a file's own, or a table folder's (its manifest's, with the
/// folder's totals; the folder opened and checked).
pub fn footer(path: &Path) -> Result<Footer> {
    if is_folder(path) { Ok(TableFolder::open(path)?.manifest.footer) } else { shard_footer(path) }
}

/// The trajectory footer of the shard at `path`.
pub fn shard_footer(path: &Path) -> Result<Footer> {
    let json = crate::table::read_footer(path)?;
    Footer::from_json(&path.display().to_string(), json)
}

/// The shard at `path` opened for reading row groups, with its trajectory footer: its Parquet
/// metadata parsed once for both.
pub fn open_shard(path: &Path) -> Result<(ShardFile, Footer)> {
    let file = ShardFile::open(path)?;
    let footer = Footer::from_json(&path.display().to_string(), file.footer_json()?)?;
    Ok((file, footer))
}

impl Manifest {
    /// The manifest of shards `files` (in folder order) inside `dir`, their footers read and
    /// checked to agree, each file hashed. `command` is the folder's.
    pub fn of_shards(
        dir: &Path,
        files: &[String],
        command: &str,
        validation: bool,
        settings: Option<serde_json::Value>,
    ) -> Result<Manifest> {
        let Some(first_file) = files.first() else { bail!("{}: no shards to list", dir.display()) };
        let first = shard_footer(&dir.join(first_file))?;
        let mut footer = first.clone();
        footer.sources.clear();
        footer.command = command.to_string();
        footer.pgser_version = env!("CARGO_PKG_VERSION").to_string();
        let (mut rows, mut episodes) = (0usize, 0usize);
        let mut shards = Vec::with_capacity(files.len());
        for file in files {
            let path = dir.join(file);
            let f = shard_footer(&path)?;
            if let Some(d) = difference(&first, &f) {
                bail!("{}: {d} ({}): the shards of one table must agree", path.display(), first_file);
            }
            for (m, p) in footer.passthrough.iter_mut().zip(&f.passthrough) {
                for x in &p.files {
                    if !m.files.contains(x) {
                        m.files.push(x.clone());
                    }
                }
            }
            footer.sources.extend(f.sources.iter().cloned());
            let bytes = std::fs::metadata(&path).with_context(|| format!("{}: cannot read", path.display()))?.len();
            shards.push(Shard {
                file: file.clone(),
                rows: f.rows,
                episodes: f.episodes,
                first_episode: episodes,
                bytes,
                sha256: crate::output::sha256_file(&path)?,
            });
            rows += f.rows;
            episodes += f.episodes;
        }
        footer.rows = rows;
        footer.episodes = episodes;
        Ok(Manifest { format: FORMAT.into(), version: VERSION, rows, episodes, footer, shards, validation, settings })
    }

    /// Written as `dir/manifest.json`, atomically.
    pub fn write(&self, dir: &Path) -> Result<()> {
        write_json(&dir.join(MANIFEST), &serde_json::to_value(self).expect("a manifest serializes"))
    }
}

/// `value` as pretty JSON at `path`, atomically.
pub fn write_json(path: &Path, value: &serde_json::Value) -> Result<()> {
    let out = crate::output::AtomicFile::create(path)?;
    let text = serde_json::to_string_pretty(value).expect("JSON serializes");
    let mut file = out.handle()?;
    std::io::Write::write_all(&mut file, text.as_bytes())
        .and_then(|_| std::io::Write::write_all(&mut file, b"\n"))
        .with_context(|| format!("{}: cannot write", path.display()))?;
    out.commit()
}

/// The manifest of folder `dir`, which must say `format` and `version`, parsed as `M`, with its
/// shards' file names checked to be names inside the folder (no path, not hidden): shared by table
/// folders and scored folders (`score/folder.rs`). `missing` says what a folder without one is.
pub fn read_manifest<M: serde::de::DeserializeOwned>(
    dir: &Path,
    format: &str,
    version: u32,
    missing: &str,
) -> Result<(M, Vec<String>)> {
    let path = dir.join(MANIFEST);
    let at = path.display();
    if !dir.is_dir() {
        bail!("{}: not a folder", dir.display());
    }
    if !path.is_file() {
        bail!("{}: a folder without {MANIFEST}: {missing}", dir.display());
    }
    let text = crate::output::read_input_text(&path)?;
    let json: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("{at}: not valid JSON"))?;
    match json.get("format").and_then(|f| f.as_str()) {
        Some(f) if f == format => {}
        other => bail!("{at}: format {other:?}, not {format:?}"),
    }
    match json.get("version").and_then(|v| v.as_u64()) {
        Some(v) if v == version as u64 => {}
        other => bail!("{at}: manifest version {other:?}; this pgser reads version {version}"),
    }
    let files: Vec<String> = json
        .get("shards")
        .and_then(|s| s.as_array())
        .map(|a| a.iter().map(|s| s.get("file").and_then(|f| f.as_str()).unwrap_or("").to_string()).collect())
        .unwrap_or_default();
    if files.is_empty() {
        bail!("{at}: the manifest lists no shards");
    }
    for (i, f) in files.iter().enumerate() {
        if f.is_empty() || f.contains('/') || f.contains('\\') || f.starts_with('.') {
            bail!("{at}: shard {i}: {f:?} is not a file name inside the folder");
        }
    }
    let m: M = serde_json::from_value(json).with_context(|| format!("{at}: the manifest is corrupt"))?;
    Ok((m, files))
}

impl TableFolder {
    /// Opens the table folder `dir`: its manifest read, and every shard there, of the size the
    /// manifest says, with a footer that agrees with it (counts, task, columns). The shards'
    /// bytes are not hashed here (`pgser-etl verify` does): opening reads footers only.
    pub fn open(dir: &Path) -> Result<TableFolder> {
        Self::open_inner(dir, false).map(|(folder, _)| folder)
    }

    /// As [`TableFolder::open`], keeping every shard opened for reading row groups, with its
    /// footer (in folder order): a reader of the shards' rows (the out-of-core pool) parses each
    /// shard's metadata once, here.
    pub fn open_shards(dir: &Path) -> Result<(TableFolder, Vec<(ShardFile, Footer)>)> {
        Self::open_inner(dir, true)
    }

    fn open_inner(dir: &Path, keep: bool) -> Result<(TableFolder, Vec<(ShardFile, Footer)>)> {
        let path = dir.join(MANIFEST);
        let at = path.display();
        let (m, _): (Manifest, _) = read_manifest(
            dir,
            FORMAT,
            VERSION,
            "not a table folder, or a convert into it is unfinished (run it again: finished shards are kept)",
        )?;
        let footer = Footer::from_json(&at.to_string(), serde_json::to_value(&m.footer).expect("serializes"))?;
        let (mut rows, mut episodes) = (0usize, 0usize);
        let mut opened = Vec::with_capacity(if keep { m.shards.len() } else { 0 });
        for (i, s) in m.shards.iter().enumerate() {
            let shard = dir.join(&s.file);
            let len = std::fs::metadata(&shard)
                .with_context(|| format!("{at}: shard {i}: {} is missing", shard.display()))?
                .len();
            if len != s.bytes {
                bail!(
                    "{}: {len} bytes where the manifest says {} (shard {i}): the file changed",
                    shard.display(),
                    s.bytes
                );
            }
            let (file, f) = if keep {
                let (file, f) = open_shard(&shard)?;
                (Some(file), f)
            } else {
                (None, shard_footer(&shard)?)
            };
            if (f.rows, f.episodes) != (s.rows, s.episodes) {
                bail!(
                    "{}: {} rows in {} episodes where the manifest says {} in {} (shard {i})",
                    shard.display(),
                    f.rows,
                    f.episodes,
                    s.rows,
                    s.episodes
                );
            }
            if s.first_episode != episodes {
                bail!(
                    "{at}: shard {i} ({}) starts at episode {} where the shards before it end at {episodes}",
                    s.file,
                    s.first_episode
                );
            }
            if let Some(d) = difference(&footer, &f) {
                bail!("{}: {d} (the manifest's footer)", shard.display());
            }
            rows += s.rows;
            episodes += s.episodes;
            opened.extend(file.map(|file| (file, f)));
        }
        if (rows, episodes) != (m.rows, m.episodes) || (footer.rows, footer.episodes) != (rows, episodes) {
            bail!(
                "{at}: the shards hold {rows} rows in {episodes} episodes where the manifest says {} in {}",
                m.rows,
                m.episodes
            );
        }
        Ok((TableFolder { dir: dir.to_path_buf(), manifest: m }, opened))
    }

    /// The shards' paths, in folder order.
    pub fn shard_paths(&self) -> Vec<PathBuf> {
        self.manifest.shards.iter().map(|s| self.dir.join(&s.file)).collect()
    }

    /// The folder's footer: the shards' shared one with the folder's totals.
    pub fn footer(&self) -> &Footer {
        &self.manifest.footer
    }

    /// The shard holding the folder's episode `e`, and `e`'s number inside it.
    pub fn locate(&self, e: usize) -> Option<(usize, usize)> {
        let s = &self.manifest.shards;
        let i = s.partition_point(|x| x.first_episode + x.episodes <= e);
        (i < s.len()).then(|| (i, e - s[i].first_episode))
    }

    /// The validation table folder (`val/`), when the manifest says there is one.
    pub fn validation(&self) -> Result<Option<TableFolder>> {
        if !self.manifest.validation {
            return Ok(None);
        }
        TableFolder::open(&self.dir.join(VALIDATION)).map(Some)
    }
}
