//! `pgser-train`: the training job around the agent. Loads the data, fits the normalizer,
//! samples batches, runs updates, evaluates and checkpoints on schedule, and can resume.
//!
//! A run is a function of (data, config, seed): the networks' initial weights, the batches and
//! the target noise come from separate streams spawned from the seed, and all of their states go
//! into the checkpoint, so `--resume` after an interruption reaches the same weights as a run
//! that was never stopped.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use burn::tensor::Device;
use clap::Args;
use indicatif::ProgressBar;
use serde::{Deserialize, Serialize};

use crate::agent::{Agent, AgentConfig, Backend, Batch, Normalizer, Rows, Shards, checkpoint};
use crate::eval::{self, EvalReport};
use crate::output::AtomicFile;
use crate::progress;
use crate::sampler::SamplerConfig;
use crate::sampler::priority::PriorityConfig;
use crate::sampler::stream::{BatchSource, BatchStream, StreamConfig};
use crate::sampler::view::Budget;
use crate::trajectory::Episodes;
use rayon::prelude::*;

mod bench;
pub(crate) mod differ;
pub mod online;
mod resume;
pub mod stop;
pub use bench::{BenchReport, SamplerBenchReport, StreamBenchReport, bench_agents, bench_sampler, bench_stream};
pub use resume::{StaleCheckpoint, resume_point};
use resume::{continued_metrics, restore};

/// The training job's settings; with the agent's, this is everything a run depends on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Args)]
pub struct TrainConfig {
    #[command(flatten)]
    pub agent: AgentConfig,
    #[command(flatten)]
    pub sampler: SamplerConfig,
    /// Gradient updates to run (the paper: 500k per agent, 1M for the pre-trained Q).
    #[arg(long, default_value_t = 500_000)]
    pub updates: u64,
    /// Transitions per update.
    #[arg(long, default_value_t = 512)]
    pub batch_size: usize,
    /// Seed of the run: initial weights, batches and target noise.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Evaluate every M updates (0: only at the end).
    #[arg(long, default_value_t = 10_000)]
    pub eval_every: u64,
    /// Episodes per evaluation (0: no evaluation).
    #[arg(long, default_value_t = 50)]
    pub eval_episodes: usize,
    /// Seed of evaluation episode 0 (episode i uses eval_seed + i). Kept away from the small
    /// seeds `collect` uses, so agents are not evaluated on the starts of their own data.
    #[arg(long, default_value_t = 1_000_000)]
    pub eval_seed: u64,
    /// Write the checkpoint every M updates (0: only at the end).
    #[arg(long, default_value_t = 10_000)]
    pub save_every: u64,
    /// With a scored table (`--data scored.parquet`, the `-mem` variant): the fraction of each
    /// batch drawn by priority from its swapped rows; the rest comes from the original data.
    #[arg(long, default_value_t = 0.5)]
    pub aug_ratio: f64,
    #[command(flatten)]
    pub priority: PriorityConfig,
    /// With a scored table: hold its rows in memory instead of reading them from the file
    /// (same batches either way).
    #[arg(long)]
    pub aug_in_memory: bool,
    /// Record losses in the metrics file every M updates.
    #[arg(long, default_value_t = 1_000)]
    pub log_every: u64,
    /// Hold the original data within this much memory (e.g. 8GB, 512MiB): whole when it fits
    /// (the same batches as without), streamed from its row groups otherwise, with transitions
    /// and random goals from the whole table (docs/ogbench.md, "Datasets larger than memory").
    #[arg(long, value_name = "SIZE", value_parser = crate::sampler::view::parse_bytes)]
    #[serde(
        default,
        skip_serializing_if = "Option::is_none",
        deserialize_with = "crate::sampler::view::budget_setting"
    )]
    pub memory_budget: Option<u64>,
    /// With --memory-budget, when the data does not fit it: keep each row group resident for N
    /// draws per transition it holds (default 1: a pass of draws reads the table once). 2 reads
    /// half as much, for a trainer faster than the reading; every shard still gets its share of
    /// each pass of reading, and each block is drawn from for twice as long.
    #[arg(long, value_name = "N", requires = "memory_budget", value_parser = clap::value_parser!(u32).range(1..))]
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub draws_per_row: Option<u32>,
    /// Emulate Horizon Reduction's one-shard-at-a-time loading, for comparison: hold one shard of
    /// a table folder, move to the next (in folder order) every N updates, and draw every goal,
    /// random and prioritized ones included, from the held shard (docs/ogbench.md, "One shard at a
    /// time"). Horizon Reduction reloads every 1000 updates (4000 for humanoidmaze).
    #[arg(long, value_name = "N", conflicts_with = "memory_budget")]
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard_window: Option<u64>,
}

