//! `pgser-etl pipeline run FILE`: the paper's whole experiment as one command.
//!
//! A pipeline file (`spec.rs`) becomes a list of steps — data, Q pre-training, scoring, the grid
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
//! Before the first step runs, everything that does not need an earlier step's output is
//! checked (`check.rs`: settings, input pickles, the report's positives, the out folder, the
//! device), and the cost of the steps that will run is estimated and printed (`cost.rs`: updates,
//! a wall time measured on this machine, disk), so a mistake or a run of days shows up in a
//! second rather than at the end.

mod check;
mod cost;
mod spec;
mod state;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use serde::Serialize;
use serde_json::json;

pub use cost::{Cost, Measured, StepCost};
pub use spec::{Data, Pipeline, Variant, normalize, train_config};
use state::Hashes;

use crate::agent::{Algo, Backend, checkpoint};
use crate::env::policy::{PolicyKind, PolicySpec};
use crate::train::{TrainConfig, metrics_path};
use crate::{collect, progress, report, score, trajectory};

/// What one step does, with everything it needs.
enum Action {
    Collect(collect::CollectOptions),
    Convert(trajectory::ConvertOptions),
    /// `stack`: agent cells of one stack id train at once as one stack of networks.
    Train {
        data: PathBuf,
        out: PathBuf,
        cfg: Box<TrainConfig>,
        stack: Option<usize>,
    },
    Score(score::ScoreOptions),
    Report(report::QReportOptions),
    Results(Vec<report::Run>),
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
    /// `ran`, `resumed` (a training step continued from its checkpoint), `up to date`, or with
    /// `--dry-run` `would run`.
    pub status: String,
    pub seconds: f64,
    pub outputs: Vec<PathBuf>,
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
}

/// The steps of `p`, in the order they run.
pub fn plan(p: &Pipeline) -> Result<Vec<Step>> {
    let out = &p.out;
    let cmd = |step: &str| format!("pgser pipeline {} step {step}", p.name);
    let mut steps = Vec::new();
    let traj = out.join("traj.parquet");
    let (pickles, episodes) = match &p.data {
        Data::Pickles { inputs, episodes } => (inputs.clone(), episodes.clone()),
        Data::Collect { expert, random, seed, noise } => {
            let mut files = Vec::new();
            for (kind, n, s) in
                [(PolicyKind::Expert, *expert, *seed), (PolicyKind::Random, *random, seed + *expert as u64)]
            {
                let name = format!("collect_{}", kind.name());
                let file = out.join(format!("data/{}.pkl", kind.name()));
                let noise = if kind == PolicyKind::Expert { *noise } else { 0.0 };
                steps.push(Step {
                    params: json!({"task": p.task, "policy": kind.name(), "episodes": n, "seed": s, "noise": noise}),
                    name: name.clone(),
                    inputs: vec![],
                    outputs: vec![file.clone()],
                    action: Action::Collect(collect::CollectOptions {
                        task: p.task.clone(),
                        policy: PolicySpec { kind, noise, epsilon: 0.0 },
                        episodes: n,
                        seed: s,
                        output: file.clone(),
                        float32: false,
                        row_group_rows: 65_536,
                        command: cmd(&name),
                    }),
                });
                files.push(file);
            }
            (files, None)
        }
    };
    steps.push(Step {
        name: "convert".into(),
        params: json!({"task": p.task, "episodes": episodes}),
        inputs: pickles.clone(),
        outputs: vec![traj.clone()],
        action: Action::Convert(trajectory::ConvertOptions {
            inputs: pickles,
            output: traj.clone(),
            task: Some(p.task.clone()),
            threshold: None,
            episodes,
            float32: false,
            allow_nonfinite: false,
            row_group_rows: 65_536,
            command: cmd("convert"),
        }),
    });

    let q = out.join("q.ckpt");
    steps.push(train_step("pretrain", &traj, &q, p.pretrain_config()?));
    let scored = out.join("scored.parquet");
    let s = &p.score;
    steps.push(Step {
        name: "score".into(),
        params: json!({"swaps": s.swaps, "seed": s.seed, "include_original": s.include_original,
                       "chunk_episodes": s.chunk_episodes}),
        inputs: vec![q.clone(), traj.clone()],
        outputs: vec![scored.clone()],
        action: Action::Score(score::ScoreOptions {
            checkpoint: q.clone(),
            data: traj.clone(),
            output: scored.clone(),
            swaps: s.swaps,
            seed: s.seed,
            include_original: s.include_original,
            device: Backend::Cpu,
            chunk_episodes: s.chunk_episodes,
            threads: 0,
            command: cmd("score"),
        }),
    });
    let mut runs = Vec::new();
    for &algo in &p.agents.algos {
        for &variant in &p.agents.variants {
            for &seed in &p.agents.seeds {
                let id = format!("{}_{}_s{seed}", algo_name(algo), variant.name());
                let ckpt = out.join(format!("agents/{id}.ckpt"));
                let data = if variant == Variant::Mem { &scored } else { &traj };
                let mut step = train_step(&format!("agent {id}"), data, &ckpt, p.agent_config(algo, variant, seed)?);
                if variant == Variant::Mem {
                    // The scored table names β; training reads it too.
                    step.inputs.push(traj.clone());
                }
                steps.push(step);
                runs.push(report::Run {
                    task: p.task.clone(),
                    algo: algo_name(algo).into(),
                    variant: variant.name().into(),
                    seed,
                    metrics: metrics_path(&ckpt),
                });
            }
        }
    }
    let report_dir = out.join("report");
    let r = report::QReportOptions {
        scored: scored.clone(),
        out_dir: report_dir.clone(),
        positive_episodes: p.report.positive_episodes,
        seed: p.report.seed,
        ..report::QReportOptions::default()
    };
    steps.push(Step {
        name: "report".into(),
        params: json!({"positive_episodes": r.positive_episodes, "seed": r.seed, "test_fraction": r.test_fraction,
                       "max_samples": r.max_samples, "svm_max_train": r.svm_max_train}),
        inputs: vec![scored.clone(), traj.clone(), q.clone()],
        outputs: ["fig5_q_hist.png", "table1.md", "table1.json"].iter().map(|f| report_dir.join(f)).collect(),
        action: Action::Report(r),
    });

    steps.push(Step {
        name: "results".into(),
        params: json!({"runs": runs.iter().map(|r| (&r.algo, &r.variant, r.seed)).collect::<Vec<_>>()}),
        inputs: runs.iter().map(|r| r.metrics.clone()).collect(),
        outputs: vec![out.join("results.md"), out.join("results.csv"), out.join(format!("curves_{}.png", p.task))],
        action: Action::Results(runs),
    });
    assign_stacks(&mut steps, p.agents.batch.unwrap_or(usize::MAX));
    let names: std::collections::HashSet<_> = steps.iter().map(|s| &s.name).collect();
    debug_assert_eq!(names.len(), steps.len());
    Ok(steps)
}

