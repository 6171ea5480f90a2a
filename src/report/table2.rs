//! The paper's Table 2 across its six tasks, from several pipelines' `results.csv` files
//! (`pgser-etl table2`).
//!
//! A pipeline reports one task ([`super::results`]); the paper's table is six of them side by
//! side: rows TD3BC-mem, TD3BC-swap, TD3BC, TD3-mem, TD3-swap, TD3, a column per task, and under
//! each measured row the same cell over pooled episodes and the paper's own value with its marks,
//! from a reference committed with its source named ([`super::paper`]; `--reference` reads
//! another). Lines per task then say where pgser and the paper agree on the ordering and on each
//! significant difference ([`super::agree`]).
//!
//! The tests are recomputed here from each cell's (mean, std, n), which is all Welch's test
//! needs, so every comparison the paper marks (mem vs swap, swap vs baseline, mem vs baseline) is
//! available, twice: over the seeds' mean scores, the test the marks of the (pgser) rows use, and
//! over all evaluation episodes pooled ([`super::spread`]), the paper's likely terms. The pooled
//! spread comes from the results.csv's own columns or, when a `scores.csv` lies beside it, from
//! that file's per-run (or per-episode) scores, which must then agree with the results.csv; a
//! results.csv written before pgser kept either has it "n/a", never estimated.
//!
//! Inputs are checked before anything is written, each fault a one-line error naming the file
//! and line: a cell given twice (in one file or two), a task or agent the paper's table does not
//! have, a task with results for only some of its six agents. A task with no results at all is a
//! column marked "not run", so the table can be assembled while grids are still running.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::{Result, bail};
use serde::Serialize;

use super::agree::{self, Agreement};
use super::cells::{AGENTS, Measured, RowOf, TASKS, fmt_cell};
use super::chosen::{self, Chosen, ChosenOptions};
use super::measured::read_results;
use super::paper::{self, PaperCell};
use super::welch::{ALPHA, BETTER, WORSE, mark, welch_from_summary};
use super::{ensure_dir, write_text};

#[derive(Debug, Clone)]
pub struct Table2Options {
    /// `results.csv` files of pipelines (`pgser-etl pipeline run` writes one per pipeline).
    pub inputs: Vec<PathBuf>,
    /// The paper's values; None: the compiled-in `assets/paper_table2.csv`.
    pub reference: Option<PathBuf>,
    pub out_dir: PathBuf,
    /// Rows for a `-mem` setting beside the grids' ([`super::chosen`]), where given.
    pub chosen: Option<ChosenOptions>,
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
    /// Sample std over the seeds' mean scores; NaN with one seed.
    pub std: f64,
    /// Evaluation episodes of all seeds pooled, and the sample std over them; None where the
    /// input kept no per-run spread (a results.csv written before pgser kept them).
    pub episodes: Option<usize>,
    pub std_episodes: Option<f64>,
    pub paper_mean: Option<f64>,
    pub paper_std: Option<f64>,
    /// The paper's marks in pgser's notation: `▲b` its pink box, `▲s` its bold.
    pub paper_marks: String,
    /// Welch's two-sided p over the seeds' means: mem and swap against the same learner's
    /// baseline, mem against its swap (None on other rows).
    pub p_vs_baseline: Option<f64>,
    pub p_vs_swap: Option<f64>,
    /// The same tests over pooled episodes.
    pub p_episodes_vs_baseline: Option<f64>,
    pub p_episodes_vs_swap: Option<f64>,
    /// The significant differences over seeds: `▲b` (above baseline), `▼s` (below swap), …
    pub marks: String,
    /// The same over pooled episodes.
    pub marks_episodes: String,
    /// Where the cell came from: `FILE:LINE`.
    pub source: String,
}

#[derive(Debug, Clone, Serialize)]
pub struct Table2 {
    pub cells: Vec<Table2Cell>,
    /// Tasks of the paper with no results among the inputs (their columns say "not run").
    pub not_run: Vec<String>,
    /// Cells of the paper's table the reference lacks (`TASK AGENT`; their (paper) cells say "—").
    pub paper_missing: Vec<String>,
    /// Per measured task, whether mem ≥ swap ≥ baseline holds for each learner here and in the
    /// paper, each comparison's tests, and where pgser and the paper agree.
    pub orderings: Vec<String>,
    /// How many orderings and marks agree with the paper's.
    pub agreement: Agreement,
    /// The chosen setting's rows and counts, with `--chosen`.
    pub chosen: Option<Chosen>,
    pub markdown: PathBuf,
    pub csv: PathBuf,
}

