//! Table 2 of the paper and the training curves behind it, from the metrics files of finished
//! training runs.
//!
//! A run's score is its final evaluation: the last metrics line that carries `eval` (training
//! evaluates every `--eval-every` updates and once at the end). Scores are averaged over seeds
//! per (task, algorithm, variant), with two spreads ([`super::spread`]): the sample std of the
//! seeds' mean scores (n − 1), and the std of all evaluation episodes pooled (seeds × episodes),
//! which the paper's ± most likely is. Whether prioritized swapping (`mem`) beats `baseline` and
//! `swap` is tested with Welch's t-test on the per-seed scores, the test the marks use: the runs
//! are the independent replicates, the variants' spreads differ, so Student's pooled variance
//! would be wrong, and with ~10 seeds a rank test has little power. The same test over pooled
//! episodes, which counts each episode as independent, is in results.csv for comparison with the
//! paper's marks. `scores.csv` beside it keeps each run's (episodes, mean, std), from which both
//! are recomputed.
//!
//! The table shows the two-sided p and marks a significant difference with its direction (▲ mem
//! better, ▼ mem worse): a bare star read as "better" even where mem was significantly worse.
//! The CSV adds the one-sided p of the paper's claim, "mem outperforms the reference" (H1: mem's
//! mean > the reference's), which is the test to quote for that claim, decided before the run.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use polars::prelude::{Column, DataFrame, Expr, IntoLazy, PolarsResult, SortMultipleOptions, col};
use serde::Serialize;

use super::plot::{self, Curve};
use super::spread::{Block, ScoreRow, pool, scores_csv};
use super::welch::{ALPHA, BETTER, WORSE, fmt_p_above, mean_std, welch_from_summary, welch_greater, welch_t_test};
use super::{FIG_SIZE, ensure_dir, file_safe, fmt3, write_text};
use crate::eval::scored_by_success;
use crate::train::MetricsLine;

/// One training run: which cell of Table 2 it belongs to, and its metrics file
/// (`<ckpt>.metrics.jsonl`, see [`crate::train::metrics_path`]).
#[derive(Debug, Clone)]
pub struct Run {
    pub task: String,
    /// `td3` or `td3bc`.
    pub algo: String,
    /// `baseline`, `swap` or `mem`.
    pub variant: String,
    pub seed: u64,
    pub metrics: PathBuf,
}