/// Puts the agent cells into stacks of at most `batch`, in plan order, each stack of cells that
/// may train together (same networks and schedule: TD3 and TD3+BC cells go to separate stacks).
fn assign_stacks(steps: &mut [Step], batch: usize) {
    let mut open: Vec<(serde_json::Value, usize, usize)> = Vec::new(); // (schedule, id, members)
    for step in steps.iter_mut().filter(|s| s.name.starts_with("agent ")) {
        let Action::Train { cfg, stack, .. } = &mut step.action else { continue };
        let key = crate::train::schedule(cfg);
        let id = match open.iter_mut().find(|(k, _, n)| *k == key && *n < batch) {
            Some((_, id, n)) => {
                *n += 1;
                *id
            }
            None => {
                open.push((key, open.len(), 1));
                open.len() - 1
            }
        };
        *stack = Some(id);
    }
}

fn stack_of(step: &Step) -> Option<usize> {
    match &step.action {
        Action::Train { stack, .. } => *stack,
        _ => None,
    }
}

fn algo_name(a: Algo) -> &'static str {
    match a {
        Algo::Td3 => "td3",
        Algo::Td3bc => "td3bc",
    }
}

fn train_step(name: &str, data: &Path, ckpt: &Path, cfg: TrainConfig) -> Step {
    Step {
        name: name.into(),
        params: json!({ "train": cfg }),
        inputs: vec![data.to_path_buf()],
        outputs: vec![ckpt.to_path_buf(), metrics_path(ckpt)],
        action: Action::Train { data: data.to_path_buf(), out: ckpt.to_path_buf(), cfg: Box::new(cfg), stack: None },
    }
}

