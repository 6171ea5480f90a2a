//! What a run will cost, said before it starts (`--dry-run` and the start of every run): the
//! updates, environment steps and scored rows of the steps that will run (up-to-date steps cost
//! nothing; an agent that continues from its checkpoint counts only the updates it has left),
//! the disk their outputs will take, and a wall time from a short measurement on this machine.
//!
//! The measurement times what dominates a pipeline, with the pipeline's own settings: a few
//! updates of the actual networks at its batch size and dimensions (`train::bench`), the batch
//! sampling of each training setting on random data of the task's shape, a few evaluation
//! episodes of the task (environment steps/s, which also prices collection), and the critic's
//! scoring throughput. It takes a second or two. Not measured, so not in the estimate: the
//! background reading of the scored table by the `-mem` agents, and the steps that take seconds
//! (convert, report, results). Table sizes are uncompressed, an upper bound of the zstd files.

use std::collections::BTreeMap;
use std::time::Instant;

use anyhow::Result;
use rayon::prelude::*;
use serde::Serialize;

use super::check::Checked;
use super::state::{self, Forecast};
use super::{Action, Pipeline, Step};
use crate::agent::{Agent, AgentConfig, Backend, Batch, Normalizer};
use crate::nprandom::NpRandom;
use crate::progress::{count, duration};
use crate::task::Task;
use crate::train::TrainConfig;
use crate::trajectory::{Episodes, FloatType, Footer};

/// Seconds spent timing the updates of one network setting.
const UPDATE_SECONDS: f64 = 0.5;

/// One step that will run.
#[derive(Debug, Clone, Serialize)]
pub struct StepCost {
    pub name: String,
    /// Gradient updates left to run (from the checkpoint's count when the step resumes).
    pub updates: u64,
    /// Environment steps: simulated episodes, and the evaluations of a training step.
    pub env_steps: u64,
    /// Environments created (evaluations create one per episode).
    pub envs_created: u64,
    /// Rows the critic scores.
    pub scored_rows: u64,
    /// Bytes its outputs will take (tables uncompressed).
    pub bytes: u64,
    /// Estimated wall time; None when not measured or not estimated (convert, report, results).
    pub seconds: Option<f64>,
}

impl StepCost {
    /// Several steps' costs added up (a stack's cells); seconds only where every one has them.
    pub fn total(steps: &[&StepCost]) -> StepCost {
        let sum = |f: fn(&StepCost) -> u64| steps.iter().map(|s| f(s)).sum::<u64>();
        StepCost {
            name: steps.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(","),
            updates: sum(|s| s.updates),
            env_steps: sum(|s| s.env_steps),
            envs_created: sum(|s| s.envs_created),
            scored_rows: sum(|s| s.scored_rows),
            bytes: sum(|s| s.bytes),
            seconds: steps.iter().map(|s| s.seconds).sum(),
        }
    }
}

/// Rates measured on this machine, with the pipeline's settings.
#[derive(Debug, Clone, Serialize)]
pub struct Measured {
    /// Updates/s, batch sampling included, per training setting ("td3bc, batch 512, swap random").
    pub updates_per_sec: BTreeMap<String, f64>,
    /// Environment steps/s, episodes stepping in parallel as in collection and evaluation.
    pub env_steps_per_sec: Option<f64>,
    /// Seconds to create one environment (loading and compiling its model): every evaluation
    /// creates one per episode, one after the other.
    pub env_create_seconds: Option<f64>,
    pub scored_rows_per_sec: Option<f64>,
    pub threads: usize,
    pub device: String,
    /// How long measuring took.
    pub seconds: f64,
}

/// The cost of the steps a run will run.
#[derive(Debug, Clone, Serialize)]
pub struct Cost {
    /// Steps that will run.
    pub steps: usize,
    pub updates: u64,
    pub env_steps: u64,
    pub scored_rows: u64,
    pub bytes: u64,
    /// Estimated wall time of the steps that will run; None without a measurement.
    pub seconds: Option<f64>,
    pub measured: Option<Measured>,
    pub per_step: Vec<StepCost>,
}