/// One cell group of Table 2: a (task, algorithm, variant) over its seeds.
#[derive(Debug, Clone, Serialize)]
pub struct ResultRow {
    pub task: String,
    pub algo: String,
    pub variant: String,
    pub seeds: usize,
    pub paper_score_mean: f64,
    /// Sample std over seeds; NaN (JSON null) with one seed.
    pub paper_score_std: f64,
    pub success_mean: f64,
    /// Welch's two-sided p of `mem` (or a named arm) against `baseline` / `swap` of the same task
    /// and algorithm; None for baseline and swap themselves, a missing counterpart, or fewer than 2 seeds on either side.
    pub p_vs_baseline: Option<f64>,
    pub p_vs_swap: Option<f64>,
    /// Welch's one-sided p of the same pairs for H1: mem's mean > the reference's (near 1 when
    /// mem is clearly worse); None where the two-sided p is.
    pub p_one_sided_vs_baseline: Option<f64>,
    pub p_one_sided_vs_swap: Option<f64>,
    /// Evaluation episodes of all seeds pooled; None for a results.csv written before pgser kept
    /// them, or a group whose runs were evaluated on different numbers of episodes (its pooled
    /// mean would not be the table's mean).
    pub episodes: Option<usize>,
    /// Sample std over the pooled episodes.
    pub paper_score_std_episodes: Option<f64>,
    /// Welch's two-sided p of mem against baseline / swap over pooled episodes.
    pub p_episodes_vs_baseline: Option<f64>,
    pub p_episodes_vs_swap: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Results {
    pub rows: Vec<ResultRow>,
    pub markdown: PathBuf,
    pub csv: PathBuf,
    /// Each run's final evaluation as (episodes, mean, std): `scores.csv`.
    pub scores: PathBuf,
    pub curves: Vec<PathBuf>,
}

/// The columns that name a Table 2 group, in table order: task, then TD3 before TD3+BC, then
/// baseline, swap, mem (the ranks), then anything else by name.
const GROUP: [&str; 5] = ["task", "algo_rank", "algo", "variant_rank", "variant"];

/// One evaluation line of a run.
#[derive(Debug, Clone, Copy)]
struct Eval {
    updates: u64,
    paper_score: f64,
    success_rate: f64,
    episodes: u64,
    /// Std of the episodes' scores (n, not n − 1), `EvalReport::return_std`.
    episode_std: f64,
}

/// Writes `out_dir/results.md`, `out_dir/results.csv`, `out_dir/scores.csv` and
/// `out_dir/curves_<task>.png`.
///
/// The metrics files become one frame of evaluation lines (a row per line, in run and file
/// order), which polars groups: the last line of each run, then the runs of each group (in run
/// order), and for the curves the seeds' scores at each update count. Means and stds are then
/// taken with [`mean_std`], the statistics Welch's test uses, so the table shows the numbers its p
/// values are computed from.
pub fn results(runs: &[Run], out_dir: &Path) -> Result<Results> {
    if runs.is_empty() {
        bail!("{}: no training runs to report", out_dir.display());
    }
    let evals = evals_frame(runs)?;
    let groups = final_scores(&evals).context("Table 2: grouping the final evaluations")?;
    let group_of = |task: &str, algo: &str, variant: &str| {
        groups.iter().find(|g| g.task == task && g.algo == algo && g.variant == variant)
    };
    let mut rows = Vec::new();
    for g in &groups {
        // (two-sided p, one-sided p of H1: mem > other).
        let p_vs = |other: &str| -> Option<(f64, f64)> {
            if !tested(&g.variant) {
                return None;
            }
            let theirs = &group_of(&g.task, &g.algo, other)?.scores;
            Some((welch_t_test(&g.scores, theirs)?.2, welch_greater(&g.scores, theirs)?))
        };
        let (vs_baseline, vs_swap) = (p_vs("baseline"), p_vs("swap"));
        let (m, s) = mean_std(&g.scores);
        let pooled = pooled_episodes(g);
        let p_episodes_vs = |other: &str| -> Option<f64> {
            if !tested(&g.variant) {
                return None;
            }
            let (mine, theirs) = (pooled?, pooled_episodes(group_of(&g.task, &g.algo, other)?)?);
            Some(welch_from_summary((m, mine.1, mine.0), (theirs.2, theirs.1, theirs.0))?.2)
        };
        rows.push(ResultRow {
            task: g.task.clone(),
            algo: g.algo.clone(),
            variant: g.variant.clone(),
            seeds: g.scores.len(),
            paper_score_mean: m,
            paper_score_std: s,
            success_mean: mean_std(&g.success).0,
            p_vs_baseline: vs_baseline.map(|p| p.0),
            p_vs_swap: vs_swap.map(|p| p.0),
            p_one_sided_vs_baseline: vs_baseline.map(|p| p.1),
            p_one_sided_vs_swap: vs_swap.map(|p| p.1),
            episodes: pooled.map(|p| p.0),
            paper_score_std_episodes: pooled.map(|p| p.1),
            p_episodes_vs_baseline: p_episodes_vs("baseline"),
            p_episodes_vs_swap: p_episodes_vs("swap"),
        });
    }
    let scores: Vec<ScoreRow> = groups
        .iter()
        .flat_map(|g| {
            g.blocks.iter().zip(&g.seeds).map(|(b, seed)| ScoreRow {
                task: g.task.clone(),
                algo: g.algo.clone(),
                variant: g.variant.clone(),
                seed: *seed,
                block: *b,
            })
        })
        .collect();

    ensure_dir(out_dir)?;
    let mut curves = Vec::new();
    for (task, lines) in task_curves(&evals).context("Table 2: grouping the evaluations by update count")? {
        let path = out_dir.join(format!("curves_{}.png", file_safe(&task)));
        plot::mean_std_curves(
            &path,
            FIG_SIZE,
            &format!("{task}: evaluation during training"),
            "updates",
            score_name(&task),
            &lines,
        )?;
        curves.push(path);
    }
    let r = Results {
        rows,
        markdown: out_dir.join("results.md"),
        csv: out_dir.join("results.csv"),
        scores: out_dir.join("scores.csv"),
        curves,
    };
    write_text(&r.markdown, &results_markdown(&r))?;
    write_text(&r.csv, &csv(&r.rows))?;
    write_text(&r.scores, &scores_csv(&scores))?;
    Ok(r)
}

/// A group's episodes pooled over its seeds: (episodes, sample std, mean); None when its runs
/// were evaluated on different numbers of episodes, so that the pooled mean would weigh the
/// seeds unequally and differ from the seeds' mean the table shows.
fn pooled_episodes(g: &Group) -> Option<(usize, f64, f64)> {
    if g.blocks.iter().any(|b| b.episodes != g.blocks[0].episodes) {
        return None;
    }
    pool(&g.blocks).map(|p| (p.episodes, p.std, p.mean))
}

/// A Table 2 group: its runs' final scores and success rates, in run order.
struct Group {
    task: String,
    algo: String,
    variant: String,
    scores: Vec<f64>,
    success: Vec<f64>,
    /// Each run's final evaluation as a block of episodes, and its seed, in run order.
    blocks: Vec<Block>,
    seeds: Vec<u64>,
}

/// The score column's name for a task's table and curves.
fn score_name(task: &str) -> &'static str {
    if scored_by_success(task) { "success (%)" } else { "paper score" }
}

