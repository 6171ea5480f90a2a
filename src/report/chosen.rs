//! Table 2's rows for one `-mem` setting beside the grids' (`pgser-etl table2 --chosen`): the
//! priority chosen on FetchPush (rank, α = 1: RESULTS.md), run on every task and learner by
//! pipelines that train it with their own baseline and `-swap` (`pipelines/*_priority_*_cpu.toml`).
//!
//! Each of those results.csv files gives, per (task, learner), three cells: the arm (by its name,
//! `mem_rank`), and the baseline and `-swap` trained beside it by the same build on the same data
//! and Q. The arm's marks are against those two, not against the grid's cells, which a later
//! build does not reproduce bit for bit. Other arms in the file (`mem_q3`) are left out. Beside
//! each cell: the arm's share of draws above the own-goal median Q, from the `table1.json` of
//! the same pipeline, and uniform drawing's share (`-swap`'s picture).
//!
//! The same counts as the grids' rows follow ([`agree::task_line`] over the three cells in the
//! paper's row names), so the two settings can be compared with the paper on equal terms: `-mem`
//! significantly above `-swap`, and each of the paper's marks.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Serialize;

use super::agree::{self, Agreement};
use super::cells::{AGENTS, Measured, RowOf, TASKS, fmt_cell};
use super::measured::read_results;
use super::paper::PaperCell;
use super::share::PriorityShares;
use super::welch::{ALPHA, mark, welch_from_summary};
use crate::sampler::priority::PriorityConfig;

/// Which arm is the chosen setting, and the results files that train it.
#[derive(Debug, Clone)]
pub struct ChosenOptions {
    /// results.csv files of pipelines training the arm beside their own baseline and `-swap`.
    pub inputs: Vec<PathBuf>,
    /// The arm's name in those files (their `variant` column): `mem_rank`.
    pub arm: String,
    /// Its priority setting, to find its share in each pipeline's `table1.json`.
    pub setting: PriorityConfig,
}

impl ChosenOptions {
    /// "rank α = 1": the setting as the table's rows name it.
    pub fn label(&self) -> String {
        let kind = serde_json::to_value(self.setting.priority).ok().and_then(|v| v.as_str().map(str::to_string));
        format!("{} α = {}", kind.unwrap_or_default(), self.setting.priority_alpha)
    }
}

/// One (task, learner) of the chosen setting: the arm with the two it is tested against.
#[derive(Debug, Clone, Serialize)]
pub struct ChosenCell {
    pub task: String,
    /// The paper's learner name: `TD3BC` or `TD3`.
    pub learner: String,
    pub seeds: usize,
    pub mean: f64,
    pub std: f64,
    /// The baseline and `-swap` trained beside it: (mean, std) over their seeds.
    pub baseline: (f64, f64),
    pub swap: (f64, f64),
    /// Welch's two-sided p over the seeds' means, against the baseline and against `-swap`.
    pub p_vs_baseline: Option<f64>,
    pub p_vs_swap: Option<f64>,
    /// `▲b ▲s`, as the grids' rows mark them.
    pub marks: String,
    /// Welch's p against the grid's own `-mem` (q α = 1) of the same pair, where the grids have
    /// it: the comparison step 5 of issue 57 decides the default by (a grid ran on an older build,
    /// so this compares settings and builds together; RESULTS.md says so).
    pub p_vs_grid_mem: Option<f64>,
    /// Against the grid's `-mem`, where the grids have the pair: "at least as well as α = 1" or
    /// not, or unknown where Welch's test has no p.
    pub as_well_as_grid: Option<AsWell>,
    /// Why it is unknown: "the arm over one seed", "no spread on either side".
    pub why_unknown: Option<String>,
    /// Share of the arm's draws above the own-goal median Q, and uniform drawing's; None where
    /// the pipeline's table1.json is absent or has no share of this setting.
    pub share: Option<f64>,
    pub uniform: Option<f64>,
    pub source: String,
}

/// The arm against the grid's `-mem` of the same pair, by Welch's test over seeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum AsWell {
    /// Not significantly below it.
    Yes,
    /// Significantly below it.
    No,
    /// No p to decide by: a side over one seed, or neither side with any spread (t undefined).
    /// Counting such a pair as "not significantly below" would count a test that was never made.
    Unknown,
}

impl AsWell {
    /// As table2_chosen.csv writes it.
    fn as_str(self) -> &'static str {
        match self {
            AsWell::Yes => "yes",
            AsWell::No => "no",
            AsWell::Unknown => "unknown",
        }
    }
}

