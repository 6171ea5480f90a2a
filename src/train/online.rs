//! `pgser-train online`: DDPG + HER trained online in pgser's environments, with the settings of
//! MRN (Liu et al. 2022, `--agent her --negative-reward`), whose experts the paper's in-hand
//! datasets come from (docs/online.md).
//!
//! An epoch is `cycles` cycles and then an evaluation of the deterministic policy. A cycle
//! (MRN's `learn`): `episodes_per_cycle` exploring episodes, stepped in parallel; they go into
//! the replay buffer; the running normalizer is updated from T of their transitions, HER
//! relabelled; `updates_per_cycle` DDPG updates on HER batches; then the targets move by Polyak
//! averaging (the agent's `policy_delay` is the cycle's update count, so its schedule is that).
//!
//! A run is a function of its settings and seed, never of the thread count: every random draw
//! comes from a stream spawned from (seed, stream, epoch, cycle[, episode]), each episode
//! starts from `GoalEnv::restart` with a seed drawn the same way, and the environments of a
//! cycle only ever see their own episode. So the state at a cycle boundary is the networks,
//! Adam, the normalizer's sums, the buffer and the counters, which is what a checkpoint saves;
//! `--resume` continues from it to the bits of a run that was never stopped.

mod state;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Result, bail};
use clap::Args;
use indicatif::ProgressBar;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::agent::{Agent, AgentConfig, Algo, Backend, Batch};
use crate::env::{self, GoalEnv, Obs, applied_action};
use crate::eval::{self, EvalReport};
use crate::nprandom::NpRandom;
use crate::sampler::replay::{self, Replay};
use crate::task::Task;
use crate::trajectory::Episodes;

use state::Progress;
pub use state::{RunningNorm, buffer_path};

/// The run's settings, named after MRN's flags (`src/args.py`) with its defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Args)]
pub struct OnlineConfig {
    /// Task to train in (FetchReach, FetchPush, ..., HandManipulateBlockRotateZ, HandManipulateEggRotate).
    #[arg(long)]
    pub task: String,
    /// Epochs; each ends with an evaluation and a checkpoint (MRN's --n-epochs; 50 for the hand
    /// tasks). --resume may raise it.
    #[arg(long, default_value_t = 50)]
    pub epochs: u64,
    /// Cycles per epoch (MRN's --n-cycles).
    #[arg(long, default_value_t = 50)]
    pub cycles: u64,
    /// Exploring episodes per cycle, stepped in parallel (MRN's --rollout-n-episodes).
    #[arg(long, default_value_t = 20)]
    pub episodes_per_cycle: usize,
    /// DDPG updates per cycle (MRN's --n-batches).
    #[arg(long, default_value_t = 40)]
    pub updates_per_cycle: u64,
    /// Transitions per update.
    #[arg(long, default_value_t = 1024)]
    pub batch_size: usize,
    /// Replay buffer size in transitions: it holds buffer_size / T whole episodes.
    #[arg(long, default_value_t = 1_000_000)]
    pub buffer_size: usize,
    /// Probability that a sampled transition's goal is relabelled to a future achieved goal of
    /// its episode (HER "future").
    #[arg(long, default_value_t = 0.8)]
    pub relabel_rate: f64,
    /// Exploration: Gaussian noise of this std is added to each action value, then clipped.
    #[arg(long, default_value_t = 0.2)]
    pub noise_eps: f64,
    /// Exploration: with this probability a step takes a uniform random action instead.
    #[arg(long, default_value_t = 0.3)]
    pub random_eps: f64,
    /// Weight of the action penalty in the actor loss (mean of squared actions).
    #[arg(long, default_value_t = 1.0)]
    pub action_l2: f64,
    /// Adam learning rate of actor and critic (MRN's --lr-actor and --lr-critic).
    #[arg(long, default_value_t = 1e-3)]
    pub lr: f64,
    /// Target networks: target ← polyak · target + (1 − polyak) · online, once per cycle.
    #[arg(long, default_value_t = 0.9)]
    pub polyak: f64,
    /// Discount factor γ; TD targets are clipped to [−1/(1−γ), 0].
    #[arg(long, default_value_t = 0.98)]
    pub gamma: f64,
    /// Observations and goals are clipped to ±clip_obs before they enter the normalizer's
    /// statistics.
    #[arg(long, default_value_t = 200.0)]
    pub clip_obs: f64,
    /// Normalized inputs are clipped to ±clip_range.
    #[arg(long, default_value_t = 5.0)]
    pub clip_range: f64,
    /// Units per hidden layer (MRN's --dim-hidden).
    #[arg(long, default_value_t = 256)]
    pub hidden: usize,
    /// Hidden layers per network.
    #[arg(long, default_value_t = 3)]
    pub layers: usize,
    /// Evaluation episodes after each epoch (MRN's --eval-rollout-n-episodes).
    #[arg(long, default_value_t = 100)]
    pub eval_episodes: usize,
    /// Evaluation episode i resets with seed eval_seed + i (the same episodes every epoch).
    #[arg(long, default_value_t = 1_000_000)]
    pub eval_seed: u64,
    /// Seed of the run: initial weights, episode starts, exploration, batches.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Also save at the first cycle boundary this many minutes after the last save (0: only at
    /// the end of each epoch). Not a setting of the run: it changes no result.
    #[arg(long, default_value_t = 10.0)]
    #[serde(skip)]
    pub save_minutes: f64,
    /// Stop, saved, at the first cycle boundary this many minutes after the start, even before
    /// --epochs (continue with --resume): for machines lent by the hour. Not a setting of the run.
    #[arg(long)]
    #[serde(skip)]
    pub max_minutes: Option<f64>,
}