impl TrainConfig {
    /// The settings the batch stream depends on.
    pub fn stream(&self) -> StreamConfig {
        StreamConfig {
            sampler: self.sampler.clone(),
            batch_size: self.batch_size,
            aug_ratio: self.aug_ratio,
            priority: self.priority.clone(),
            aug_in_memory: self.aug_in_memory,
            seed: self.seed,
        }
    }

    /// `--memory-budget` as the sampler takes it.
    pub fn budget(&self) -> Budget {
        match (self.shard_window, self.memory_budget) {
            (Some(updates), _) => Budget::ShardWindow(updates.saturating_mul(self.batch_size as u64)),
            (None, Some(bytes)) => Budget::Bytes { bytes, draws_per_row: self.draws_per_row.unwrap_or(1) },
            (None, None) => Budget::Unbounded,
        }
    }
}

/// One line of the metrics file.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct MetricsLine {
    pub updates: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub critic_loss: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub actor_loss: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub q_mean: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub eval: Option<EvalReport>,
}

/// What `--json` prints (docs/checkpoint.md, JSON summaries).
#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub updates: u64,
    pub updates_per_sec: f64,
    pub eval: Option<EvalReport>,
    pub checkpoint: PathBuf,
    pub metrics: PathBuf,
}

/// Where the metrics of checkpoint `out` go: `out` + `.metrics.jsonl`.
pub fn metrics_path(out: &Path) -> PathBuf {
    crate::output::with_suffix(out, ".metrics.jsonl")
}

/// Trains on `data_path` (a trajectory table, or a scored table for the `-mem` variant) into
/// the checkpoint `out`; `command` is recorded in the checkpoint (the CLI passes its command line,
/// a pipeline its step name, so a re-run writes the same bytes however it was invoked). A stack
/// of one cell (`train_stack`).
pub fn train(
    data_path: &Path,
    out: &Path,
    cfg: &TrainConfig,
    resume: bool,
    backend: Backend,
    command: &str,
    bar: &ProgressBar,
) -> Result<Summary> {
    let cell = Cell { data: data_path.to_path_buf(), out: out.to_path_buf(), cfg: cfg.clone(), resume };
    Ok(train_stack(std::slice::from_ref(&cell), backend, &[command.to_string()], bar)?.remove(0))
}

/// One run of a stack: its data, its checkpoint, its settings, and whether it continues from its
/// checkpoint.
#[derive(Debug, Clone)]
pub struct Cell {
    pub data: PathBuf,
    pub out: PathBuf,
    pub cfg: TrainConfig,
    pub resume: bool,
}

/// What the cells of one stack must share: the networks' settings and the schedule, since all
/// agents of a stack take their updates, evaluations and checkpoints together. Seeds, data,
/// sampling (`--swap`, the scored table's mix and priorities) may differ.
pub fn schedule(cfg: &TrainConfig) -> serde_json::Value {
    serde_json::json!({
        "agent": cfg.agent, "updates": cfg.updates, "batch_size": cfg.batch_size, "eval_every": cfg.eval_every,
        "eval_episodes": cfg.eval_episodes, "eval_seed": cfg.eval_seed, "save_every": cfg.save_every,
        "log_every": cfg.log_every,
    })
}

