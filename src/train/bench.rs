//! `pgser-train bench` and `bench-sampler`: the training job's parts timed alone, the figures
//! `make bench` compares with the Python peers. Kept apart from the job itself.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Result;
use serde::Serialize;

use crate::agent::{Agent, AgentConfig, Backend, Batch, Normalizer, Shards};
use crate::nprandom::NpRandom;
use crate::sampler::open::beta_of;
use crate::sampler::priority::PriorityConfig;
use crate::sampler::scored::ScoredSampler;
use crate::score::ScoredTable;

/// `pgser-train bench`: updates/s of the agent alone on random batches of a task's dimensions,
/// the figure `make bench` compares with the same update in PyTorch; with `agents` > 1, a stack
/// of that many agents trained at once (agent-updates/s = agents × updates/s).
#[derive(Debug, Clone, Serialize)]
pub struct BenchReport {
    pub task: String,
    pub algo: crate::agent::Algo,
    pub backend: String,
    pub threads: usize,
    pub batch_size: usize,
    pub agents: usize,
    /// Stacks the agents were split into, updated side by side (one per worker thread on CPU).
    pub shards: usize,
    pub updates: u64,
    pub seconds: f64,
    pub updates_per_sec: f64,
    pub agent_updates_per_sec: f64,
}

#[allow(clippy::too_many_arguments)]
pub fn bench_agents(
    task: &crate::task::Task,
    agent_cfg: &AgentConfig,
    batch_size: usize,
    updates: u64,
    warmup: u64,
    backend: Backend,
    agents: usize,
) -> Result<BenchReport> {
    let device = backend.device()?;
    let mut rng = NpRandom::new(0);
    let mut uniform = |n: usize| (0..n).map(|_| rng.uniform(-1.0, 1.0) as f32).collect::<Vec<f32>>();
    let n = batch_size;
    // Eight distinct sets of batches (one per agent), cycled, so data generation is not timed.
    let sets: Vec<Vec<Batch>> = (0..8)
        .map(|_| {
            (0..agents)
                .map(|_| Batch {
                    n,
                    obs: uniform(n * task.obs_dim),
                    goal: uniform(n * task.goal_dim),
                    action: uniform(n * task.act_dim),
                    reward: uniform(n).into_iter().map(|x| if x < 0.0 { -1.0 } else { 0.0 }).collect(),
                    next_obs: uniform(n * task.obs_dim),
                    weight: vec![],
                })
                .collect()
        })
        .collect();
    let norm = Normalizer::identity(task, agent_cfg.norm_clip);
    // As the trainer holds a grid (agent/shards.rs).
    let alone =
        (0..agents as u64).map(|s| Agent::new(agent_cfg.clone(), task.clone(), norm.clone(), s, device.clone()));
    let mut agent = Shards::new(alone.collect(), backend)?;
    let shards = agent.parts().len();
    let mut run = |k: u64| {
        let mut last = None;
        for i in 0..k {
            // Losses of the last update only, as the trainer asks only on logging steps: on a GPU
            // each read waits for the device.
            last = agent.step(&sets[i as usize % sets.len()], i + 1 == k);
        }
        // Reading the last loss waits for all queued work (asynchronous backends).
        if let Some(s) = last {
            s.read();
        }
    };
    run(warmup);
    let t0 = Instant::now();
    run(updates);
    let seconds = t0.elapsed().as_secs_f64();
    Ok(BenchReport {
        task: task.name.clone(),
        algo: agent_cfg.algo,
        backend: backend.name().to_string(),
        threads: rayon::current_num_threads(),
        batch_size,
        agents,
        shards,
        updates,
        seconds,
        updates_per_sec: updates as f64 / seconds,
        agent_updates_per_sec: (updates * agents as u64) as f64 / seconds,
    })
}

