//! The batches a training run draws, as one stream: `pgser-train` trains on it, `pgser-train
//! batches` writes its first batches to a table, and the Python module's `pgser.Sampler` iterates
//! it. One type for all three is what makes "the same settings and seed give the batches
//! pgser-train trains on" true by construction instead of by a second implementation kept in step.
//!
//! A batch of `batch_size` rows is, in order: `batch_size − k_aug` rows from the original data β
//! (uniform transitions, HER, and `--swap random`: [`super::sample`]), then, when the data is a
//! scored table (the `-mem` variant), `k_aug = round(batch_size · aug_ratio)` rows drawn by
//! priority from its swapped rows ([`ScoredSampler`]), with their importance weights.

use std::path::Path;
use std::sync::Arc;

use anyhow::{Result, bail};

use super::open::{self, Beta, Observations, Opened, Scoring};
use super::pool::{Pool, Position, ScoredDraw};
use super::priority::PriorityConfig;
use super::scored::ScoredSampler;
use super::view::{Budget, View};
use super::{RowKey, SamplerConfig, Swap};
use crate::agent::{Batch, Rows};
use crate::nprandom::NpRandom;
use crate::score::ScoredTable;
use crate::task::Task;
use crate::trajectory::Episodes;

/// Spawn key of the batch stream (the agent's streams use 1 and 2, the prioritized draws 4).
const STREAM_BATCHES: u64 = 3;

/// What a stream depends on besides its data: the sampling half of `pgser-train`'s settings.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct StreamConfig {
    pub sampler: SamplerConfig,
    pub batch_size: usize,
    /// With a scored table: the fraction of each batch drawn by priority from its swapped rows.
    pub aug_ratio: f64,
    pub priority: PriorityConfig,
    /// With a scored table: hold its row keys in memory (same batches either way).
    pub aug_in_memory: bool,
    pub seed: u64,
}

/// Where each row of a batch came from.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct RowIds {
    /// The transition's (episode, step) in β.
    pub episode: Vec<u32>,
    pub step: Vec<u32>,
    /// The row of the scored table for prioritized rows; −1 for rows of the original data.
    pub scored_row: Vec<i64>,
}

/// The data a stream draws from, opened and checked, before the stream starts: the trainer fits
/// its normalizer on `data` and restores a checkpoint before it knows where the stream resumes.
pub struct BatchSource {
    pub data: Beta,
    scored: Option<ScoredTable>,
    /// The batch a pool was opened at: the stream must start there.
    first: u64,
}

impl BatchSource {
    /// Opens a trajectory table (a file or a table folder), or a scored table and the trajectory
    /// table its footer names, whole in memory. Settings that cannot make batches from this data
    /// are refused here, naming the file.
    pub fn open(path: &Path, cfg: &StreamConfig) -> Result<BatchSource> {
        BatchSource::open_within(path, cfg, Budget::Unbounded)
    }

    /// As [`BatchSource::open`], with β held within `budget` (`--memory-budget`): whole when it
    /// fits (the same batches as `open`), an out-of-core pool otherwise (`pool.rs`).
    pub fn open_within(path: &Path, cfg: &StreamConfig, budget: Budget) -> Result<BatchSource> {
        BatchSource::open_resuming(path, cfg, budget, 0)
    }

    /// As [`BatchSource::open_within`], for a stream that resumes at batch `first`
    /// ([`BatchSource::resume`]): a pool is opened as it is there, so a resumed run reads its
    /// blocks and fills its reservoir once, and never holds a second pool.
    pub fn open_resuming(path: &Path, cfg: &StreamConfig, budget: Budget, first: u64) -> Result<BatchSource> {
        if cfg.batch_size == 0 {
            bail!("--batch-size must be at least 1");
        }
        cfg.priority.validate()?;
        // Every batch of a pool's stream draws `batch_size` rows, its scored ones included.
        let at = Position { batches: first, rows: cfg.batch_size };
        let source = match ScoredTable::open_if_scored(path)? {
            Some(table) => BatchSource::open_scored(table, cfg, budget, at)?,
            None => BatchSource {
                data: open::plan(path, budget, None, Observations::States)?.open(cfg.seed, at)?.data,
                scored: None,
                first,
            },
        };
        if source.data.view().t() < 2 {
            bail!("{}: episodes of {} step(s) hold no transition", path.display(), source.data.view().t());
        }
        Ok(source)
    }