/// Writes `out_dir/table2.md` and `out_dir/table2.csv`.
pub fn table2(opts: &Table2Options) -> Result<Table2> {
    if opts.inputs.is_empty() {
        bail!("table2 needs at least one results.csv (a pipeline writes one in its out folder)");
    }
    let mut measured: Vec<Measured> = Vec::new();
    let paper_row = |algo: &str, variant: &str| {
        AGENTS.iter().position(|x| x.0 == algo && x.1 == variant).map_or(RowOf::Unknown, RowOf::Agent)
    };
    for path in &opts.inputs {
        for m in read_results(path, &paper_row)? {
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
            paper::read_table2(&text, &p.display().to_string())?
        }
        None => paper::read_table2(paper::TABLE2, "assets/paper_table2.csv")?,
    };

    let find = |task: &str, agent: usize| measured.iter().find(|m| m.task == task && m.agent == agent);
    let mut cells = Vec::new();
    for (a, (algo, variant, name)) in AGENTS.iter().enumerate() {
        for (task, _) in TASKS {
            let Some(m) = find(task, a) else { continue };
            let other = |v: &str| AGENTS.iter().position(|x| x.0 == *algo && x.1 == v).and_then(|o| find(task, o));
            // The comparisons the paper marks on this row: against the baseline (mem and swap
            // rows, letter b) and against swap (mem rows, letter s).
            let against: Vec<(&Measured, &str)> = match *variant {
                "mem" => [other("baseline").map(|o| (o, "b")), other("swap").map(|o| (o, "s"))]
                    .into_iter()
                    .flatten()
                    .collect(),
                "swap" => other("baseline").map(|o| (o, "b")).into_iter().collect(),
                _ => Vec::new(),
            };
            let (mut p_seeds, mut p_episodes) = ([None, None], [None, None]);
            let (mut marks, mut marks_episodes) = (Vec::new(), Vec::new());
            for (o, letter) in against {
                let slot = usize::from(letter == "s");
                let seeds = welch_from_summary(m.seeds_side(), o.seeds_side()).map(|t| t.2);
                let episodes =
                    m.episodes_side().zip(o.episodes_side()).and_then(|(x, y)| welch_from_summary(x, y)).map(|t| t.2);
                p_seeds[slot] = seeds;
                p_episodes[slot] = episodes;
                marks.extend(mark(seeds, m.mean > o.mean, letter));
                marks_episodes.extend(mark(episodes, m.mean > o.mean, letter));
            }
            let p = paper.iter().find(|r| r.task == task && r.agent == a);
            cells.push(Table2Cell {
                task: task.to_string(),
                agent: name.to_string(),
                seeds: m.seeds,
                mean: m.mean,
                std: m.std,
                episodes: m.pooled.map(|p| p.0),
                std_episodes: m.pooled.map(|p| p.2),
                paper_mean: p.map(|r| r.mean),
                paper_std: p.map(|r| r.std),
                paper_marks: p.map(PaperCell::marks).unwrap_or_default(),
                p_vs_baseline: p_seeds[0],
                p_vs_swap: p_seeds[1],
                p_episodes_vs_baseline: p_episodes[0],
                p_episodes_vs_swap: p_episodes[1],
                marks: marks.join(" "),
                marks_episodes: marks_episodes.join(" "),
                source: m.source.clone(),
            });
        }
    }
    let not_run: Vec<String> =
        TASKS.iter().filter(|(t, _)| !measured.iter().any(|m| m.task == *t)).map(|(t, _)| t.to_string()).collect();
    let paper_missing = TASKS
        .iter()
        .flat_map(|(t, short)| AGENTS.iter().enumerate().map(move |(a, agent)| (*t, *short, a, agent.2)))
        .filter(|(t, _, a, _)| !paper.iter().any(|r| r.task == *t && r.agent == *a))
        .map(|(_, short, _, name)| format!("{short} {name}"))
        .collect();
    let mut agreement = Agreement::default();
    let orderings = TASKS
        .iter()
        .filter(|(t, _)| !not_run.iter().any(|n| n == t))
        .map(|(t, short)| agree::task_line(t, short, &find, &paper, &mut agreement))
        .collect();

    let chosen = opts.chosen.as_ref().map(|o| chosen::chosen(o, &paper, &find)).transpose()?;

    ensure_dir(&opts.out_dir)?;
    let t = Table2 {
        cells,
        not_run,
        paper_missing,
        orderings,
        agreement,
        chosen,
        markdown: opts.out_dir.join("table2.md"),
        csv: opts.out_dir.join("table2.csv"),
    };
    let mut text = markdown(&t, &paper);
    if let Some(c) = &t.chosen {
        let grid_mem = |task: &str, learner: &str| {
            let agent = format!("{learner}-mem");
            t.cells.iter().find(|x| x.task == task && x.agent == agent).map(|x| fmt_cell(x.mean, x.std, &x.marks))
        };
        // The grids' counts again over only the pairs the chosen setting was measured on.
        let learner = |a: usize| if AGENTS[a].0 == "td3bc" { "TD3BC" } else { "TD3" };
        let same_pairs = |task: &str, a: usize| {
            find(task, a).filter(|_| c.cells.iter().any(|x| x.task == task && x.learner == learner(a)))
        };
        let mut on_same = Agreement::default();
        for (task, short) in TASKS {
            agree::task_line(task, short, &same_pairs, &paper, &mut on_same);
        }
        text += &chosen::markdown(
            c,
            &grid_mem,
            &paper,
            &[("q α = 1 (the grids)", &t.agreement), ("q α = 1 (the grids), the same pairs", &on_same)],
        );
        write_text(&opts.out_dir.join("table2_chosen.csv"), &chosen::csv(c))?;
    }
    write_text(&t.markdown, &text)?;
    write_text(&t.csv, &csv(&t, &paper))?;
    Ok(t)
}