/// A cell's batch stream and records while it trains.
struct Run {
    cell: Cell,
    batches: BatchStream,
    metrics: Vec<MetricsLine>,
    extra: BTreeMap<String, String>,
    last_eval: Option<EvalReport>,
}

impl Run {
    fn next_batch(&mut self) -> Result<Batch> {
        Ok(self.batches.next_batch()?.0)
    }

    /// The next batch as rows of held table `table` (the engine holds this cell's β there).
    fn next_rows(&mut self, table: usize) -> Result<Rows> {
        let mut rows = self.batches.next_rows()?.0;
        rows.table = table;
        Ok(rows)
    }

    /// Writes agent i of the stack as this cell's checkpoint, resume state and metrics.
    fn save(&self, agents: &Shards, i: usize) -> Result<()> {
        let (agent, i) = agents.locate(i);
        let out = &self.cell.out;
        let mut resume_extra = BTreeMap::new();
        resume_extra.insert("batch_rng".to_string(), serde_json::to_string(&self.batches.rng().words())?);
        // All three are written first, then put in place: the metrics (later lines are dropped
        // on resume), then the checkpoint with its resume state (`checkpoint::commit_with`), so
        // that a crash at any instant leaves a checkpoint whose resume state loads with it. Both
        // record their update count, and `--resume` never continues from a mixed pair.
        let metrics = stage_metrics(&metrics_path(out), &self.metrics)?;
        let resume = checkpoint::stage_resume(agent, i, &checkpoint::resume_path(out), &resume_extra)?;
        let model = checkpoint::stage(agent, i, out, &self.extra)?;
        metrics.commit()?;
        checkpoint::commit_with(model, vec![resume])
    }
}