impl OnlineConfig {
    /// The agent these settings train: MRN's DDPG, its targets moved once per cycle.
    pub fn agent(&self) -> AgentConfig {
        AgentConfig {
            algo: Algo::Ddpg,
            gamma: self.gamma,
            lr: Some(self.lr),
            policy_delay: self.updates_per_cycle,
            tau: 1.0 - self.polyak,
            hidden: self.hidden,
            layers: self.layers,
            norm_clip: self.clip_range,
            action_l2: Some(self.action_l2),
            ..AgentConfig::default()
        }
    }

    /// Episodes the buffer holds (MRN: buffer_size // T).
    pub fn capacity(&self, task: &Task) -> usize {
        self.buffer_size / task.t
    }

    /// What two runs must share for one to continue the other (all but the epoch count).
    fn identity(&self) -> OnlineConfig {
        OnlineConfig { epochs: 0, save_minutes: 0.0, max_minutes: None, ..self.clone() }
    }

    pub(crate) fn validate(&self, task: &Task) -> Result<()> {
        let probability = |name: &str, p: f64| {
            if (0.0..=1.0).contains(&p) { Ok(()) } else { Err(anyhow::anyhow!("--{name} must be in [0, 1], got {p}")) }
        };
        probability("relabel-rate", self.relabel_rate)?;
        probability("random-eps", self.random_eps)?;
        probability("polyak", self.polyak)?;
        if self.epochs == 0
            || self.cycles == 0
            || self.episodes_per_cycle == 0
            || self.updates_per_cycle == 0
            || self.batch_size == 0
        {
            bail!("--epochs, --cycles, --episodes-per-cycle, --updates-per-cycle and --batch-size must be at least 1");
        }
        if self.capacity(task) < self.episodes_per_cycle {
            bail!(
                "--buffer-size {} holds {} episodes of {} steps, fewer than one cycle's {}",
                self.buffer_size,
                self.capacity(task),
                task.t,
                self.episodes_per_cycle
            );
        }
        let minutes = self.max_minutes.unwrap_or(0.0);
        if !(self.noise_eps >= 0.0 && self.noise_eps.is_finite() && self.save_minutes >= 0.0 && minutes >= 0.0) {
            bail!("--noise-eps, --save-minutes and --max-minutes must be finite and ≥ 0");
        }
        Ok(())
    }
}

/// One line of the metrics file, per epoch: the fields `pgser-train` writes (updates, losses,
/// eval) and the online ones. Losses are means over the epoch's updates; rates are per second
/// of rollouts (env steps, exploring episodes only) and of updates (sampling included).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EpochLine {
    pub epoch: u64,
    pub updates: u64,
    pub episodes: u64,
    pub env_steps: u64,
    pub critic_loss: f64,
    pub actor_loss: f64,
    pub q_mean: f64,
    /// Final-step success of the epoch's exploring episodes.
    pub train_success_rate: f64,
    pub eval: Option<EvalReport>,
    pub env_steps_per_sec: f64,
    pub updates_per_sec: f64,
    /// Wall time of the epoch: rollouts, updates and evaluation.
    pub seconds: f64,
}