/// Runs (or with `dry_run` only checks) the steps of `p` in order, skipping those up to date.
/// Before the first step runs, everything that does not need an earlier step's output is
/// checked (`check.rs`) and the cost of the steps to run is estimated (`cost.rs`). `log`
/// receives the cost and one line per step.
pub fn run(p: &Pipeline, o: &RunOptions, log: &mut dyn FnMut(&str)) -> Result<RunReport> {
    let steps = plan(p)?;
    let last = match &o.until {
        None => steps.len() - 1,
        Some(u) => match steps.iter().position(|s| &s.name == u) {
            Some(i) => i,
            None => {
                let names: Vec<_> = steps.iter().map(|s| s.name.as_str()).collect();
                bail!("--until {u}: no such step (steps: {})", names.join(", "));
            }
        },
    };
    let data = check::check(p, &steps[..=last], o.device)?;
    let mut hashes = Hashes::default();
    let forecast = state::forecast(&p.out, &steps[..=last], &mut hashes)?;
    let cost = cost::estimate(p, &steps[..=last], &forecast, &data, o.measure, o.device)?;
    for line in cost::render(&cost).lines() {
        log(line);
    }
    let brief = |name: &str| match cost.per_step.iter().find(|c| c.name == name).map(cost::brief) {
        Some(b) if !b.is_empty() => format!(" ({b})"),
        _ => String::new(),
    };
    let mut report = RunReport {
        pipeline: p.name.clone(),
        out: p.out.clone(),
        steps: vec![],
        results: None,
        table1: None,
        cost: cost.clone(),
    };
    let n = steps.len();
    // Steps already run as members of a stack: their status and seconds.
    let mut stacked: std::collections::HashMap<usize, (String, f64)> = std::collections::HashMap::new();
    for (i, step) in steps.iter().enumerate() {
        let head = format!("[{}/{n}] {}", i + 1, step.name);
        let key = hashes.key(step)?;
        // A dry run reports the forecast: a step after one that would run reads outputs that
        // do not exist yet.
        let up = if o.dry_run {
            !forecast[i].runs
        } else {
            key.as_ref().is_some_and(|k| state::up_to_date(&p.out, step, k, &mut hashes))
        };
        let status = if let Some((how, secs)) = stacked.remove(&i) {
            log(&format!("{head}: {how} (in a stack) in {secs:.1} s"));
            (how, secs)
        } else if up {
            log(&format!("{head}: up to date"));
            ("up to date".to_string(), 0.0)
        } else if o.dry_run {
            log(&format!("{head}: would run{}", brief(&step.name)));
            ("would run".to_string(), 0.0)
        } else {
            // An agent cell runs with the later cells of its stack that must run too.
            let mut members = vec![i];
            if let Some(id) = stack_of(step) {
                for (j, later) in steps.iter().enumerate().take(last + 1).skip(i + 1) {
                    if stack_of(later) == Some(id) {
                        let k = hashes.key(later)?;
                        if !k.as_ref().is_some_and(|k| state::up_to_date(&p.out, later, k, &mut hashes)) {
                            members.push(j);
                        }
                    }
                }
            }
            let what = if members.len() > 1 {
                format!(" with {} more in one stack", members.len() - 1)
            } else {
                String::new()
            };
            log(&format!("{head}: running{}{what}", brief(&step.name)));
            let t0 = Instant::now();
            // A training step may continue from its checkpoint after a crash (no record) or a
            // change of settings (another key; `train` refuses what cannot continue), but not when
            // a finished output no longer has its recorded bytes (that one is rebuilt from scratch)
            // nor when another pgser version finished it.
            let resume: Vec<bool> = members
                .iter()
                .map(|&j| Ok(state::may_resume(&p.out, &steps[j], hashes.key(&steps[j])?.as_deref())))
                .collect::<Result<_>>()?;
            let how: Vec<&str> = if members.len() == 1 {
                vec![
                    execute(step, o.device, resume[0])
                        .with_context(|| format!("pipeline {}, step {}", p.name, step.name))?,
                ]
            } else {
                let group: Vec<&Step> = members.iter().map(|&j| &steps[j]).collect();
                execute_stack(&group, o.device, &resume).with_context(|| format!("pipeline {}", p.name))?
            };
            let secs = t0.elapsed().as_secs_f64();
            for (&j, how) in members.iter().zip(&how) {
                let key = hashes.key(&steps[j])?.context("an input vanished while the step ran")?;
                state::record(&p.out, &steps[j], &key, secs, &mut hashes)?;
                if j != i {
                    stacked.insert(j, (how.to_string(), secs));
                }
            }
            log(&format!("{head}: {} in {secs:.1} s", how[0]));
            (how[0].to_string(), secs)
        };
        match step.action {
            Action::Results(_) if status.0 != "would run" => report.results = Some(step.outputs[0].clone()),
            Action::Report(_) if status.0 != "would run" => report.table1 = Some(step.outputs[1].clone()),
            _ => {}
        }
        let stop = o.until.as_deref() == Some(step.name.as_str());
        report.steps.push(StepReport {
            name: step.name.clone(),
            status: status.0,
            seconds: status.1,
            outputs: step.outputs.clone(),
        });
        if stop {
            break;
        }
    }
    Ok(report)
}

/// Runs one step; returns `ran` or `resumed`.
fn execute(step: &Step, device: Backend, resume: bool) -> Result<&'static str> {
    for o in &step.outputs {
        if let Some(dir) = o.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
        }
    }
    let bar = progress::bar("step", "");
    let mut how = "ran";
    match &step.action {
        Action::Collect(o) => drop(collect::collect(o, &bar)?),
        Action::Convert(o) => drop(trajectory::convert(o, &bar)?),
        Action::Score(o) => drop(score::score(&score::ScoreOptions { device, ..o.clone() }, &bar)?),
        Action::Report(o) => drop(report::q_report(o)?),
        Action::Results(runs) => drop(report::results(runs, step.outputs[0].parent().expect("in the out folder"))?),
        Action::Train { .. } => how = execute_stack(&[step], device, &[resume])?[0],
    }
    bar.finish_and_clear();
    Ok(how)
}

