//! A study across pipelines: arms that differ in one thing (the Q's pre-training budget, the
//! priority's sharpness, …) in one table and one figure, each tested against reference arms.
//!
//! A study is a small TOML file (`pgser-etl study FILE`, example in `pipelines/`): each
//! `[[arm]]` names a pipeline's results folder and the variant (or named arm) to take from its
//! `results.csv`, and optionally the report (`table1.json`) of the Q it sampled with and the
//! priority it drew with. Arms with an `x` are the study's points, joined by `series` in the
//! figure; arms without are references (the baseline, `-swap`), drawn as bands across it. The
//! table gives each point its Q's Table 1 accuracy (paper's and controlled negatives), the share
//! of its draws above the own-goal median Q ([`super::share`]), its score over seeds, and Welch's
//! two-sided p against each reference from the results' mean, std and seed count, the test that
//! results.csv's own p columns use.
//!
//! Nothing is recomputed from training runs: a study reads committed results, so it can join a
//! grid run months ago with one run today, and a reader can redo it from the repository alone.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use polars::prelude::DataType;
use serde::{Deserialize, Serialize};

use super::plot::{self, PointSeries};
use super::share::{PriorityShares, parse_setting};
use super::welch::{ALPHA, BETTER, WORSE, fmt_p_above, welch_from_summary};
use super::{FIG_SIZE, ensure_dir, write_text};
use crate::sampler::priority::PriorityConfig;

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct StudyFile {
    name: String,
    title: String,
    out: String,
    task: String,
    algo: String,
    x_label: String,
    /// A logarithmic x axis (budgets that grow by factors).
    #[serde(default)]
    x_log: bool,
    arm: Vec<ArmFile>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct ArmFile {
    label: String,
    /// A folder holding the pipeline's results.csv.
    results: String,
    variant: String,
    x: Option<f64>,
    series: Option<String>,
    /// A folder holding the report (table1.json) of the Q this arm sampled with.
    report: Option<String>,
    /// The priority this arm drew with, `KIND[:ALPHA[:EPS]]`; unset: pgser-train's default (`rank:1`
    /// since 0.4; an arm trained by 0.3 with its default drew with `q:1`, and says so).
    priority: Option<String>,
}

/// One arm as measured.
#[derive(Debug, Clone, Serialize)]
pub struct StudyRow {
    pub label: String,
    pub series: Option<String>,
    pub x: Option<f64>,
    pub seeds: usize,
    pub mean: f64,
    pub std: f64,
    pub success: f64,
    /// Table 1, logistic regression: the paper's negatives, and controlled ones.
    pub accuracy: Option<f64>,
    pub accuracy_controlled: Option<f64>,
    /// Share of this arm's draws above the own-goal median, and uniform drawing's.
    pub share_above: Option<f64>,
    pub share_uniform: Option<f64>,
    /// Welch's two-sided p against each reference arm, in the file's order (None on references).
    pub p: Vec<Option<f64>>,
    /// `results.csv:LINE` it came from.
    pub source: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Study {
    pub name: String,
    pub references: Vec<String>,
    pub rows: Vec<StudyRow>,
    pub markdown: PathBuf,
    pub csv: PathBuf,
    pub figure: PathBuf,
}

/// Reads the study file at `path`, writes `out/study.md`, `study.csv` and `study.png`.
pub fn study(path: &Path) -> Result<Study> {
    let at = path.display();
    let text = crate::output::read_input_text(path)?;
    let f: StudyFile =
        toml::from_str(&text).map_err(|e| anyhow!("{at}: {}", e.to_string().trim().replace('\n', " ")))?;
    let dir = path.parent().unwrap_or(Path::new(""));
    let resolve = |p: &str| crate::output::normalize(&dir.join(p));
    if f.arm.iter().all(|a| a.x.is_some()) || f.arm.iter().all(|a| a.x.is_none()) {
        bail!("{at}: a study needs reference arms (no x) and arms to compare with them (with x)");
    }
    if f.x_log && f.arm.iter().any(|a| a.x.is_some_and(|x| x <= 0.0)) {
        bail!("{at}: x_log = true needs every x > 0");
    }
    let mut rows = Vec::new();
    for (i, a) in f.arm.iter().enumerate() {
        let arm = format!("{at}: arm {} ({:?})", i + 1, a.label);
        let m =
            read_row(&resolve(&a.results).join("results.csv"), &f.task, &f.algo, &a.variant).context(arm.clone())?;
        let (mut accuracy, mut accuracy_controlled, mut share_above, mut share_uniform) = (None, None, None, None);
        if let Some(r) = &a.report {
            let priority =
                a.priority.as_deref().map(parse_setting).transpose().context(arm.clone())?.unwrap_or_default();
            let t = read_report(&resolve(r).join("table1.json")).context(arm.clone())?;
            accuracy = Some(t.accuracy);
            accuracy_controlled = Some(t.accuracy_controlled);
            if let Some(s) = &t.priority {
                share_above = Some(share_of(s, &priority).with_context(|| {
                    format!(
                        "{arm}: its report gives no share for priority {}",
                        a.priority.as_deref().unwrap_or("rank:1 (the default)")
                    )
                })?);
                share_uniform = Some(s.uniform);
            }
        }
        rows.push(StudyRow {
            label: a.label.clone(),
            series: a.series.clone().or_else(|| a.x.map(|_| a.label.clone())),
            x: a.x,
            seeds: m.seeds,
            mean: m.mean,
            std: m.std,
            success: m.success,
            accuracy,
            accuracy_controlled,
            share_above,
            share_uniform,
            p: Vec::new(),
            source: m.source,
        });
    }
    let references: Vec<usize> = (0..rows.len()).filter(|&i| rows[i].x.is_none()).collect();
    for i in 0..rows.len() {
        if rows[i].x.is_some() {
            let mine = (rows[i].mean, rows[i].std, rows[i].seeds);
            rows[i].p = references
                .iter()
                .map(|&r| welch_from_summary(mine, (rows[r].mean, rows[r].std, rows[r].seeds)).map(|t| t.2))
                .collect();
        }
    }
    let out = resolve(&f.out);
    ensure_dir(&out)?;
    let s = Study {
        name: f.name.clone(),
        references: references.iter().map(|&r| rows[r].label.clone()).collect(),
        rows,
        markdown: out.join("study.md"),
        csv: out.join("study.csv"),
        figure: out.join("study.png"),
    };
    write_text(&s.markdown, &markdown(&s, &f.title))?;
    write_text(&s.csv, &csv(&s))?;
    figure(&s, &f)?;
    Ok(s)
}

struct Measured {
    seeds: usize,
    mean: f64,
    std: f64,
    success: f64,
    source: String,
}

/// The row of `task`, `algo`, `variant` in a results.csv.
fn read_row(path: &Path, task: &str, algo: &str, variant: &str) -> Result<Measured> {
    let at = path.display();
    let df = crate::query::scan(path)?.collect().map_err(|e| anyhow!("{at}: {e}"))?;
    let column = |name: &str, ty: &DataType| {
        df.column(name)
            .and_then(|c| c.cast(ty))
            .map_err(|_| anyhow!("{at}: no column {name} (is it a results.csv written by a pipeline?)"))
    };
    let (t, al, v) =
        (column("task", &DataType::String)?, column("algo", &DataType::String)?, column("variant", &DataType::String)?);
    let (t, al, v) = (t.str()?, al.str()?, v.str()?);
    let found: Vec<usize> = (0..df.height())
        .filter(|&i| t.get(i) == Some(task) && al.get(i) == Some(algo) && v.get(i) == Some(variant))
        .collect();
    let i = match found[..] {
        [i] => i,
        [] => bail!("{at}: no row for {task} {algo} {variant}"),
        _ => bail!("{at}: {} rows for {task} {algo} {variant}", found.len()),
    };
    let source = format!("{at}:{}", i + 2);
    let float = |name: &str| -> Result<f64> {
        let c = column(name, &DataType::Float64)?;
        c.f64()?.get(i).ok_or_else(|| anyhow!("{source}: {name} is empty"))
    };
    let seeds = float("seeds")?;
    let (mean, std, success) =
        (float("paper_score_mean")?, float("paper_score_std").unwrap_or(f64::NAN), float("success_mean")?);
    // Written as what is accepted, negated: NaN seeds fail it too.
    #[allow(clippy::nonminimal_bool)]
    let bad = !(seeds >= 1.0 && seeds.fract() == 0.0) || !mean.is_finite();
    if bad {
        bail!("{source}: seeds must be a count ≥ 1 and paper_score_mean a number");
    }
    Ok(Measured { seeds: seeds as usize, mean, std, success, source })
}

/// What a study takes from a report's table1.json.
struct Report {
    accuracy: f64,
    accuracy_controlled: f64,
    /// Absent from reports written before pgser measured it.
    priority: Option<PriorityShares>,
}

fn read_report(path: &Path) -> Result<Report> {
    let at = path.display();
    let json: serde_json::Value =
        serde_json::from_str(&crate::output::read_input_text(path)?).map_err(|e| anyhow!("{at}: not JSON: {e}"))?;
    let lr = |v: &serde_json::Value| -> Option<f64> {
        v.as_array()?.iter().find(|c| c["name"] == "logistic regression")?["accuracy"].as_f64()
    };
    let accuracy = lr(&json["classifiers"]).ok_or_else(|| anyhow!("{at}: no logistic regression in classifiers"))?;
    let accuracy_controlled = lr(&json["controlled"]["classifiers"])
        .ok_or_else(|| anyhow!("{at}: no logistic regression in controlled.classifiers"))?;
    let priority = match json.get("priority") {
        None => None,
        Some(p) => Some(serde_json::from_value(p.clone()).map_err(|e| anyhow!("{at}: priority: {e}"))?),
    };
    Ok(Report { accuracy, accuracy_controlled, priority })
}

fn share_of(s: &PriorityShares, p: &PriorityConfig) -> Option<f64> {
    s.settings
        .iter()
        .find(|x| x.priority == p.priority && x.priority_alpha == p.priority_alpha && x.priority_eps == p.priority_eps)
        .map(|x| x.share_above)
}

/// A CSV cell: empty where the arm has no such number.
fn opt(x: Option<f64>, digits: usize) -> String {
    x.map_or(String::new(), |x| format!("{x:.digits$}"))
}

fn markdown(s: &Study, title: &str) -> String {
    let mut md = format!(
        "# {title}\n\n| arm | x | Table 1 accuracy (paper's / controlled) | share above own-goal median (uniform) | seeds | paper score | success |"
    );
    for r in &s.references {
        let _ = write!(md, " p vs {r} |");
    }
    md += "\n|---|---:|---:|---:|---:|---:|---:|";
    md += &"---:|".repeat(s.references.len());
    md += "\n";
    for row in &s.rows {
        let acc = match (row.accuracy, row.accuracy_controlled) {
            (Some(a), Some(c)) => format!("{a:.3} / {c:.3}"),
            _ => "—".into(),
        };
        let share = match (row.share_above, row.share_uniform) {
            (Some(a), Some(u)) => format!("{a:.3} ({u:.3})"),
            _ => "—".into(),
        };
        let x = row.x.map_or("—".into(), |x| format!("{x}"));
        let _ = write!(
            md,
            "| {} | {x} | {acc} | {share} | {} | {:.2} ± {:.2} | {:.3} |",
            row.label, row.seeds, row.mean, row.std, row.success
        );
        for (k, r) in s.rows.iter().filter(|r| r.x.is_none()).enumerate() {
            let p = row.p.get(k).copied().flatten();
            let _ =
                write!(md, " {} |", if row.x.is_none() { "—".into() } else { fmt_p_above(p, Some(row.mean > r.mean)) });
        }
        md += "\n";
    }
    md += &format!(
        "\nPaper score: mean ± sample std over the seeds' final evaluations. p: Welch's two-sided t-test over those \
         seed means against each reference arm (arms without x); {BETTER}/{WORSE}: significantly above/below \
         (p < {ALPHA}). Table 1 accuracy: logistic regression on Q alone, positives against the paper's negatives / \
         controlled negatives. Share: the part of the arm's draws whose Q lies above the median Q of expert \
         transitions with their own goals, beside the part uniform drawing gives.\n\nSources: {}.\n",
        s.rows.iter().map(|r| r.source.as_str()).collect::<Vec<_>>().join(", ")
    );
    md
}

fn csv(s: &Study) -> String {
    let mut out = String::from(
        "label,series,x,seeds,paper_score_mean,paper_score_std,success_mean,accuracy,accuracy_controlled,share_above,share_uniform",
    );
    for r in &s.references {
        let _ = write!(out, ",p_vs_{}", r.replace(',', ";"));
    }
    out += "\n";
    for row in &s.rows {
        let _ = write!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{}",
            row.label.replace(',', ";"),
            row.series.as_deref().unwrap_or("").replace(',', ";"),
            row.x.map_or(String::new(), |x| x.to_string()),
            row.seeds,
            row.mean,
            row.std,
            row.success,
            opt(row.accuracy, 6),
            opt(row.accuracy_controlled, 6),
            opt(row.share_above, 6),
            opt(row.share_uniform, 6),
        );
        for k in 0..s.references.len() {
            let _ = write!(out, ",{}", row.p.get(k).copied().flatten().map_or(String::new(), |p| p.to_string()));
        }
        out += "\n";
    }
    out
}

fn figure(s: &Study, f: &StudyFile) -> Result<()> {
    let mut series: Vec<PointSeries> = Vec::new();
    for row in s.rows.iter().filter(|r| r.x.is_some()) {
        let name = row.series.clone().unwrap_or_default();
        let x = row.x.unwrap_or_default();
        let x = if f.x_log { x.log10() } else { x };
        match series.iter_mut().find(|p| p.label == name) {
            Some(p) => p.points.push((x, row.mean, row.std)),
            None => series.push(PointSeries { label: name, points: vec![(x, row.mean, row.std)] }),
        }
    }
    let bands: Vec<(String, f64, f64)> =
        s.rows.iter().filter(|r| r.x.is_none()).map(|r| (r.label.clone(), r.mean, r.std)).collect();
    let y_label = "paper score (mean ± std over seeds)";
    plot::points_and_bands(&s.figure, FIG_SIZE, &f.title, (&f.x_label, f.x_log), y_label, &series, &bands)
}
