//! `pgser-etl pipeline run FILE`: the paper's whole experiment as one command.
//!
//! A pipeline file (`spec.rs`) becomes a list of steps — data (with, for a trained expert that is
//! absent, its online training first), Q pre-training, scoring, the grid
//! of agents, the Fig. 5 / Table 1 report, the results table — each calling the same library
//! function as its CLI command. (The report comes after the agents so that the hours of training
//! never wait on it; it reads only the scored table and the Q.) A step is *up to date* when its record in `OUT/.pipeline/`
//! holds the same key — the sha256 of its parameters and of its inputs' contents — and its
//! outputs still have the sha256 recorded when they were written. So a second run repeats
//! nothing, changing one parameter reruns only the steps whose inputs or parameters changed, and
//! because every step is deterministic a deleted output is rebuilt byte for byte and the steps
//! after it stay up to date.
//!
//! Crashes: every output is written atomically, and a record is written only after its step
//! finished, so an interrupted run is resumed by running it again. A training step interrupted
//! after a checkpoint continues from it (`pgser-train --resume`), which gives the same weights
//! as an uninterrupted run; so does raising `updates` on a finished agent. Only a checkpoint of
//! another run (settings, data, a longer run: `train::StaleCheckpoint`) is started over, and it
//! is kept aside as `.stale`; any other error while resuming stops the step and touches nothing.
//!
//! The key includes pgser's version (`state.rs` says why a version rather than a finer code
//! identity), so upgrading pgser reruns every step once, training from scratch.
//!
//! Where steps run: one after another here, several at once with `--jobs` (`exec.rs`), or as
//! Slurm jobs (`slurm.rs`), each job running `pipeline step` — every runner takes a step's lock
//! (`lock.rs`) and applies the rules above through the same function (`exec::run_unit`), so two
//! runs of one pipeline never run a step twice. `status.rs` says where each step stands.
//!
//! Before the first step runs, everything that does not need an earlier step's output is
//! checked (`check.rs`: settings, input pickles, the report's positives, the out folder, the
//! device), and the cost of the steps that will run is estimated and printed (`cost.rs`: updates,
//! a wall time measured on this machine, disk), so a mistake or a run of days shows up in a
//! second rather than at the end.

mod check;
mod cost;
pub mod demo;
mod exec;
mod lock;
mod plan;
pub mod slurm;
mod spec;
mod state;
mod status;

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use serde_json::json;

pub use cost::{Cost, Measured, StepCost};
pub use plan::plan;
use plan::positives;
pub use spec::{Data, Pipeline, Variant, normalize, train_config};
use state::Hashes;
pub use status::{StepState, render as render_status, status};

use crate::agent::Backend;
use crate::collect::policy::{PolicyKind, PolicySpec};
use crate::train::online::OnlineConfig;
use crate::train::{TrainConfig, metrics_path};
use crate::{collect, convert, report, score};

/// What one step does, with everything it needs.
enum Action {
    Collect(CollectStep),
    /// Online DDPG + HER training of the expert (`pgser-train online`).
    Online {
        cfg: Box<OnlineConfig>,
        out: PathBuf,
    },
    Convert(convert::ConvertOptions),
    /// `stack`: agent cells of one stack id train at once as one stack of networks.
    Train {
        data: PathBuf,
        out: PathBuf,
        cfg: Box<TrainConfig>,
        stack: Option<usize>,
    },
    Score(ScoreStep),
    Report(report::QReportOptions),
    Results(Vec<report::Run>),
}

/// A `collect` step. With `checkpoint` the policy is that trained actor, read when the step
/// runs (an earlier step may write it), and `opts.policy.kind` stands in for it until then.
struct CollectStep {
    opts: collect::CollectOptions,
    checkpoint: Option<PathBuf>,
}

impl CollectStep {
    /// The options `collect` runs with: the checkpoint's actor read in when there is one.
    fn options(&self) -> Result<collect::CollectOptions> {
        let mut o = self.opts.clone();
        if let Some(c) = &self.checkpoint {
            o.policy.kind = PolicyKind::parse(&format!("checkpoint:{}", c.display()))?;
        }
        Ok(o)
    }
}

/// The `score` step. Over a table folder `shards` names β's shards in order (the scored folder's
/// shards get the same names): locally the step scores them all, under Slurm each is one element
/// of a job array (`pipeline step FILE score --shard I`, [`step_shard`]) and the step's own job
/// then writes the manifest and the record. Empty for a single table.
struct ScoreStep {
    opts: score::ScoreOptions,
    shards: Vec<String>,
}

