//! Running steps. Every runner — a local `pipeline run` one unit at a time or several side by
//! side (`--jobs N`), and each Slurm job's `pipeline step` — goes through [`run_unit`], so the
//! rules are the same everywhere: take the steps' locks (`lock.rs`), skip what is up to date,
//! continue a training step from its checkpoint when allowed (`state::may_resume`), run, record.
//!
//! A *unit* is one step, or the agent cells of one stack that train together. Side by side, a
//! stack is also split by the steps it reads, so that the -baseline and -swap cells (which read
//! only β) train while the Q is pre-trained, and the -mem cells once it has been scored; stacked
//! or alone, a cell ends with the same weights (`train::train_stack`), so this changes no output.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::{Condvar, Mutex};
use std::time::Instant;

use anyhow::{Context, Result, bail};

use super::lock::StepLock;
use super::state::{self, Hashes};
use super::{Action, Cost, Pipeline, Step, cost, stack_of};
use crate::agent::{Backend, checkpoint};
use crate::train::metrics_path;
use crate::train::online::{OnlineConfig, buffer_path, train_online};
use crate::{collect, convert, progress, report, score};

/// Steps that run together, and the units whose outputs they read.
pub(crate) struct Unit {
    pub members: Vec<usize>,
    pub after: Vec<usize>,
}

/// What happened to one step: `ran`, `resumed` or `up to date`, and its seconds.
#[derive(Debug, Clone)]
pub(crate) struct Outcome {
    pub status: String,
    pub seconds: f64,
    /// The Slurm log of a step whose job failed.
    pub log: Option<PathBuf>,
}

/// What every unit of a run shares.
pub(crate) struct Ctx<'a> {
    pub p: &'a Pipeline,
    pub steps: &'a [Step],
    pub device: Backend,
    pub cost: Option<&'a Cost>,
    pub log: &'a (dyn Fn(&str) + Sync),
}

/// The units of the steps `include` (indices into `steps`, in plan order): agent cells of one
/// stack id together, split by the steps they read when `split`.
pub(crate) fn units(steps: &[Step], include: &[usize], split: bool) -> Vec<Unit> {
    let writer: HashMap<&PathBuf, usize> =
        steps.iter().enumerate().flat_map(|(i, s)| s.outputs.iter().map(move |o| (o, i))).collect();
    let reads = |i: usize| -> Vec<usize> {
        let mut w: Vec<usize> = steps[i].inputs.iter().filter_map(|p| writer.get(p).copied()).collect();
        w.sort();
        w.dedup();
        w
    };
    let mut units: Vec<Unit> = Vec::new();
    let mut stacks: BTreeMap<(usize, Vec<usize>), usize> = BTreeMap::new();
    for &i in include {
        match stack_of(&steps[i]) {
            Some(id) => {
                let key = (id, if split { reads(i) } else { vec![] });
                match stacks.get(&key) {
                    Some(&u) => units[u].members.push(i),
                    None => {
                        stacks.insert(key, units.len());
                        units.push(Unit { members: vec![i], after: vec![] });
                    }
                }
            }
            None => units.push(Unit { members: vec![i], after: vec![] }),
        }
    }
    let unit_of: HashMap<usize, usize> =
        units.iter().enumerate().flat_map(|(u, unit)| unit.members.iter().map(move |&m| (m, u))).collect();
    for (u, unit) in units.iter_mut().enumerate() {
        let mut after: Vec<usize> =
            unit.members.iter().flat_map(|&m| reads(m)).filter_map(|w| unit_of.get(&w).copied()).collect();
        after.sort();
        after.dedup();
        after.retain(|&a| a != u);
        unit.after = after;
    }
    units
}