/// Every evaluation line of every run: the group columns, the run's index, and the line.
fn evals_frame(runs: &[Run]) -> Result<DataFrame> {
    let (mut task, mut algo, mut variant) = (Vec::new(), Vec::new(), Vec::new());
    let (mut algo_ranks, mut variant_ranks, mut run) = (Vec::new(), Vec::new(), Vec::new());
    let (mut updates, mut score, mut success) = (Vec::new(), Vec::new(), Vec::new());
    let (mut seed, mut episodes, mut episode_std) = (Vec::new(), Vec::new(), Vec::new());
    for (i, r) in runs.iter().enumerate() {
        for e in read_evals(&r.metrics)? {
            task.push(r.task.as_str());
            algo.push(r.algo.as_str());
            variant.push(r.variant.as_str());
            algo_ranks.push(algo_rank(&r.algo));
            variant_ranks.push(variant_rank(&r.variant));
            run.push(i as u64);
            updates.push(e.updates);
            success.push(e.success_rate);
            seed.push(r.seed);
            episodes.push(e.episodes);
            if scored_by_success(&r.task) {
                // Each episode a success (100) or not (0): their std, n not n − 1, as return_std.
                let p = e.success_rate;
                score.push(100.0 * p);
                episode_std.push(100.0 * (p * (1.0 - p)).sqrt());
            } else {
                score.push(e.paper_score);
                episode_std.push(e.episode_std);
            }
        }
    }
    let columns = vec![
        Column::new("task".into(), task),
        Column::new("algo_rank".into(), algo_ranks),
        Column::new("algo".into(), algo),
        Column::new("variant_rank".into(), variant_ranks),
        Column::new("variant".into(), variant),
        Column::new("run".into(), run),
        Column::new("updates".into(), updates),
        Column::new("paper_score".into(), score),
        Column::new("success_rate".into(), success),
        Column::new("seed".into(), seed),
        Column::new("episodes".into(), episodes),
        Column::new("episode_std".into(), episode_std),
    ];
    Ok(DataFrame::new_infer_height(columns)?)
}