/// One step of the plan.
pub struct Step {
    /// Unique within the pipeline: `pretrain`, `agent td3bc_mem_s0`, …
    pub name: String,
    pub inputs: Vec<PathBuf>,
    pub outputs: Vec<PathBuf>,
    /// What, besides the inputs' bytes, the outputs depend on.
    pub params: serde_json::Value,
    action: Action,
}

/// How a step went.
#[derive(Debug, Clone, Serialize)]
pub struct StepReport {
    pub name: String,
    /// `ran`, `resumed` (a training step continued from its checkpoint), `up to date`, with
    /// `--dry-run` `would run`; through Slurm also `failed` (its job failed) and `not run` (its
    /// job was cancelled as a step it reads failed).
    pub status: String,
    pub seconds: f64,
    pub outputs: Vec<PathBuf>,
    /// The Slurm job's log of a step that failed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub log: Option<PathBuf>,
}

#[derive(Debug, Clone, Serialize)]
pub struct RunReport {
    pub pipeline: String,
    pub out: PathBuf,
    pub steps: Vec<StepReport>,
    /// The results table (Markdown) and the Fig. 5 / Table 1 report, when they were reached.
    pub results: Option<PathBuf>,
    pub table1: Option<PathBuf>,
    /// What the steps that were to run would cost, foreseen before the first one ran.
    pub cost: Cost,
}

/// Where `pipeline run` runs the steps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Executor {
    /// On this machine (`--jobs` at once).
    Local,
    /// As Slurm jobs (`slurm.rs`).
    Slurm,
}

#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Stop after the step of this name (e.g. `score` to prepare the data and Q only).
    pub until: Option<String>,
    /// Only say which steps would run.
    pub dry_run: bool,
    pub device: Backend,
    /// Time a few updates, episodes and scores on this machine for the cost estimate (a second
    /// or two); without it the cost says updates and disk but no wall time.
    pub measure: bool,
    /// Units (steps, stacks of agents) run at once; 1 runs them one after another.
    pub jobs: usize,
    /// Threads to split between the `jobs` (None: rayon's pool, i.e. `--threads` or all cores).
    pub threads: Option<usize>,
}

pub(crate) fn stack_of(step: &Step) -> Option<usize> {
    match &step.action {
        Action::Train { stack, .. } => *stack,
        _ => None,
    }
}

/// The index of the last step a run goes to: `until`'s, or the plan's last.
pub(crate) fn last_step(steps: &[Step], until: Option<&str>) -> Result<usize> {
    match until {
        None => Ok(steps.len() - 1),
        Some(u) => match steps.iter().position(|s| s.name == u) {
            Some(i) => Ok(i),
            None => {
                let names: Vec<_> = steps.iter().map(|s| s.name.as_str()).collect();
                bail!("--until {u}: no such step (steps: {})", names.join(", "))
            }
        },
    }
}

/// Runs (or with `dry_run` only checks) the steps of `p`, skipping those up to date: in plan
/// order, or with `jobs` > 1 as many independent ones at once (`exec.rs`). Before the first step
/// runs, everything that does not need an earlier step's output is checked (`check.rs`) and the
/// cost of the steps to run is estimated (`cost.rs`). `log` receives the cost and one line per
/// step.
pub fn run(p: &Pipeline, o: &RunOptions, log: &(dyn Fn(&str) + Sync)) -> Result<RunReport> {
    let steps = plan(p)?;
    let last = last_step(&steps, o.until.as_deref())?;
    let data = check::check(p, &steps[..=last], o.device)?;
    let mut hashes = Hashes::default();
    let forecast = state::forecast(&p.out, &steps[..=last], &mut hashes)?;
    let cost = cost::estimate(p, &steps[..=last], &forecast, &data, o.measure, o.device)?;
    for line in cost::render(&cost).lines() {
        log(line);
    }
    let n = steps.len();
    let outcomes: Vec<exec::Outcome> = if o.dry_run {
        // A dry run reports the forecast: a step after one that would run reads outputs that
        // do not exist yet.
        (0..=last)
            .map(|i| {
                let head = format!("[{}/{n}] {}", i + 1, steps[i].name);
                if forecast[i].runs {
                    let b = cost.per_step.iter().find(|c| c.name == steps[i].name).map(cost::brief);
                    let b = b.filter(|b| !b.is_empty()).map(|b| format!(" ({b})")).unwrap_or_default();
                    log(&format!("{head}: would run{b}"));
                    exec::Outcome { status: "would run".into(), seconds: 0.0, log: None }
                } else {
                    log(&format!("{head}: up to date"));
                    exec::Outcome { status: "up to date".into(), seconds: 0.0, log: None }
                }
            })
            .collect()
    } else {
        let units = exec::units(&steps, &(0..=last).collect::<Vec<_>>(), o.jobs > 1);
        let c = exec::Ctx { p, steps: &steps, device: o.device, cost: Some(&cost), log };
        let threads = o.threads.unwrap_or_else(rayon::current_num_threads);
        let mut done = exec::run_units(&c, &units, o.jobs, threads, hashes)?;
        (0..=last).map(|i| done.remove(&i).expect("every step of the run has an outcome")).collect()
    };
    Ok(report_of(p, &steps[..=last], outcomes, cost))
}

