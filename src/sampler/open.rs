//! Opening what a sampler draws from: the one place that decides, from a table's footers and
//! Parquet metadata and the user's budget, whether β is held whole in memory or as an
//! out-of-core pool (`pool.rs`), and where a scored table's rows go (beside β whole, or inside
//! the pool's blocks). `pgser-train` and `pgser.Sampler`'s pgser layout open their data through
//! [`super::stream::BatchSource`], OGBench's layout through `ogbench/swapped.rs`; both come here,
//! so a budget means the same thing in every sampler.
//!
//! Opening is two steps, [`plan`] then [`Planned::open`]: the plan reads footers and metadata
//! only, so a caller can refuse settings that a pool cannot serve (OGBench's swapped goals that
//! are not whole observations) before the pool reads its first block and fills its reservoir.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Result, bail};

use super::pool::{Layout, Plan, Pool, PoolConfig, Position};
use super::priority::PriorityConfig;
use super::view::{Budget, View};
use crate::score::ScoredTable;
use crate::trajectory::Episodes;

/// β for a sampler: whole, or a pool.
pub enum Beta {
    Whole(Arc<Episodes>),
    Pool(Box<Pool>),
}

impl Beta {
    /// β as draws see it.
    pub fn view(&self) -> &dyn View {
        match self {
            Beta::Whole(d) => d.as_ref(),
            Beta::Pool(p) => p.as_ref(),
        }
    }

    /// The arrays a trainer fits its normalizer on (observations; desired and achieved goals):
    /// the whole table, or the pool's first blocks, a uniform sample of the table's blocks.
    pub fn normalizer_arrays(&self) -> (Vec<&[f32]>, Vec<&[f32]>) {
        match self {
            Beta::Whole(d) => (vec![&d.obs[..]], vec![&d.g[..], &d.ag[..]]),
            Beta::Pool(p) => {
                let [obs, g, ag] = p.resident_arrays();
                (obs, g.into_iter().chain(ag).collect())
            }
        }
    }
}

/// Which observations a sampler takes: pgser's agents read float vectors (an image table is
/// refused, naming the file); OGBench's layout takes a visual dataset's images too, kept as bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Observations {
    States,
    /// Images too, a pool's random goals keeping `frames` of them each (`frame_stack`).
    StatesOrImages {
        frames: usize,
    },
}

/// A scored table opened beside its original data: its rows' priorities by `priority`; with
/// `goal_sources`, a pool's blocks keep each scored row's goal (episode, step), 8 bytes a row
/// (OGBench's layout reports them; pgser's batches do not need them).
pub struct Scoring {
    pub table: ScoredTable,
    pub priority: PriorityConfig,
    pub goal_sources: bool,
}

/// What was opened: β, and the scored table when it is held whole beside a whole β (a pool
/// carries its scored rows in its blocks).
pub struct Opened {
    pub data: Beta,
    pub scored: Option<ScoredTable>,
}

/// How a table will be held, decided before anything is loaded.
pub struct Planned {
    data: PathBuf,
    how: How,
    observations: Observations,
}

enum How {
    /// β whole, loaded from `data`, with the scored table whole beside it when there is one.
    Whole(Option<Box<ScoredTable>>),
    /// One shard resident at a time, the next after this many draws (`--shard-window`).
    Window(Box<Layout>, u64),
    /// A pool within `budget` bytes, as the plan split it.
    Pool { layout: Box<Layout>, budget: u64, draws_per_row: u32, slots: usize, reservoir: usize },
}

