//! `pgser-etl pipeline status FILE`: where each step stands, from what any machine sharing the
//! out folder can see — the records (`up to date`), the step locks (`running`, locally or in a
//! job), the jobs submitted (`OUT/.pipeline/slurm.jsonl`) and `squeue` (`pending`, `running`).
//! A submitted step that left the queue unfinished `failed` when its job wrote a log, and was
//! cancelled before it started (a step it reads failed) otherwise. Only `squeue` is asked:
//! `sacct` needs job accounting, which many clusters (and small test ones) do not run.
//!
//! A training step that has saved part of its run (a checkpoint the next run continues, as
//! `train --resume` would) also says how far it got and its last evaluation: grids run for
//! hours, and this is how far along they are, from any machine that sees the out folder.

use std::path::PathBuf;

use anyhow::Result;
use serde::Serialize;

use super::state::{self, Hashes};
use super::{Action, Pipeline, Step, lock, slurm};
use crate::progress;
use crate::train::{MetricsLine, metrics_path};

/// One step's state.
#[derive(Debug, Clone, Serialize)]
pub struct StepState {
    pub name: String,
    /// `up to date`, `pending`, `running`, `failed`, `stopped` (saved part of its run, which the
    /// next run continues), `not started`.
    pub state: String,
    /// The Slurm job (element) of its latest submission, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub job: Option<String>,
    /// Its job's log, when there is one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub log: Option<PathBuf>,
    /// Who runs it now (from its lock), when it runs.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub holder: Option<String>,
    /// How far a training step got, when it has saved part of its run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub progress: Option<Progress>,
    /// The score step over a table folder, not up to date, submitted to Slurm: its job array of
    /// one element per shard.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shards: Option<Shards>,
}

/// A shard array's elements by state (`slurm::element_states`).
#[derive(Debug, Clone, Serialize)]
pub struct Shards {
    /// The array's job id.
    pub job: String,
    /// Elements: β's shards.
    pub of: usize,
    pub done: usize,
    pub running: usize,
    pub pending: usize,
    pub failed: usize,
    /// Cancelled before they began (an element before them failed), or not yet begun.
    pub not_started: usize,
}

/// A training step's saved progress: its checkpoint's update count and last evaluation.
#[derive(Debug, Clone, Serialize)]
pub struct Progress {
    /// Updates in the checkpoint the next run continues from.
    pub updates: u64,
    /// Updates the step asks for.
    pub of: u64,
    /// The last evaluation in its metrics, at or before `updates`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub last_eval: Option<MetricsLine>,
}

/// The state of every step of `p`, in plan order.
pub fn status(p: &Pipeline) -> Result<Vec<StepState>> {
    let steps = super::plan(p)?;
    let jobs = slurm::jobs(&p.out)?;
    let queue = if jobs.is_empty() { None } else { slurm::queue() };
    let mut hashes = Hashes::default();
    let forecast = state::forecast(&p.out, &steps, &mut hashes)?;
    let mut all = Vec::with_capacity(steps.len());
    for (step, f) in steps.iter().zip(&forecast) {
        // The latest job that runs this step, and which element (a shard array's elements only
        // score: the step's own job is submitted after it).
        let latest = jobs.iter().rev().filter(|j| !j.shards).find_map(|j| {
            let k = j.elements.iter().position(|e| e.contains(&step.name))?;
            Some((j, k))
        });
        let job = latest.map(|(j, k)| j.element_id(k));
        let log = latest.map(|(j, k)| j.log(&p.out, k)).filter(|l| l.exists());
        let key = hashes.key(step)?;
        let mut s = StepState {
            name: step.name.clone(),
            state: String::new(),
            job,
            log,
            holder: None,
            progress: None,
            shards: None,
        };
        s.state = if key.as_ref().is_some_and(|k| state::up_to_date(&p.out, step, k, &mut hashes)) {
            "up to date".into()
        } else if let Some(h) = lock::holder(&p.out, &step.name) {
            s.holder = Some(h);
            "running".into()
        } else {
            match (&s.job, &queue) {
                (Some(id), Some(q)) if q.contains_key(id) => {
                    if q[id] == "PENDING" {
                        "pending".into()
                    } else {
                        "running".into()
                    }
                }
                (Some(_), _) if s.log.is_some() => "failed".into(),
                _ => "not started".into(),
            }
        };
        if f.runs {
            s.progress = progress(p, step, f);
            if s.state == "not started" && s.progress.is_some() {
                s.state = "stopped".into();
            }
        }
        if s.state != "up to date"
            && let Some(array) =
                jobs.iter().rev().find(|j| j.shards && j.elements.iter().any(|e| e.contains(&step.name)))
        {
            let states = slurm::element_states(&p.out, array, queue.as_ref());
            let count = |what: &str| states.iter().filter(|s| *s == what).count();
            // Its own job is cancelled once an element fails: the step failed, and that
            // element's log says why.
            if s.state == "not started" && count("failed") > 0 {
                s.state = "failed".into();
                s.log = slurm::failed_log(&p.out, &jobs, &step.name);
            }
            s.shards = Some(Shards {
                job: array.id.clone(),
                of: states.len(),
                done: count("done"),
                running: count("running"),
                pending: count("pending"),
                failed: count("failed"),
                not_started: count("not started"),
            });
        }
        all.push(s);
    }
    Ok(all)
}

