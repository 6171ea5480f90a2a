//! Table 2 of the paper and the training curves behind it, from the metrics files of finished
//! training runs.
//!
//! A run's score is its final evaluation: the last metrics line that carries `eval` (training
//! evaluates every `--eval-every` updates and once at the end). Scores are averaged over seeds
//! per (task, algorithm, variant); the paper reports mean ± std over seeds, and so do we (sample
//! std, n − 1). Whether prioritized swapping (`mem`) beats `baseline` and `swap` is tested with
//! Welch's t-test on the per-seed scores: the variants' spreads differ, so Student's pooled
//! variance would be wrong, and with ~10 seeds a rank test has little power.
//!
//! The table shows the two-sided p and marks a significant difference with its direction (▲ mem
//! better, ▼ mem worse): a bare star read as "better" even where mem was significantly worse.
//! The CSV adds the one-sided p of the paper's claim, "mem outperforms the reference" (H1: mem's
//! mean > the reference's), which is the test to quote for that claim, decided before the run.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, StudentsT};

use super::plot::{self, Curve};
use super::{FIG_SIZE, ensure_dir, file_safe, fmt3, write_text};
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
    /// Welch's two-sided p of `mem` against `baseline` / `swap` of the same task and algorithm;
    /// None for other variants, a missing counterpart, or fewer than 2 seeds on either side.
    pub p_vs_baseline: Option<f64>,
    pub p_vs_swap: Option<f64>,
    /// Welch's one-sided p of the same pairs for H1: mem's mean > the reference's (near 1 when
    /// mem is clearly worse); None where the two-sided p is.
    pub p_one_sided_vs_baseline: Option<f64>,
    pub p_one_sided_vs_swap: Option<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct Results {
    pub rows: Vec<ResultRow>,
    pub markdown: PathBuf,
    pub csv: PathBuf,
    pub curves: Vec<PathBuf>,
}

/// Significance level of the two-sided test, whose significant differences the markdown marks
/// with their direction.
pub const ALPHA: f64 = 0.05;
/// Marks of a significant difference: the variant's mean above / below the reference's.
pub const BETTER: &str = "▲";
pub const WORSE: &str = "▼";

/// A Table 2 group in table order: (task, algo rank, algo, variant rank, variant).
type GroupKey = (String, usize, String, usize, String);
/// Each seed of a group with its evaluation history.
type Seeds = Vec<(u64, Vec<Eval>)>;

/// One evaluation line of a run.
#[derive(Debug, Clone, Copy)]
struct Eval {
    updates: u64,
    paper_score: f64,
    success_rate: f64,
}