/// What `--json` prints: the run's totals and this invocation's rates.
#[derive(Debug, Clone, Serialize)]
pub struct OnlineSummary {
    /// Whether the run reached --epochs (false: stopped by --max-minutes, saved).
    pub finished: bool,
    pub epochs: u64,
    pub cycles: u64,
    pub episodes: u64,
    pub env_steps: u64,
    pub updates: u64,
    pub env_steps_per_sec: f64,
    pub updates_per_sec: f64,
    pub eval: Option<EvalReport>,
    pub checkpoint: PathBuf,
    pub metrics: PathBuf,
    pub buffer: PathBuf,
}

/// Spawn keys of the run's streams (the agent's own use 1 and 2).
const STREAM_RESET: u64 = 11;
const STREAM_EXPLORE: u64 = 12;
const STREAM_STORE: u64 = 13;
const STREAM_NORM: u64 = 14;
const STREAM_BATCHES: u64 = 15;

/// Everything a run holds between cycles.
struct Run {
    cfg: OnlineConfig,
    out: PathBuf,
    command: String,
    agent: Agent,
    norm: RunningNorm,
    replay: Replay,
    progress: Progress,
    metrics: Vec<EpochLine>,
}

/// Trains (or, with `resume`, continues) the run whose checkpoint is `out`; `command` is
/// recorded in the checkpoint.
pub fn train_online(
    cfg: &OnlineConfig,
    out: &Path,
    resume: bool,
    backend: Backend,
    command: &str,
    bar: &ProgressBar,
) -> Result<OnlineSummary> {
    let device = backend.device()?;
    let _training = super::stop::Training::start();
    let mut envs: Vec<Box<dyn GoalEnv + Send>> =
        (0..cfg.episodes_per_cycle).map(|_| env::make(&cfg.task)).collect::<Result<_>>()?;
    let task = envs[0].task().clone();
    cfg.validate(&task)?;
    let mut run = if resume {
        state::restore(cfg, out, command, device)?
    } else {
        let norm = RunningNorm::new(&task, cfg.clip_obs, cfg.clip_range);
        let agent = Agent::new(cfg.agent(), task.clone(), norm.normalizer(), cfg.seed, device);
        let replay = Replay::new(&task, cfg.capacity(&task));
        let progress = Progress::default();
        Run {
            cfg: cfg.clone(),
            out: out.to_path_buf(),
            command: command.into(),
            agent,
            norm,
            replay,
            progress,
            metrics: vec![],
        }
    };
    if let Some(kind) = backend.engine() {
        run.agent.attach(kind)?;
    }
    bar.set_length(cfg.epochs * cfg.cycles);
    bar.set_position(run.progress.epoch * cfg.cycles + run.progress.cycle);
    let (mut steps, mut rollout_secs, mut updates, mut update_secs) = (0u64, 0.0f64, 0u64, 0.0f64);
    let started = Instant::now();
    let mut last_save = started;
    let out_of_time =
        |now: &Instant| cfg.max_minutes.is_some_and(|m| now.duration_since(started).as_secs_f64() >= 60.0 * m);
    while run.progress.epoch < cfg.epochs {
        let t0 = Instant::now();
        let (new, successes) = rollout(&run, &mut envs)?;
        let dt = t0.elapsed().as_secs_f64();
        let n_steps = (new.n * task.t) as u64;
        let t1 = Instant::now();
        run.cycle(&new)?;
        let du = t1.elapsed().as_secs_f64();
        run.progress.count_cycle(new.n as u64, successes as u64, n_steps, dt, du);
        (steps, rollout_secs, updates, update_secs) =
            (steps + n_steps, rollout_secs + dt, updates + cfg.updates_per_cycle, update_secs + du);
        if run.progress.cycle == cfg.cycles {
            run.end_epoch()?;
            // One line per epoch, for the logs of long runs (the bar draws only on a terminal).
            let line = run.epoch_summary();
            bar.suspend(|| eprintln!("{line}"));
        }
        let now = Instant::now();
        // --max-minutes, or SIGTERM (`stop`, as a pipeline's training step): save and stop here.
        let signal = super::stop::requested();
        let stop = (out_of_time(&now) || signal) && run.progress.epoch < cfg.epochs;
        if run.progress.cycle == 0
            || stop
            || (cfg.save_minutes > 0.0 && (now - last_save).as_secs_f64() >= 60.0 * cfg.save_minutes)
        {
            run.save()?;
            last_save = Instant::now();
        }
        bar.set_position(run.progress.epoch * cfg.cycles + run.progress.cycle);
        if stop && signal {
            let of = cfg.epochs * cfg.cycles * cfg.updates_per_cycle;
            return Err(super::stop::Interrupted { updates: run.agent.updates, of }.into());
        }
        if stop {
            break;
        }
    }
    bar.finish_and_clear();
    let rate = |n: u64, secs: f64| if secs > 0.0 { n as f64 / secs } else { 0.0 };
    Ok(OnlineSummary {
        finished: run.progress.epoch >= cfg.epochs,
        epochs: run.progress.epoch,
        cycles: run.progress.epoch * cfg.cycles + run.progress.cycle,
        episodes: run.progress.episodes,
        env_steps: run.progress.env_steps,
        updates: run.agent.updates,
        env_steps_per_sec: rate(steps, rollout_secs),
        updates_per_sec: rate(updates, update_secs),
        eval: run.metrics.last().and_then(|m| m.eval.clone()),
        checkpoint: out.to_path_buf(),
        metrics: super::metrics_path(out),
        buffer: buffer_path(out),
    })
}

