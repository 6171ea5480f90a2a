//! The paper's own numbers, which pgser prints beside its measurements: Table 2 (`table2`) and
//! Table 1 (`fig5`), each from a CSV committed with its source named in its `#` lines
//! (`assets/paper_table2.csv`, `assets/paper_table1.csv`) and compiled in, so the commands work
//! from any folder and a reader can check each number against the paper.
//!
//! A reference may lack cells (the command prints "—" there and says how many), but a row it has
//! must be whole: a value that is not a number, a marker that is not yes / no, a cell given twice
//! or a task, agent or classifier the paper does not have is refused with its file and line,
//! since a wrong paper value beside a measured one is worse than none.

use anyhow::{Result, anyhow, bail};

use super::cells::{AGENTS, TASKS};

/// The compiled-in references.
pub const TABLE2: &str = include_str!("../../assets/paper_table2.csv");
pub const TABLE1: &str = include_str!("../../assets/paper_table1.csv");

/// The paper's protocol for Table 2 (its section on the experiments): 10 seeds per agent, each
/// evaluated on 50 episodes.
pub const SEEDS: usize = 10;
pub const EPISODES: usize = 50;

/// One cell of the paper's Table 2.
#[derive(Debug, Clone, PartialEq)]
pub struct PaperCell {
    /// pgser's task name.
    pub task: &'static str,
    /// Index into [`AGENTS`].
    pub agent: usize,
    pub mean: f64,
    pub std: f64,
    /// The pink box: significantly above the same learner's baseline (swap and mem rows). None:
    /// not a comparison of this row, or the reference does not say (a 4-column reference).
    pub above_baseline: Option<bool>,
    /// The bold: mem significantly above swap (mem rows).
    pub above_swap: Option<bool>,
}

impl PaperCell {
    /// The marks in pgser's notation: `▲b` for the pink box, `▲s` for the bold.
    pub fn marks(&self) -> String {
        let b = self.above_baseline.unwrap_or(false).then_some("▲b");
        let s = self.above_swap.unwrap_or(false).then_some("▲s");
        [b, s].into_iter().flatten().collect::<Vec<_>>().join(" ")
    }

    /// The cell as the paper prints it, with its marks: `29.85 ± 11.57 ▲b ▲s`.
    pub(super) fn text(&self) -> String {
        let cell = format!("{} ± {}", fmt_paper(self.mean), fmt_paper(self.std));
        if self.marks().is_empty() { cell } else { format!("{cell} {}", self.marks()) }
    }
}

/// A number of the paper as it prints it: at least two decimals, more where it gave more.
fn fmt_paper(x: f64) -> String {
    let s = x.to_string();
    if s.split_once('.').is_some_and(|(_, d)| d.len() >= 2) { s } else { format!("{x:.2}") }
}

/// A pgser or paper name of one of the six tasks.
pub fn paper_task(name: &str) -> Option<&'static str> {
    let canonical = crate::task::Task::known(name).map(|t| t.name);
    TASKS
        .iter()
        .find(|(t, short)| canonical.as_deref() == Some(*t) || short.eq_ignore_ascii_case(name.trim()))
        .map(|(t, _)| *t)
}

