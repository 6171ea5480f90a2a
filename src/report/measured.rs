//! A results.csv read into Table 2's measured cells ([`Measured`]): each row checked, and its
//! pooled spread of evaluation episodes taken from the file's own columns or from the scores.csv
//! beside it. Both the grids' rows ([`super::table2`]) and a chosen setting's ([`super::chosen`])
//! read their files here; `row` says where each (algo, variant) goes.

use std::path::Path;

use anyhow::{Result, anyhow, bail};
use polars::prelude::{DataFrame, DataType};

use super::cells::{AGENTS, Measured, RowOf, TASKS};
use super::paper::paper_task;
use super::spread::read_scores;
use crate::query::first_line;

/// The cells of one results.csv, each checked, with the pooled spread of its columns or of the
/// scores.csv beside it; `row` says where each (algo, variant) goes, or that it is left out.
pub(super) fn read_results(path: &Path, row: &dyn Fn(&str, &str) -> RowOf) -> Result<Vec<Measured>> {
    let at = path.display();
    let df = crate::query::scan(path)?.collect().map_err(|e| anyhow!("{at}: {}", first_line(&e)))?;
    let text = |name: &str| -> Result<Vec<Option<String>>> {
        let c = df.column(name).map_err(|_| no_column(path, name))?;
        let c = c.cast(&DataType::String).map_err(|e| anyhow!("{at}: column {name}: {}", first_line(&e)))?;
        Ok(c.str()?.iter().map(|v| v.map(str::to_string)).collect())
    };
    let float = |name: &str| -> Result<Vec<Option<f64>>> { floats(&df, path, name) };
    // Columns a results.csv has had since pgser kept the episodes' spread.
    let optional = |name: &str| -> Result<Vec<Option<f64>>> {
        if df.column(name).is_ok() { floats(&df, path, name) } else { Ok(vec![None; df.height()]) }
    };
    let (task, algo, variant) = (text("task")?, text("algo")?, text("variant")?);
    let (seeds, mean, std) = (float("seeds")?, float("paper_score_mean")?, float("paper_score_std")?);
    let (episodes, std_episodes) = (optional("episodes")?, optional("paper_score_std_episodes")?);
    let mut out = Vec::with_capacity(df.height());
    for i in 0..df.height() {
        let source = format!("{at}:{}", i + 2);
        let field = |v: &Option<String>, name: &str| v.clone().ok_or_else(|| anyhow!("{source}: no {name}"));
        let (t, al, v) = (field(&task[i], "task")?, field(&algo[i], "algo")?, field(&variant[i], "variant")?);
        let Some(task) = paper_task(&t) else {
            let names: Vec<&str> = TASKS.iter().map(|x| x.0).collect();
            bail!("{source}: task {t} is not in the paper's Table 2 ({})", names.join(", "));
        };
        let agent = match row(&al, &v) {
            RowOf::Agent(a) => a,
            RowOf::Skip => continue,
            RowOf::Unknown => bail!(
                "{source}: {al} {v} is not a row of the paper's Table 2 (algo td3 or td3bc; variant baseline, swap or mem)"
            ),
        };
        let n = seeds[i]
            .filter(|s| *s >= 1.0 && s.fract() == 0.0)
            .ok_or_else(|| anyhow!("{source}: seeds must be a count ≥ 1"))?;
        let m =
            mean[i].filter(|x| x.is_finite()).ok_or_else(|| anyhow!("{source}: paper_score_mean is not a number"))?;
        // One seed has no std (results.csv leaves it empty or NaN); more must have a finite one.
        let s = std[i].unwrap_or(f64::NAN);
        if n > 1.0 && !(s.is_finite() && s >= 0.0) {
            bail!("{source}: paper_score_std must be a finite std ≥ 0 over {n} seeds");
        }
        let pooled = match (episodes[i], std_episodes[i]) {
            (None, None) => None,
            (Some(e), Some(sd)) if e >= 1.0 && e.fract() == 0.0 && (sd.is_nan() || sd >= 0.0) => {
                Some((e as usize, m, sd))
            }
            _ => bail!(
                "{source}: episodes and paper_score_std_episodes must be a count ≥ 1 and a std ≥ 0, or both empty"
            ),
        };
        out.push(Measured { task, agent, seeds: n as usize, mean: m, std: s, pooled, source });
    }
    if out.is_empty() {
        bail!("{at}: no rows (an empty results.csv)");
    }
    let scores = path.with_file_name("scores.csv");
    if scores.is_file() {
        with_scores(&mut out, &scores, row)?;
    }
    Ok(out)
}