/// Table 2's groups in table order, each with the final evaluation (the last line) of its runs.
fn final_scores(evals: &DataFrame) -> PolarsResult<Vec<Group>> {
    let group: Vec<Expr> = GROUP.iter().map(|c| col(*c)).collect();
    let mut by_run = group.clone();
    by_run.push(col("run"));
    let df = evals
        .clone()
        .lazy()
        .group_by_stable(by_run)
        .agg([
            col("paper_score").last(),
            col("success_rate").last(),
            col("seed").last(),
            col("episodes").last(),
            col("episode_std").last(),
        ])
        .group_by_stable(group)
        .agg([col("paper_score"), col("success_rate"), col("seed"), col("episodes"), col("episode_std")])
        .sort(GROUP, SortMultipleOptions::default().with_maintain_order(true))
        .collect()?;
    let text = |name: &str| -> PolarsResult<Vec<String>> {
        Ok(df.column(name)?.str()?.iter().map(|v| v.unwrap_or_default().to_string()).collect())
    };
    let (task, algo, variant) = (text("task")?, text("algo")?, text("variant")?);
    let (scores, success) = (f64_lists(df.column("paper_score")?)?, f64_lists(df.column("success_rate")?)?);
    let (seeds, episodes) = (u64_lists(df.column("seed")?)?, u64_lists(df.column("episodes")?)?);
    let episode_std = f64_lists(df.column("episode_std")?)?;
    Ok((0..df.height())
        .map(|i| Group {
            task: task[i].clone(),
            algo: algo[i].clone(),
            variant: variant[i].clone(),
            blocks: (0..scores[i].len())
                .map(|j| Block { episodes: episodes[i][j] as usize, mean: scores[i][j], std: episode_std[i][j] })
                .collect(),
            seeds: seeds[i].clone(),
            scores: scores[i].clone(),
            success: success[i].clone(),
        })
        .collect())
}

/// Each task with its groups' curves, in table order: mean ± std over the seeds that evaluated
/// at each update count (runs with different `--eval-every` still plot).
fn task_curves(evals: &DataFrame) -> PolarsResult<Vec<(String, Vec<Curve>)>> {
    let mut by = GROUP.to_vec();
    by.push("updates");
    let df = evals
        .clone()
        .lazy()
        .group_by(by.iter().map(|c| col(*c)).collect::<Vec<_>>())
        .agg([col("paper_score")])
        .sort(by, SortMultipleOptions::default().with_maintain_order(true))
        .collect()?;
    let text = |name: &str| -> PolarsResult<Vec<String>> {
        Ok(df.column(name)?.str()?.iter().map(|v| v.unwrap_or_default().to_string()).collect())
    };
    let (task, algo, variant) = (text("task")?, text("algo")?, text("variant")?);
    let updates: Vec<u64> = df.column("updates")?.u64()?.into_no_null_iter().collect();
    let scores = f64_lists(df.column("paper_score")?)?;
    let mut out: Vec<(String, Vec<Curve>)> = Vec::new();
    for i in 0..df.height() {
        if out.last().is_none_or(|(t, _)| *t != task[i]) {
            out.push((task[i].clone(), Vec::new()));
        }
        let lines = &mut out.last_mut().expect("pushed above").1;
        let new_group = i == 0 || (&task[i], &algo[i], &variant[i]) != (&task[i - 1], &algo[i - 1], &variant[i - 1]);
        if new_group {
            let label = format!("{} {}", algo_name(&algo[i]), variant[i]);
            lines.push(Curve { label, x: Vec::new(), mean: Vec::new(), std: Vec::new() });
        }
        let c = lines.last_mut().expect("pushed above");
        let (m, s) = mean_std(&scores[i]);
        c.x.push(updates[i] as f64);
        c.mean.push(m);
        c.std.push(if s.is_finite() { s } else { 0.0 });
    }
    Ok(out)
}

/// A list column of floats as vectors.
fn f64_lists(c: &Column) -> PolarsResult<Vec<Vec<f64>>> {
    let lists = c.list()?;
    (0..lists.len())
        .map(|i| lists.get_as_series(i).map_or(Ok(Vec::new()), |s| Ok(s.f64()?.into_no_null_iter().collect())))
        .collect()
}

