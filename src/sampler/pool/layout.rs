//! Where every block of a table is (read from footers and Parquet metadata alone), how a budget
//! splits between resident blocks, blocks in flight and the goal reservoir ([`Plan`]), and reading
//! one block, checked, as float32.

use std::path::Path;

use anyhow::{Context, Result, anyhow, bail};

use super::buffers::{Bytes, Floats};
use crate::sampler::priority::{PriorityConfig, SumTree};
use crate::score::ScoredTable;
use crate::table::ShardFile;
use crate::task::Task;
use crate::trajectory::Footer;
use crate::trajectory::folder::{TableFolder, is_folder, open_shard};
use crate::trajectory::read::{append, append_images, check_keys};

/// The share of the budget the goal reservoir may take.
pub(super) const RESERVOIR_SHARE: f64 = 0.125;
/// Blocks held beyond the resident ones: one waiting in the channel, and one being decoded (its
/// Arrow arrays and its float32 copy side by side).
pub(super) const IN_FLIGHT: u64 = 3;
/// The columns a block reads.
pub(super) const VECTORS: [&str; 4] = ["obs", "achieved_goal", "desired_goal", "action"];

/// One shard of the table, as the pool reads it.
pub(super) struct Shard {
    /// The file, opened once: its metadata, checksums and identity (a block read from a file
    /// replaced since is refused as changed).
    pub(super) file: ShardFile,
    /// The shard's own footer (its own rows and episodes): what `check_keys` checks rows against.
    pub(super) footer: Footer,
}

/// One block: a row group of a shard, holding whole episodes.
#[derive(Debug, Clone, Copy)]
pub(super) struct BlockInfo {
    pub(super) shard: usize,
    /// Its first row group, and how many it spans (one, or a whole shard in a shard window).
    pub(super) group: usize,
    pub(super) groups: usize,
    /// The block's first row in its shard.
    pub(super) first_row: usize,
    pub(super) episodes: usize,
    /// The table-wide number of its first episode.
    pub(super) first_episode: u64,
}

/// Where every block of a table is, read from footers and Parquet metadata only.
pub struct Layout {
    pub(super) task: Task,
    pub(super) t: usize,
    pub(super) episodes: u64,
    /// An image table's observation shape (its footer's `image_shape`); empty for states.
    pub(super) image_shape: Vec<usize>,
    /// Images each reservoir entry keeps (OGBench's `frame_stack`: a random goal's frames are
    /// its own and those before it, which its block is gone by the time they are read); 1
    /// otherwise.
    pub(super) frames: usize,
    pub(super) shards: Vec<Shard>,
    pub(super) blocks: Vec<BlockInfo>,
    /// Episodes of the largest block: the size the plan counts every block at, and that every
    /// block's arrays are made for.
    pub(super) largest: usize,
    /// With `-mem`: the scored table whose rows each block carries.
    pub(super) scored: Option<Scored>,
}

/// A scored table read beside β's blocks (`-mem` within a budget): each block carries the scored
/// rows of its transitions, their stored goals and their priorities.
pub(super) struct Scored {
    pub(super) table: ScoredTable,
    /// Scored rows per transition.
    pub(super) per: usize,
    pub(super) priority: PriorityConfig,
    /// Whether blocks keep each scored row's goal (episode, step), 8 bytes a row (OGBench's
    /// layout reports them; pgser's batches do not need them).
    pub(super) sources: bool,
}

impl Layout {
    /// The blocks of a table file or table folder; a row group that does not hold whole
    /// episodes is refused, naming the shard and row group.
    pub fn open(path: &Path) -> Result<Layout> {
        let (footer, shards): (Footer, Vec<(ShardFile, Footer, u64)>) = if is_folder(path) {
            let (folder, files) = TableFolder::open_shards(path)?;
            let firsts = folder.manifest.shards.iter().map(|s| s.first_episode as u64);
            let shards = files.into_iter().zip(firsts).map(|((file, f), first)| (file, f, first)).collect();
            (folder.footer().clone(), shards)
        } else {
            let (file, f) = open_shard(path)?;
            (f.clone(), vec![(file, f, 0)])
        };
        let (t, mut blocks, mut opened) = (footer.t, Vec::new(), Vec::new());
        if t < 2 {
            bail!("{}: episodes of {t} step(s) hold no transition", path.display());
        }
        for (i, (file, f, first_episode)) in shards.into_iter().enumerate() {
            let p = file.path().to_path_buf();
            let mut row = 0usize;
            for (g, rows) in file.group_rows()?.into_iter().enumerate() {
                if !row.is_multiple_of(t) || !rows.is_multiple_of(t) {
                    bail!(
                        "{}: row group {g} holds rows {row}..{}, not whole episodes of T = {t} (pgser's writers cut row \
                         groups between episodes; convert the data again)",
                        p.display(),
                        row + rows
                    );
                }
                let first = first_episode + (row / t) as u64;
                blocks.push(BlockInfo {
                    shard: i,
                    group: g,
                    groups: 1,
                    first_row: row,
                    episodes: rows / t,
                    first_episode: first,
                });
                row += rows;
            }
            if row != f.rows {
                bail!("{}: its row groups hold {row} rows but its footer says {}", p.display(), f.rows);
            }
            opened.push(Shard { file, footer: f });
        }
        let largest = largest(&blocks);
        Ok(Layout {
            task: footer.task(),
            t,
            episodes: footer.episodes as u64,
            image_shape: footer.image_shape.clone(),
            frames: 1,
            shards: opened,
            blocks,
            largest,
            scored: None,
        })
    }

