//! What a pipeline checks before its first step runs: everything that does not need an earlier
//! step's output. A mistake found after days of training — a misspelt setting, a pickle of
//! another task, a report that cannot tell which episodes are expert, an unbuilt `--device` —
//! costs those days; found here it costs a second, and nothing has been written (no out folder
//! is created: its writability is probed in the deepest folder that already exists).
//!
//! Each check calls the code the step itself runs (`collect::check`, `convert::check`,
//! `Backend::device`) or repeats a check its step makes before doing any work, so the two cannot
//! disagree about what is valid. Errors name the pipeline key or the file.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

use super::{Action, Data, Pipeline, Step};
use crate::agent::Backend;
use crate::collect::policy::{PolicyKind, PolicySpec};
use crate::task::Task;
use crate::train::TrainConfig;
use crate::trajectory::FloatType;

/// What the checks found out about the data, for the cost estimate.
#[derive(Debug, Clone)]
pub struct Checked {
    pub task: Task,
    /// Episodes of β (the converted table), and bytes per value of its vectors.
    pub episodes: usize,
    pub float_bytes: usize,
}

/// Checks `steps` (the plan of `p`) before any of them runs.
pub fn check(p: &Pipeline, steps: &[Step], device: Backend) -> Result<Checked> {
    device.device()?;
    check_writable(&p.out).with_context(|| format!("out = {:?}", p.out.display().to_string()))?;
    // Simulated data is float64 pickles of the pipeline's task; pickles are read below.
    let mut beta = match &p.data {
        Data::Collect { expert, random, .. } => {
            let task = Task::known(&p.task).context("task")?;
            Some((task, vec![(PathBuf::from("expert"), *expert), (PathBuf::from("random"), *random)], 8))
        }
        Data::Oracle { episodes, .. } => {
            let (_, task) = crate::collect::ogbench::recipe(&p.task).context("task")?;
            Some((task, vec![(PathBuf::from("oracle"), *episodes)], 4))
        }
        Data::Pickles { .. } => None,
        Data::Table { path } => Some(
            check_table(path, &p.task).with_context(|| format!("[data] table = {:?}", path.display().to_string()))?,
        ),
    };
    if let Some(q) = p.q_checkpoint.as_ref().filter(|q| q.exists()) {
        check_q(q, &p.task).with_context(|| format!("[pretrain] checkpoint = {:?}", q.display().to_string()))?;
    }
    for step in steps {
        let name = &step.name;
        match &step.action {
            Action::Collect(c) => {
                let o = match &c.checkpoint {
                    // Written by the `expert` step: only the environment and the output are checked now.
                    Some(f) if !f.exists() => crate::collect::CollectOptions {
                        policy: PolicySpec { kind: PolicyKind::Random, noise: 0.0, epsilon: 0.0 },
                        ..c.opts.clone()
                    },
                    Some(f) => c.options().with_context(|| format!("[data] expert_checkpoint {}", f.display()))?,
                    None => c.opts.clone(),
                };
                let what = if c.checkpoint.is_some() { "expert_checkpoint" } else { o.policy.kind.name() };
                crate::collect::check(&o).with_context(|| format!("[data] {what} (step {name})"))?;
            }
            Action::Online { cfg, .. } => {
                let task = Task::known(&p.task).context("task")?;
                cfg.validate(&task).context("[expert]")?;
            }
            Action::Convert(o) if beta.is_none() => {
                let plan = crate::convert::check(o).map_err(|e| {
                    // The reader's advice names convert's flag; say where a pipeline takes it.
                    let hint =
                        if format!("{e:#}").contains("--drop") { " ([data] drop takes --drop's keys)" } else { "" };
                    e.context(format!("[data] pickles{hint}"))
                })?;
                let sources = o.inputs.iter().cloned().zip(plan.episodes_taken.iter().copied()).collect();
                let bytes = if plan.float_type == FloatType::Float32 { 4 } else { 8 };
                beta = Some((plan.task, sources, bytes));
            }
            Action::Convert(_) => {}
            Action::Train { data, cfg, .. } => {
                let section = if name == "pretrain" { "[pretrain]".to_string() } else { format!("[agents] ({name})") };
                check_train(cfg, *data == super::plan::scored_path(p)).context(section)?;
            }
            Action::Score(super::ScoreStep { opts: o, .. }) => {
                if o.swaps == 0 && !o.include_original {
                    bail!("[score] swaps = 0 without include_original = true leaves the scored table empty");
                }
                if o.chunk_episodes == Some(0) {
                    bail!("[score] chunk_episodes = 0: must be at least 1");
                }
                if o.goal_sample == Some(0) {
                    bail!("[score] goal_sample = 0: must be at least 1");
                }
            }
            Action::Report(_) => {
                let (_, sources, _) = beta.as_ref().expect("convert comes before the report");
                positive_episodes(super::positives(p), sources)?;
            }
            Action::Results(_) => {}
        }
    }
    // Every training step evaluates in the task's environment (its model and assets).
    if steps.iter().any(|s| matches!(&s.action, Action::Train { cfg, .. } if cfg.eval_episodes > 0)) {
        crate::env::make(&p.task).context("evaluation needs the task's environment")?;
    }
    let (task, sources, float_bytes) = beta.expect("a plan of pickles starts with convert; the other data say β");
    Ok(Checked { task, episodes: sources.iter().map(|s| s.1).sum(), float_bytes })
}

/// What the checks know of β: its task (with the table's dimensions), its sources with the
/// episodes taken from each, and bytes per value of its vectors.
type Beta = (Task, Vec<(PathBuf, usize)>, usize);