impl Run {
    /// A stream of this cycle (`episode` too for a rollout's own).
    fn stream(&self, key: u64, episode: Option<usize>) -> NpRandom {
        let p = &self.progress;
        match episode {
            Some(i) => NpRandom::spawned(self.cfg.seed, &[key, p.epoch, p.cycle, i as u64]),
            None => NpRandom::spawned(self.cfg.seed, &[key, p.epoch, p.cycle]),
        }
    }

    /// The cycle after its rollouts: store them, update the normalizer, train.
    fn cycle(&mut self, new: &Episodes) -> Result<()> {
        self.replay.store(new, &mut self.stream(STREAM_STORE, None));
        // MRN's `_update_normalizer`: T transitions of the new episodes, HER relabelled, and the
        // goals they are trained on.
        let mut sample = Batch::default();
        let (rate, t) = (self.cfg.relabel_rate, self.agent.task.t);
        replay::sample_her(new, rate, &mut self.stream(STREAM_NORM, None), t, &mut sample);
        self.norm.update(&sample.obs, &sample.goal);
        self.agent.norms[0] = self.norm.normalizer();
        let mut rng = self.stream(STREAM_BATCHES, None);
        let mut batch = Batch::default();
        for _ in 0..self.cfg.updates_per_cycle {
            self.replay.sample(self.cfg.relabel_rate, &mut rng, self.cfg.batch_size, &mut batch);
            let (critic, q, actor) = self.agent.update(std::slice::from_ref(&batch)).read()[0];
            if !critic.is_finite() {
                bail!(
                    "{}: update {}: the critic loss is {critic}; training diverged (try a lower --lr)",
                    self.out.display(),
                    self.agent.updates
                );
            }
            let s = &mut self.progress.stats;
            s.critic_loss += critic;
            s.q_mean += q;
            s.actor_loss += actor.unwrap_or(0.0);
            s.updates += 1;
        }
        Ok(())
    }

    /// The last epoch's metrics in a line.
    fn epoch_summary(&self) -> String {
        let m = self.metrics.last().expect("an epoch has ended");
        let success = m.eval.as_ref().map_or("-".to_string(), |e| format!("{:.3}", e.success_rate));
        format!(
            "{}: epoch {}/{}: eval success {success}, exploring success {:.3}, critic loss {:.4}, \
             {:.0} env steps/s, {:.1} updates/s, {:.0} s",
            self.out.display(),
            m.epoch,
            self.cfg.epochs,
            m.train_success_rate,
            m.critic_loss,
            m.env_steps_per_sec,
            m.updates_per_sec,
            m.seconds
        )
    }