    /// The layout with `table`'s rows carried by each block: refused unless `table` scored every
    /// transition of this one, with the same task.
    pub fn with_scored(mut self, table: ScoredTable, priority: PriorityConfig) -> Result<Layout> {
        let f = &table.footer;
        let at = table.path.display();
        let transitions = self.episodes as usize * (self.t - 1);
        if table.task != self.task || f.transitions != transitions || !f.rows.is_multiple_of(transitions.max(1)) {
            bail!(
                "{at}: scores {} transitions of {} where its original data holds {transitions} of {}: it is not this \
                 table's scored table",
                f.transitions,
                f.task,
                self.task.name
            );
        }
        let per = f.rows / transitions;
        self.scored = Some(Scored { table, per, priority, sources: false });
        Ok(self)
    }

    /// The layout with each block's scored rows keeping their goals' (episode, step) as well.
    pub fn with_goal_sources(mut self) -> Layout {
        if let Some(s) = self.scored.as_mut() {
            s.sources = true;
        }
        self
    }

    /// The layout with each reservoir entry of an image table keeping `frames` images: a random
    /// goal's stacked frames (OGBench's `frame_stack`).
    pub fn with_frames(mut self, frames: usize) -> Layout {
        if self.is_image() {
            self.frames = frames.max(1);
        }
        self
    }

    /// The layout with one block per shard, all its row groups: a shard window's unit.
    pub fn by_shard(mut self) -> Layout {
        let mut merged: Vec<BlockInfo> = Vec::with_capacity(self.shards.len());
        for b in self.blocks {
            match merged.last_mut() {
                Some(m) if m.shard == b.shard => {
                    m.groups += 1;
                    m.episodes += b.episodes;
                }
                _ => merged.push(b),
            }
        }
        self.largest = largest(&merged);
        self.blocks = merged;
        self
    }

    /// The table's task.
    pub fn task(&self) -> &Task {
        &self.task
    }

    /// Whether observations are images (their bytes held as bytes, not float32).
    pub fn is_image(&self) -> bool {
        !self.image_shape.is_empty()
    }

    /// An image observation's shape; empty for states.
    pub fn image_shape(&self) -> &[usize] {
        &self.image_shape
    }

    /// Bytes one observation takes in memory: an image's bytes, or `obs_dim` float32 values.
    fn obs_bytes(&self) -> u64 {
        self.task.obs_dim as u64 * if self.is_image() { 1 } else { 4 }
    }

    /// The scored table `with_scored` attached, taken back (to draw from β held whole).
    pub fn into_scored(self) -> Option<ScoredTable> {
        self.scored.map(|s| s.table)
    }

    /// Bytes of one episode as a block holds it (float32 vectors; an image table's observations
    /// as bytes), with its scored rows (a goal and a priority each, and the goal's source when
    /// kept) when it carries them.
    pub(super) fn episode_bytes(&self) -> u64 {
        let (t, task) = (self.t as u64, &self.task);
        let scored = self
            .scored
            .as_ref()
            .map_or(0, |s| (t - 1) * s.per as u64 * (4 * (task.goal_dim as u64 + 1) + if s.sources { 8 } else { 0 }));
        t * self.obs_bytes() + 4 * (t * task.goal_dim as u64 + (t - 1) * (task.goal_dim + task.act_dim) as u64) + scored
    }

    /// Bytes of the whole table in memory.
    pub fn bytes(&self) -> u64 {
        self.episodes * self.episode_bytes()
    }

    /// Bytes of one reservoir entry: an achieved goal, an observation (an image table's `frames`
    /// of them), where they came from (16 bytes: `Reservoir::at`) and its key (12 bytes:
    /// `Keys::slots`).
    pub(super) fn entry_bytes(&self) -> u64 {
        self.obs_bytes() * self.frames as u64 + 4 * self.task.goal_dim as u64 + 16 + 12
    }