/// A list column of counts as vectors.
fn u64_lists(c: &Column) -> PolarsResult<Vec<Vec<u64>>> {
    let lists = c.list()?;
    (0..lists.len())
        .map(|i| lists.get_as_series(i).map_or(Ok(Vec::new()), |s| Ok(s.u64()?.into_no_null_iter().collect())))
        .collect()
}

/// Table 2 as markdown: one table per task, one row per algorithm and variant. The pooled
/// episodes' columns appear when the rows have them (a results.csv written before pgser kept them
/// is drawn as it was).
pub fn results_markdown(r: &Results) -> String {
    let pooled = r.rows.iter().any(|row| row.episodes.is_some());
    let mut s = String::from("# Table 2: final paper score (mean ± std over seeds)\n");
    let mut task: Option<&str> = None;
    for row in &r.rows {
        if task != Some(row.task.as_str()) {
            task = Some(&row.task);
            let _ = write!(s, "\n## {}\n\n", row.task);
            let head = if pooled {
                "| agent | paper score | ± over episodes | success | seeds | episodes | p vs baseline | p vs swap | \
                 p vs baseline (episodes) | p vs swap (episodes) |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n"
            } else {
                "| agent | paper score | success | seeds | p vs baseline | p vs swap |\n|---|---:|---:|---:|---:|---:|\n"
            };
            s += &head.replacen("paper score", score_name(&row.task), 1);
        }
        let seeds = format!("{} ± {}", fmt3(row.paper_score_mean), fmt3(row.paper_score_std));
        let tests =
            [fmt_p(row.p_vs_baseline, row.p_one_sided_vs_baseline), fmt_p(row.p_vs_swap, row.p_one_sided_vs_swap)];
        let agent = format!("{} {}", algo_name(&row.algo), row.variant);
        let success = fmt3(row.success_mean);
        if pooled {
            // The episodes' test is two-sided only: its direction is the means'.
            let dir = |p: Option<f64>, other: &str| {
                let o = r.rows.iter().find(|x| x.task == row.task && x.algo == row.algo && x.variant == other);
                fmt_p_above(p, o.map(|o| row.paper_score_mean > o.paper_score_mean))
            };
            let _ = writeln!(
                s,
                "| {agent} | {seeds} | {} | {success} | {} | {} | {} | {} | {} | {} |",
                row.paper_score_std_episodes.map_or("n/a".to_string(), fmt3),
                row.seeds,
                row.episodes.map_or("n/a".to_string(), |n| n.to_string()),
                tests[0],
                tests[1],
                dir(row.p_episodes_vs_baseline, "baseline"),
                dir(row.p_episodes_vs_swap, "swap"),
            );
        } else {
            let _ = writeln!(s, "| {agent} | {seeds} | {success} | {} | {} | {} |", row.seeds, tests[0], tests[1]);
        }
    }
    s += &legend();
    if r.rows.iter().any(|row| scored_by_success(&row.task)) {
        s += "\nOGBench's tasks (pointmaze-…) are scored as OGBench scores them, by the success rate in percent (the \
              share of evaluation episodes that reached the goal; an episode ends there), in place of the paper \
              score; their p values test those.\n";
    }
    if pooled {
        s += "\nThe marks and the p columns test the seeds' mean scores (n = seeds), the test pgser's claims rest on. \
              ± over episodes is the std of every evaluation episode of every seed pooled (n = episodes), and the \
              (episodes) columns are Welch's test over those pooled episodes, which counts each episode as an \
              independent sample: the paper's likely terms, for comparing with its marks. scores.csv holds each \
              run's final evaluation (episodes, mean, std) that both are computed from.\n";
    }
    s
}

/// What the p columns and marks mean, under every Table 2.
fn legend() -> String {
    format!(
        "\np: Welch's two-sided t-test (unequal variances) of the per-seed final paper scores of mem against \
         baseline / swap; {BETTER} marks mem significantly better (p < {ALPHA}, higher mean), {WORSE} significantly \
         worse (lower mean); no mark: no significant difference. results.csv adds the paper's one-sided test, \
         mem outperforms the reference (Welch, H1: mem mean > reference mean), as p_one_sided_vs_baseline and \
         p_one_sided_vs_swap.\n"
    )
}