fn markdown(t: &Table2, paper: &[PaperCell]) -> String {
    let mut s = String::from(
        "# Table 2: average cumulative reward (the paper score: the sum of {0, 1} rewards over an evaluation \
         episode), mean ± std\n\n",
    );
    let head: Vec<&str> = TASKS.iter().map(|t| t.1).collect();
    let _ = writeln!(s, "| agent | {} |", head.join(" | "));
    let _ = writeln!(s, "|---|{}", "---:|".repeat(TASKS.len()));
    for (a, (_, _, name)) in AGENTS.iter().enumerate() {
        let (mut seeds, mut episodes, mut theirs) = (Vec::new(), Vec::new(), Vec::new());
        for (task, _) in TASKS {
            match t.cells.iter().find(|c| c.task == task && c.agent == *name) {
                Some(c) => {
                    seeds.push(fmt_cell(c.mean, c.std, &c.marks));
                    episodes.push(match c.std_episodes {
                        Some(sd) => fmt_cell(c.mean, sd, &c.marks_episodes),
                        None => "n/a".to_string(),
                    });
                }
                None => {
                    seeds.push("not run".to_string());
                    episodes.push("not run".to_string());
                }
            }
            theirs.push(paper.iter().find(|r| r.task == task && r.agent == a).map_or("—".to_string(), PaperCell::text));
        }
        let _ = writeln!(s, "| {name} (pgser) | {} |", seeds.join(" | "));
        let _ = writeln!(s, "| {name} (pgser, episodes) | {} |", episodes.join(" | "));
        let _ = writeln!(s, "| {name} (paper) | {} |", theirs.join(" | "));
    }
    let _ = write!(
        s,
        "\n(pgser): mean ± std over the seeds' mean scores (n = seeds); its marks are Welch's two-sided t-test \
         (unequal variances) over those seed means, the test pgser's claims rest on. (pgser, episodes): the same \
         mean ± std over every evaluation episode of every seed pooled (n = seeds × episodes), with the same test \
         over the pooled episodes, which counts each episode as an independent sample: the paper's likely terms \
         (it does not say over what its ± and tests are taken). \"n/a\": the input kept no per-run spread of its \
         episodes (results written before pgser kept them), so the pooled std is not known and not estimated. \
         Marks: {BETTER} / {WORSE} significantly above / below (α = {ALPHA}) the same learner's baseline (b, on \
         mem and swap rows) or swap (s, on mem rows); no mark: no significant difference. \"not run\": no results \
         for that task among the inputs.\n\n\
         (paper): the reference file's values of the paper's Table 2 (its source is named in the file), with \
         the paper's marks in the same notation: ▲b its pink box (the variant above the same learner's baseline \
         by a t-test at p < 0.05), ▲s its bold (mem above swap, p < 0.05).\n"
    );
    if !t.paper_missing.is_empty() {
        let _ = write!(
            s,
            "\n**The reference lacks {} of the paper's 36 cells** ({}), which print \"—\".\n",
            t.paper_missing.len(),
            t.paper_missing.join(", ")
        );
    }
    if !t.orderings.is_empty() {
        s += "\n## Per task: the paper's ordering, mem ≥ swap ≥ baseline, and its marks against pgser's tests\n\n";
        for line in &t.orderings {
            let _ = writeln!(s, "- {line}");
        }
        let _ = writeln!(s, "\n{}", t.agreement.summary());
        s += "\nA comparison agrees when pgser's test finds it significantly above exactly where the paper marks \
              it: the paper marks only that, so pgser's ▼ (significantly below) counts as unmarked.\n";
    }
    if !paper.is_empty() {
        let (n, e) = (paper::SEEDS, paper::SEEDS * paper::EPISODES);
        let ((a, of), (b, _)) = (agree::paper_reproduced(paper, n), agree::paper_reproduced(paper, e));
        let _ = writeln!(
            s,
            "\nThe paper's own marks recomputed by the same test from its printed mean ± std: {a} of {of} come out \
             as it marks them with n = {n} a side (its seeds), {b} of {of} with n = {e} (its seeds × episodes \
             pooled). {}",
            if a == of || b == of {
                "The paper does not say which it used."
            } else {
                "Neither reproduces all of them: its marks do not follow from its printed mean ± std by this test \
                 at either n (the paper does not say which test it ran, or over what)."
            }
        );
    }
    s += "\n## Sources\n\n";
    for c in &t.cells {
        let _ = writeln!(s, "- {} {}: {} ({} seeds)", c.task, c.agent, c.source, c.seeds);
    }
    s
}