/// Writes `out_dir/results.md`, `out_dir/results.csv` and `out_dir/curves_<task>.png`.
pub fn results(runs: &[Run], out_dir: &Path) -> Result<Results> {
    if runs.is_empty() {
        bail!("{}: no training runs to report", out_dir.display());
    }
    // (task, algo, variant) → per-seed evaluation histories, in a stable order.
    let mut groups: BTreeMap<GroupKey, Seeds> = BTreeMap::new();
    for r in runs {
        let evals = read_evals(&r.metrics)?;
        let key = (r.task.clone(), algo_rank(&r.algo), r.algo.clone(), variant_rank(&r.variant), r.variant.clone());
        groups.entry(key).or_default().push((r.seed, evals));
    }
    let finals = |k: &GroupKey| -> Option<Vec<f64>> {
        groups.get(k).map(|runs| runs.iter().map(|(_, e)| e.last().expect("checked").paper_score).collect())
    };
    let mut rows = Vec::new();
    for (key, seeds) in &groups {
        let (task, _, algo, _, variant) = key;
        let scores: Vec<f64> = seeds.iter().map(|(_, e)| e.last().expect("checked").paper_score).collect();
        let success: Vec<f64> = seeds.iter().map(|(_, e)| e.last().expect("checked").success_rate).collect();
        // (two-sided p, one-sided p of H1: mem > other).
        let p_vs = |other: &str| -> Option<(f64, f64)> {
            if variant != "mem" {
                return None;
            }
            let theirs = finals(&(task.clone(), key.1, algo.clone(), variant_rank(other), other.to_string()))?;
            Some((welch_t_test(&scores, &theirs)?.2, welch_greater(&scores, &theirs)?))
        };
        let (vs_baseline, vs_swap) = (p_vs("baseline"), p_vs("swap"));
        let (m, s) = mean_std(&scores);
        rows.push(ResultRow {
            task: task.clone(),
            algo: algo.clone(),
            variant: variant.clone(),
            seeds: seeds.len(),
            paper_score_mean: m,
            paper_score_std: s,
            success_mean: mean_std(&success).0,
            p_vs_baseline: vs_baseline.map(|p| p.0),
            p_vs_swap: vs_swap.map(|p| p.0),
            p_one_sided_vs_baseline: vs_baseline.map(|p| p.1),
            p_one_sided_vs_swap: vs_swap.map(|p| p.1),
        });
    }

    ensure_dir(out_dir)?;
    let mut curves = Vec::new();
    let mut tasks: Vec<&String> = groups.keys().map(|k| &k.0).collect();
    tasks.dedup();
    for task in tasks {
        let lines: Vec<Curve> = groups
            .iter()
            .filter(|(k, _)| &k.0 == task)
            .map(|(k, seeds)| curve(format!("{} {}", algo_name(&k.2), k.4), seeds))
            .collect();
        let path = out_dir.join(format!("curves_{}.png", file_safe(task)));
        plot::mean_std_curves(
            &path,
            FIG_SIZE,
            &format!("{task}: evaluation during training"),
            "updates",
            "paper score",
            &lines,
        )?;
        curves.push(path);
    }
    let r = Results { rows, markdown: out_dir.join("results.md"), csv: out_dir.join("results.csv"), curves };
    write_text(&r.markdown, &results_markdown(&r))?;
    write_text(&r.csv, &csv(&r.rows))?;
    Ok(r)
}

