//! The paper's Table 2 across its six tasks, from several pipelines' `results.csv` files
//! (`pgser-etl table2`).
//!
//! A pipeline reports one task ([`super::results`]); the paper's table is six of them side by
//! side: rows TD3BC-mem, TD3BC-swap, TD3BC, TD3-mem, TD3-swap, TD3, a column per task, and under
//! each measured row the paper's own value for the same cell, from a reference file committed
//! with its source (`assets/paper_table2.csv`, compiled in; `--reference` reads another).
//!
//! The tests are recomputed here from each cell's (mean, std, seeds), which is all Welch's test
//! needs, so the three comparisons the paper's ordering makes (mem vs swap, swap vs baseline, mem
//! vs baseline) are all available, not only the two that results.csv carries.
//!
//! Inputs are checked before anything is written, each fault a one-line error naming the file
//! and line: a cell given twice (in one file or two), a task or agent the paper's table does not
//! have, a task with results for only some of its six agents. A task with no results at all is a
//! column marked "not run", so the table can be assembled while grids are still running.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Result, anyhow, bail};
use polars::prelude::{DataFrame, DataType};
use serde::Serialize;

use super::results::{ALPHA, BETTER, WORSE, welch_from_summary};
use super::{ensure_dir, write_text};
use crate::query::first_line;
use crate::task::Task;

/// The paper's columns: pgser's task name, and the paper's short header.
pub const TASKS: [(&str, &str); 6] = [
    ("FetchReach", "FetchReach"),
    ("FetchPush", "FetchPush"),
    ("FetchPickAndPlace", "FetchPick"),
    ("FetchSlide", "FetchSlide"),
    ("HandManipulateBlockRotateZ", "HandBlock-Z"),
    ("HandManipulateEggRotate", "HandEgg-Rotate"),
];

/// The paper's rows in its order: (algo, variant, the paper's name).
pub const AGENTS: [(&str, &str, &str); 6] = [
    ("td3bc", "mem", "TD3BC-mem"),
    ("td3bc", "swap", "TD3BC-swap"),
    ("td3bc", "baseline", "TD3BC"),
    ("td3", "mem", "TD3-mem"),
    ("td3", "swap", "TD3-swap"),
    ("td3", "baseline", "TD3"),
];

/// The paper's values, compiled in so the command works from any folder.
const PAPER: &str = include_str!("../../assets/paper_table2.csv");

#[derive(Debug, Clone)]
pub struct Table2Options {
    /// `results.csv` files of pipelines (`pgser-etl pipeline run` writes one per pipeline).
    pub inputs: Vec<PathBuf>,
    /// The paper's values; None: the compiled-in `assets/paper_table2.csv`.
    pub reference: Option<PathBuf>,
    pub out_dir: PathBuf,
}