/// `pgser-train bench-sampler`: prioritized batches/s from a scored table, from disk or memory.
#[derive(Debug, Clone, Serialize)]
pub struct SamplerBenchReport {
    pub rows: usize,
    pub batch_size: usize,
    pub batches: u64,
    pub in_memory: bool,
    /// Seconds to read q and build the sum tree (and, in memory, load the rows).
    pub setup_seconds: f64,
    pub seconds: f64,
    pub batches_per_sec: f64,
    pub samples_per_sec: f64,
}

pub fn bench_sampler(
    path: &Path,
    cfg: &PriorityConfig,
    k: usize,
    batches: u64,
    in_memory: bool,
) -> Result<SamplerBenchReport> {
    let t0 = Instant::now();
    let table = ScoredTable::open(path)?;
    let rows = table.rows;
    let beta = Arc::new(beta_of(&table)?);
    let mut s = ScoredSampler::start(table, beta, cfg, k, 0, 0, in_memory)?;
    let first = s.next_batch()?; // the first block is ready: setup is over
    let setup_seconds = t0.elapsed().as_secs_f64();
    drop(first);
    let t1 = Instant::now();
    for _ in 1..batches {
        s.next_batch()?;
    }
    let seconds = t1.elapsed().as_secs_f64();
    let per_sec = (batches - 1) as f64 / seconds;
    Ok(SamplerBenchReport {
        rows,
        batch_size: k,
        batches,
        in_memory,
        setup_seconds,
        seconds,
        batches_per_sec: per_sec,
        samples_per_sec: per_sec * k as f64,
    })
}

/// `pgser-train bench-sampler --stream`: the host's half of a stack's update on a GPU, timed
/// alone. A stack of `agents` cells (seeds 0…) draws one batch each per update, side by side on
/// the worker threads, as the trainer does (`train_stack`): β's rows with HER and swaps, the
/// scored table's prioritized rows with a scored table, the rewards, as the row numbers an engine
/// that holds the data is sent (`BatchStream::next_rows`); with `gather`, also built into batches
/// on the host (what the CPU engine, and a GPU that does not hold the data, train on).
#[derive(Debug, Clone, Serialize)]
pub struct StreamBenchReport {
    pub agents: usize,
    pub batch_size: usize,
    pub batches: u64,
    pub gather: bool,
    pub threads: usize,
    pub seconds: f64,
    /// Stack updates/s the host can feed, and agent-updates/s (× agents).
    pub updates_per_sec: f64,
    pub agent_updates_per_sec: f64,
    pub rows_per_sec: f64,
}

pub fn bench_stream(
    path: &Path,
    cfg: &crate::sampler::stream::StreamConfig,
    agents: usize,
    batches: u64,
    gather: bool,
) -> Result<StreamBenchReport> {
    use crate::sampler::stream::BatchSource;
    use rayon::prelude::*;
    let mut streams = (0..agents as u64)
        .map(|seed| {
            let c = crate::sampler::stream::StreamConfig { seed, ..cfg.clone() };
            BatchSource::open(path, &c)?.start(&c)
        })
        .collect::<Result<Vec<_>>>()?;
    let draw = |streams: &mut Vec<crate::sampler::stream::BatchStream>| -> Result<()> {
        streams
            .par_iter_mut()
            .map(|s| {
                let rows = s.next_rows()?.0;
                if gather {
                    let data = s.whole().expect("opened whole");
                    std::hint::black_box(rows.gather(&crate::sampler::table(data)));
                }
                Ok(())
            })
            .collect::<Result<()>>()
    };
    draw(&mut streams)?; // the prioritized samplers' first blocks: setup, not drawing
    let t = Instant::now();
    for _ in 0..batches {
        draw(&mut streams)?;
    }
    let seconds = t.elapsed().as_secs_f64();
    let updates_per_sec = batches as f64 / seconds;
    Ok(StreamBenchReport {
        agents,
        batch_size: cfg.batch_size,
        batches,
        gather,
        threads: rayon::current_num_threads(),
        seconds,
        updates_per_sec,
        agent_updates_per_sec: updates_per_sec * agents as f64,
        rows_per_sec: updates_per_sec * (agents * cfg.batch_size) as f64,
    })
}
