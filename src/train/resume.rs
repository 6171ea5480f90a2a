//! Continuing a run: which checkpoint `--resume` may continue (same settings but the number of
//! updates, same data), restoring its agent, random streams and metrics, and where a pipeline's
//! cell would start.

use std::path::Path;

use anyhow::{Context, Result, bail};
use burn::tensor::Device;

use super::{Cell, MetricsLine, TrainConfig, differ, metrics_path, read_metrics};
use crate::agent::{Agent, checkpoint};
use crate::eval::EvalReport;
use crate::nprandom::NpRandom;

/// The metrics of a checkpoint at update `u` as an uninterrupted run would have them there: a run
/// that ended at `u` recorded its final evaluation as a line of its own, which a longer run has
/// on its loss line when `u` is on the evaluation schedule and does not have at all otherwise.
/// Returns them with the evaluation at `u`, if one stays.
pub(super) fn continued_metrics(
    mut metrics: Vec<MetricsLine>,
    u: u64,
    eval_every: u64,
) -> (Vec<MetricsLine>, Option<EvalReport>) {
    let is_final = |m: &MetricsLine| m.updates == u && m.eval.is_some() && m.critic_loss.is_none();
    let Some(pos) = metrics.iter().position(is_final) else {
        let last = metrics.iter().rev().find_map(|m| m.eval.clone().filter(|_| m.updates == u));
        return (metrics, last);
    };
    let report = metrics.remove(pos).eval;
    if eval_every == 0 || !u.is_multiple_of(eval_every) {
        return (metrics, None);
    }
    match metrics.iter_mut().find(|m| m.updates == u) {
        Some(line) => line.eval = report.clone(),
        None => metrics.push(MetricsLine {
            updates: u,
            critic_loss: None,
            actor_loss: None,
            q_mean: None,
            eval: report.clone(),
        }),
    }
    (metrics, report)
}

/// `--resume` refused because the checkpoint belongs to another run: other settings, other data,
/// or more updates than asked for. Only this refusal lets a pipeline start the step over (it keeps
/// the old checkpoint aside); any other failure while resuming is reported and the checkpoint
/// left as it is, so no progress is thrown away by an I/O error or a bad read.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct StaleCheckpoint(pub String);

/// Where `cell` would start: `None` without a checkpoint, `Some(updates)` when its checkpoint can
/// be continued, a `StaleCheckpoint` error when it belongs to another run. What a pipeline asks
/// before it stacks cells, which must start from the same update.
pub fn resume_point(cell: &Cell) -> Result<Option<u64>> {
    if !cell.out.exists() {
        return Ok(None);
    }
    let (mut agent, _) =
        checked_checkpoint(&cell.out, &cell.cfg, &crate::trajectory::folder::digest(&cell.data)?, Device::flex())?;
    // The resume state must load too, so a stack never starts on a cell it cannot continue.
    checkpoint::load_resume(&mut agent, &checkpoint::resume_path(&cell.out))?;
    Ok(Some(agent.updates))
}

/// The checkpoint at `out`, if it is one `cfg` on the data of `data_sha` may continue: same
/// settings (the number of updates may grow), same data.
fn checked_checkpoint(
    out: &Path,
    cfg: &TrainConfig,
    data_sha: &str,
    device: Device,
) -> Result<(Agent, std::collections::HashMap<String, String>)> {
    let at = out.display();
    if !out.exists() {
        bail!("{at}: --resume given but there is no checkpoint to resume");
    }
    let (agent, meta) = checkpoint::load(out, device)?;
    let saved: TrainConfig = serde_json::from_str(meta.get("train").context("no train config in metadata")?)
        .with_context(|| format!("{at}: the checkpoint's train config is not readable"))?;
    let comparable = TrainConfig { updates: cfg.updates, ..saved.clone() };
    let stale = |why: String| Err(StaleCheckpoint(why).into());
    if &comparable != cfg {
        return stale(format!(
            "{at}: --resume with settings that differ from the checkpoint's (only --updates may change): {}",
            differ::differing_settings(&comparable, cfg)?
        ));
    }
    if agent.updates > cfg.updates {
        return stale(format!(
            "{at}: --resume with --updates {} but the checkpoint already has {} updates (a run cannot be shortened)",
            cfg.updates, agent.updates
        ));
    }
    if meta.get("data_sha256").map(String::as_str) != Some(data_sha) {
        return stale(format!(
            "{at}: --resume with a different data file than the checkpoint was trained on (sha256 differs)"
        ));
    }
    Ok((agent, meta))
}

/// Loads checkpoint, resume state and metrics of an interrupted run and checks that it is the
/// same run.
pub(super) fn restore(
    out: &Path,
    cfg: &TrainConfig,
    data_sha: &str,
    device: Device,
) -> Result<(Agent, NpRandom, Vec<MetricsLine>)> {
    let at = out.display();
    let (mut agent, _) = checked_checkpoint(out, cfg, data_sha, device)?;
    let resume_meta = checkpoint::load_resume(&mut agent, &checkpoint::resume_path(out))?;
    let words = resume_meta.get("batch_rng").with_context(|| format!("{at}.resume: batch_rng missing"))?;
    let batches = NpRandom::from_words(serde_json::from_str(words)?);
    let metrics =
        read_metrics::<MetricsLine>(&metrics_path(out))?.into_iter().filter(|m| m.updates <= agent.updates).collect();
    Ok((agent, batches, metrics))
}