/// β given as a table (`[data] table`): a trajectory table of the pipeline's task, one file or a
/// table folder (opened: every shard there, of its size, its footer agreeing with the manifest;
/// a few KB a shard). Returns what the checks after it and the cost need: the task with the
/// table's dimensions, its sources with the episodes taken from each (the report's default
/// positives are the first source's, as for pickles; the whole table when its footer lists no
/// sources that add up to it), and bytes per value.
fn check_table(path: &Path, task: &str) -> Result<Beta> {
    if path.is_dir() && !crate::trajectory::folder::is_folder(path) {
        bail!("a folder without {}: not a table folder", crate::trajectory::folder::MANIFEST);
    }
    let footer = crate::trajectory::folder::footer(path)?;
    let want = crate::env::task(task)?;
    let has = crate::env::task(&footer.task).map(|t| t.name).unwrap_or_else(|_| footer.task.clone());
    if has != want.name {
        bail!("a table of {}, not of the pipeline's task {}", footer.task, want.name);
    }
    let taken: usize = footer.sources.iter().map(|s| s.episodes_taken).sum();
    let sources = if !footer.sources.is_empty() && taken == footer.episodes {
        footer.sources.iter().map(|s| (PathBuf::from(&s.path), s.episodes_taken)).collect()
    } else {
        vec![(path.to_path_buf(), footer.episodes)]
    };
    let bytes = if footer.float_type == FloatType::Float32 { 4 } else { 8 };
    Ok((footer.task(), sources, bytes))
}

/// The report's positives: the first `given` episodes of β, by default those of the first of
/// two or more sources (the expert file, GoFAR's order). With a single source nothing says
/// which of its episodes are expert, and a guess would silently change what Fig. 5 and Table 1
/// mean, so the file must say; the report can only take a prefix of β, so "the successful
/// episodes" is not an option either.
fn positive_episodes(given: Option<usize>, sources: &[(PathBuf, usize)]) -> Result<usize> {
    let total: usize = sources.iter().map(|s| s.1).sum();
    match given {
        Some(n) if n == 0 || n > total => {
            bail!("[report] positive_episodes = {n}: must be between 1 and the {total} episodes of the data")
        }
        Some(n) => Ok(n),
        None if sources.len() >= 2 => Ok(sources[0].1),
        None => bail!(
            "[report] positive_episodes is required: the data has one source ({}, {} episodes taken), so which \
             episodes are expert is unknown; set positive_episodes = N to make the first N the positives of \
             Fig. 5 and Table 1 (N = {} if all are expert)",
            sources[0].0.display(),
            total,
            total
        ),
    }
}

/// A given Q must be a pgser checkpoint of the pipeline's task: `score` would refuse it only
/// after the data were collected.
fn check_q(q: &Path, task: &str) -> Result<()> {
    let (agent, _) = crate::agent::checkpoint::load(q, Backend::Cpu.device()?)?;
    let want = crate::env::task(task)?;
    if agent.task.name != want.name {
        bail!("a critic trained on {}, not on the pipeline's task {}", agent.task.name, want.name);
    }
    Ok(())
}

/// The settings `train` refuses before any work, and those that would only fail (or give
/// nonsense) later: a pipeline must not find them after the steps before it ran.
fn check_train(cfg: &TrainConfig, scored: bool) -> Result<()> {
    let a = &cfg.agent;
    if cfg.batch_size == 0 {
        bail!("batch_size = 0: must be at least 1");
    }
    if a.hidden == 0 {
        bail!("hidden = 0: the networks need at least one unit per layer");
    }
    if !(0.0..1.0).contains(&a.gamma) {
        bail!("gamma = {}: must be in [0, 1)", a.gamma);
    }
    if let Some(lr) = a.lr
        && !(lr.is_finite() && lr > 0.0)
    {
        bail!("lr = {lr}: must be a positive number");
    }
    match cfg.draws_per_row {
        Some(0) => bail!("draws_per_row = 0: must be at least 1"),
        Some(n) if cfg.memory_budget.is_none() => {
            bail!("draws_per_row = {n} needs memory_budget: it says how long a streamed row group stays")
        }
        _ => {}
    }
    if scored && !(0.0..=1.0).contains(&cfg.aug_ratio) {
        bail!("aug_ratio = {}: must be in [0, 1]", cfg.aug_ratio);
    }
    cfg.priority.validate()
}

/// Whether `out` can be created and written, without creating it: the deepest folder on its path
/// that exists must be a folder (not a file) in which a file can be created. The probe is an
/// unnamed file (`O_TMPFILE` on Linux), so a kill at any moment leaves nothing behind; a named
/// probe was left in `out/` by the crash harness's kill 43.
fn check_writable(out: &Path) -> Result<()> {
    let mut at = out;
    let existing = loop {
        match std::fs::metadata(at) {
            Ok(m) if m.is_dir() => break at,
            Ok(_) => bail!("{} is a file, not a folder", at.display()),
            Err(_) => match at.parent() {
                Some(parent) if !parent.as_os_str().is_empty() => at = parent,
                _ => break Path::new("."),
            },
        }
    };
    tempfile::tempfile_in(existing).with_context(|| format!("cannot write in {}", existing.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_writability_probe_leaves_no_name_behind() {
        let dir = tempfile::tempdir().unwrap();
        check_writable(&dir.path().join("out/deeper")).unwrap();
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "the probe left a file, or made the folder");
        std::fs::write(dir.path().join("f"), b"").unwrap();
        let e = format!("{:#}", check_writable(&dir.path().join("f/out")).unwrap_err());
        assert!(e.ends_with("f is a file, not a folder"), "{e}");
    }
}
