//! Fig. 5 and Table 1 across the paper's tasks (`pgser-etl fig5`): one figure with a panel per
//! task, as in the paper, and both Table 1s (the paper's negatives and the controlled ones) for
//! every task side by side.
//!
//! Each task's report ([`super::q_report`], a pipeline's `report` step) leaves a `table1.json`
//! holding its classifiers and Fig. 5's two histograms as drawn; this reads only those files, so
//! the combined figure needs neither the scored tables nor the checkpoints, and a figure of six
//! tasks is drawn in a second from six small files that can be copied off a cluster.
//!
//! Beneath each classifier's row is the paper's own accuracy for the same kind of classifier
//! (`assets/paper_table1.csv`, compiled in, its source named there), so the two can be read side
//! by side; the paper's classes are described in its caption a little differently (transitions of
//! successful trajectories or not), which the table's note says.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};

use super::cells::TASKS;
use super::classify::ClassifierScore;
use super::paper::{self, PaperAccuracy};
use super::plot::{self, DensityPanel, PALETTE};
use super::qreport::Fig5Hist;
use super::{ensure_dir, write_text};

#[derive(Debug, Clone)]
pub struct Fig5Options {
    /// Reports: `table1.json` files, or the folders holding them (a pipeline's `out/report`).
    pub inputs: Vec<PathBuf>,
    pub out_dir: PathBuf,
}

#[derive(Debug, Clone, Serialize)]
pub struct Fig5All {
    /// The tasks drawn, in the paper's order.
    pub tasks: Vec<String>,
    /// The paper's tasks with no report among the inputs (their panels are left out).
    pub missing: Vec<String>,
    pub figure: PathBuf,
    pub table1: PathBuf,
}

/// The part of a report's table1.json this needs (its numbers: two reports of one Q on one data
/// set are equal here even where they record other paths).
#[derive(Debug, Clone, PartialEq, Deserialize)]
struct Report {
    task: String,
    positives: usize,
    negatives: usize,
    positive_q_mean: f64,
    negative_q_mean: f64,
    classifiers: Vec<ClassifierScore>,
    controlled: Controlled,
    fig5_hist: Option<Fig5Hist>,
}

#[derive(Debug, Clone, PartialEq, Deserialize)]
struct Controlled {
    negatives: usize,
    negative_q_mean: f64,
    classifiers: Vec<ClassifierScore>,
}

/// Writes `out_dir/fig5_all.png` (a panel per task, three to a row) and `out_dir/table1_all.md`.
pub fn fig5_all(opts: &Fig5Options) -> Result<Fig5All> {
    if opts.inputs.is_empty() {
        bail!("fig5 needs at least one report (table1.json, or the folder `pgser-etl report` wrote it in)");
    }
    let mut reports: Vec<(usize, PathBuf, Report)> = Vec::new();
    for input in &opts.inputs {
        let path = if input.is_dir() { input.join("table1.json") } else { input.clone() };
        let at = path.display();
        let text = std::fs::read_to_string(&path).with_context(|| format!("{at}: cannot read the report"))?;
        let r: Report =
            serde_json::from_str(&text).with_context(|| format!("{at}: not a table1.json of `pgser-etl report`"))?;
        let Some(i) = TASKS.iter().position(|(t, short)| *t == r.task || *short == r.task) else {
            let names: Vec<&str> = TASKS.iter().map(|t| t.0).collect();
            bail!("{at}: task {} is not one of the paper's ({})", r.task, names.join(", "));
        };
        if r.fig5_hist.is_none() {
            bail!(
                "{at}: has no fig5_hist (written by an older pgser): run `pgser-etl report` on its scored table again"
            );
        }
        if let Some((_, other, first)) = reports.iter().find(|(j, _, _)| *j == i) {
            // A task whose grid was split in two pipelines (one per learner, each small enough
            // for one session) has its one Q reported twice: the same numbers, drawn once.
            if *first == r {
                continue;
            }
            bail!(
                "{at}: a second report for {} with other numbers than the first ({}): give each task's Q once",
                r.task,
                other.display()
            );
        }
        reports.push((i, path, r));
    }
    reports.sort_by_key(|(i, _, _)| *i);

    ensure_dir(&opts.out_dir)?;
    let panels: Vec<DensityPanel> = reports
        .iter()
        .map(|(i, _, r)| {
            let h = r.fig5_hist.as_ref().expect("checked above");
            DensityPanel {
                title: TASKS[*i].1.to_string(),
                range: (h.lo, h.hi),
                series: vec![
                    (format!("own goal (n={})", r.positives), h.positives.clone(), PALETTE[0]),
                    (format!("random swap (n={})", r.negatives), h.negatives.clone(), PALETTE[1]),
                ],
            }
        })
        .collect();
    let cols = panels.len().min(3);
    let rows = panels.len().div_ceil(cols);
    let figure = opts.out_dir.join("fig5_all.png");
    plot::density_panels(&figure, (600 * cols as u32, 450 * rows as u32), cols, ("Q(s, g, a)", "density"), &panels)?;
    let table1 = opts.out_dir.join("table1_all.md");
    let theirs = paper::read_table1(paper::TABLE1, "assets/paper_table1.csv")?;
    write_text(&table1, &markdown(&reports, &theirs))?;
    Ok(Fig5All {
        tasks: reports.iter().map(|(i, _, _)| TASKS[*i].0.to_string()).collect(),
        missing: TASKS
            .iter()
            .enumerate()
            .filter(|(i, _)| !reports.iter().any(|(j, _, _)| j == i))
            .map(|(_, t)| t.0.to_string())
            .collect(),
        figure,
        table1,
    })
}