/// The run's report from each step's outcome, in plan order.
pub(crate) fn report_of(p: &Pipeline, steps: &[Step], outcomes: Vec<exec::Outcome>, cost: Cost) -> RunReport {
    let mut report =
        RunReport { pipeline: p.name.clone(), out: p.out.clone(), steps: vec![], results: None, table1: None, cost };
    for (step, o) in steps.iter().zip(outcomes) {
        let reached = o.status != "would run" && o.status != "failed" && o.status != "not run";
        match step.action {
            Action::Results(_) if reached => report.results = Some(step.outputs[0].clone()),
            Action::Report(_) if reached => report.table1 = Some(step.outputs[1].clone()),
            _ => {}
        }
        report.steps.push(StepReport {
            name: step.name.clone(),
            status: o.status,
            seconds: o.seconds,
            outputs: step.outputs.clone(),
            log: o.log,
        });
    }
    report
}

/// `pgser-etl pipeline step FILE STEP…`: runs the named steps of `p` exactly as `pipeline run`
/// would at their turn — under their locks, skipping those up to date, continuing a training
/// step from its checkpoint — with agent cells of one stack as one stack. What each Slurm job
/// runs (`slurm.rs`); their inputs must exist (the steps that write them have finished).
pub fn step(p: &Pipeline, names: &[String], device: Backend, log: &(dyn Fn(&str) + Sync)) -> Result<Vec<StepReport>> {
    let steps = plan(p)?;
    let mut include = Vec::with_capacity(names.len());
    for name in names {
        match steps.iter().position(|s| &s.name == name) {
            Some(i) => include.push(i),
            None => {
                let all: Vec<_> = steps.iter().map(|s| s.name.as_str()).collect();
                bail!("pipeline {}: no step {name:?} (steps: {})", p.name, all.join(", "))
            }
        }
    }
    // Plan order, so that every runner takes the locks of a stack in the same order.
    include.sort();
    include.dedup();
    let units = exec::units(&steps, &include, false);
    let c = exec::Ctx { p, steps: &steps, device, cost: None, log };
    let mut done = exec::run_units(&c, &units, 1, rayon::current_num_threads(), Hashes::default())?;
    Ok(include
        .iter()
        .map(|&i| {
            let o = done.remove(&i).expect("every named step has an outcome");
            StepReport {
                name: steps[i].name.clone(),
                status: o.status,
                seconds: o.seconds,
                outputs: steps[i].outputs.clone(),
                log: None,
            }
        })
        .collect())
}