/// Trains the cells as one stack of agents: each cell's agent draws the same batches and noise
/// and ends with the same checkpoint, metrics and evaluations as when trained alone, while every
/// network layer runs once for all of them. `commands[i]` is recorded in cell i's checkpoint.
/// The cells share `schedule`, the task, and the update count they start from.
pub fn train_stack(cells: &[Cell], backend: Backend, commands: &[String], bar: &ProgressBar) -> Result<Vec<Summary>> {
    let first = cells.first().context("no cell to train")?;
    let device = backend.device()?;
    let _training = stop::Training::start();
    for c in cells {
        if schedule(&c.cfg) != schedule(&first.cfg) {
            bail!(
                "{}: a stack's cells must share the agent settings and schedule; {} has {}, {} has {}",
                c.out.display(),
                first.out.display(),
                schedule(&first.cfg),
                c.out.display(),
                schedule(&c.cfg)
            );
        }
    }
    let mut outs: Vec<&Path> = cells.iter().map(|c| c.out.as_path()).collect();
    outs.sort();
    if let Some(w) = outs.windows(2).find(|w| w[0] == w[1]) {
        bail!("{}: two cells of one stack write the same checkpoint", w[0].display());
    }
    let mut runs = Vec::with_capacity(cells.len());
    let mut agents = Vec::with_capacity(cells.len());
    for (cell, command) in cells.iter().zip(commands) {
        let (run, agent) = prepare(cell, command, device.clone())?;
        if let Some(prev) = agents.first().map(|a: &Agent| (a.task.clone(), a.updates))
            && (prev.0 != agent.task || prev.1 != agent.updates)
        {
            bail!(
                "{}: a stack's cells must share the task and the update they start from ({} at {} vs {} at {})",
                cell.out.display(),
                prev.0.name,
                prev.1,
                agent.task.name,
                agent.updates
            );
        }
        runs.push(run);
        agents.push(agent);
    }
    // OGBench's mazes are scored by success in percent, as their results tables are.
    let by_success = eval::scored_by_success(&agents[0].task.name);
    // Both cores busy, the same bits at any thread count (agent/shards.rs, agent/fused.rs).
    let mut agent = Shards::new(agents, backend)?;
    for run in &runs {
        if let Some(pool) = run.batches.pool()
            && pool.is_window()
        {
            let (_, shards) = pool.blocks();
            progress::note(
                bar,
                &format!(
                    "{}: one of {shards} shards at a time (--shard-window {}: the next every {} updates), every goal \
                     from the held shard",
                    run.cell.out.display(),
                    run.cell.cfg.shard_window.unwrap_or(0),
                    run.cell.cfg.shard_window.unwrap_or(0)
                ),
            );
        } else if let Some(pool) = run.batches.pool() {
            let (resident, blocks) = pool.blocks();
            progress::note(
                bar,
                &format!(
                    "{}: the data stream from disk within --memory-budget {}: {resident} of {blocks} row groups resident \
                     ({} episodes), {} random goals from the whole table",
                    run.cell.out.display(),
                    crate::progress::bytes(run.cell.cfg.memory_budget.unwrap_or(0)),
                    pool.resident_episodes(),
                    pool.reservoir()
                ),
            );
        }
    }
    // An engine on a GPU keeps the cells' data there (each distinct β once) and is sent each
    // batch as row numbers; elsewhere batches are gathered here. Same batches either way.
    let (datas, table_of) = distinct_data(&runs).unwrap_or_default();
    let tables: Vec<_> = datas.iter().map(|d| crate::sampler::table(d)).collect();
    let held = !tables.is_empty() && agent.hold(&tables)?;
    if held {
        let mb = tables.iter().map(|t| t.bytes()).sum::<usize>() as f64 / 1e6;
        progress::milestone(bar, &format!("the device holds the data ({mb:.1} MB): batches are sent as row numbers"));
    }
    let cfg = first.cfg.clone();
    let evaluate = |agent: &Shards| -> Result<Option<Vec<EvalReport>>> {
        if cfg.eval_episodes == 0 {
            return Ok(None);
        }
        eval::evaluate_stack(agent, cfg.eval_episodes, cfg.eval_seed).map(Some)
    };

    bar.set_length(cfg.updates);
    bar.set_position(agent.updates());
    let mut update_time = 0.0f64;
    let start_updates = agent.updates();
    let started = Instant::now();
    let mut saved_at = None;
    loop {
        // SIGTERM (`stop`): save where we are (unless a scheduled save just did) and stop.
        if stop::requested() && agent.updates() < cfg.updates {
            if saved_at != Some(agent.updates()) {
                agent.sync();
                for (i, run) in runs.iter().enumerate() {
                    run.save(&agent, i)?;
                }
            }
            return Err(stop::Interrupted { updates: agent.updates(), of: cfg.updates }.into());
        }
        if agent.updates() >= cfg.updates {
            break;
        }
        let t0 = Instant::now();
        // Each cell samples from its own streams, so doing it in parallel changes no draw.
        let u = agent.updates() + 1;
        let log = cfg.log_every > 0 && u.is_multiple_of(cfg.log_every);
        // Losses only on logging steps: on a GPU, reading them waits for the update.
        let stats = if held {
            let rows: Vec<Rows> =
                runs.par_iter_mut().zip(&table_of).map(|(r, &t)| r.next_rows(t)).collect::<Result<_>>()?;
            agent.step_rows(&rows, log)
        } else {
            let batches: Vec<Batch> = runs.par_iter_mut().map(Run::next_batch).collect::<Result<_>>()?;
            agent.step(&batches, log)
        };
        let mut lines: Vec<MetricsLine> = (0..runs.len())
            .map(|_| MetricsLine { updates: u, critic_loss: None, actor_loss: None, q_mean: None, eval: None })
            .collect();
        if log {
            let stats = stats.expect("asked for on logging steps");
            for ((line, (critic, q, actor)), run) in lines.iter_mut().zip(stats.read()).zip(&runs) {
                if !critic.is_finite() {
                    bail!(
                        "{}: update {u}: the critic loss is {critic}; training diverged (try a lower --lr)",
                        run.cell.out.display()
                    );
                }
                (line.critic_loss, line.q_mean, line.actor_loss) = (Some(critic), Some(q), actor);
            }
        }
        update_time += t0.elapsed().as_secs_f64();
        if cfg.eval_every > 0 && u.is_multiple_of(cfg.eval_every) && u < cfg.updates {
            for (i, report) in evaluate(&agent)?.into_iter().flatten().enumerate() {
                lines[i].eval = Some(report.clone());
                runs[i].last_eval = Some(report);
            }
        }
        for (run, line) in runs.iter_mut().zip(lines) {
            if log || line.eval.is_some() {
                run.metrics.push(line);
            }
        }
        if cfg.save_every > 0 && u.is_multiple_of(cfg.save_every) && u < cfg.updates {
            agent.sync();
            for (i, run) in runs.iter().enumerate() {
                run.save(&agent, i)?;
            }
            saved_at = Some(u);
            progress::milestone(
                bar,
                &saved_line(&runs, u, cfg.updates, (u - start_updates, started.elapsed()), by_success),
            );
        }
        bar.set_position(u);
    }
    // The final evaluation and checkpoint (also when resuming a run that had already finished).
    if agent.updates() > start_updates || runs.iter().any(|r| r.last_eval.is_none()) {
        let u = agent.updates();
        for (i, report) in evaluate(&agent)?.into_iter().flatten().enumerate() {
            let run = &mut runs[i];
            run.last_eval = Some(report.clone());
            run.metrics.retain(|m| m.updates < u || m.eval.is_none());
            run.metrics.push(MetricsLine {
                updates: u,
                critic_loss: None,
                actor_loss: None,
                q_mean: None,
                eval: Some(report),
            });
        }
    }
    agent.sync();
    for (i, run) in runs.iter().enumerate() {
        run.save(&agent, i)?;
    }
    bar.finish_and_clear();
    let done = agent.updates() - start_updates;
    Ok(runs
        .iter()
        .map(|r| Summary {
            updates: agent.updates(),
            updates_per_sec: if update_time > 0.0 { done as f64 / update_time } else { 0.0 },
            eval: r.last_eval.clone(),
            checkpoint: r.cell.out.clone(),
            metrics: metrics_path(&r.cell.out),
        })
        .collect())
}

