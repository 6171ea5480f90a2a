//! Streaming a trajectory table for `score`: the goal pool in a first pass over one column, then
//! blocks of whole episodes in a second pass, each checked row by row as `Episodes::load` checks
//! a whole table (the same functions), so a bad table fails with the row named, not as a wrong
//! score. Memory is one block and one Parquet row group of the projected columns at a time.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use arrow_array::RecordBatch;
use parquet::arrow::arrow_reader::ParquetRecordBatchReader;

use crate::swap::GoalPool;

/// Spawn key of `--goal-sample`'s draws ("GSMP"), apart from the chunks' swap streams.
pub const STREAM_GOAL_SAMPLE: u64 = 0x4753_4d50;
use crate::trajectory::Episodes;
use crate::trajectory::Footer;
use crate::trajectory::folder::{TableFolder, is_folder};
use crate::trajectory::read::{append, check_all_read, check_keys, open_checked, rows_read_error};

/// The files of a table and the table-wide number of each one's first episode: the file itself,
/// or a table folder's shards in order (the folder opened and checked).
fn files(path: &Path) -> Result<Vec<(PathBuf, usize)>> {
    if !is_folder(path) {
        return Ok(vec![(path.to_path_buf(), 0)]);
    }
    let folder = TableFolder::open(path)?;
    Ok(folder.shard_paths().into_iter().zip(folder.manifest.shards.iter().map(|s| s.first_episode)).collect())
}

/// The footer of a trajectory table, checked against the file's row count and column types; a
/// table folder's is its manifest's (the shards' shared one with the folder's totals), each
/// shard's checked the same way.
pub fn footer(path: &Path) -> Result<Footer> {
    if is_folder(path) {
        for (shard, _) in files(path)? {
            open_checked(&shard, &[], 1)?;
        }
        return Ok(TableFolder::open(path)?.footer().clone());
    }
    Ok(open_checked(path, &[], 1)?.0)
}

/// The goals swaps come from, read as a stream of the `achieved_goal` column alone (a folder's
/// shards in order): every achieved goal of the table, or, with `sample = Some((k, seed))`, `k`
/// of them drawn uniformly with replacement from the stream spawned from (seed,
/// [`STREAM_GOAL_SAMPLE`]), which holds k goals whatever the table's size. A sample of at least
/// the table's observations is the whole table. `table` is the table's [`footer`].
pub fn goal_pool(path: &Path, table: &Footer, sample: Option<(usize, u64)>) -> Result<GoalPool> {
    let observations = table.episodes * table.t;
    // The sampled observations' table-wide indices, in order (a repeat is a second entry).
    let mut wanted: Option<Vec<u64>> = sample.filter(|&(k, _)| k < observations).map(|(k, seed)| {
        let mut rng = crate::nprandom::NpRandom::spawned(seed, &[STREAM_GOAL_SAMPLE]);
        let mut idx: Vec<u64> = (0..k).map(|_| rng.below(observations) as u64).collect();
        idx.sort_unstable();
        idx
    });
    let gd = table.goal_dim;
    let mut pool = GoalPool { n: table.episodes, t: table.t, goal_dim: gd, ag: Vec::new(), at: Vec::new() };
    let mut next = 0usize;
    for (file, first_episode) in files(path)? {
        let at = file.display().to_string();
        let (f, reader) = open_checked(&file, &["achieved_goal"], 1024)?;
        let first = (first_episode * table.t) as u64;
        let mut row = 0;
        let mut ag = Vec::new();
        for batch in reader {
            let batch = batch.with_context(|| format!("{at}: cannot read the rows after row {row}"))?;
            check_keys(&at, &batch, row, &f)?;
            let col = batch.column_by_name("achieved_goal").expect("projected");
            ag.clear();
            append(&mut ag, col, "achieved_goal", gd, false, row, f.t).map_err(|e| anyhow::anyhow!("{at}: {e}"))?;
            match wanted.as_deref() {
                None => pool.ag.extend_from_slice(&ag),
                Some(idx) => {
                    let end = first + (row + batch.num_rows()) as u64;
                    while next < idx.len() && idx[next] < end {
                        let local = (idx[next] - first) as usize - row;
                        let (e, s) = (idx[next] / table.t as u64, (idx[next] % table.t as u64) as u32);
                        pool.at.push((e, s));
                        pool.ag.extend_from_slice(&ag[local * gd..][..gd]);
                        next += 1;
                    }
                }
            }
            row += batch.num_rows();
        }
        check_all_read(&at, row, &f)?;
    }
    if let Some(idx) = wanted.take() {
        assert_eq!(next, idx.len(), "every sampled observation lies in the table");
    }
    Ok(pool)
}