    /// A scored table and its original data: β whole with the prioritized rows drawn from the
    /// whole scored table when both fit `budget`, else a pool whose blocks carry their scored rows
    /// (`pool.rs`, "PGSER within a budget").
    fn open_scored(table: ScoredTable, cfg: &StreamConfig, budget: Budget, pos: Position) -> Result<BatchSource> {
        let at = table.path.display().to_string();
        if cfg.sampler.swap != Swap::None {
            bail!(
                "{at}: --swap random with a scored table; its swapped rows already come from the table (use --swap none)"
            );
        }
        if !(0.0..=1.0).contains(&cfg.aug_ratio) {
            bail!("--aug-ratio {} is not in [0, 1]", cfg.aug_ratio);
        }
        let source = open::checked_source(&table)?;
        let scoring = Scoring { table, priority: cfg.priority.clone(), goal_sources: false };
        let Opened { data, scored } =
            open::plan(&source, budget, Some(scoring), Observations::States)?.open(cfg.seed, pos)?;
        Ok(BatchSource { data, scored, first: pos.batches })
    }

    /// Whether the data is a scored table (batches then mix in prioritized swapped rows).
    pub fn is_scored(&self) -> bool {
        self.scored.is_some() || matches!(&self.data, Beta::Pool(p) if p.is_scored())
    }

    /// The task of the data.
    pub fn task(&self) -> &Task {
        self.data.view().task()
    }

    /// The stream a fresh run of `cfg` draws: batch 0 on.
    pub fn start(self, cfg: &StreamConfig) -> Result<BatchStream> {
        self.resume(cfg, NpRandom::spawned(cfg.seed, &[STREAM_BATCHES]), 0)
    }

    /// The stream from batch `first` on, with the original data's generator as it was after
    /// batch `first − 1` (a resumed run's saved state): the batches an uninterrupted run draws.
    /// A pool must have been opened there ([`BatchSource::open_resuming`]).
    pub fn resume(self, cfg: &StreamConfig, rng: NpRandom, first: u64) -> Result<BatchStream> {
        if matches!(self.data, Beta::Pool(_)) && first != self.first {
            bail!(
                "a pool opened for batch {} cannot start at batch {first}: open it where the stream resumes \
                 (BatchSource::open_resuming)",
                self.first
            );
        }
        let k_aug = if self.is_scored() { ((cfg.batch_size as f64) * cfg.aug_ratio).round() as usize } else { 0 };
        let aug = match (self.scored, &self.data) {
            (Some(t), Beta::Whole(data)) => {
                Some(ScoredSampler::start(t, data.clone(), &cfg.priority, k_aug, cfg.seed, first, cfg.aug_in_memory)?)
            }
            (Some(_), Beta::Pool(_)) => unreachable!("a pool carries its scored rows in its blocks (open_scored)"),
            (None, _) => None,
        };
        Ok(BatchStream { data: self.data, aug, k_aug, rng, cfg: cfg.clone() })
    }
}

/// Batch after batch of one run's training data.
pub struct BatchStream {
    data: Beta,
    aug: Option<ScoredSampler>,
    k_aug: usize,
    rng: NpRandom,
    cfg: StreamConfig,
}

impl BatchStream {
    /// β, when it is held whole (what an engine may hold on its device).
    pub fn whole(&self) -> Option<&Arc<Episodes>> {
        match &self.data {
            Beta::Whole(d) => Some(d),
            Beta::Pool(_) => None,
        }
    }

    /// The out-of-core pool, when β is one.
    pub fn pool(&self) -> Option<&Pool> {
        match &self.data {
            Beta::Whole(_) => None,
            Beta::Pool(p) => Some(p),
        }
    }

    /// The original data's generator, as a resumed run must restore it.
    pub fn rng(&self) -> &NpRandom {
        &self.rng
    }