    /// The epoch's evaluation and metrics line; counters move to the next epoch.
    fn end_epoch(&mut self) -> Result<()> {
        let t0 = Instant::now();
        let eval = if self.cfg.eval_episodes > 0 {
            Some(eval::evaluate(&self.agent.task.name, &self.agent, self.cfg.eval_episodes, self.cfg.eval_seed)?)
        } else {
            None
        };
        let s = std::mem::take(&mut self.progress.stats);
        let per = |x: f64, n: u64| if n > 0 { x / n as f64 } else { 0.0 };
        let rate = |n: u64, secs: f64| if secs > 0.0 { n as f64 / secs } else { 0.0 };
        self.progress.epoch += 1;
        self.progress.cycle = 0;
        self.metrics.push(EpochLine {
            epoch: self.progress.epoch,
            updates: self.agent.updates,
            episodes: self.progress.episodes,
            env_steps: self.progress.env_steps,
            critic_loss: per(s.critic_loss, s.updates),
            actor_loss: per(s.actor_loss, s.updates),
            q_mean: per(s.q_mean, s.updates),
            train_success_rate: per(s.successes as f64, s.episodes),
            eval,
            env_steps_per_sec: rate(s.steps, s.rollout_secs),
            updates_per_sec: rate(s.updates, s.update_secs),
            seconds: s.rollout_secs + s.update_secs + t0.elapsed().as_secs_f64(),
        });
        Ok(())
    }
}

/// One environment's episode in the making.
struct Live {
    obs: Obs,
    rng: NpRandom,
    o: Vec<f32>,
    ag: Vec<f32>,
    g: Vec<f32>,
    u: Vec<f32>,
    success: bool,
}

/// The cycle's exploring episodes, in lockstep so the actor sees one batch per step (one forward
/// pass), the environments stepping in parallel. Exploration is MRN's `_select_actions`: per
/// action value a N(0, 1) draw times noise_eps is added and the action clipped to [−1, 1]; then
/// per value a uniform draw in [−1, 1]; with probability random_eps (one more draw) the uniform
/// action is taken instead. Returns the episodes and how many ended at the goal.
fn rollout(run: &Run, envs: &mut [Box<dyn GoalEnv + Send>]) -> Result<(Episodes, usize)> {
    let cfg = &run.cfg;
    let task = run.agent.task.clone();
    let mut live: Vec<Live> = envs
        .par_iter_mut()
        .enumerate()
        .map(|(i, env)| {
            let obs = env.restart(run.stream(STREAM_RESET, Some(i)).next_u64());
            Live {
                obs,
                rng: run.stream(STREAM_EXPLORE, Some(i)),
                o: vec![],
                ag: vec![],
                g: vec![],
                u: vec![],
                success: false,
            }
        })
        .collect();
    let f32s = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    for _ in 0..task.t {
        let o: Vec<f32> = live.iter().flat_map(|l| f32s(&l.obs.observation)).collect();
        let g: Vec<f32> = live.iter().flat_map(|l| f32s(&l.obs.desired_goal)).collect();
        let actions = run.agent.act(&o, &g, live.len());
        live.par_iter_mut().zip(envs.par_iter_mut()).zip(actions.par_chunks(task.act_dim)).for_each(
            |((l, env), pi)| {
                let mut a: Vec<f64> =
                    pi.iter().map(|&x| (x as f64 + cfg.noise_eps * l.rng.standard_normal()).clamp(-1.0, 1.0)).collect();
                let random: Vec<f64> = (0..a.len()).map(|_| l.rng.uniform(-1.0, 1.0)).collect();
                if l.rng.random() < cfg.random_eps {
                    a = random;
                }
                l.o.extend(f32s(&l.obs.observation));
                l.ag.extend(f32s(&l.obs.achieved_goal));
                l.g.extend(f32s(&l.obs.desired_goal));
                l.u.extend(a.iter().map(|&x| applied_action(x)));
                let step = env.step(&a);
                l.success = step.success;
                l.obs = step.obs;
            },
        );
    }
    let mut out = replay::empty(&task);
    let mut successes = 0;
    for mut l in live {
        l.o.extend(f32s(&l.obs.observation));
        l.ag.extend(f32s(&l.obs.achieved_goal));
        out.obs.extend(l.o);
        out.ag.extend(l.ag);
        out.g.extend(l.g);
        out.u.extend(l.u);
        successes += l.success as usize;
    }
    out.n = envs.len();
    Ok((out, successes))
}
