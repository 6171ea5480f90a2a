//! A scored folder: the swapped, scored transitions of a table folder, one scored shard per
//! trajectory shard, plus one manifest.
//!
//! Why shards: scoring 100M transitions with 4 swaps each is 400M rows, hours of CPU. Kept as
//! one output per input shard, a cluster scores the shards as one array job (`--shard I` per
//! task, `pipeline run --executor slurm`), a killed run redoes only unfinished shards, and a
//! trainer within a memory budget reads a block's scored rows beside the block itself
//! (`sampler/pool.rs`).
//!
//! Layout: `OUT/NAME-i.parquet` has the file name of trajectory shard i and holds the scored rows
//! of its transitions, episodes numbered across the folder. Each is an ordinary transition table
//! (docs/tables.md) whose footer names the whole table folder as its source (goals come from every
//! shard) and says which shard it scored ([`ShardOf`]); its `episodes`, `transitions` and `rows`
//! are the shard's. Chunk c of shard i draws its goals from the stream spawned from (seed, i, c),
//! so a shard's bytes depend on its inputs and settings, never on which machine or task scored
//! it, or in what order. `OUT/manifest.json` is written last, atomically, once every shard is
//! there: a folder without it is a score still running, never a table.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use indicatif::ProgressBar;
use serde::{Deserialize, Serialize};

use super::{Footer, Job, STREAM_SWAP, ScoreOptions, ScoreSummary, read, stats};
use crate::table::TableWriter;
use crate::trajectory::folder::{MANIFEST, TableFolder, is_folder, read_manifest, write_json};

/// The manifest's `format`.
pub const FORMAT: &str = "pgser-scored-folder";
/// Bumped when the manifest changes meaning.
pub const VERSION: u32 = 1;

/// Which shard of a table folder a scored shard holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardOf {
    /// Its position among the table folder's shards, 0-based.
    pub index: usize,
    /// The table folder's number of shards.
    pub shards: usize,
    /// The trajectory shard's file name (the scored shard's too).
    pub file: String,
    /// The folder's number of the shard's episode 0.
    pub first_episode: usize,
}

/// One scored shard as the manifest lists it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Shard {
    pub file: String,
    pub rows: usize,
    pub episodes: usize,
    pub first_episode: usize,
    pub bytes: u64,
    pub sha256: String,
}

/// `manifest.json` of a scored folder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    pub format: String,
    pub version: u32,
    pub rows: usize,
    pub episodes: usize,
    /// What every shard's footer says, with the folder's totals and the q statistics of all rows.
    pub footer: Footer,
    pub shards: Vec<Shard>,
}

/// A scored folder, opened and checked.
#[derive(Debug, Clone)]
pub struct ScoredFolder {
    pub dir: PathBuf,
    pub manifest: Manifest,
}

/// Whether `o` scores a table folder into a scored folder: the data is a table folder and the
/// output is not a `.parquet` file (which gets the whole folder's rows as one table).
pub fn scores_into_a_folder(o: &ScoreOptions) -> bool {
    is_folder(&o.data) && o.output.extension().is_none_or(|e| e != "parquet")
}

/// Whether `path` is a scored folder (its manifest says so).
pub fn is_scored_folder(path: &Path) -> bool {
    let manifest = path.join(MANIFEST);
    path.is_dir()
        && std::fs::read_to_string(&manifest)
            .ok()
            .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok())
            .is_some_and(|j| j["format"] == FORMAT)
}