/// Every cell of the paper's table, measured or not, with the paper's value beside it.
fn csv(t: &Table2, paper: &[PaperCell]) -> String {
    let mut s = String::from(
        "task,agent,seeds,mean,std,marks,episodes,std_episodes,marks_episodes,p_vs_baseline,p_vs_swap,\
         p_episodes_vs_baseline,p_episodes_vs_swap,paper_mean,paper_std,paper_marks,source\n",
    );
    let opt = |x: Option<f64>| x.map(|v| v.to_string()).unwrap_or_default();
    let num = |x: f64| if x.is_finite() { x.to_string() } else { String::new() };
    for (task, _) in TASKS {
        for (a, (_, _, name)) in AGENTS.iter().enumerate() {
            let p = paper.iter().find(|r| r.task == task && r.agent == a);
            let theirs = format!(
                "{},{},{}",
                opt(p.map(|r| r.mean)),
                opt(p.map(|r| r.std)),
                p.map(PaperCell::marks).unwrap_or_default()
            );
            match t.cells.iter().find(|c| c.task == task && c.agent == *name) {
                Some(c) => {
                    let _ = writeln!(
                        s,
                        "{task},{name},{},{},{},{},{},{},{},{},{},{},{},{theirs},{}",
                        c.seeds,
                        num(c.mean),
                        num(c.std),
                        c.marks,
                        c.episodes.map(|n| n.to_string()).unwrap_or_default(),
                        opt(c.std_episodes.filter(|x| x.is_finite())),
                        c.marks_episodes,
                        opt(c.p_vs_baseline),
                        opt(c.p_vs_swap),
                        opt(c.p_episodes_vs_baseline),
                        opt(c.p_episodes_vs_swap),
                        c.source.replace(',', ";")
                    );
                }
                None => {
                    let _ = writeln!(s, "{task},{name},0,,,,,,,,,,,{theirs},not run");
                }
            }
        }
    }
    s
}