/// Blocks of `per_block` whole episodes, in table order, as float32 [`Episodes`] (a file's last
/// block may be shorter; a folder's blocks never span two shards), each with the table-wide
/// number of its first episode. `desired_goal` is read only when `with_goals` (for original rows).
pub struct Blocks {
    files: std::collections::VecDeque<(PathBuf, usize)>,
    current: Option<(usize, FileBlocks)>,
    per_block: usize,
    with_goals: bool,
    done: bool,
}

impl Blocks {
    pub fn open(path: &Path, per_block: usize, with_goals: bool) -> Result<Blocks> {
        let mut files: std::collections::VecDeque<_> = files(path)?.into();
        let (first, offset) = files.pop_front().expect("a table has a file");
        let current = Some((offset, FileBlocks::open(&first, per_block, with_goals)?));
        Ok(Blocks { files, current, per_block, with_goals, done: false })
    }
}

impl Iterator for Blocks {
    type Item = Result<(usize, Episodes)>;

    /// Stops after the first error.
    fn next(&mut self) -> Option<Self::Item> {
        while !self.done {
            let (offset, blocks) = self.current.as_mut()?;
            match blocks.next() {
                Some(Ok((first, block))) => return Some(Ok((*offset + first, block))),
                Some(Err(e)) => {
                    self.done = true;
                    return Some(Err(e));
                }
                None => match self.files.pop_front() {
                    None => self.done = true,
                    Some((file, offset)) => match FileBlocks::open(&file, self.per_block, self.with_goals) {
                        Ok(b) => self.current = Some((offset, b)),
                        Err(e) => {
                            self.done = true;
                            return Some(Err(e));
                        }
                    },
                },
            }
        }
        None
    }
}

/// [`Blocks`] of one file.
struct FileBlocks {
    at: String,
    footer: Footer,
    reader: ParquetRecordBatchReader,
    per_block: usize,
    with_goals: bool,
    /// Table rows consumed so far.
    row: usize,
    /// Rows of the last batch read that belong to the next block.
    rest: Option<RecordBatch>,
    done: bool,
}

impl FileBlocks {
    fn open(path: &Path, per_block: usize, with_goals: bool) -> Result<FileBlocks> {
        let mut columns = vec!["obs", "achieved_goal", "action"];
        if with_goals {
            columns.push("desired_goal");
        }
        // Batches of one block: blocks are then cut from whole batches, not pieced together.
        let (footer, reader) = open_checked(path, &columns, per_block)?;
        Ok(FileBlocks {
            at: path.display().to_string(),
            footer,
            reader,
            per_block,
            with_goals,
            row: 0,
            rest: None,
            done: false,
        })
    }

    /// Read the next block: (first episode, episodes), or None at the end of the table.
    fn next_block(&mut self) -> Result<Option<(usize, Episodes)>> {
        let f = &self.footer;
        let (t, at) = (f.t, self.at.as_str());
        let first = self.row / t;
        let end_row = (first + self.per_block).min(f.episodes) * t;
        // The file's row count was checked against the footer's when it was opened.
        if self.row >= f.rows {
            return Ok(None);
        }
        let n = end_row / t - first;
        let mut block = Episodes {
            footer: f.clone(),
            task: f.task(),
            n,
            t,
            obs: Vec::with_capacity(n * t * f.obs_dim),
            ag: Vec::with_capacity(n * t * f.goal_dim),
            g: Vec::with_capacity(if self.with_goals { n * (t - 1) * f.goal_dim } else { 0 }),
            u: Vec::with_capacity(n * (t - 1) * f.act_dim),
            images: Vec::new(),
        };
        while self.row < end_row {
            let batch = match self.rest.take() {
                Some(b) => b,
                None => match self.reader.next() {
                    Some(b) => b.with_context(|| format!("{at}: cannot read the rows after row {}", self.row))?,
                    None => return Err(rows_read_error(at, self.row, f)),
                },
            };
            let take = batch.num_rows().min(end_row - self.row);
            if take < batch.num_rows() {
                self.rest = Some(batch.slice(take, batch.num_rows() - take));
            }
            let part = batch.slice(0, take);
            check_keys(at, &part, self.row, f)?;
            let add = |out: &mut Vec<f32>, name: &str, dim: usize, padded: bool| {
                let col = part.column_by_name(name).expect("projected");
                append(out, col, name, dim, padded, self.row, t).map_err(|e| anyhow::anyhow!("{at}: {e}"))
            };
            add(&mut block.obs, "obs", f.obs_dim, false)?;
            add(&mut block.ag, "achieved_goal", f.goal_dim, false)?;
            add(&mut block.u, "action", f.act_dim, true)?;
            if self.with_goals {
                add(&mut block.g, "desired_goal", f.goal_dim, true)?;
            }
            self.row += take;
        }
        Ok(Some((first, block)))
    }
}

impl Iterator for FileBlocks {
    type Item = Result<(usize, Episodes)>;

    /// Stops after the first error.
    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        let r = self.next_block().transpose();
        if !matches!(r, Some(Ok(_))) {
            self.done = true;
        }
        r
    }
}
