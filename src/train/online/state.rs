//! What an online run saves and restores: its counters and the epoch's running sums
//! ([`Progress`]), the running normalizer ([`RunningNorm`]), and the replay buffer, beside the
//! checkpoint and resume state that `pgser-train` writes (docs/checkpoint.md, docs/online.md).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use burn::tensor::Device;
use serde::{Deserialize, Serialize};

use super::{EpochLine, OnlineConfig, Run};
use crate::agent::{Normalizer, checkpoint};
use crate::sampler::replay::Replay;
use crate::task::Task;
use crate::train::{StaleCheckpoint, metrics_path, read_metrics, stage_metrics};

/// Where the replay buffer of checkpoint `out` goes: `out` + `.buffer.parquet`, a trajectory
/// table of the buffer's episodes (T + 1 rows each).
pub fn buffer_path(out: &Path) -> PathBuf {
    crate::output::with_suffix(out, ".buffer.parquet")
}

/// Where a run stands: epochs done, cycles done in the current epoch, totals, and the sums the
/// epoch's metrics line is made of (so a run resumed inside an epoch writes the line an
/// uninterrupted one does; only its timings differ).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Progress {
    pub epoch: u64,
    pub cycle: u64,
    pub episodes: u64,
    pub env_steps: u64,
    pub stats: EpochStats,
}

impl Progress {
    /// Counts a finished cycle: its episodes, their successes and steps, and its times.
    pub fn count_cycle(&mut self, episodes: u64, successes: u64, steps: u64, rollout_secs: f64, update_secs: f64) {
        self.cycle += 1;
        self.episodes += episodes;
        self.env_steps += steps;
        let s = &mut self.stats;
        s.episodes += episodes;
        s.successes += successes;
        s.steps += steps;
        s.rollout_secs += rollout_secs;
        s.update_secs += update_secs;
    }

    /// Names this point of the run; the buffer's footer carries it and `--resume` checks it.
    fn note(&self, cfg: &OnlineConfig) -> String {
        format!(
            "online replay buffer of {} seed {} after epoch {} cycle {}",
            cfg.task, cfg.seed, self.epoch, self.cycle
        )
    }
}

/// Sums over the current epoch's cycles.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct EpochStats {
    pub critic_loss: f64,
    pub actor_loss: f64,
    pub q_mean: f64,
    pub updates: u64,
    pub successes: u64,
    pub episodes: u64,
    pub steps: u64,
    pub rollout_secs: f64,
    pub update_secs: f64,
}

/// The running mean and standard deviation of observations and goals, as MRN's `Normalizer`
/// keeps them: sums and sums of squares of the values (clipped to ±clip_obs) and a count that
/// starts at 1, std = √max(0.01², E[x²] − E[x]²). Until the first update the normalizer is the
/// identity (MRN's initial mean 0, std 1). Sums are f64 here (MRN: f32).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunningNorm {
    obs: Moments,
    goal: Moments,
    clip_obs: f64,
    clip_range: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Moments {
    sum: Vec<f64>,
    sumsq: Vec<f64>,
    /// Rows added plus MRN's initial 1.
    count: f64,
}

/// MRN's `eps`: the floor of the standard deviation.
const MIN_STD: f64 = 1e-2;

impl Moments {
    fn new(dim: usize) -> Moments {
        Moments { sum: vec![0.0; dim], sumsq: vec![0.0; dim], count: 1.0 }
    }

    fn add(&mut self, rows: &[f32], clip: f64) {
        let dim = self.sum.len();
        for row in rows.chunks_exact(dim) {
            for ((s, q), &x) in self.sum.iter_mut().zip(&mut self.sumsq).zip(row) {
                let x = (x as f64).clamp(-clip, clip);
                *s += x;
                *q += x * x;
            }
            self.count += 1.0;
        }
    }

    fn mean_std(&self) -> (Vec<f32>, Vec<f32>) {
        let mean: Vec<f64> = self.sum.iter().map(|s| s / self.count).collect();
        let std =
            self.sumsq.iter().zip(&mean).map(|(q, m)| (q / self.count - m * m).max(MIN_STD * MIN_STD).sqrt() as f32);
        (mean.iter().map(|&m| m as f32).collect(), std.collect())
    }
}

impl RunningNorm {
    pub fn new(task: &Task, clip_obs: f64, clip_range: f64) -> RunningNorm {
        RunningNorm { obs: Moments::new(task.obs_dim), goal: Moments::new(task.goal_dim), clip_obs, clip_range }
    }

    /// Adds rows of observations and of goals.
    pub fn update(&mut self, obs: &[f32], goals: &[f32]) {
        self.obs.add(obs, self.clip_obs);
        self.goal.add(goals, self.clip_obs);
    }

    /// The normalizer the networks use now.
    pub fn normalizer(&self) -> Normalizer {
        let (od, gd) = (self.obs.sum.len(), self.goal.sum.len());
        if self.obs.count == 1.0 {
            let ones = |d| vec![1.0; d];
            let zeros = |d| vec![0.0; d];
            let clip = self.clip_range as f32;
            return Normalizer {
                obs_mean: zeros(od),
                obs_std: ones(od),
                goal_mean: zeros(gd),
                goal_std: ones(gd),
                clip,
            };
        }
        let (obs_mean, obs_std) = self.obs.mean_std();
        let (goal_mean, goal_std) = self.goal.mean_std();
        Normalizer { obs_mean, obs_std, goal_mean, goal_std, clip: self.clip_range as f32 }
    }
}