/// Table 1 for every task: a column per task, a row per classifier, each cell the paper's
/// negatives' accuracy and the controlled negatives' beside it, and beneath each row the paper's
/// accuracy for that classifier.
fn markdown(reports: &[(usize, PathBuf, Report)], theirs: &[PaperAccuracy]) -> String {
    let mut s = String::from(
        "# Table 1 across tasks: held-out accuracy of telling own goals from swapped goals by Q alone\n\n\
         Each cell: the paper's negatives (random goal swaps of the whole table) / controlled negatives (the \
         positive transitions themselves with another goal).\n\n",
    );
    let heads: Vec<&str> = reports.iter().map(|(i, _, _)| TASKS[*i].1).collect();
    let _ = writeln!(s, "| classifier | {} |", heads.join(" | "));
    let _ = writeln!(s, "|---|{}", "---:|".repeat(heads.len()));
    let names: Vec<String> =
        reports.first().map(|r| r.2.classifiers.iter().map(|c| c.name.clone()).collect()).unwrap_or_default();
    for name in &names {
        let cells: Vec<String> = reports
            .iter()
            .map(|(_, _, r)| {
                let acc =
                    |cs: &[ClassifierScore]| cs.iter().find(|c| &c.name == name).map(|c| format!("{:.3}", c.accuracy));
                format!(
                    "{} / {}",
                    acc(&r.classifiers).unwrap_or_else(|| "—".into()),
                    acc(&r.controlled.classifiers).unwrap_or_else(|| "—".into())
                )
            })
            .collect();
        let _ = writeln!(s, "| {name} | {} |", cells.join(" | "));
        let paper: Vec<String> = reports
            .iter()
            .map(|(i, _, _)| {
                theirs
                    .iter()
                    .find(|(task, c, _)| *task == TASKS[*i].0 && c == name)
                    .map_or("—".to_string(), |(_, _, acc)| format!("{acc:.3}"))
            })
            .collect();
        let _ = writeln!(s, "| {name} (paper) | {} |", paper.join(" | "));
    }
    let stat = |f: &dyn Fn(&Report) -> String| reports.iter().map(|(_, _, r)| f(r)).collect::<Vec<_>>().join(" | ");
    let _ = writeln!(s, "| mean Q, own goals | {} |", stat(&|r| format!("{:.2}", r.positive_q_mean)));
    let _ = writeln!(
        s,
        "| mean Q, negatives | {} |",
        stat(&|r| format!("{:.2} / {:.2}", r.negative_q_mean, r.controlled.negative_q_mean))
    );
    let _ = writeln!(
        s,
        "| samples (own / negatives) | {} |",
        stat(&|r| format!("{} / {} / {}", r.positives, r.negatives, r.controlled.negatives))
    );
    let names: Vec<String> = paper::CLASSIFIERS.iter().map(|(p, ours)| format!("{p} beneath {ours}")).collect();
    let _ = writeln!(
        s,
        "\n(paper): the paper's Table 1 (assets/paper_table1.csv names the source), its rows {}. Its caption \
         describes the classes as transitions of successful trajectories (goals reachable) and the rest; pgser's \
         are own goals and random goal swaps, Fig. 5's two classes. The paper does not give its classifiers' \
         settings or its split.",
        names.join(", ")
    );
    s += "\nSources:\n\n";
    for (i, path, _) in reports {
        let _ = writeln!(s, "- {}: {}", TASKS[*i].0, display(path));
    }
    s
}

fn display(p: &Path) -> String {
    p.display().to_string()
}