    /// The next batch, with where each of its rows came from.
    pub fn next_batch(&mut self) -> Result<(Batch, RowIds)> {
        match &mut self.data {
            Beta::Whole(data) => {
                let data = data.clone();
                let (rows, ids) = self.next_rows()?;
                Ok((rows.gather(&super::table(&data)), ids))
            }
            Beta::Pool(pool) => {
                pool.refresh(self.cfg.batch_size)?;
                let n = self.cfg.batch_size - self.k_aug;
                let drawn = super::draw(pool.as_ref(), &self.cfg.sampler, &mut self.rng, n);
                let mut ids = RowIds {
                    episode: drawn.iter().map(|r| pool.episode_number(r.0) as u32).collect(),
                    step: drawn.iter().map(|r| r.1 as u32).collect(),
                    scored_row: vec![-1; drawn.len()],
                };
                let mut batch = super::gather(pool.as_ref(), &drawn);
                if self.k_aug > 0 {
                    let aug = pool.draw_scored(self.k_aug, &mut self.rng);
                    ids.episode.extend(aug.iter().map(|d| pool.episode_number(d.e) as u32));
                    ids.step.extend(aug.iter().map(|d| d.step as u32));
                    ids.scored_row.extend(aug.iter().map(|d| pool.scored_row(d) as i64));
                    batch.append(&gather_scored(pool, &aug));
                }
                Ok((batch, ids))
            }
        }
    }

    /// The next batch as the rows it names in β (`super::table` of [`BatchStream::whole`]), with
    /// their rewards and weights: what an engine that holds β gathers on its device. Only for β
    /// held whole; a pool's batches are gathered on the host ([`BatchStream::next_batch`]).
    pub fn next_rows(&mut self) -> Result<(Rows, RowIds)> {
        let Beta::Whole(data) = &self.data else {
            bail!("an out-of-core pool's batches are built on the host, not sent as rows of a held table");
        };
        let n = self.cfg.batch_size - self.k_aug;
        let drawn = super::draw(data.as_ref(), &self.cfg.sampler, &mut self.rng, n);
        let mut keys: Vec<RowKey> = drawn.iter().map(|&(e, t, s)| RowKey::of(e as u64, t, s)).collect();
        let mut ids = RowIds {
            episode: drawn.iter().map(|r| r.0 as u32).collect(),
            step: drawn.iter().map(|r| r.1 as u32).collect(),
            scored_row: vec![-1; n],
        };
        let mut weight = Vec::new();
        if let Some(aug) = self.aug.as_mut() {
            let (scored, aug_keys, aug_weights) = aug.next_keys()?;
            if self.cfg.priority.is_beta.is_some() {
                weight = vec![1.0; n];
                weight.extend_from_slice(&aug_weights);
            }
            ids.episode.extend(aug_keys.iter().map(|k| k.episode));
            ids.step.extend(aug_keys.iter().map(|k| k.step));
            ids.scored_row.extend(scored.iter().map(|&r| r as i64));
            keys.extend(aug_keys);
        }
        let mut rows = super::rows(data, keys);
        rows.weight = weight;
        Ok((rows, ids))
    }
}

/// The batch of prioritized rows `drawn` from a pool's blocks: the transition from β, the goal
/// it was scored with, the reward recomputed as [`super::gather`] does.
fn gather_scored(pool: &Pool, drawn: &[ScoredDraw]) -> Batch {
    let task = pool.task();
    let mut b = Batch { n: drawn.len(), ..Batch::default() };
    let mut next_ag = Vec::with_capacity(drawn.len() * task.goal_dim);
    for d in drawn {
        b.obs.extend_from_slice(pool.obs(d.e, d.step));
        b.next_obs.extend_from_slice(pool.obs(d.e, d.step + 1));
        b.action.extend_from_slice(pool.action(d.e, d.step));
        b.goal.extend_from_slice(pool.scored_goal(d));
        next_ag.extend_from_slice(pool.ag(d.e, d.step + 1));
    }
    b.reward = vec![0.0; b.n];
    task.rewards(&next_ag, &b.goal, &mut b.reward);
    b
}