impl Run {
    /// Writes metrics, resume state, buffer and checkpoint, each staged first and then put in
    /// place as `pgser-train` does (`checkpoint::commit_with`): a checkpoint in place always has
    /// its metrics, resume state and buffer, whatever instant a crash hits, and each of them
    /// names the point of the run it belongs to, so `--resume` never continues from a mixed set.
    pub(super) fn save(&mut self) -> Result<()> {
        self.agent.sync();
        let out = &self.out;
        let note = self.progress.note(&self.cfg);
        let mut extra = BTreeMap::new();
        extra.insert("online".to_string(), serde_json::to_string(&self.cfg)?);
        extra.insert("command".to_string(), self.command.clone());
        let mut resume_extra = BTreeMap::new();
        resume_extra.insert("online_progress".to_string(), serde_json::to_string(&self.progress)?);
        resume_extra.insert("running_norm".to_string(), serde_json::to_string(&self.norm)?);
        resume_extra.insert("buffer".to_string(), note.clone());
        let metrics = stage_metrics(&metrics_path(out), &self.metrics)?;
        let resume = checkpoint::stage_resume(&self.agent, 0, &checkpoint::resume_path(out), &resume_extra)?;
        let buffer = self.replay.stage(&buffer_path(out), &note, &self.command)?;
        let model = checkpoint::stage(&self.agent, 0, out, &extra)?;
        metrics.commit()?;
        checkpoint::commit_with(model, vec![resume, buffer])
    }
}

/// The run saved at `out`, if `cfg` may continue it: same settings but the epoch count, which
/// may grow. Refusals that mean "another run" are `StaleCheckpoint`s, as `pgser-train`'s.
pub(super) fn restore(cfg: &OnlineConfig, out: &Path, command: &str, device: Device) -> Result<Run> {
    let at = out.display();
    if !out.exists() {
        anyhow::bail!("{at}: --resume given but there is no checkpoint to resume");
    }
    let (mut agent, meta) = checkpoint::load(out, device)?;
    let stale = |why: String| -> Result<Run> { Err(StaleCheckpoint(why).into()) };
    let Some(saved) = meta.get("online") else {
        return stale(format!("{at}: not a checkpoint of `pgser-train online` (no online settings in its metadata)"));
    };
    let saved: OnlineConfig = serde_json::from_str(saved)
        .with_context(|| format!("{at}: the checkpoint's online settings are not readable"))?;
    if saved.identity() != cfg.identity() {
        return stale(format!(
            "{at}: --resume with settings that differ from the checkpoint's (only --epochs may change): {}",
            crate::train::differ::differing_settings(&saved.identity(), &cfg.identity())?
        ));
    }
    let resume_file = checkpoint::resume_path(out);
    let r = checkpoint::load_resume(&mut agent, &resume_file)?;
    let json = |key: &str| -> Result<&String> {
        r.get(key)
            .with_context(|| format!("{}: {key} missing (not an online run's resume state)", resume_file.display()))
    };
    let progress: Progress = serde_json::from_str(json("online_progress")?)
        .with_context(|| format!("{}: online_progress is not readable", resume_file.display()))?;
    let norm: RunningNorm = serde_json::from_str(json("running_norm")?)
        .with_context(|| format!("{}: running_norm is not readable", resume_file.display()))?;
    if progress.epoch > cfg.epochs || (progress.epoch == cfg.epochs && progress.cycle > 0) {
        return stale(format!(
            "{at}: --resume with --epochs {} but the run is past epoch {} (a run cannot be shortened)",
            cfg.epochs, progress.epoch
        ));
    }
    let task = agent.task.clone();
    // The buffer of this checkpoint: the one in place, or the pending one a save killed between
    // its renames left (`checkpoint::commit_with`).
    let (buffer, note) = (buffer_path(out), json("buffer")?);
    let replay = match Replay::load(&buffer, &task, cfg.capacity(&task), note) {
        Err(e) => match checkpoint::pending_path(&buffer) {
            pending if pending.exists() => Replay::load(&pending, &task, cfg.capacity(&task), note).map_err(|_| e)?,
            _ => return Err(e),
        },
        ok => ok?,
    };
    let metrics: Vec<EpochLine> =
        read_metrics::<EpochLine>(&metrics_path(out))?.into_iter().filter(|m| m.epoch <= progress.epoch).collect();
    Ok(Run {
        cfg: cfg.clone(),
        out: out.to_path_buf(),
        command: command.to_string(),
        agent,
        norm,
        replay,
        progress,
        metrics,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn running_norm_is_mrns_with_its_count_starting_at_one() {
        let task = Task::custom("t", 2, 2, 1, 1, 0.1);
        let mut n = RunningNorm::new(&task, 200.0, 5.0);
        assert_eq!(n.normalizer(), Normalizer::identity(&task, 5.0), "identity before any update");
        // Rows (1, 7) and (3, 7): count 3, mean (4/3, 14/3), E[x²] (10/3, 98/3).
        n.update(&[1.0, 7.0, 3.0, 7.0], &[500.0, -500.0]);
        let z = n.normalizer();
        let var0: f64 = 10.0 / 3.0 - (4.0f64 / 3.0).powi(2);
        assert_eq!(z.obs_mean, vec![(4.0f64 / 3.0) as f32, (14.0f64 / 3.0) as f32]);
        assert_eq!(z.obs_std[0], var0.sqrt() as f32);
        // Goals are clipped to ±200 before they are summed: mean 0, E[x²] = 2·200²/3.
        assert_eq!(z.goal_mean, vec![0.0]);
        assert_eq!(z.goal_std, vec![(80_000.0f64 / 3.0).sqrt() as f32]);
    }
}
