//! `pgser-etl pipeline status FILE`: where each step stands, from what any machine sharing the
//! out folder can see — the records (`up to date`), the step locks (`running`, locally or in a
//! job), the jobs submitted (`OUT/.pipeline/slurm.jsonl`) and `squeue` (`pending`, `running`).
//! A submitted step that left the queue unfinished `failed` when its job wrote a log, and was
//! cancelled before it started (a step it reads failed) otherwise. Only `squeue` is asked:
//! `sacct` needs job accounting, which many clusters (and small test ones) do not run.

use std::path::PathBuf;

use anyhow::Result;
use serde::Serialize;

use super::state::{self, Hashes};
use super::{Pipeline, lock, slurm};

/// One step's state.
#[derive(Debug, Clone, Serialize)]
pub struct StepState {
    pub name: String,
    /// `up to date`, `pending`, `running`, `failed`, `not started`.
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
}

/// The state of every step of `p`, in plan order.
pub fn status(p: &Pipeline) -> Result<Vec<StepState>> {
    let steps = super::plan(p)?;
    let jobs = slurm::jobs(&p.out)?;
    let queue = if jobs.is_empty() { None } else { slurm::queue() };
    let mut hashes = Hashes::default();
    let mut all = Vec::with_capacity(steps.len());
    for step in &steps {
        // The latest job that holds this step, and which element.
        let latest = jobs.iter().rev().find_map(|j| {
            let k = j.elements.iter().position(|e| e.contains(&step.name))?;
            Some((j, k))
        });
        let job = latest.map(|(j, k)| j.element_id(k));
        let log = latest.map(|(j, k)| j.log(&p.out, k)).filter(|l| l.exists());
        let key = hashes.key(step)?;
        let mut s = StepState { name: step.name.clone(), state: String::new(), job, log, holder: None };
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
        all.push(s);
    }
    Ok(all)
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
        text += &line;
        text.push('\n');
    }
    text
}