/// Runs training steps as one stack of agents (cells that start from different updates — some
/// continuing a checkpoint, some from scratch — as one stack per starting update); returns
/// `ran` or `resumed` for each. A cell continues its checkpoint when `resume` allows and the
/// checkpoint belongs to the same run; a checkpoint of another run is set aside as `.stale` and
/// the cell starts over; any other failure stops the stack and leaves every checkpoint as it was.
fn execute_stack(steps: &[&Step], device: Backend, resume: &[bool]) -> Result<Vec<&'static str>> {
    let mut cells = Vec::with_capacity(steps.len());
    let mut starts = std::collections::BTreeMap::<u64, Vec<usize>>::new();
    let mut how = Vec::with_capacity(steps.len());
    for (i, (step, &resume)) in steps.iter().zip(resume).enumerate() {
        for o in &step.outputs {
            if let Some(dir) = o.parent().filter(|d| !d.as_os_str().is_empty()) {
                std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create", dir.display()))?;
            }
        }
        let Action::Train { data, out, cfg, .. } = &step.action else { bail!("{}: not a training step", step.name) };
        let mut cell = crate::train::Cell { data: data.clone(), out: out.clone(), cfg: (**cfg).clone(), resume: false };
        let mut start = 0;
        if resume && out.exists() && checkpoint::resume_path(out).exists() {
            match crate::train::resume_point(&cell) {
                Ok(point) => {
                    cell.resume = point.is_some();
                    start = point.unwrap_or(0);
                }
                // The checkpoint is of another run (settings, data, a longer run): it cannot be
                // continued, so start over, but keep it aside rather than overwrite it.
                Err(e) if e.downcast_ref::<crate::train::StaleCheckpoint>().is_some() => {
                    let kept = set_aside_stale(out)?;
                    eprintln!(
                        "pgser pipeline: {}: not resumed ({e:#}); the old checkpoint is kept as {}; training from scratch",
                        step.name,
                        kept.display()
                    );
                }
                // Anything else (an unreadable file, a failed read of the data) is reported; the
                // checkpoint and its progress stay as they are.
                Err(e) => {
                    return Err(e.context(format!(
                        "step {}: resuming {} failed; the checkpoint is left as it was",
                        step.name,
                        out.display()
                    )));
                }
            }
        } else if resume && out.exists() {
            // A checkpoint without its resume state cannot be continued; keep it anyway.
            set_aside_stale(out)?;
        }
        how.push(if cell.resume { "resumed" } else { "ran" });
        starts.entry(start).or_default().push(i);
        cells.push(cell);
    }
    let bar = progress::bar("agents", "updates");
    for members in starts.values() {
        let stack: Vec<crate::train::Cell> = members.iter().map(|&i| cells[i].clone()).collect();
        let commands: Vec<String> = members.iter().map(|&i| format!("pgser pipeline step {}", steps[i].name)).collect();
        let names: Vec<&str> = members.iter().map(|&i| steps[i].name.as_str()).collect();
        crate::train::train_stack(&stack, device.device()?, &commands, &bar).with_context(|| {
            format!("training {} (one stack); checkpoints are left as they were at their last save", names.join(", "))
        })?;
    }
    bar.finish_and_clear();
    Ok(how)
}

/// Moves a checkpoint that cannot be continued, with its resume state and metrics, to
/// `NAME.stale` (`.resume.stale`, `.metrics.jsonl.stale`), replacing an older stale copy; returns
/// the checkpoint's new path.
fn set_aside_stale(ckpt: &Path) -> Result<PathBuf> {
    let stale = |p: &Path| {
        let mut s = p.as_os_str().to_owned();
        s.push(".stale");
        PathBuf::from(s)
    };
    for p in [ckpt.to_path_buf(), checkpoint::resume_path(ckpt), metrics_path(ckpt)] {
        if p.exists() {
            std::fs::rename(&p, stale(&p))
                .with_context(|| format!("{}: cannot move aside to {}", p.display(), stale(&p).display()))?;
        }
    }
    Ok(stale(ckpt))
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
    s.push('\n');
    if let Some(t) = &r.table1 {
        s += &format!("Fig. 5 and Table 1: {} (and fig5_q_hist.png beside it)\n", t.display());
    }
    if let Some(t) = &r.results {
        s += &format!("results: {} (CSV and curves beside it)\n", t.display());
    }
    s
}