/// Scores the shards of `o.data` that are not yet in `o.output` (only shard `o.shard` when it
/// is given), then, without `--shard`, writes the manifest.
pub(super) fn score(o: &ScoreOptions, bar: &ProgressBar, start: Instant) -> Result<ScoreSummary> {
    let beta = TableFolder::open(&o.data)?;
    let shards = &beta.manifest.shards;
    if let Some(i) = o.shard
        && i >= shards.len()
    {
        bail!("--shard {i}: {} has {} shards (0 to {})", o.data.display(), shards.len(), shards.len() - 1);
    }
    let job = Job::open(o)?;
    std::fs::create_dir_all(&o.output).with_context(|| format!("{}: cannot create the folder", o.output.display()))?;
    let todo: Vec<usize> = match o.shard {
        Some(i) => vec![i],
        None => (0..shards.len()).collect(),
    };
    let t1 = beta.footer().t - 1;
    bar.set_length(todo.iter().map(|&i| shards[i].episodes * t1).sum::<usize>() as u64);
    let mut scored_rows = 0;
    for &i in &todo {
        let shard = &shards[i];
        let dest = o.output.join(&shard.file);
        let of =
            ShardOf { index: i, shards: shards.len(), file: shard.file.clone(), first_episode: shard.first_episode };
        if kept(&job, &of, shard.episodes, &dest)? {
            crate::progress::advance(bar, (shard.episodes * t1) as u64)?;
            continue;
        }
        // A manifest beside a shard being replaced would list what is no longer there.
        // Array tasks scoring shards anew may race to remove it: gone is what both want.
        let manifest = o.output.join(MANIFEST);
        match std::fs::remove_file(&manifest) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(e).with_context(|| format!("{}: cannot remove", manifest.display()));
            }
            _ => {}
        }
        let mut writer = TableWriter::create(&dest, job.schema.clone())?;
        let first = shard.first_episode;
        let blocks = read::Blocks::open(&beta.dir.join(&shard.file), job.chunk_episodes, o.include_original)?
            .map(move |b| b.map(|(e, block)| (first + e, block)));
        let (rows, q) = job.score_blocks(blocks, &[STREAM_SWAP, i as u64], &mut writer, bar)?;
        if rows != shard.episodes * t1 * job.per {
            bail!(
                "{}: {rows} rows scored where its {} episodes in the folder's manifest make {}: the shard changed \
                 since the folder was opened; score it again",
                beta.dir.join(&shard.file).display(),
                shard.episodes,
                shard.episodes * t1 * job.per
            );
        }
        let mut footer = job.footer(shard.episodes, rows, q.finish(), &dest)?;
        footer.shard = Some(of);
        writer.finish(&serde_json::to_value(&footer)?)?;
        scored_rows += rows;
    }
    let (footer, bytes) = match o.shard {
        Some(i) => {
            let dest = o.output.join(&shards[i].file);
            (super::read_footer(&dest)?, std::fs::metadata(&dest)?.len())
        }
        None => {
            let m = Manifest::of(&o.output, &beta, &o.command)?;
            write_json(&o.output.join(MANIFEST), &serde_json::to_value(&m).expect("a manifest serializes"))?;
            let bytes = m.shards.iter().map(|s| s.bytes).sum();
            (m.footer, bytes)
        }
    };
    let mut summary = job.summary(&footer, bytes, scored_rows, start);
    if let Some(i) = o.shard {
        summary.output = o.output.join(&shards[i].file);
    }
    Ok(summary)
}

/// Whether the scored shard at `dest` is what this run would write (same source, checkpoint,
/// settings and shard, every row there), so it is kept rather than scored again.
fn kept(job: &Job, of: &ShardOf, episodes: usize, dest: &Path) -> Result<bool> {
    if !dest.exists() {
        return Ok(false);
    }
    let Ok(found) = super::read_footer(dest) else { return Ok(false) };
    let mut want = job.footer(episodes, episodes * (job.task.t - 1) * job.per, found.q.clone(), dest)?;
    want.shard = Some(of.clone());
    want.command.clone_from(&found.command);
    want.pgser_version.clone_from(&found.pgser_version);
    Ok(want == found)
}