/// Runs one unit under its steps' locks; returns each member's outcome. A member up to date
/// once its lock is held (another run finished it meanwhile) is skipped; the others run as one
/// stack (agent cells) or alone, and get their records.
pub(crate) fn run_unit(c: &Ctx, members: &[usize], hashes: &mut Hashes) -> Result<Vec<(usize, Outcome)>> {
    let (p, steps, n) = (c.p, c.steps, c.steps.len());
    let head = |i: usize| format!("[{}/{n}] {}", i + 1, steps[i].name);
    let mut locks = Vec::with_capacity(members.len());
    for &i in members {
        let waiting = |holder: &str| (c.log)(&format!("{}: waiting for its lock ({holder})", head(i)));
        locks.push(StepLock::acquire(&p.out, &steps[i].name, &waiting)?);
    }
    let mut done = Vec::new();
    let mut todo = Vec::new();
    for &i in members {
        let step = &steps[i];
        let Some(key) = hashes.key(step)? else {
            let missing = step.inputs.iter().find(|f| !f.exists()).map(|f| f.display().to_string());
            bail!(
                "pipeline {}, step {}: input {} is missing (the step that writes it has not finished)",
                p.name,
                step.name,
                missing.unwrap_or_default()
            );
        };
        if state::up_to_date(&p.out, step, &key, hashes) {
            (c.log)(&format!("{}: up to date", head(i)));
            done.push((i, Outcome { status: "up to date".into(), seconds: 0.0, log: None }));
        } else {
            todo.push((i, key));
        }
    }
    if todo.is_empty() {
        return Ok(done);
    }
    // The cost of what runs now: one step, or every cell of the stack together.
    let priced: Vec<&cost::StepCost> = todo
        .iter()
        .filter_map(|(i, _)| c.cost.and_then(|k| k.per_step.iter().find(|s| s.name == steps[*i].name)))
        .collect();
    let brief = match cost::brief(&cost::StepCost::total(&priced)) {
        b if b.is_empty() || priced.is_empty() => String::new(),
        b if todo.len() > 1 => format!(" ({b} for the stack)"),
        b => format!(" ({b})"),
    };
    let first = todo[0].0;
    let more = if todo.len() > 1 { format!(" with {} more in one stack", todo.len() - 1) } else { String::new() };
    (c.log)(&format!("{}: running{more}{brief}", head(first)));
    let t0 = Instant::now();
    // A training step may continue from its checkpoint after a crash (no record) or a change of
    // settings (another key; `train` refuses what cannot continue), but not when a finished
    // output no longer has its recorded bytes (that one is rebuilt from scratch) nor when
    // another pgser version finished it.
    let resume: Vec<bool> = todo.iter().map(|(i, key)| state::may_resume(&p.out, &steps[*i], Some(key))).collect();
    let how: Vec<&str> = if todo.len() == 1 {
        let step = &steps[first];
        vec![execute(step, c.device, resume[0]).with_context(|| format!("pipeline {}, step {}", p.name, step.name))?]
    } else {
        let group: Vec<&Step> = todo.iter().map(|(i, _)| &steps[*i]).collect();
        execute_stack(&group, c.device, &resume).with_context(|| format!("pipeline {}", p.name))?
    };
    let secs = t0.elapsed().as_secs_f64();
    for (k, ((i, _), how)) in todo.iter().zip(&how).enumerate() {
        let step = &steps[*i];
        let key = hashes.key(step)?.with_context(|| format!("step {}: an input vanished while it ran", step.name))?;
        state::record(&p.out, step, &key, secs, how, hashes)?;
        let stacked = if k > 0 { " (in a stack)" } else { "" };
        (c.log)(&format!("{}: {how}{stacked} in {secs:.1} s", head(*i)));
        done.push((*i, Outcome { status: how.to_string(), seconds: secs, log: None }));
    }
    drop(locks);
    Ok(done)
}