/// The paper's Table 2 from a reference CSV: `#` lines are comments (the source), then the header
/// `task,agent,mean,std` with, optionally, `significant_vs_baseline,significant_vs_swap`.
pub fn read_table2(text: &str, at: &str) -> Result<Vec<PaperCell>> {
    let mut rows: Vec<PaperCell> = Vec::new();
    let mut columns = 0;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if columns == 0 {
            const HEAD: [&str; 6] = ["task", "agent", "mean", "std", "significant_vs_baseline", "significant_vs_swap"];
            if f != HEAD[..4] && f != HEAD {
                bail!("{at}:{}: the header must be task,agent,mean,std[,{},{}]", i + 1, HEAD[4], HEAD[5]);
            }
            columns = f.len();
            continue;
        }
        let pos = format!("{at}:{}", i + 1);
        if f.len() != columns {
            bail!("{pos}: expected {columns} fields, got {}", f.len());
        }
        let task = paper_task(f[0]).ok_or_else(|| anyhow!("{pos}: task {} is not in the paper's Table 2", f[0]))?;
        let agent =
            AGENTS.iter().position(|a| a.2 == f[1]).ok_or_else(|| anyhow!("{pos}: no row {} in Table 2", f[1]))?;
        let num = |s: &str, name: &str| {
            s.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| anyhow!("{pos}: {name} {s:?} is not a number (a cell without a value is left out)"))
        };
        let variant = AGENTS[agent].1;
        // A marker where the paper compares (yes / no; empty: not given), none where it does not.
        let mark = |s: Option<&&str>, name: &str, applies: bool| -> Result<Option<bool>> {
            match (s.copied().unwrap_or(""), applies) {
                ("", _) => Ok(None),
                ("yes", true) => Ok(Some(true)),
                ("no", true) => Ok(Some(false)),
                (v, true) => bail!("{pos}: {name} must be yes, no or empty, not {v:?}"),
                (v, false) => bail!("{pos}: {name} is {v:?} on a {variant} row, which the paper does not mark"),
            }
        };
        let above_baseline = mark(f.get(4), "significant_vs_baseline", variant != "baseline")?;
        let above_swap = mark(f.get(5), "significant_vs_swap", variant == "mem")?;
        if rows.iter().any(|r| r.task == task && r.agent == agent) {
            bail!("{pos}: {task} {} is given twice", AGENTS[agent].2);
        }
        rows.push(PaperCell {
            task,
            agent,
            mean: num(f[2], "mean")?,
            std: num(f[3], "std")?,
            above_baseline,
            above_swap,
        });
    }
    if columns == 0 {
        bail!("{at}: no header line (task,agent,mean,std,...)");
    }
    Ok(rows)
}

/// The paper's classifier names and pgser's (`classify`) for the same kind of classifier.
pub const CLASSIFIERS: [(&str, &str); 4] = [
    ("Logistic regression", "logistic regression"),
    ("Naive Bayes", "Gaussian naive Bayes"),
    ("KNN", "k-NN (k=5)"),
    ("SVM", "SVC (RBF, C=1, γ=1)"),
];

/// One accuracy of the paper's Table 1: (pgser's task, pgser's classifier name, accuracy).
pub type PaperAccuracy = (&'static str, &'static str, f64);

/// The paper's Table 1 from a reference CSV: `#` lines are comments, then `classifier` and a
/// column per task (the paper's or pgser's task names, any order), a row per classifier.
pub fn read_table1(text: &str, at: &str) -> Result<Vec<PaperAccuracy>> {
    let mut out: Vec<PaperAccuracy> = Vec::new();
    let mut tasks: Option<Vec<&'static str>> = None;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let pos = format!("{at}:{}", i + 1);
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        let Some(tasks) = &tasks else {
            if f[0] != "classifier" || f.len() < 2 {
                bail!("{pos}: the header must be classifier followed by task names");
            }
            let named = f[1..]
                .iter()
                .map(|t| paper_task(t).ok_or_else(|| anyhow!("{pos}: task {t} is not in the paper's Table 1")))
                .collect::<Result<Vec<_>>>()?;
            tasks = Some(named);
            continue;
        };
        if f.len() != tasks.len() + 1 {
            bail!("{pos}: expected {} fields, got {}", tasks.len() + 1, f.len());
        }
        let Some(&(_, ours)) = CLASSIFIERS.iter().find(|(paper, _)| paper.eq_ignore_ascii_case(f[0])) else {
            let names: Vec<&str> = CLASSIFIERS.iter().map(|c| c.0).collect();
            bail!("{pos}: classifier {} is not one of the paper's ({})", f[0], names.join(", "));
        };
        if out.iter().any(|(_, c, _)| *c == ours) {
            bail!("{pos}: classifier {} is given twice", f[0]);
        }
        for (task, v) in tasks.iter().zip(&f[1..]) {
            let acc = v
                .parse::<f64>()
                .ok()
                .filter(|x| (0.0..=1.0).contains(x))
                .ok_or_else(|| anyhow!("{pos}: {task}: {v:?} is not an accuracy in [0, 1]"))?;
            out.push((task, ours, acc));
        }
    }
    if tasks.is_none() {
        bail!("{at}: no header line (classifier,TASK,...)");
    }
    Ok(out)
}