#[derive(Debug, Clone, Serialize)]
pub struct Chosen {
    /// "rank α = 1".
    pub label: String,
    pub cells: Vec<ChosenCell>,
    /// Per measured task, the paper's ordering and marks against this setting's tests.
    pub orderings: Vec<String>,
    pub agreement: Agreement,
}

/// The chosen setting's cells from `o.inputs`, each checked, and their agreement with `paper`.
/// `grid_mem(task, agent)`: the grids' cell of that row, for the comparison with α = 1.
pub fn chosen<'g>(
    o: &ChosenOptions,
    paper: &[PaperCell],
    grid_mem: &dyn Fn(&str, usize) -> Option<&'g Measured>,
) -> Result<Chosen> {
    let mut measured: Vec<Measured> = Vec::new();
    let mut shares: Vec<(&'static str, &'static str, Option<f64>, Option<f64>)> = Vec::new();
    for path in &o.inputs {
        let arm = o.arm.as_str();
        let row = |algo: &str, variant: &str| {
            let as_variant = match variant {
                "baseline" | "swap" => variant,
                v if v == arm => "mem",
                _ => return RowOf::Skip,
            };
            AGENTS.iter().position(|a| a.0 == algo && a.1 == as_variant).map_or(RowOf::Unknown, RowOf::Agent)
        };
        let cells = read_results(path, &row)?;
        let (share, uniform) = share_of(path, o)?;
        for (task, _) in TASKS {
            for algo in ["td3bc", "td3"] {
                let here: Vec<&Measured> =
                    cells.iter().filter(|m| m.task == task && AGENTS[m.agent].0 == algo).collect();
                if here.is_empty() {
                    continue;
                }
                for v in ["mem", "swap", "baseline"] {
                    if !here.iter().any(|m| AGENTS[m.agent].1 == v) {
                        let what = if v == "mem" { format!("arm {arm}") } else { v.to_string() };
                        bail!(
                            "{}: {task} {algo} has no {what} (a --chosen file trains the arm {arm} beside its own \
                             baseline and swap)",
                            path.display()
                        );
                    }
                }
                if let Some(other) = measured.iter().find(|m| m.task == task && AGENTS[m.agent].0 == algo) {
                    bail!("{}: {task} {algo} is also in {}: give each chosen cell once", path.display(), other.source);
                }
                shares.push((task, algo, share, uniform));
            }
        }
        measured.extend(cells);
    }
    if measured.is_empty() {
        bail!("table2 --chosen: no rows of arm {} in {} file(s)", o.arm, o.inputs.len());
    }

    let find = |task: &str, agent: usize| measured.iter().find(|m| m.task == task && m.agent == agent);
    let mut cells = Vec::new();
    for (algo, learner) in [("td3bc", "TD3BC"), ("td3", "TD3")] {
        let row = |v: &str| AGENTS.iter().position(|a| a.0 == algo && a.1 == v).expect("a known row");
        for (task, _) in TASKS {
            let (Some(m), Some(s), Some(b)) =
                (find(task, row("mem")), find(task, row("swap")), find(task, row("baseline")))
            else {
                continue;
            };
            let p = |o: &Measured| welch_from_summary(m.seeds_side(), o.seeds_side()).map(|t| t.2);
            let (pb, ps) = (p(b), p(s));
            let marks: Vec<String> =
                [mark(pb, m.mean > b.mean, "b"), mark(ps, m.mean > s.mean, "s")].into_iter().flatten().collect();
            let grid = grid_mem(task, row("mem"));
            let p_vs_grid_mem = grid.and_then(p);
            let as_well_as_grid = grid.map(|g| match p_vs_grid_mem {
                None => AsWell::Unknown,
                Some(p) if p < ALPHA && m.mean < g.mean => AsWell::No,
                Some(_) => AsWell::Yes,
            });
            let why_unknown = grid.filter(|_| p_vs_grid_mem.is_none()).map(|g| {
                match (m.seeds < 2, g.seeds < 2) {
                    (true, false) => "the arm over one seed",
                    (false, true) => "the grid's over one seed",
                    (true, true) => "both over one seed",
                    (false, false) => "no spread on either side",
                }
                .to_string()
            });
            let (share, uniform) =
                shares.iter().find(|x| x.0 == task && x.1 == algo).map_or((None, None), |x| (x.2, x.3));
            cells.push(ChosenCell {
                task: task.to_string(),
                learner: learner.to_string(),
                seeds: m.seeds,
                mean: m.mean,
                std: m.std,
                baseline: (b.mean, b.std),
                swap: (s.mean, s.std),
                p_vs_baseline: pb,
                p_vs_swap: ps,
                marks: marks.join(" "),
                p_vs_grid_mem,
                as_well_as_grid,
                why_unknown,
                share,
                uniform,
                source: m.source.clone(),
            });
        }
    }
    let mut agreement = Agreement::default();
    let orderings = TASKS
        .iter()
        .filter(|(t, _)| measured.iter().any(|m| m.task == *t))
        .map(|(t, short)| agree::task_line(t, short, &find, paper, &mut agreement))
        .collect();
    Ok(Chosen { label: o.label(), cells, orderings, agreement })
}