/// Table 2 as markdown: one table per task, one row per algorithm and variant.
pub fn results_markdown(r: &Results) -> String {
    let mut s = String::from("# Table 2: final paper score (mean ± std over seeds)\n");
    let mut task: Option<&str> = None;
    for row in &r.rows {
        if task != Some(row.task.as_str()) {
            task = Some(&row.task);
            let _ = write!(
                s,
                "\n## {}\n\n| agent | paper score | success | seeds | p vs baseline | p vs swap |\n\
                 |---|---:|---:|---:|---:|---:|\n",
                row.task
            );
        }
        let _ = writeln!(
            s,
            "| {} {} | {} ± {} | {} | {} | {} | {} |",
            algo_name(&row.algo),
            row.variant,
            fmt3(row.paper_score_mean),
            fmt3(row.paper_score_std),
            fmt3(row.success_mean),
            row.seeds,
            fmt_p(row.p_vs_baseline, row.p_one_sided_vs_baseline),
            fmt_p(row.p_vs_swap, row.p_one_sided_vs_swap)
        );
    }
    s += &legend();
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

/// Welch's t-test (unequal variances) of `a` against `b`: (t, degrees of freedom, two-sided
/// p). None with fewer than 2 samples on either side or when both variances are 0 (t undefined).
pub fn welch_t_test(a: &[f64], b: &[f64]) -> Option<(f64, f64, f64)> {
    if a.len() < 2 || b.len() < 2 {
        return None;
    }
    let (ma, sa) = mean_std(a);
    let (mb, sb) = mean_std(b);
    let (va, vb) = (sa * sa / a.len() as f64, sb * sb / b.len() as f64);
    let se2 = va + vb;
    if se2 <= 0.0 || !se2.is_finite() {
        return None;
    }
    let t = (ma - mb) / se2.sqrt();
    // Welch–Satterthwaite.
    let df = se2 * se2 / (va * va / (a.len() - 1) as f64 + vb * vb / (b.len() - 1) as f64);
    let dist = StudentsT::new(0.0, 1.0, df).ok()?;
    // 2·sf(|t|) rather than 2·(1 − cdf): keeps precision for tiny p.
    let p = (2.0 * dist.sf(t.abs())).min(1.0);
    Some((t, df, p))
}

/// Welch's one-sided p of `a` against `b` for H1: mean(a) > mean(b), i.e. sf(t) on the
/// Welch–Satterthwaite degrees of freedom: small when `a` is clearly higher, near 1 when it is
/// clearly lower. None where [`welch_t_test`] is.
pub fn welch_greater(a: &[f64], b: &[f64]) -> Option<f64> {
    let (t, df, _) = welch_t_test(a, b)?;
    Some(StudentsT::new(0.0, 1.0, df).ok()?.sf(t))
}

/// Mean and sample std (n − 1; NaN for one value).
fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let m = v.iter().sum::<f64>() / n;
    let s = if v.len() < 2 { f64::NAN } else { (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt() };
    // Equal scores give a mean one ulp off and a "std" of 1e-15, which would make Welch's t
    // astronomically large (p ≈ 1e-27 between two constant groups): round-off is zero spread.
    let s = if s < 1e-12 * m.abs().max(1.0) { 0.0 } else { s };
    (m, s)
}

/// The evaluation lines of a metrics file; an unreadable or eval-less file is an error.
fn read_evals(path: &Path) -> Result<Vec<Eval>> {
    let at = path.display();
    let text = std::fs::read_to_string(path).with_context(|| format!("{at}: cannot read the metrics file"))?;
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
            evals.push(Eval { updates: m.updates, paper_score: e.paper_score, success_rate: e.success_rate });
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

/// Mean ± std over seeds at each update count that any seed evaluated at (over the seeds that
/// did: runs with different `--eval-every` still plot).
fn curve(label: String, seeds: &[(u64, Vec<Eval>)]) -> Curve {
    let mut at: BTreeMap<u64, Vec<f64>> = BTreeMap::new();
    for (_, evals) in seeds {
        for e in evals {
            at.entry(e.updates).or_default().push(e.paper_score);
        }
    }
    let mut c = Curve { label, x: Vec::new(), mean: Vec::new(), std: Vec::new() };
    for (u, v) in at {
        let (m, s) = mean_std(&v);
        c.x.push(u as f64);
        c.mean.push(m);
        c.std.push(if s.is_finite() { s } else { 0.0 });
    }
    c
}

fn csv(rows: &[ResultRow]) -> String {
    let mut s = String::from(
        "task,algo,variant,seeds,paper_score_mean,paper_score_std,success_mean,p_vs_baseline,p_vs_swap,\
         p_one_sided_vs_baseline,p_one_sided_vs_swap\n",
    );
    let opt = |p: Option<f64>| p.map(|p| p.to_string()).unwrap_or_default();
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{}",
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
            opt(r.p_one_sided_vs_swap)
        );
    }
    s
}

/// The two-sided p with the direction of a significant difference: the one-sided p of "mem is
/// higher" is below ½ exactly when mem's mean is above the reference's.
fn fmt_p(two_sided: Option<f64>, one_sided: Option<f64>) -> String {
    match (two_sided, one_sided) {
        (Some(p), Some(up)) => {
            let mark = match (p < ALPHA, up < 0.5) {
                (false, _) => "",
                (true, true) => BETTER,
                (true, false) => WORSE,
            };
            let p = if p < 1e-3 { format!("{p:.1e}") } else { format!("{p:.3}") };
            if mark.is_empty() { p } else { format!("{p} {mark}") }
        }
        _ => "—".to_string(),
    }
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
fn algo_rank(algo: &str) -> usize {
    match algo {
        "td3" => 0,
        "td3bc" => 1,
        _ => 2,
    }
}

/// Table order: baseline, swap, mem, then anything else by name.
fn variant_rank(variant: &str) -> usize {
    match variant {
        "baseline" => 0,
        "swap" => 1,
        "mem" => 2,
        _ => 3,
    }
}