/// The cost of the `steps` whose forecast says they run; `measure` times this machine.
pub fn estimate(
    p: &Pipeline,
    steps: &[Step],
    forecast: &[Forecast],
    data: &Checked,
    measure: bool,
    device: Backend,
) -> Result<Cost> {
    let task = &data.task;
    let (t, eps) = (task.t as u64, data.episodes as u64);
    let mut per_step = Vec::new();
    let mut trains = Vec::new();
    // Cells of one stack train together, so each is priced at the stack's agent-updates/s.
    let mut stack_sizes = BTreeMap::new();
    for (step, _) in steps.iter().zip(forecast).filter(|(_, f)| f.runs) {
        if let Some(id) = super::stack_of(step) {
            *stack_sizes.entry(id).or_insert(0usize) += 1;
        }
    }
    for (step, f) in steps.iter().zip(forecast).filter(|(_, f)| f.runs) {
        let mut c = StepCost {
            name: step.name.clone(),
            updates: 0,
            env_steps: 0,
            envs_created: 0,
            scored_rows: 0,
            bytes: 0,
            seconds: None,
        };
        match &step.action {
            Action::Collect(o) => {
                let n = o.opts.episodes as u64;
                c.env_steps = n * (t - 1);
                let (obs, goal, act) = (task.obs_dim as u64, task.goal_dim as u64, task.act_dim as u64);
                c.bytes = n * (t * (obs + goal) + (t - 1) * (act + goal)) * 8;
            }
            Action::Convert(_) => {
                let vectors = (task.obs_dim + 2 * task.goal_dim + task.act_dim) * data.float_bytes;
                c.bytes = eps * t * (12 + vectors as u64);
            }
            Action::Train { cfg, .. } => {
                let start = state::resumes_from(&p.out, step, f, cfg);
                c.updates = cfg.updates.saturating_sub(start);
                c.envs_created = evaluations(cfg, start) * cfg.eval_episodes as u64;
                c.env_steps = c.envs_created * t;
                let lines = c.updates / cfg.log_every.max(1) + evaluations(cfg, 0);
                c.bytes = 4 * parameters(&cfg.agent, task) * 4 + lines * 160;
                let agents = super::stack_of(step).map_or(1, |id| stack_sizes[&id]);
                let scored = step.inputs[0] == super::plan::scored_path(p);
                trains.push(Priced { step: per_step.len(), cfg: cfg.as_ref().clone(), scored, agents });
            }
            Action::Score(super::ScoreStep { opts: o, .. }) => {
                c.scored_rows = eps * (t - 1) * (o.swaps as u64 + o.include_original as u64);
                let vectors = (2 * task.obs_dim + task.act_dim + 2 * task.goal_dim) as u64 * 4;
                c.bytes = c.scored_rows * (32 + vectors);
            }
            Action::Online { cfg, .. } => {
                let (epochs, cycles) = (cfg.epochs, cfg.cycles);
                let episodes = epochs * cycles * cfg.episodes_per_cycle as u64;
                c.updates = epochs * cycles * cfg.updates_per_cycle;
                c.envs_created = cfg.episodes_per_cycle as u64 + epochs * cfg.eval_episodes as u64;
                c.env_steps = (episodes + epochs * cfg.eval_episodes as u64) * t;
                // The replay buffer saved beside the checkpoint dominates.
                let stored = episodes.min(cfg.capacity(task) as u64);
                let (obs, goal, act) = (task.obs_dim as u64, task.goal_dim as u64, task.act_dim as u64);
                c.bytes = stored * ((t + 1) * (obs + goal) + t * (act + goal)) * 8;
                let mut as_train = super::train_config(&[])?;
                as_train.agent = cfg.agent();
                as_train.batch_size = cfg.batch_size;
                trains.push(Priced { step: per_step.len(), cfg: as_train, scored: false, agents: 1 });
            }
            Action::Report(_) | Action::Results(_) => {}
        }
        per_step.push(c);
    }
    let sum = |f: fn(&StepCost) -> u64| per_step.iter().map(f).sum::<u64>();
    let mut cost = Cost {
        steps: per_step.len(),
        updates: sum(|c| c.updates),
        env_steps: sum(|c| c.env_steps),
        scored_rows: sum(|c| c.scored_rows),
        bytes: sum(|c| c.bytes),
        seconds: None,
        measured: None,
        per_step,
    };
    if measure && cost.steps > 0 {
        let m = measure_rates(p, task, &trains, &cost, device)?;
        for c in cost.per_step.iter_mut() {
            if c.env_steps > 0 || c.scored_rows > 0 {
                c.seconds = Some(0.0);
            }
            if let (Some(rate), Some(create)) = (m.env_steps_per_sec, m.env_create_seconds) {
                c.seconds = c.seconds.map(|s| s + c.env_steps as f64 / rate + c.envs_created as f64 * create);
            }
            if let Some(rate) = m.scored_rows_per_sec {
                c.seconds = c.seconds.map(|s| s + c.scored_rows as f64 / rate);
            }
        }
        for t in &trains {
            let c = &mut cost.per_step[t.step];
            if let Some(rate) = m.updates_per_sec.get(&t.setting()) {
                c.seconds = Some(c.seconds.unwrap_or(0.0) + c.updates as f64 / rate);
            }
        }
        cost.seconds = Some(cost.per_step.iter().filter_map(|c| c.seconds).sum());
        cost.measured = Some(m);
    }
    Ok(cost)
}