/// The evaluation lines of a metrics file; an unreadable or eval-less file is an error.
fn read_evals(path: &Path) -> Result<Vec<Eval>> {
    let at = path.display();
    let text = crate::output::read_input_text(path).with_context(|| format!("{at}: cannot read the metrics file"))?;
    let mut evals = Vec::new();
    let mut lines = 0;
    for (i, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        lines += 1;
        let m: MetricsLine =
            serde_json::from_str(line).with_context(|| format!("{at}: line {}: not a metrics line", i + 1))?;
        if let Some(e) = m.eval {
            if !e.paper_score.is_finite() {
                bail!("{at}: line {}: paper score is {}", i + 1, e.paper_score);
            }
            if !(e.return_std.is_finite() && e.return_std >= 0.0) {
                bail!("{at}: line {}: return_std is {}, not a std", i + 1, e.return_std);
            }
            evals.push(Eval {
                updates: m.updates,
                paper_score: e.paper_score,
                success_rate: e.success_rate,
                episodes: e.episodes as u64,
                episode_std: e.return_std,
            });
        }
    }
    if lines == 0 {
        bail!("{at}: the metrics file is empty");
    }
    if evals.is_empty() {
        bail!("{at}: no evaluation line (train with --eval-episodes > 0 to get a final evaluation)");
    }
    Ok(evals)
}

fn csv(rows: &[ResultRow]) -> String {
    let mut s = String::from(
        "task,algo,variant,seeds,paper_score_mean,paper_score_std,success_mean,p_vs_baseline,p_vs_swap,\
         p_one_sided_vs_baseline,p_one_sided_vs_swap,episodes,paper_score_std_episodes,p_episodes_vs_baseline,\
         p_episodes_vs_swap\n",
    );
    let opt = |p: Option<f64>| p.map(|p| p.to_string()).unwrap_or_default();
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            r.task,
            r.algo,
            r.variant,
            r.seeds,
            r.paper_score_mean,
            r.paper_score_std,
            r.success_mean,
            opt(r.p_vs_baseline),
            opt(r.p_vs_swap),
            opt(r.p_one_sided_vs_baseline),
            opt(r.p_one_sided_vs_swap),
            r.episodes.map(|n| n.to_string()).unwrap_or_default(),
            opt(r.paper_score_std_episodes),
            opt(r.p_episodes_vs_baseline),
            opt(r.p_episodes_vs_swap)
        );
    }
    s
}

/// The two-sided p with the direction of a significant difference: the one-sided p of "mem is
/// higher" is below ½ exactly when mem's mean is above the reference's.
fn fmt_p(two_sided: Option<f64>, one_sided: Option<f64>) -> String {
    fmt_p_above(two_sided, one_sided.map(|up| up < 0.5))
}

/// The paper's names: TD3 and TD3+BC.
fn algo_name(algo: &str) -> String {
    match algo {
        "td3" => "TD3".to_string(),
        "td3bc" => "TD3+BC".to_string(),
        other => other.to_string(),
    }
}

/// Table order: TD3 before TD3+BC, then anything else by name.
fn algo_rank(algo: &str) -> u32 {
    match algo {
        "td3" => 0,
        "td3bc" => 1,
        _ => 2,
    }
}

/// Whether a group is tested against baseline and swap: mem, and every named arm of a pipeline
/// (`[agents.arms]`: -mem at another α, with rank priorities, …), which are ablations of it.
fn tested(variant: &str) -> bool {
    !matches!(variant, "baseline" | "swap")
}

/// Table order: baseline, swap, mem, then anything else by name.
fn variant_rank(variant: &str) -> u32 {
    match variant {
        "baseline" => 0,
        "swap" => 1,
        "mem" => 2,
        _ => 3,
    }
}