/// The setting's share of draws above the own-goal median, and uniform's, from the table1.json
/// beside `results` (the same pipeline's report); None where it has none.
fn share_of(results: &Path, o: &ChosenOptions) -> Result<(Option<f64>, Option<f64>)> {
    let path = results.with_file_name("table1.json");
    if !path.is_file() {
        return Ok((None, None));
    }
    let text = crate::output::read_input_text(&path)?;
    let v: serde_json::Value = serde_json::from_str(&text).with_context(|| format!("{}: not JSON", path.display()))?;
    let Some(p) = v.get("priority").filter(|p| !p.is_null()) else { return Ok((None, None)) };
    let p: PriorityShares = serde_json::from_value(p.clone())
        .with_context(|| format!("{}: priority: not a report's shares", path.display()))?;
    let want = &o.setting;
    let share = p
        .settings
        .iter()
        .find(|s| s.priority == want.priority && s.priority_alpha == want.priority_alpha)
        .map(|s| s.share_above);
    Ok((share, Some(p.uniform)))
}

/// The chosen setting's section of table2.md: its rows beside the grids' (α = 1) and the paper's
/// `-mem`, the shares, and the counts against the paper for both settings.
pub fn markdown(
    c: &Chosen,
    grid_mem: &dyn Fn(&str, &str) -> Option<String>,
    paper: &[PaperCell],
    grids: &[(&str, &Agreement)],
) -> String {
    let mut s = format!("\n## -mem with the chosen priority, {}\n\n", c.label);
    let head: Vec<&str> = TASKS.iter().map(|t| t.1).collect();
    let _ = writeln!(s, "| agent | {} |", head.join(" | "));
    let _ = writeln!(s, "|---|{}", "---:|".repeat(TASKS.len()));
    for learner in ["TD3BC", "TD3"] {
        let cell = |task: &str| c.cells.iter().find(|x| x.task == task && x.learner == learner);
        let row = |f: &dyn Fn(&ChosenCell) -> String| -> String {
            TASKS.iter().map(|(t, _)| cell(t).map_or("not run".to_string(), f)).collect::<Vec<_>>().join(" | ")
        };
        let _ = writeln!(s, "| {learner}-mem, {} (pgser) | {} |", c.label, row(&|x| fmt_cell(x.mean, x.std, &x.marks)));
        let _ = writeln!(s, "| {learner}-swap beside it (pgser) | {} |", row(&|x| fmt_cell(x.swap.0, x.swap.1, "")));
        let _ = writeln!(s, "| {learner} beside it (pgser) | {} |", row(&|x| fmt_cell(x.baseline.0, x.baseline.1, "")));
        let share = |x: &ChosenCell| match (x.share, x.uniform) {
            (Some(a), Some(u)) => format!("{} ({})", fmt_share(a), fmt_share(u)),
            _ => "n/a".to_string(),
        };
        let _ =
            writeln!(s, "| {learner}-mem, {}: share above the own-goal median (uniform) | {} |", c.label, row(&share));
        let grid: Vec<String> =
            TASKS.iter().map(|(t, _)| grid_mem(t, learner).unwrap_or_else(|| "not run".to_string())).collect();
        let _ = writeln!(s, "| {learner}-mem, q α = 1 (pgser, the grids) | {} |", grid.join(" | "));
        let theirs: Vec<String> = TASKS
            .iter()
            .map(|(t, _)| {
                let a = AGENTS.iter().position(|x| x.2 == format!("{learner}-mem")).expect("a known row");
                paper.iter().find(|r| r.task == *t && r.agent == a).map_or("—".to_string(), PaperCell::text)
            })
            .collect();
        let _ = writeln!(s, "| {learner}-mem (paper) | {} |", theirs.join(" | "));
    }
    let _ = write!(
        s,
        "\nThe chosen rows' marks are Welch's two-sided test over seed means against the baseline (b) and `-swap` \
         (s) trained beside the arm, by the same build on the same data and Q (the next two rows), not against the \
         grids' cells. Share: the fraction of the arm's draws whose Q lies above the median Q of the dataset's own \
         goals (the report's positives), against uniform drawing's, from the pipeline's table1.json.\n\n\
         **Counts against the paper** (each over the (task, learner) pairs measured with that setting):\n\n\
         | | pairs | -mem significantly above -swap (the paper's ▲s on the same pairs) | -mem vs baseline marks agreeing | every mark agreeing | ordering agreeing |\n\
         |---|---:|---:|---:|---:|---:|\n",
    );
    for (name, a) in grids.iter().copied().chain([(c.label.as_str(), &c.agreement)]) {
        let _ = writeln!(s, "{}", count_row(name, a));
    }
    let compared: Vec<&ChosenCell> = c.cells.iter().filter(|x| x.as_well_as_grid.is_some()).collect();
    let pairs = |verdict: AsWell, note: &dyn Fn(&ChosenCell) -> String| -> Vec<String> {
        compared
            .iter()
            .filter(|x| x.as_well_as_grid == Some(verdict))
            .map(|x| format!("{} {} ({})", x.task, x.learner, note(x)))
            .collect()
    };
    let below = pairs(AsWell::No, &|x| format!("p = {}", agree::fmt_p(x.p_vs_grid_mem.unwrap_or(f64::NAN))));
    let unknown = pairs(AsWell::Unknown, &|x| x.why_unknown.clone().unwrap_or_default());
    let as_well = compared.iter().filter(|x| x.as_well_as_grid == Some(AsWell::Yes)).count();
    let _ = writeln!(
        s,
        "\n**{} at least as well as q α = 1** (its `-mem` not significantly below the grid's `-mem` of the same \
         pair, Welch over seeds; the grids ran on an older build): {as_well} of {} pairs{}{}.",
        c.label,
        compared.len(),
        if unknown.is_empty() {
            String::new()
        } else {
            format!(" ({} unknown: {})", unknown.len(), unknown.join(", "))
        },
        if below.is_empty() { String::new() } else { format!("; below it: {}", below.join(", ")) }
    );
    s += "\n### Per task, with the chosen setting\n\n";
    for line in &c.orderings {
        let _ = writeln!(s, "- {line}");
    }
    s
}