impl Manifest {
    /// The manifest of the scored shards in `dir`, one per shard of `beta`, each read, checked
    /// to belong (same source, settings, shard) and hashed. `command` is the folder's.
    pub fn of(dir: &Path, beta: &TableFolder, command: &str) -> Result<Manifest> {
        let mut shards = Vec::with_capacity(beta.manifest.shards.len());
        let mut footers = Vec::with_capacity(shards.capacity());
        for (i, s) in beta.manifest.shards.iter().enumerate() {
            let path = dir.join(&s.file);
            if !path.exists() {
                bail!(
                    "{}: shard {i} is not scored yet: run `pgser-etl score` with --shard {i}, or without --shard",
                    path.display()
                );
            }
            let f = super::read_footer(&path)?;
            check_shard(&path, &f, i, s.first_episode, s.episodes)?;
            if let Some(first) = footers.first() {
                check_same(&path, first, &f)?;
            }
            shards.push(Shard {
                file: s.file.clone(),
                rows: f.rows,
                episodes: f.episodes,
                first_episode: s.first_episode,
                bytes: std::fs::metadata(&path).with_context(|| format!("{}: cannot read", path.display()))?.len(),
                sha256: crate::output::sha256_file(&path)?,
            });
            footers.push(f);
        }
        let mut footer = footers[0].clone();
        footer.episodes = footers.iter().map(|f| f.episodes).sum();
        footer.transitions = footers.iter().map(|f| f.transitions).sum();
        footer.rows = footers.iter().map(|f| f.rows).sum();
        footer.q = stats::merged(footers.iter().map(|f| (&f.q, f.rows as u64)));
        footer.shard = None;
        footer.command = command.to_string();
        footer.pgser_version = env!("CARGO_PKG_VERSION").to_string();
        Ok(Manifest {
            format: FORMAT.into(),
            version: VERSION,
            rows: footer.rows,
            episodes: footer.episodes,
            footer,
            shards,
        })
    }
}

/// A scored shard's footer must say it is shard `index` of `episodes` episodes from `first`.
fn check_shard(path: &Path, f: &Footer, index: usize, first: usize, episodes: usize) -> Result<()> {
    let Some(of) = &f.shard else {
        bail!("{}: a transition table of a whole table, not a scored shard", path.display());
    };
    if (of.index, of.first_episode, f.episodes) != (index, first, episodes) {
        bail!(
            "{}: scores shard {} ({} episodes from {}) where the folder's shard {index} has {episodes} from {first}",
            path.display(),
            of.index,
            f.episodes,
            of.first_episode
        );
    }
    Ok(())
}

/// Shards of one scored folder share their source, critic and settings.
fn check_same(path: &Path, a: &Footer, b: &Footer) -> Result<()> {
    let fields = |f: &Footer| {
        (
            f.source.sha256.clone(),
            f.checkpoint.sha256.clone(),
            f.seed,
            f.swaps,
            f.include_original,
            f.chunk_episodes,
            f.goal_sample,
            f.task.clone(),
        )
    };
    if fields(a) != fields(b) {
        bail!(
            "{}: scored from another source, critic or settings than the folder's first shard (source, checkpoint, seed, \
             swaps, include_original, chunk_episodes, goal_sample or task differ)",
            path.display()
        );
    }
    Ok(())
}

impl ScoredFolder {
    /// Opens the scored folder `dir`: its manifest read, and every shard there, of the size the
    /// manifest says, with a footer that agrees with it. Bytes are not hashed here (opening reads
    /// footers only; `pgser-etl verify` hashes).
    pub fn open(dir: &Path) -> Result<ScoredFolder> {
        let path = dir.join(MANIFEST);
        let at = path.display();
        let (m, _): (Manifest, _) =
            read_manifest(dir, FORMAT, VERSION, "not a scored folder, or a score into it is unfinished")?;
        let mut rows = 0;
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
            let f = super::read_footer(&shard)?;
            check_shard(&shard, &f, i, s.first_episode, s.episodes)?;
            check_same(&shard, &m.footer, &f)?;
            if f.rows != s.rows {
                bail!("{}: {} rows where the manifest says {} (shard {i})", shard.display(), f.rows, s.rows);
            }
            rows += s.rows;
        }
        if rows != m.rows || m.footer.rows != rows {
            bail!("{at}: the shards hold {rows} rows where the manifest says {}", m.rows);
        }
        Ok(ScoredFolder { dir: dir.to_path_buf(), manifest: m })
    }

    /// The shards' paths, in folder order.
    pub fn shard_paths(&self) -> Vec<PathBuf> {
        self.manifest.shards.iter().map(|s| self.dir.join(&s.file)).collect()
    }

    /// Where the trajectory table folder the shards were scored from is.
    pub fn source_table(&self) -> PathBuf {
        self.manifest.footer.source_table(&self.dir.join(MANIFEST))
    }
}