/// Evaluations a run from `start` to `cfg.updates` makes: one every `eval_every` updates and one
/// at the end.
fn evaluations(cfg: &TrainConfig, start: u64) -> u64 {
    match (cfg.eval_episodes, cfg.eval_every) {
        (0, _) => 0,
        (_, 0) => 1,
        (_, e) => cfg.updates.saturating_sub(1) / e - start.min(cfg.updates.saturating_sub(1)) / e + 1,
    }
}

/// Parameters of the actor and the two critics (a checkpoint holds them; its resume state
/// holds their targets and Adam's two moments: 4× in all).
fn parameters(a: &AgentConfig, task: &Task) -> u64 {
    let net = |inputs: usize, outputs: usize| {
        let sizes: Vec<usize> = [inputs].into_iter().chain(vec![a.hidden; a.layers]).chain([outputs]).collect();
        sizes.windows(2).map(|w| (w[0] * w[1] + w[1]) as u64).sum::<u64>()
    };
    let (o, g, u) = (task.obs_dim, task.goal_dim, task.act_dim);
    net(o + g, u) + 2 * net(o + g + u, 1)
}

/// A training step to price: its settings, whether it reads the scored table, and how many
/// agents train in its stack (1 alone).
#[derive(Clone)]
struct Priced {
    step: usize,
    cfg: TrainConfig,
    scored: bool,
    agents: usize,
}

impl Priced {
    /// The setting as far as its speed goes: the networks, the batch, how it is drawn and the
    /// stack it trains in ("td3bc, batch 512, swap random, stack of 15"). Rates are per agent.
    fn setting(&self) -> String {
        let a = &self.cfg.agent;
        let mut s = format!("{}, batch {}", a.algo.name(), self.cfg.batch_size);
        if (a.hidden, a.layers) != (256, 3) {
            s += &format!(", {}×{}", a.layers, a.hidden);
        }
        s += match (self.scored, self.cfg.sampler.swap) {
            (true, _) => ", scored table",
            (false, crate::sampler::Swap::Random) => ", swap random",
            (false, _) => "",
        };
        if self.agents > 1 {
            s += &format!(", stack of {}", self.agents);
        }
        s
    }
}