/// One cell of the table: a measured (task, agent), with the paper's value beside it.
#[derive(Debug, Clone, Serialize)]
pub struct Table2Cell {
    /// pgser's task name.
    pub task: String,
    /// The paper's row name (`TD3BC-mem`).
    pub agent: String,
    pub seeds: usize,
    pub mean: f64,
    /// Sample std over seeds; NaN with one seed.
    pub std: f64,
    pub paper_mean: Option<f64>,
    pub paper_std: Option<f64>,
    /// Welch's two-sided p of this learner's mem against its baseline / swap (mem rows only).
    pub p_vs_baseline: Option<f64>,
    pub p_vs_swap: Option<f64>,
    /// The mem row's significant differences: `▲b` (above baseline), `▼s` (below swap), …
    pub marks: String,
    /// Where the cell came from: `FILE:LINE`.
    pub source: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Table2 {
    pub cells: Vec<Table2Cell>,
    /// Tasks of the paper with no results among the inputs (their columns say "not run").
    pub not_run: Vec<String>,
    /// Per measured task, whether mem ≥ swap ≥ baseline holds for each learner, and which of
    /// those comparisons are significant.
    pub orderings: Vec<String>,
    pub markdown: PathBuf,
    pub csv: PathBuf,
}

/// A measured cell as read, before the table is assembled.
struct Measured {
    task: &'static str,
    agent: usize,
    seeds: usize,
    mean: f64,
    std: f64,
    source: String,
}

/// Writes `out_dir/table2.md` and `out_dir/table2.csv`.
pub fn table2(opts: &Table2Options) -> Result<Table2> {
    if opts.inputs.is_empty() {
        bail!("table2 needs at least one results.csv (a pipeline writes one in its out folder)");
    }
    let mut measured: Vec<Measured> = Vec::new();
    for path in &opts.inputs {
        for m in read_results(path)? {
            if let Some(other) = measured.iter().find(|o| o.task == m.task && o.agent == m.agent) {
                bail!(
                    "{}: {} {} is also in {}: give each cell of Table 2 once",
                    m.source,
                    m.task,
                    AGENTS[m.agent].2,
                    other.source
                );
            }
            measured.push(m);
        }
    }
    for (task, _) in TASKS {
        let have: Vec<&Measured> = measured.iter().filter(|m| m.task == task).collect();
        if have.is_empty() || have.len() == AGENTS.len() {
            continue;
        }
        let missing: Vec<&str> =
            (0..AGENTS.len()).filter(|a| !have.iter().any(|m| m.agent == *a)).map(|a| AGENTS[a].2).collect();
        let files: Vec<&str> = have.iter().map(|m| m.source.rsplit_once(':').map_or("", |(f, _)| f)).collect();
        bail!(
            "{}: {task} has no {} (each task needs both learners and all three variants; the paper's grid is \
             {{TD3, TD3+BC}} × {{baseline, swap, mem}})",
            files[0],
            missing.join(", ")
        );
    }
    let paper = match &opts.reference {
        Some(p) => {
            let text = crate::output::read_input_text(p)?;
            read_reference(&text, &p.display().to_string())?
        }
        None => read_reference(PAPER, "assets/paper_table2.csv")?,
    };

    let find = |task: &str, agent: usize| measured.iter().find(|m| m.task == task && m.agent == agent);
    let mut cells = Vec::new();
    for (a, (_, variant, name)) in AGENTS.iter().enumerate() {
        for (task, _) in TASKS {
            let Some(m) = find(task, a) else { continue };
            // Welch's two-sided p against the same learner's `other` variant, and the mark
            // (direction and which) when it is significant.
            let vs = |other: &str, letter: &str| -> (Option<f64>, String) {
                if *variant != "mem" {
                    return (None, String::new());
                }
                let o = AGENTS.iter().position(|x| x.0 == AGENTS[a].0 && x.1 == other).and_then(|o| find(task, o));
                let Some(o) = o else { return (None, String::new()) };
                let Some((_, _, p)) = welch_from_summary((m.mean, m.std, m.seeds), (o.mean, o.std, o.seeds)) else {
                    return (None, String::new());
                };
                let mark = if p < ALPHA {
                    format!("{}{letter}", if m.mean > o.mean { BETTER } else { WORSE })
                } else {
                    String::new()
                };
                (Some(p), mark)
            };
            let ((p_b, mark_b), (p_s, mark_s)) = (vs("baseline", "b"), vs("swap", "s"));
            let p = paper.iter().find(|r| r.0 == task && r.1 == a);
            cells.push(Table2Cell {
                task: task.to_string(),
                agent: name.to_string(),
                seeds: m.seeds,
                mean: m.mean,
                std: m.std,
                paper_mean: p.map(|r| r.2),
                paper_std: p.map(|r| r.3),
                p_vs_baseline: p_b,
                p_vs_swap: p_s,
                marks: [mark_b, mark_s].into_iter().filter(|x| !x.is_empty()).collect::<Vec<_>>().join(" "),
                source: m.source.clone(),
            });
        }
    }
    let not_run: Vec<String> =
        TASKS.iter().filter(|(t, _)| !measured.iter().any(|m| m.task == *t)).map(|(t, _)| t.to_string()).collect();
    let orderings = TASKS
        .iter()
        .filter(|(t, _)| !not_run.iter().any(|n| n == t))
        .map(|(t, short)| {
            ordering_line(t, short, &|task: &str, a: usize| find(task, a).map(|m| (m.mean, m.std, m.seeds)))
        })
        .collect();

    ensure_dir(&opts.out_dir)?;
    let t = Table2 {
        cells,
        not_run,
        orderings,
        markdown: opts.out_dir.join("table2.md"),
        csv: opts.out_dir.join("table2.csv"),
    };
    write_text(&t.markdown, &markdown(&t, &paper))?;
    write_text(&t.csv, &csv(&t, &paper))?;
    Ok(t)
}

/// A pgser or paper name of one of the six tasks.
fn paper_task(name: &str) -> Option<&'static str> {
    let canonical = Task::known(name).map(|t| t.name);
    TASKS
        .iter()
        .find(|(t, short)| canonical.as_deref() == Some(*t) || short.eq_ignore_ascii_case(name.trim()))
        .map(|(t, _)| *t)
}