/// The saved progress of a training step that will continue from its checkpoint.
fn progress(p: &Pipeline, step: &Step, f: &state::Forecast) -> Option<Progress> {
    let Action::Train { cfg, out, .. } = &step.action else { return None };
    let updates = state::resumes_from(&p.out, step, f, cfg);
    if updates == 0 {
        return None;
    }
    let text = std::fs::read_to_string(metrics_path(out)).unwrap_or_default();
    let last_eval = text
        .lines()
        .rev()
        .filter_map(|l| serde_json::from_str::<MetricsLine>(l).ok())
        .find(|m| m.eval.is_some() && m.updates <= updates);
    Some(Progress { updates, of: cfg.updates, last_eval })
}

/// "7.5k of 30.0k updates saved; last evaluation at 5.0k: paper score 1.38, success 0.04", or on
/// a task scored by success alone (OGBench's): "…: success 4.0 %".
fn render_progress(g: &Progress, task: &str) -> String {
    let mut s = format!("{} of {} updates saved", progress::count(g.updates), progress::count(g.of));
    if let Some((m, e)) = g.last_eval.as_ref().and_then(|m| Some((m, m.eval.as_ref()?))) {
        let at = progress::count(m.updates);
        if crate::eval::scored_by_success(task) {
            s += &format!("; last evaluation at {at}: success {:.1} %", 100.0 * e.success_rate);
        } else {
            s += &format!("; last evaluation at {at}: paper score {:.2}, success {:.2}", e.paper_score, e.success_rate);
        }
    }
    s
}

/// "shards (job array 12): 2 of 4 scored, 1 running, 1 pending".
fn render_shards(a: &Shards) -> String {
    let mut s = format!("shards (job array {}): {} of {} scored", a.job, a.done, a.of);
    for (n, what) in
        [(a.running, "running"), (a.pending, "pending"), (a.failed, "failed"), (a.not_started, "not started")]
    {
        if n > 0 {
            s += &format!(", {n} {what}");
        }
    }
    s
}

/// One line per step.
pub fn render(p: &Pipeline, states: &[StepState]) -> String {
    let n = states.len();
    let mut text = String::new();
    for (i, s) in states.iter().enumerate() {
        let mut line = format!("pipeline {}: [{}/{n}] {}: {}", p.name, i + 1, s.name, s.state);
        match (s.state.as_str(), &s.job) {
            ("pending" | "running", Some(j)) => line += &format!(" (Slurm job {j})"),
            ("failed", _) => line += &format!(" (log {})", s.log.as_ref().expect("a failed job has a log").display()),
            _ => {}
        }
        if let Some(h) = &s.holder {
            line += &format!(" ({h})");
        }
        if let Some(g) = &s.progress {
            line += &format!(" — {}", render_progress(g, &p.task));
        }
        if let Some(a) = &s.shards {
            line += &format!(" — {}", render_shards(a));
        }
        text += &line;
        text.push('\n');
    }
    text
}