fn measure_rates(p: &Pipeline, task: &Task, trains: &[Priced], cost: &Cost, backend: Backend) -> Result<Measured> {
    let t0 = Instant::now();
    let device = backend.device()?;
    let mut updates_per_sec = BTreeMap::new();
    let mut update_secs: BTreeMap<(String, usize, usize), f64> = BTreeMap::new();
    let data = random_episodes(task, 64);
    for t in trains {
        let (cfg, name) = (&t.cfg, t.setting());
        if cost.per_step[t.step].updates == 0 || updates_per_sec.contains_key(&name) {
            continue;
        }
        // Seconds per agent-update: a stack is timed as the trainer runs it (split over the
        // worker threads on the CPU), which is faster per agent than one agent alone.
        let key = (serde_json::to_string(&cfg.agent)?, cfg.batch_size, t.agents);
        let update = match update_secs.get(&key) {
            Some(&s) => s,
            None => {
                let bench = |n, warmup| {
                    crate::train::bench_agents(task, &cfg.agent, cfg.batch_size, n, warmup, backend, t.agents)
                };
                let probe = bench(2, 1)?.updates_per_sec;
                let n = (probe * UPDATE_SECONDS).clamp(3.0, 2000.0) as u64;
                let s = 1.0 / bench(n, 2)?.agent_updates_per_sec;
                update_secs.insert(key, s);
                s
            }
        };
        // Batch sampling runs on the training thread, between updates. The -mem agents draw
        // part of the batch from the scored table in the background: not measured.
        let k_aug = if t.scored { (cfg.batch_size as f64 * cfg.aug_ratio).round() as usize } else { 0 };
        let (mut rng, mut batch) = (NpRandom::new(0), Batch::default());
        let s0 = Instant::now();
        let draws = 20;
        for _ in 0..draws {
            crate::sampler::sample(&data, &cfg.sampler, &mut rng, cfg.batch_size - k_aug, &mut batch);
        }
        let sample = s0.elapsed().as_secs_f64() / draws as f64;
        updates_per_sec.insert(name, 1.0 / (update + sample));
    }
    let (env_steps_per_sec, env_create_seconds) = if cost.env_steps > 0 {
        let (rate, create) = measure_env(&p.task, task)?;
        (Some(rate), Some(create))
    } else {
        (None, None)
    };
    let scored_rows_per_sec = if cost.scored_rows > 0 {
        let agent = Agent::new(p.pretrain_config()?.agent, task.clone(), Normalizer::identity(task, 5.0), 0, device);
        let n = crate::score::Q_BATCH;
        let rows = random_episodes(task, n.div_ceil(task.t - 1));
        let calls = 4 * rayon::current_num_threads();
        let s0 = Instant::now();
        (0..calls).into_par_iter().for_each(|_| {
            agent.q(&rows.obs[..n * task.obs_dim], &rows.ag[..n * task.goal_dim], &rows.u[..n * task.act_dim], n);
        });
        Some((calls * n) as f64 / s0.elapsed().as_secs_f64())
    } else {
        None
    };
    Ok(Measured {
        updates_per_sec,
        env_steps_per_sec,
        env_create_seconds,
        scored_rows_per_sec,
        threads: rayon::current_num_threads(),
        device: backend.name().into(),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Environment steps/s of episodes of random actions stepping in parallel (as collection and
/// evaluation step them), and the seconds to create one environment.
fn measure_env(name: &str, task: &Task) -> Result<(f64, f64)> {
    let episodes = (4 * rayon::current_num_threads()).max(8);
    let s0 = Instant::now();
    let mut envs = (0..episodes).map(|_| crate::env::make(name)).collect::<Result<Vec<_>>>()?;
    let create = s0.elapsed().as_secs_f64() / episodes as f64;
    let s1 = Instant::now();
    envs.par_iter_mut().enumerate().for_each(|(i, env)| {
        let mut rng = NpRandom::new(i as u64);
        env.reset(Some(i as u64));
        for _ in 0..task.t {
            let action: Vec<f64> = (0..task.act_dim).map(|_| rng.uniform(-1.0, 1.0)).collect();
            env.step(&action);
        }
    });
    Ok(((episodes * task.t) as f64 / s1.elapsed().as_secs_f64(), create))
}

/// `n` episodes of uniform noise in the task's shape: what the samplers' speed depends on.
fn random_episodes(task: &Task, n: usize) -> Episodes {
    let mut rng = NpRandom::new(0);
    let mut noise = |len: usize| (0..len).map(|_| rng.uniform(-1.0, 1.0) as f32).collect::<Vec<f32>>();
    let t = task.t;
    Episodes {
        footer: Footer::new(task, FloatType::Float32, n, String::new()),
        task: task.clone(),
        n,
        t,
        obs: noise(n * t * task.obs_dim),
        ag: noise(n * t * task.goal_dim),
        g: noise(n * (t - 1) * task.goal_dim),
        u: noise(n * (t - 1) * task.act_dim),
        images: Vec::new(),
    }
}

/// The cost in two lines: the headline ("16 steps, 290k updates ≈ 1.9 h on this machine (55
/// updates/s measured)"), then environment steps, scored rows and disk.
pub fn render(c: &Cost) -> String {
    if c.steps == 0 {
        return "cost: nothing to run".into();
    }
    let mut s = format!("cost: {} steps, {} updates", c.steps, count(c.updates));
    match (&c.seconds, &c.measured) {
        (Some(secs), Some(m)) => {
            let rates: Vec<f64> = m.updates_per_sec.values().copied().collect();
            let lo = rates.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = rates.iter().copied().fold(0.0, f64::max);
            s += &format!(" {} on this machine", about(*secs));
            if !rates.is_empty() {
                let r = if hi - lo < 0.5 { format!("{hi:.0}") } else { format!("{lo:.0}–{hi:.0}") };
                s += &format!(" ({r} updates/s measured)");
            }
        }
        _ => s += " (wall time not measured: --no-measure)",
    }
    let m = c.measured.as_ref();
    let mut more = Vec::new();
    if c.env_steps > 0 {
        let rate = m.and_then(|m| m.env_steps_per_sec).map(|r| format!(" ({}/s measured)", count(r as u64)));
        more.push(format!("{} environment steps{}", count(c.env_steps), rate.unwrap_or_default()));
    }
    if c.scored_rows > 0 {
        let rate = m.and_then(|m| m.scored_rows_per_sec).map(|r| format!(" ({}/s measured)", count(r as u64)));
        more.push(format!("{} scored rows{}", count(c.scored_rows), rate.unwrap_or_default()));
    }
    more.push(format!("outputs ≤ {} (tables uncompressed)", bytes(c.bytes)));
    if let Some(m) = m {
        more.push(format!("measured in {:.1} s on {} threads ({})", m.seconds, m.threads, m.device));
    }
    s + "\ncost: " + &more.join("; ")
}

/// A step's cost in a few words, for its log line.
pub fn brief(c: &StepCost) -> String {
    let mut parts = Vec::new();
    if c.updates > 0 {
        parts.push(format!("{} updates", count(c.updates)));
    }
    if let Some(s) = c.seconds {
        parts.push(about(s));
    }
    parts.join(" ")
}

fn bytes(b: u64) -> String {
    match b {
        0..1_000_000 => format!("{:.0} kB", b as f64 / 1e3),
        1_000_000..1_000_000_000 => format!("{:.0} MB", b as f64 / 1e6),
        _ => format!("{:.1} GB", b as f64 / 1e9),
    }
}

/// "≈ 6.6 min", or "under 1 s".
fn about(s: f64) -> String {
    if s < 1.0 { "under 1 s".into() } else { format!("≈ {}", duration(s)) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn evaluations_count_the_schedule_and_the_end() {
        let cfg = |updates, eval_every, eval_episodes| TrainConfig {
            updates,
            eval_every,
            eval_episodes,
            ..crate::pipeline::train_config(&[]).unwrap()
        };
        // train: every 2500 updates before the end, then once at the end.
        assert_eq!(evaluations(&cfg(30_000, 2_500, 50), 0), 12);
        assert_eq!(evaluations(&cfg(30_000, 2_500, 50), 15_000), 6);
        assert_eq!(evaluations(&cfg(30_000, 2_500, 50), 30_000), 1);
        assert_eq!(evaluations(&cfg(30_001, 2_500, 50), 0), 13);
        assert_eq!(evaluations(&cfg(30_000, 0, 50), 0), 1);
        assert_eq!(evaluations(&cfg(30_000, 2_500, 0), 0), 0);
    }

    #[test]
    fn a_stack_is_priced_per_agent_and_added_up_for_its_log_line() {
        let cfg = crate::pipeline::train_config(&[]).unwrap();
        let alone = Priced { step: 0, cfg: cfg.clone(), scored: false, agents: 1 };
        let stacked = Priced { agents: 15, ..alone.clone() };
        // A stack is timed apart from a lone agent of the same networks: it is faster per agent.
        assert_ne!(alone.setting(), stacked.setting());
        assert!(stacked.setting().ends_with(", stack of 15"), "{}", stacked.setting());
        let cell = |updates, seconds| StepCost {
            name: "a".into(),
            updates,
            env_steps: 10,
            envs_created: 1,
            scored_rows: 0,
            bytes: 5,
            seconds,
        };
        let (a, b) = (cell(100, Some(2.0)), cell(50, Some(1.5)));
        let t = StepCost::total(&[&a, &b]);
        assert_eq!((t.updates, t.env_steps, t.envs_created, t.bytes, t.seconds), (150, 20, 2, 10, Some(3.5)));
        assert_eq!(brief(&t), "150 updates ≈ 4 s");
        // Unmeasured (--no-measure): no time for the stack, rather than a part of one.
        assert_eq!(StepCost::total(&[&a, &cell(50, None)]).seconds, None);
    }
}