fn count_row(name: &str, a: &Agreement) -> String {
    let (mb, mbo) = a.by_comparison[agree::MEM_VS_BASELINE];
    format!(
        "| {name} | {} | {} ({}) | {mb} of {mbo} | {} of {} | {} of {} |",
        a.pairs, a.mem_above_swap, a.paper_mem_above_swap, a.seeds_agree, a.seeds_of, a.ordering_agree, a.ordering_of
    )
}

/// The chosen cells as CSV (table2_chosen.csv).
pub fn csv(c: &Chosen) -> String {
    let mut s = String::from(
        "task,learner,setting,seeds,mean,std,marks,p_vs_baseline,p_vs_swap,baseline_mean,baseline_std,swap_mean,\
         swap_std,p_vs_grid_mem,as_well_as_grid_mem,share_above_median,uniform_share,source\n",
    );
    let opt = |x: Option<f64>| x.map(|v| v.to_string()).unwrap_or_default();
    let num = |x: f64| if x.is_finite() { x.to_string() } else { String::new() };
    for x in &c.cells {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            x.task,
            x.learner,
            c.label,
            x.seeds,
            num(x.mean),
            num(x.std),
            x.marks,
            opt(x.p_vs_baseline),
            opt(x.p_vs_swap),
            num(x.baseline.0),
            num(x.baseline.1),
            num(x.swap.0),
            num(x.swap.1),
            opt(x.p_vs_grid_mem),
            x.as_well_as_grid.map_or("", AsWell::as_str),
            opt(x.share),
            opt(x.uniform),
            x.source.replace(',', ";")
        );
    }
    s
}

/// A share to three decimals, or to two significant digits when it is smaller than that shows:
/// uniform drawing's share on HandBlock-Z is 0.00046 (454 of 990,000 rows), which "0.000" would
/// hide, and a ratio to it (1000×) is the point of the column.
fn fmt_share(x: f64) -> String {
    let decimals = if x > 0.0 && x < 0.01 { (1.0 - x.log10().floor()) as usize } else { 3 };
    format!("{x:.decimals$}")
}

#[cfg(test)]
mod tests {
    #[test]
    fn small_shares_keep_two_significant_digits() {
        let f = super::fmt_share;
        assert_eq!([f(0.736), f(0.027), f(0.012), f(0.117)], ["0.736", "0.027", "0.012", "0.117"]);
        assert_eq!([f(0.000458), f(0.0091), f(0.0), f(1.0)], ["0.00046", "0.0091", "0.000", "1.000"]);
    }
}