/// The cells' data, each distinct β once (a grid's cells mostly share one: the baseline's and
/// `-swap`'s trajectory table is the one `-mem`'s scored table names), and each cell's place
/// among them; `None` when a cell draws from an out-of-core pool, which no engine holds.
fn distinct_data(runs: &[Run]) -> Option<(Vec<Arc<Episodes>>, Vec<usize>)> {
    let same = |a: &Episodes, b: &Episodes| {
        a.task == b.task && a.n == b.n && a.t == b.t && a.obs == b.obs && a.ag == b.ag && a.g == b.g && a.u == b.u
    };
    let mut datas: Vec<Arc<Episodes>> = Vec::new();
    let mut table_of = Vec::with_capacity(runs.len());
    for r in runs {
        let d = r.batches.whole()?;
        let i = match datas.iter().position(|x| Arc::ptr_eq(x, d) || same(x, d)) {
            Some(i) => i,
            None => {
                datas.push(d.clone());
                datas.len() - 1
            }
        };
        table_of.push(i);
    }
    Some((datas, table_of))
}

/// A log line at a scheduled save: "10.0k of 30.0k updates saved (15 agents), 5.1 updates/s, ≈ 1.1 h
/// left; last evaluation (10.0k): paper score 20.12 (15.98–25.04)", or "success 42.0 % (…)" on
/// a task scored by success (`by_success`: OGBench's, where T + return means nothing). The rate
/// counts this run's updates over its wall time, evaluations and saves included, as the time left
/// will.
fn saved_line(runs: &[Run], u: u64, of: u64, (done, took): (u64, std::time::Duration), by_success: bool) -> String {
    let k = progress::count;
    let mut s = format!("{} of {} updates saved", k(u), k(of));
    if runs.len() > 1 {
        s += &format!(" ({} agents)", runs.len());
    }
    let rate = done as f64 / took.as_secs_f64();
    if rate > 0.0 {
        s += &format!(", {rate:.1} updates/s, ≈ {} left", progress::duration((of - u) as f64 / rate));
    }
    // Each agent's latest evaluation line (the agents of a stack are evaluated together).
    let last: Vec<(u64, f64)> = runs
        .iter()
        .filter_map(|r| {
            r.metrics.iter().rev().find_map(|m| {
                let e = m.eval.as_ref()?;
                Some((m.updates, if by_success { 100.0 * e.success_rate } else { e.paper_score }))
            })
        })
        .collect();
    s + &progress::last_evaluation(&last, by_success)
}