    /// Where block `id` is, for messages: its shard and row group(s).
    pub(super) fn at(&self, id: usize) -> String {
        let b = self.blocks[id];
        let path = self.shards[b.shard].file.path().display();
        match b.groups {
            1 => format!("{path} (row group {})", b.group),
            n => format!("{path} (row groups {}..{})", b.group, b.group + n),
        }
    }

    /// Reads block `id`: its chunks checked against the shard's checksums, every row checked as
    /// `Episodes::load` checks them, decoded to float32.
    pub(super) fn read(&self, id: usize) -> Result<Block> {
        self.read_columns(id, &[true; 4], Arrays::default())
    }

    /// Reads the columns of block `id` that `which` marks (in [`VECTORS`] order) into `into`'s
    /// arrays (a leaving block's, or empty ones); the others stay empty. The reservoir's first
    /// fill reads observations and achieved goals only.
    pub(super) fn read_columns(&self, id: usize, which: &[bool; 4], into: Arrays) -> Result<Block> {
        let b = self.blocks[id];
        let shard = &self.shards[b.shard];
        let at = self.at(id);
        let groups: Vec<usize> = (b.group..b.group + b.groups).collect();
        let mut names = vec!["episode", "step"];
        names.extend(VECTORS.iter().zip(which).filter(|(_, w)| **w).map(|(n, _)| *n));
        let t = self.t;
        let task = &self.task;
        let image = self.is_image();
        // An image's bytes are a quarter of as many floats.
        let obs_width = if image { task.obs_dim.div_ceil(4) } else { task.obs_dim };
        let widest = obs_width.max(task.goal_dim).max(task.act_dim);
        // Every chunk decoded is read once and checked first, on the loader's own threads.
        let reader = shard.file.read(&groups, &names, None, decode_rows(widest))?;
        let dims = [task.obs_dim, task.goal_dim, task.goal_dim, task.act_dim];
        let steps = [t, t, t - 1, t - 1];
        let largest = self.largest;
        let Arrays { floats: mut out, mut images } = into;
        images.clear();
        for (k, v) in out.iter_mut().enumerate() {
            v.clear();
            if !which[k] || (image && k == 0) {
                *v = Floats::default();
            } else {
                // Room for the largest block, so an array recycled from a short block (a shard's
                // last row group) takes any later one; the plan counts every block at that size.
                v.reserve(largest * steps[k] * dims[k])?;
            }
        }
        if image && which[0] {
            images.reserve(largest * t * dims[0])?;
        } else {
            images = Bytes::default();
        }
        let mut row = b.first_row;
        for batch in reader {
            let batch = batch.with_context(|| format!("{at}: cannot read the rows after row {row}"))?;
            check_keys(&at, &batch, row, &shard.footer)?;
            for (k, v) in out.iter_mut().enumerate().filter(|(k, _)| which[*k]) {
                let col = batch.column_by_name(VECTORS[k]).expect("projected");
                if image && k == 0 {
                    append_images(&mut images, col, dims[0], row, t).map_err(|e| anyhow!("{at}: {e}"))?;
                    continue;
                }
                append(v, col, VECTORS[k], dims[k], steps[k] < t, row, t).map_err(|e| anyhow!("{at}: {e}"))?;
            }
            row += batch.num_rows();
        }
        if row != b.first_row + b.episodes * t {
            bail!("{at}: {} rows read where the row group holds {}", row - b.first_row, b.episodes * t);
        }
        let [obs, ag, g, u] = out;
        let aug = match &self.scored {
            Some(s) if which.iter().all(|w| *w) => Some(self.read_scored(s, &b)?),
            _ => None,
        };
        Ok(Block { id, n: b.episodes, first_episode: b.first_episode, obs, ag, g, u, images, aug })
    }

    /// The scored rows of block `b`'s transitions: their goals, and their priorities ranked or
    /// computed within the block (`pool.rs` says why).
    fn read_scored(&self, s: &Scored, b: &BlockInfo) -> Result<ScoredRows> {
        let per_episode = (self.t - 1) * s.per;
        let first = b.first_episode as usize * per_episode;
        let rows = (first, first + b.episodes * per_episode);
        let read = s.table.read_goals(rows, b.first_episode, self.t, s.per, s.sources)?;
        let priorities = s
            .priority
            .priorities(read.q, s.table.gamma)
            .with_context(|| format!("{}: rows {}..{}", s.table.path.display(), rows.0, rows.1))?;
        Ok(ScoredRows { first_row: first as u64, goal: read.goal, at: read.at, tree: SumTree::new(priorities) })
    }
}

fn largest(blocks: &[BlockInfo]) -> usize {
    blocks.iter().map(|b| b.episodes).max().unwrap_or(0)
}