/// The cells of one results.csv, each checked.
fn read_results(path: &Path) -> Result<Vec<Measured>> {
    let at = path.display();
    let df = crate::query::scan(path)?.collect().map_err(|e| anyhow!("{at}: {}", first_line(&e)))?;
    let text = |name: &str| -> Result<Vec<Option<String>>> {
        let c = df.column(name).map_err(|_| no_column(path, name))?;
        let c = c.cast(&DataType::String).map_err(|e| anyhow!("{at}: column {name}: {}", first_line(&e)))?;
        Ok(c.str()?.iter().map(|v| v.map(str::to_string)).collect())
    };
    let float = |name: &str| -> Result<Vec<Option<f64>>> { floats(&df, path, name) };
    let (task, algo, variant) = (text("task")?, text("algo")?, text("variant")?);
    let (seeds, mean, std) = (float("seeds")?, float("paper_score_mean")?, float("paper_score_std")?);
    let mut out = Vec::with_capacity(df.height());
    for i in 0..df.height() {
        let source = format!("{at}:{}", i + 2);
        let field = |v: &Option<String>, name: &str| v.clone().ok_or_else(|| anyhow!("{source}: no {name}"));
        let (t, al, v) = (field(&task[i], "task")?, field(&algo[i], "algo")?, field(&variant[i], "variant")?);
        let Some(task) = paper_task(&t) else {
            let names: Vec<&str> = TASKS.iter().map(|x| x.0).collect();
            bail!("{source}: task {t} is not in the paper's Table 2 ({})", names.join(", "));
        };
        let Some(agent) = AGENTS.iter().position(|x| x.0 == al && x.1 == v) else {
            bail!(
                "{source}: {al} {v} is not a row of the paper's Table 2 (algo td3 or td3bc; variant baseline, swap or mem)"
            );
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
        out.push(Measured { task, agent, seeds: n as usize, mean: m, std: s, source });
    }
    if out.is_empty() {
        bail!("{at}: no rows (an empty results.csv)");
    }
    Ok(out)
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

/// The paper's (task, agent, mean, std) rows from the reference CSV: `#` lines are comments (the
/// source), then `task,agent,mean,std` with the paper's task and row names.
fn read_reference(text: &str, at: &str) -> Result<Vec<(&'static str, usize, f64, f64)>> {
    let mut rows = Vec::new();
    let mut header = false;
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = line.split(',').map(str::trim).collect();
        if !header {
            if f != ["task", "agent", "mean", "std"] {
                bail!("{at}:{}: the header must be task,agent,mean,std", i + 1);
            }
            header = true;
            continue;
        }
        let pos = format!("{at}:{}", i + 1);
        let [task, agent, mean, std] = f[..] else { bail!("{pos}: expected 4 fields, got {}", f.len()) };
        let task = paper_task(task).ok_or_else(|| anyhow!("{pos}: task {task} is not in the paper's Table 2"))?;
        let agent =
            AGENTS.iter().position(|a| a.2 == agent).ok_or_else(|| anyhow!("{pos}: no row {agent} in Table 2"))?;
        let num = |s: &str| {
            s.parse::<f64>().ok().filter(|x| x.is_finite()).ok_or_else(|| anyhow!("{pos}: {s} is not a number"))
        };
        if rows.iter().any(|r: &(&str, usize, f64, f64)| r.0 == task && r.1 == agent) {
            bail!("{pos}: {task} {} is given twice", AGENTS[agent].2);
        }
        rows.push((task, agent, num(mean)?, num(std)?));
    }
    Ok(rows)
}

/// One task's line: for each learner, whether mem ≥ swap ≥ baseline holds in the means, and the
/// comparisons that are significant (Welch, two-sided, α = [`ALPHA`]).
/// A cell's (mean, std, seeds) by learner variant and column.
type Lookup<'a> = &'a dyn Fn(&str, usize) -> Option<(f64, f64, usize)>;

fn ordering_line(task: &str, short: &str, find: Lookup) -> String {
    let mut parts = Vec::new();
    for (algo, learner) in [("td3bc", "TD3BC"), ("td3", "TD3")] {
        let get = |v: &str| find(task, AGENTS.iter().position(|a| a.0 == algo && a.1 == v).expect("a known row"));
        let (Some(m), Some(s), Some(b)) = (get("mem"), get("swap"), get("baseline")) else { continue };
        let holds = m.0 >= s.0 && s.0 >= b.0;
        let mut tests = Vec::new();
        for (x, y, names) in [(m, s, "mem vs swap"), (s, b, "swap vs baseline"), (m, b, "mem vs baseline")] {
            match welch_from_summary(x, y) {
                Some((_, _, p)) if p < ALPHA => {
                    tests.push(format!("{names} {} p = {}", if x.0 > y.0 { BETTER } else { WORSE }, fmt_p(p)))
                }
                Some((_, _, p)) => tests.push(format!("{names} not significant (p = {})", fmt_p(p))),
                None => tests.push(format!("{names} untested (fewer than 2 seeds or no spread)")),
            }
        }
        parts.push(format!(
            "{learner}: mem ≥ swap ≥ baseline {} ({:.2} / {:.2} / {:.2}); {}",
            if holds { "holds" } else { "does not hold" },
            m.0,
            s.0,
            b.0,
            tests.join(", ")
        ));
    }
    format!("**{short}**: {}.", parts.join(". "))
}

fn fmt_p(p: f64) -> String {
    if p < 1e-3 { format!("{p:.1e}") } else { format!("{p:.3}") }
}

fn fmt_cell(mean: f64, std: f64) -> String {
    if std.is_finite() { format!("{mean:.2} ± {std:.2}") } else { format!("{mean:.2}") }
}

fn markdown(t: &Table2, paper: &[(&str, usize, f64, f64)]) -> String {
    let mut s = String::from(
        "# Table 2: average cumulative reward (the paper score: the sum of {0, 1} rewards over an evaluation \
         episode), mean ± std over seeds\n\n",
    );
    let head: Vec<&str> = TASKS.iter().map(|t| t.1).collect();
    let _ = writeln!(s, "| agent | {} |", head.join(" | "));
    let _ = writeln!(s, "|---|{}", "---:|".repeat(TASKS.len()));
    for (a, (_, _, name)) in AGENTS.iter().enumerate() {
        let mut ours = Vec::new();
        let mut theirs = Vec::new();
        for (task, _) in TASKS {
            let cell = t.cells.iter().find(|c| c.task == task && c.agent == *name);
            ours.push(match cell {
                Some(c) if c.marks.is_empty() => fmt_cell(c.mean, c.std),
                Some(c) => format!("{} {}", fmt_cell(c.mean, c.std), c.marks),
                None => "not run".to_string(),
            });
            theirs.push(match paper.iter().find(|r| r.0 == task && r.1 == a) {
                Some(r) => fmt_cell(r.2, r.3),
                None => "—".to_string(),
            });
        }
        let _ = writeln!(s, "| {name} (pgser) | {} |", ours.join(" | "));
        let _ = writeln!(s, "| {name} (paper) | {} |", theirs.join(" | "));
    }
    let _ = write!(
        s,
        "\nMarks on the mem rows: {BETTER} / {WORSE} mem's mean significantly above / below the same learner's \
         baseline (b) or swap (s), by Welch's two-sided t-test (unequal variances) on the per-seed final scores, \
         α = {ALPHA}; no mark: no significant difference. \"not run\": no results for that task among the inputs. \
         The (paper) rows are the reference file's values of the paper's Table 2 (its source is named in the file).\n"
    );
    if paper.is_empty() {
        s += "\n**The reference file holds none of the paper's values yet**, so every (paper) cell is \"—\": \
              enter them in assets/paper_table2.csv, or give a filled copy with --reference FILE.\n";
    }
    if !t.orderings.is_empty() {
        s += "\n## The paper's ordering, mem ≥ swap ≥ baseline, per task\n\n";
        for line in &t.orderings {
            let _ = writeln!(s, "- {line}");
        }
    }
    s += "\n## Sources\n\n";
    for c in &t.cells {
        let _ = writeln!(s, "- {} {}: {} ({} seeds)", c.task, c.agent, c.source, c.seeds);
    }
    s
}

/// Every cell of the paper's table, measured or not, with the paper's value beside it.
fn csv(t: &Table2, paper: &[(&str, usize, f64, f64)]) -> String {
    let mut s = String::from("task,agent,seeds,mean,std,marks,paper_mean,paper_std,p_vs_baseline,p_vs_swap,source\n");
    let opt = |x: Option<f64>| x.map(|v| v.to_string()).unwrap_or_default();
    let num = |x: f64| if x.is_finite() { x.to_string() } else { String::new() };
    for (task, _) in TASKS {
        for (a, (_, _, name)) in AGENTS.iter().enumerate() {
            let p = paper.iter().find(|r| r.0 == task && r.1 == a);
            let (pm, ps) = (opt(p.map(|r| r.2)), opt(p.map(|r| r.3)));
            match t.cells.iter().find(|c| c.task == task && c.agent == *name) {
                Some(c) => {
                    let _ = writeln!(
                        s,
                        "{task},{name},{},{},{},{},{pm},{ps},{},{},{}",
                        c.seeds,
                        num(c.mean),
                        num(c.std),
                        c.marks,
                        opt(c.p_vs_baseline),
                        opt(c.p_vs_swap),
                        c.source.replace(',', ";")
                    );
                }
                None => {
                    let _ = writeln!(s, "{task},{name},0,,,,{pm},{ps},,,not run");
                }
            }
        }
    }
    s
}