/// A cell's data, sampler and agent (a stack of one): fresh, or restored from its checkpoint.
fn prepare(cell: &Cell, command: &str, device: Device) -> Result<(Run, Agent)> {
    let (data_path, out, cfg) = (&cell.data, &cell.out, &cell.cfg);
    crate::output::check_not_an_input(out, &[data_path.to_path_buf()])?;
    let stream = cfg.stream();
    let data_sha = crate::trajectory::folder::digest(data_path)?;
    // A resumed run's checkpoint first: its pool is opened where the run stopped, once.
    let restored = if cell.resume { Some(restore(out, cfg, &data_sha, device.clone())?) } else { None };
    let first = restored.as_ref().map_or(0, |(agent, _, _)| agent.updates);
    let source = BatchSource::open_resuming(data_path, &stream, cfg.budget(), first)?;

    let mut extra = BTreeMap::new();
    extra.insert("train".to_string(), serde_json::to_string(cfg)?);
    extra.insert("data".to_string(), data_path.display().to_string());
    extra.insert("data_sha256".to_string(), data_sha.clone());
    extra.insert("command".to_string(), command.to_string());

    let (agent, batches, metrics) = if let Some((agent, rng, metrics)) = restored {
        (agent, source.resume(&stream, rng, first)?, metrics)
    } else {
        // The goal normalizer sees achieved goals too: HER and swapping train on them.
        let task = source.task().clone();
        let (obs, goals) = source.data.normalizer_arrays();
        let norm = Normalizer::fit(&obs, task.obs_dim, &goals, task.goal_dim, cfg.agent.norm_clip);
        let agent = Agent::new(cfg.agent.clone(), task, norm, cfg.seed, device);
        (agent, source.start(&stream)?, Vec::new())
    };
    let (metrics, last_eval) = continued_metrics(metrics, agent.updates, cfg.eval_every);
    Ok((Run { cell: cell.clone(), batches, metrics, extra, last_eval }, agent))
}

/// A metrics file (one JSON line per record), staged for the caller to commit.
fn stage_metrics<T: Serialize>(path: &Path, lines: &[T]) -> Result<AtomicFile> {
    let mut text = String::new();
    for l in lines {
        text.push_str(&serde_json::to_string(l)?);
        text.push('\n');
    }
    let out = AtomicFile::create(path)?;
    std::io::Write::write_all(&mut out.handle()?, text.as_bytes())
        .with_context(|| format!("{}: write failed", path.display()))?;
    Ok(out)
}

/// A metrics file's records, one JSON object per line, as `--resume` reads them (public for the
/// fuzz target of this reader); a missing file has none.
pub fn read_metrics<T: serde::de::DeserializeOwned>(path: &Path) -> Result<Vec<T>> {
    if !path.exists() {
        return Ok(Vec::new());
    }
    let text = crate::output::read_input_text(path)?;
    text.lines()
        .enumerate()
        .map(|(i, l)| {
            serde_json::from_str(l)
                .with_context(|| format!("{}: line {} is not a metrics record", path.display(), i + 1))
        })
        .collect()
}