/// `pgser-etl pipeline step FILE score --shard I`: one element of the score step's job array
/// over a table folder (`slurm.rs`) — shard `shard` of β scored into the scored folder, as
/// `pgser-etl score --shard I` does; a shard already scored with the same settings is kept. It
/// writes no manifest and no record: the step's own job does both once every element has
/// finished, so the step is never recorded with a shard missing. Under its own lock (`score
/// shard I`), so two submissions score a shard once; a step already up to date is left alone.
pub fn step_shard(
    p: &Pipeline,
    name: &str,
    shard: usize,
    device: Backend,
    log: &(dyn Fn(&str) + Sync),
) -> Result<StepReport> {
    let steps = plan(p)?;
    let Some(step) = steps.iter().find(|s| s.name == name) else {
        let all: Vec<_> = steps.iter().map(|s| s.name.as_str()).collect();
        bail!("pipeline {}: no step {name:?} (steps: {})", p.name, all.join(", "))
    };
    let Action::Score(ScoreStep { opts, shards }) = &step.action else {
        bail!("pipeline {}: --shard is for the score step over a table folder, not for step {name}", p.name)
    };
    if shards.is_empty() {
        bail!(
            "pipeline {}: --shard {shard}: β ({}) is a single table, scored as one; --shard is for a table folder's shards",
            p.name,
            opts.data.display()
        );
    }
    if shard >= shards.len() {
        bail!("pipeline {}: --shard {shard}: β has {} shards (0 to {})", p.name, shards.len(), shards.len() - 1);
    }
    let head = format!("{name} shard {shard} of {}", shards.len());
    let waiting = |holder: &str| log(&format!("{head}: waiting for its lock ({holder})"));
    let _lock = lock::StepLock::acquire(&p.out, &format!("{name} shard {shard}"), &waiting)?;
    let mut hashes = Hashes::default();
    let Some(key) = hashes.key(step)? else {
        let missing = step.inputs.iter().find(|f| !f.exists()).map(|f| f.display().to_string());
        bail!(
            "pipeline {}, step {head}: input {} is missing (the step that writes it has not finished)",
            p.name,
            missing.unwrap_or_default()
        );
    };
    let outputs = vec![opts.output.join(&shards[shard])];
    if state::up_to_date(&p.out, step, &key, &mut hashes) {
        log(&format!("{head}: up to date"));
        return Ok(StepReport { name: name.into(), status: "up to date".into(), seconds: 0.0, outputs, log: None });
    }
    log(&format!("{head}: running"));
    let t0 = std::time::Instant::now();
    let bar = crate::progress::bar("score", "transitions");
    let o = score::ScoreOptions { device, threads: rayon::current_num_threads(), shard: Some(shard), ..opts.clone() };
    score::score(&o, &bar).with_context(|| format!("pipeline {}, step {head}", p.name))?;
    bar.finish_and_clear();
    let seconds = t0.elapsed().as_secs_f64();
    // What `slurm.rs` reads in the element's log to tell a finished element from a failed one.
    log(&format!("{head}: ran in {seconds:.1} s"));
    Ok(StepReport { name: name.into(), status: "ran".into(), seconds, outputs, log: None })
}

/// The report's one-screen summary: steps, then where the tables are.
pub fn render(r: &RunReport) -> String {
    let count = |f: &dyn Fn(&str) -> bool| r.steps.iter().filter(|s| f(&s.status)).count();
    let mut s = format!(
        "pipeline {}: {} steps, {} run, {} up to date",
        r.pipeline,
        r.steps.len(),
        count(&|s| s == "ran" || s == "resumed"),
        count(&|s| s == "up to date")
    );
    let would = count(&|s| s == "would run");
    if would > 0 {
        s += &format!(", {would} would run (dry run)");
    }
    // Slurm (`--wait`): steps whose job failed, and those cancelled as they read their outputs.
    for what in ["failed", "not run"] {
        let k = count(&|s| s == what);
        if k > 0 {
            s += &format!(", {k} {what}");
        }
    }
    s.push('\n');
    if let Some(t) = &r.table1 {
        s += &format!("Fig. 5 and Table 1: {} (and fig5_q_hist.png beside it)\n", t.display());
    }
    if let Some(t) = &r.results {
        s += &format!("results: {} (CSV and curves beside it)\n", t.display());
    }
    s
}

/// An error naming the steps that did not finish (through Slurm: failed, or not run because a
/// step they read failed) and the logs of the failed ones; Ok when every step finished.
pub fn finished(r: &RunReport) -> Result<()> {
    let failed: Vec<String> = r
        .steps
        .iter()
        .filter(|s| s.status == "failed")
        .map(|s| match &s.log {
            Some(l) => format!("{} (log {})", s.name, l.display()),
            None => s.name.clone(),
        })
        .collect();
    let not_run: Vec<&str> = r.steps.iter().filter(|s| s.status == "not run").map(|s| s.name.as_str()).collect();
    if failed.is_empty() && not_run.is_empty() {
        return Ok(());
    }
    let mut msg = format!("pipeline {}: {} step(s) failed: {}", r.pipeline, failed.len(), failed.join(", "));
    if !not_run.is_empty() {
        msg += &format!("; not run as they read a failed step's outputs: {}", not_run.join(", "));
    }
    bail!("{msg}; fix the cause and run again: only what did not finish runs")
}