/// Plans the trajectory table `data` (a file or a table folder) within `budget`, with the rows
/// of a scored table of it when `scoring` is given (the caller has checked, with
/// [`checked_source`], that `data` is the table it was scored from). Settings a pool cannot serve
/// are refused here, naming the file: importance weights (`--is-beta`) need probabilities over
/// the whole scored table, which a pool, ranking rows within each block, does not have; and an
/// image table unless `observations` takes images.
pub fn plan(data: &Path, budget: Budget, scoring: Option<Scoring>, observations: Observations) -> Result<Planned> {
    let is_beta = scoring.as_ref().and_then(|s| s.priority.is_beta);
    let at = scoring.as_ref().map_or_else(|| data.display().to_string(), |s| s.table.path.display().to_string());
    let layout = |scoring: Option<Scoring>| -> Result<Box<Layout>> {
        let layout = match observations {
            Observations::States => {
                let l = Layout::open(data)?;
                crate::trajectory::state_only(&data.display().to_string(), l.image_shape(), "this sampler")?;
                l
            }
            Observations::StatesOrImages { frames } => Layout::open(data)?.with_frames(frames),
        };
        Ok(Box::new(match scoring {
            None => layout,
            Some(s) => {
                let l = layout.with_scored(s.table, s.priority)?;
                if s.goal_sources { l.with_goal_sources() } else { l }
            }
        }))
    };
    let how = match budget {
        Budget::Unbounded => How::Whole(scoring.map(|s| Box::new(s.table))),
        Budget::ShardWindow(rows) => {
            if let Some(beta) = is_beta {
                bail!("{at}: --is-beta {beta} with --shard-window: priorities are the held shard's own");
            }
            How::Window(layout(scoring)?, rows)
        }
        Budget::Bytes { bytes, draws_per_row } => {
            let layout = layout(scoring)?;
            match Plan::of(&layout, bytes)? {
                Plan::Whole => How::Whole(layout.into_scored().map(Box::new)),
                Plan::Pool { slots, reservoir } => {
                    if let Some(beta) = is_beta {
                        bail!(
                            "{at}: --is-beta {beta} within --memory-budget: a pool ranks swapped rows within each \
                             block, so their probabilities over the whole table, which the weights need, are not \
                             known; leave --is-beta unset, or give a budget that holds the data"
                        );
                    }
                    How::Pool { layout, budget: bytes, draws_per_row, slots, reservoir }
                }
            }
        }
    };
    Ok(Planned { data: data.to_path_buf(), how, observations })
}

impl Planned {
    /// Whether β will be a pool (within a budget it does not fit, or a shard window).
    pub fn is_pool(&self) -> bool {
        !matches!(self.how, How::Whole(_))
    }

    /// β's float32 bytes as a pool plans them, when it will be a pool.
    pub fn pool_bytes(&self) -> Option<u64> {
        match &self.how {
            How::Whole(_) => None,
            How::Window(layout, _) | How::Pool { layout, .. } => Some(layout.bytes()),
        }
    }

    /// Loads β whole, or starts the pool as it is at `at` (a resumed run's position, so that
    /// it reads its blocks and fills its reservoir once), with its draws seeded by `seed`.
    pub fn open(self, seed: u64, at: Position) -> Result<Opened> {
        Ok(match self.how {
            How::Whole(scored) => {
                let data = load_whole(&self.data, scored.as_deref(), self.observations)?;
                Opened { data: Beta::Whole(Arc::new(data)), scored: scored.map(|t| *t) }
            }
            How::Window(layout, rows) => {
                Opened { data: Beta::Pool(Box::new(Pool::window(*layout, rows, seed, at)?)), scored: None }
            }
            How::Pool { layout, budget, draws_per_row, slots, reservoir } => {
                let cfg = PoolConfig { budget, draws_per_row: f64::from(draws_per_row), seed, window: None };
                Opened {
                    data: Beta::Pool(Box::new(Pool::start(Arc::new(*layout), cfg, slots, reservoir, at)?)),
                    scored: None,
                }
            }
        })
    }
}

/// The trajectory table a scored table names, loaded whole and checked: present, unchanged, of
/// the same task.
pub fn beta_of(table: &ScoredTable) -> Result<Episodes> {
    load_whole(&checked_source(table)?, Some(table), Observations::States)
}

/// The trajectory table `data` whole; the original data of `scored` when given, so of its task.
fn load_whole(data: &Path, scored: Option<&ScoredTable>, observations: Observations) -> Result<Episodes> {
    let episodes = match observations {
        Observations::States => Episodes::load(data)?,
        Observations::StatesOrImages { .. } => Episodes::load_with_images(data)?,
    };
    if let Some(t) = scored
        && episodes.task != t.task
    {
        bail!("{}: its task differs from that of its original data {}", t.path.display(), data.display());
    }
    Ok(episodes)
}

/// Where the trajectory table a scored table names is, checked present and unchanged.
pub fn checked_source(table: &ScoredTable) -> Result<PathBuf> {
    let at = table.path.display();
    let (path, sha) = table.trajectory();
    if !path.exists() {
        bail!(
            "{at}: its original data {} is missing (the footer's path is relative to the scored file)",
            path.display()
        );
    }
    if crate::trajectory::folder::digest(&path)? != sha {
        bail!("{at}: its original data {} has changed since scoring (sha256 differs)", path.display());
    }
    Ok(path)
}