/// Takes each cell's pooled spread from the per-run scores in `scores`, after checking that they
/// are the runs the results.csv summarizes: the same seeds, mean and std over seeds, and pooled
/// std where the results.csv has one.
fn with_scores(cells: &mut [Measured], scores: &Path, row: &dyn Fn(&str, &str) -> RowOf) -> Result<()> {
    let at = scores.display();
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs()).max(1.0) || (a.is_nan() && b.is_nan());
    let mut seen = vec![false; cells.len()];
    for c in read_scores(scores)? {
        let pos = format!("{at}:{}", c.line);
        let task =
            paper_task(&c.task).ok_or_else(|| anyhow!("{pos}: task {} is not in the paper's Table 2", c.task))?;
        let agent = match row(&c.algo, &c.variant) {
            RowOf::Agent(a) => Some(a),
            RowOf::Skip => continue,
            RowOf::Unknown => None,
        };
        let i = cells.iter().position(|m| m.task == task && Some(m.agent) == agent).ok_or_else(|| {
            anyhow!("{pos}: {} {} {} has no row in the results.csv beside it", c.task, c.algo, c.variant)
        })?;
        let m = &mut cells[i];
        let (n, sm) = (c.seed_means.len(), c.seed_means.iter().sum::<f64>() / c.seed_means.len() as f64);
        let ss = c.seed_means.iter().map(|x| (x - sm) * (x - sm)).sum::<f64>();
        let sd = if n < 2 { f64::NAN } else { (ss / (n - 1) as f64).sqrt() };
        let sd = if sd < 1e-12 * sm.abs().max(1.0) { 0.0 } else { sd };
        let differs = |what: &str, ours: String, theirs: String| {
            anyhow!(
                "{pos}: {} {}: {what} {ours} here, {theirs} in {}: not the same runs",
                c.task,
                AGENTS[m.agent].2,
                m.source
            )
        };
        if n != m.seeds {
            return Err(differs("seeds", n.to_string(), m.seeds.to_string()));
        }
        if !close(sm, m.mean) || (n > 1 && !close(sd, m.std)) {
            return Err(differs("mean ± std over seeds", format!("{sm} ± {sd}"), format!("{} ± {}", m.mean, m.std)));
        }
        if let Some((e, _, s)) = m.pooled
            && (e != c.pooled.episodes || !close(s, c.pooled.std))
        {
            return Err(differs(
                "episodes and their std",
                format!("{} {}", c.pooled.episodes, c.pooled.std),
                format!("{e} {s}"),
            ));
        }
        m.pooled = Some((c.pooled.episodes, c.pooled.mean, c.pooled.std));
        seen[i] = true;
    }
    if let Some(i) = seen.iter().position(|s| !s) {
        bail!("{at}: no scores for {} {} ({})", cells[i].task, AGENTS[cells[i].agent].2, cells[i].source);
    }
    Ok(())
}

fn floats(df: &DataFrame, path: &Path, name: &str) -> Result<Vec<Option<f64>>> {
    let c = df.column(name).map_err(|_| no_column(path, name))?;
    let c = c
        .strict_cast(&DataType::Float64)
        .map_err(|_| anyhow!("{}: column {name} holds something that is not a number", path.display()))?;
    Ok(c.f64()?.iter().collect())
}

fn no_column(path: &Path, name: &str) -> anyhow::Error {
    anyhow!("{}: no column {name} (is it a results.csv written by a pipeline or `pgser-etl results`?)", path.display())
}