/// Runs `units` with at most `jobs` at once, each side-by-side unit on a thread pool of
/// `threads / jobs` threads (results do not depend on it); returns each step's outcome. After a
/// failure no unit starts; those running finish, then the first error is returned.
pub(crate) fn run_units(
    c: &Ctx,
    units: &[Unit],
    jobs: usize,
    threads: usize,
    hashes: Hashes,
) -> Result<HashMap<usize, Outcome>> {
    let mut outcomes = HashMap::new();
    if jobs <= 1 {
        let mut hashes = hashes;
        for u in units {
            outcomes.extend(run_unit(c, &u.members, &mut hashes)?);
        }
        return Ok(outcomes);
    }
    struct State {
        started: Vec<bool>,
        done: Vec<bool>,
        outcomes: HashMap<usize, Outcome>,
        error: Option<anyhow::Error>,
    }
    let state = Mutex::new(State {
        started: vec![false; units.len()],
        done: vec![false; units.len()],
        outcomes: HashMap::new(),
        error: None,
    });
    let wake = Condvar::new();
    let per_job = (threads / jobs).max(1);
    std::thread::scope(|s| {
        let mut workers = Vec::with_capacity(jobs.min(units.len()));
        for _ in 0..jobs.min(units.len()) {
            let (state, wake, mut hashes) = (&state, &wake, hashes.clone());
            workers.push(s.spawn(move || {
                let pool = rayon::ThreadPoolBuilder::new().num_threads(per_job).build();
                let pool = match pool.context("cannot start threads") {
                    Ok(pool) => pool,
                    Err(e) => {
                        state.lock().expect("no panic holds it").error.get_or_insert(e);
                        wake.notify_all();
                        return;
                    }
                };
                loop {
                    let next = {
                        let mut st = state.lock().expect("no panic holds it");
                        loop {
                            if st.error.is_some() || st.started.iter().all(|&s| s) {
                                return;
                            }
                            let ready = (0..units.len())
                                .find(|&u| !st.started[u] && units[u].after.iter().all(|&a| st.done[a]));
                            if let Some(u) = ready {
                                st.started[u] = true;
                                break u;
                            }
                            st = wake.wait(st).expect("no panic holds it");
                        }
                    };
                    let result = pool.install(|| run_unit(c, &units[next].members, &mut hashes));
                    let mut st = state.lock().expect("no panic holds it");
                    match result {
                        Ok(o) => {
                            st.outcomes.extend(o);
                            st.done[next] = true;
                        }
                        Err(e) => {
                            st.error.get_or_insert(e);
                        }
                    }
                    wake.notify_all();
                }
            }));
        }
        // Joined, not only waited for: the scope waits for each worker's closure but not for its
        // OS thread, which would otherwise still be exiting when the run returns.
        for worker in workers {
            if let Err(panic) = worker.join() {
                std::panic::resume_unwind(panic);
            }
        }
    });
    let st = state.into_inner().expect("no panic holds it");
    if let Some(e) = st.error {
        return Err(e);
    }
    outcomes.extend(st.outcomes);
    Ok(outcomes)
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
        Action::Collect(c) => drop(collect::collect(&c.options()?, &bar)?),
        Action::Online { cfg, out } => how = execute_online(step, cfg, out, device, resume, &bar)?,
        Action::Convert(o) => drop(convert::convert(o, &bar)?),
        // The threads of the pool this unit runs on (all of `--threads` alone, its share with
        // `--jobs`); the scores do not depend on it.
        // Over a table folder, every shard not yet scored with these settings, then the manifest.
        Action::Score(s) => {
            let threads = rayon::current_num_threads();
            drop(score::score(&score::ScoreOptions { device, threads, ..s.opts.clone() }, &bar)?)
        }
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
        bar.set_message(match names.len() {
            1 => names[0].to_string(),
            n => format!("{} (+{} in its stack)", names[0], n - 1),
        });
        crate::train::train_stack(&stack, device, &commands, &bar).with_context(|| {
            format!("training {} (one stack); checkpoints are left as they were at their last save", names.join(", "))
        })?;
    }
    bar.finish_and_clear();
    Ok(how)
}

/// Trains the expert online, continuing its checkpoint as a training step does: when `resume`
/// allows and it is of the same run (else it is set aside as `.stale` and training starts over).
/// A run stopped before its last epoch (SIGTERM) is saved and reported as not finished.
fn execute_online(
    step: &Step,
    cfg: &OnlineConfig,
    out: &Path,
    device: Backend,
    resume: bool,
    bar: &indicatif::ProgressBar,
) -> Result<&'static str> {
    let command = format!("pgser pipeline step {}", step.name);
    let mut continuing = resume && out.exists() && checkpoint::resume_path(out).exists();
    if resume && out.exists() && !continuing {
        set_aside_stale(out)?;
    }
    let mut result = train_online(cfg, out, continuing, device, &command, bar);
    if let Err(e) = &result
        && continuing
        && e.downcast_ref::<crate::train::StaleCheckpoint>().is_some()
    {
        let kept = set_aside_stale(out)?;
        eprintln!(
            "pgser pipeline: {}: not resumed ({e:#}); the old checkpoint is kept as {}; training from scratch",
            step.name,
            kept.display()
        );
        continuing = false;
        result = train_online(cfg, out, false, device, &command, bar);
    }
    let summary = result?;
    if !summary.finished {
        bail!(
            "{}: stopped after epoch {} of {} (saved); run the pipeline again to continue",
            out.display(),
            summary.epochs,
            cfg.epochs
        );
    }
    Ok(if continuing { "resumed" } else { "ran" })
}

/// Moves a checkpoint that cannot be continued, with its resume state and metrics, to
/// `NAME.stale` (`.resume.stale`, `.metrics.jsonl.stale`, an online run's `.buffer.parquet.stale`), replacing an older stale copy; returns
/// the checkpoint's new path.
fn set_aside_stale(ckpt: &Path) -> Result<PathBuf> {
    let stale = |p: &Path| crate::output::with_suffix(p, ".stale");
    for p in [ckpt.to_path_buf(), checkpoint::resume_path(ckpt), metrics_path(ckpt), buffer_path(ckpt)] {
        if p.exists() {
            std::fs::rename(&p, stale(&p))
                .with_context(|| format!("{}: cannot move aside to {}", p.display(), stale(&p).display()))?;
        }
    }
    Ok(stale(ckpt))
}