/// Rows the loader decodes at a time: as many as keep the widest column's decoded array near
/// 256 kB, below glibc's mmap threshold, so the decoder's arrays come from the loader's heap and
/// are reused block after block instead of being mapped and zeroed anew (a whole block at once
/// made them fresh mappings of 17 MB per column on humanoidmaze's shape, and page faults were
/// about 40 % of the loader's time).
fn decode_rows(widest: usize) -> usize {
    ((256 << 10) / (4 * widest.max(1))).max(256)
}

/// How a table meets a budget.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plan {
    /// The table fits: held whole.
    Whole,
    /// `slots` resident blocks and a reservoir of `reservoir` goals.
    Pool { slots: usize, reservoir: usize },
}

impl Plan {
    /// The budget's split: the reservoir takes an eighth (at most one entry per observation of the
    /// table) and as much again (what the first fill's reads leave behind in the allocator,
    /// measured on a 1B-row folder: `Reservoir::fill`), `IN_FLIGHT` blocks are set aside, and the
    /// rest holds blocks of the largest size.
    /// Refused, saying what would do, when fewer than two blocks fit. The budget is β's: the
    /// process's own memory (code, networks, batches, Parquet metadata) comes on top of it, and
    /// BENCHMARKS.md measures the whole.
    pub fn of(layout: &Layout, budget: u64) -> Result<Plan> {
        if layout.bytes() <= budget {
            return Ok(Plan::Whole);
        }
        let block = layout.largest as u64 * layout.episode_bytes();
        let observations = layout.episodes * layout.t as u64;
        let reservoir =
            ((budget as f64 * RESERVOIR_SHARE) as u64 / layout.entry_bytes()).min(observations).max(1) as usize;
        // The reservoir twice: the first fill places each block's entries as it is read, but
        // with one reservoir's worth set aside the process stayed within the budget at 1B rows
        // (BENCHMARKS.md), and without it did not.
        let fixed = 2 * reservoir as u64 * layout.entry_bytes() + IN_FLIGHT * block;
        let slots = budget.saturating_sub(fixed) / block.max(1);
        if slots < 2 {
            let need = fixed + 2 * block;
            bail!(
                "a memory budget of {} holds fewer than two of the table's row groups ({} each in memory, {} more \
                 for reading and the goal reservoir); give at least {}, or convert with a smaller --row-group-rows",
                crate::progress::bytes(budget),
                crate::progress::bytes(block),
                crate::progress::bytes(fixed),
                crate::progress::bytes(need)
            );
        }
        if slots as usize >= layout.blocks.len() {
            return Ok(Plan::Whole);
        }
        Ok(Plan::Pool { slots: slots as usize, reservoir })
    }
}

/// A block's four arrays (in [`VECTORS`] order) and its images, emptied: a leaving block's are
/// handed back to the loader and filled with the next block's rows (`loader.rs` says why).
#[derive(Default)]
pub(super) struct Arrays {
    floats: [Floats; 4],
    images: Bytes,
}

/// A resident block.
pub(super) struct Block {
    pub(super) id: usize,
    pub(super) n: usize,
    pub(super) first_episode: u64,
    pub(super) obs: Floats,
    pub(super) ag: Floats,
    pub(super) g: Floats,
    pub(super) u: Floats,
    /// An image table's observations (then `obs` is empty).
    pub(super) images: Bytes,
    /// With `-mem`: the scored rows of its transitions.
    pub(super) aug: Option<ScoredRows>,
}

/// A block's scored rows, `per` per transition in (episode, step) order.
pub(super) struct ScoredRows {
    /// The scored table's number of the first.
    pub(super) first_row: u64,
    /// Each row's goal, as scored.
    pub(super) goal: Vec<f32>,
    /// Each row's goal (episode, step), when the layout keeps them (else empty).
    pub(super) at: Vec<[u32; 2]>,
    pub(super) tree: SumTree,
}

impl Block {
    /// Its arrays, taken for the loader to fill again.
    pub(super) fn take_arrays(&mut self) -> Arrays {
        use std::mem::take;
        Arrays {
            floats: [take(&mut self.obs), take(&mut self.ag), take(&mut self.g), take(&mut self.u)],
            images: take(&mut self.images),
        }
    }

    pub(super) fn obs(&self, e: usize, s: usize, t: usize, d: usize) -> &[f32] {
        &self.obs[(e * t + s) * d..][..d]
    }
    pub(super) fn ag(&self, e: usize, s: usize, t: usize, d: usize) -> &[f32] {
        &self.ag[(e * t + s) * d..][..d]
    }
    /// An image table's o[e, s] bytes (`d` of them); empty for states.
    pub(super) fn image(&self, e: usize, s: usize, t: usize, d: usize) -> &[u8] {
        if self.images.is_empty() { &[] } else { &self.images[(e * t + s) * d..][..d] }
    }
}
