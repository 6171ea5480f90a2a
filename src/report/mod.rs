//! The paper's evidence as files: Fig. 5 and Table 1 ([`q_report`]), Table 2 and training
//! curves ([`results`]).
//!
//! - **Fig. 5 / Table 1** ask whether the pre-trained critic tells reachable goals from
//!   unreachable ones, which is what PGSER's prioritized sampling relies on: Q of expert
//!   transitions with their own goals (positives) against Q of randomly goal-swapped transitions
//!   (negatives, the `goal_step >= 0` rows of a scored table). The figure overlays the two
//!   densities; the table reports how well simple classifiers separate the classes from Q alone.
//!   A second, controlled Table 1 takes its negatives from the positive transitions themselves
//!   (same s, a; a swapped goal), so that only the goal tells the classes apart.
//! - **Table 2** collects the final evaluation of every training run (the last `eval` line of
//!   its metrics file), averages it over seeds per (task, algorithm, variant) and tests whether
//!   the `mem` variant differs from `baseline` and `swap` (Welch's t-test, unequal variances,
//!   since the variants' spreads over seeds differ), marking a significant difference ▲ or ▼ by
//!   its direction. Each cell also has the spread of its evaluation episodes pooled over seeds,
//!   and the same test over them ([`spread`]), the paper's likely terms; `table2` sets the
//!   paper's own values and marks beside pgser's ([`paper`]) and says where they agree ([`agree`]).
//!
//! Every file is written atomically (see [`crate::output`]); errors are one line naming the file.

mod agree;
mod cells;
mod chosen;
mod classify;
mod fig5;
mod measured;
mod negatives;
mod paper;
mod plot;
mod qreport;
mod results;
mod share;
mod spread;
mod study;
mod table2;
mod welch;

use std::io::Write;
use std::path::Path;

use anyhow::{Context, Result};

pub use chosen::{AsWell, Chosen, ChosenCell, ChosenOptions};
pub use classify::{ClassifierScore, classify};
pub use fig5::{Fig5All, Fig5Options, fig5_all};
pub use negatives::{Negatives, negatives};
pub use qreport::{ControlledTable1, Fig5Hist, QReport, QReportOptions, Table1, q_report, table1, table1_markdown};
pub use results::{ResultRow, Results, Run, results, results_markdown};
pub use share::{PriorityShares, Share, parse_setting};
pub use spread::{Block, Pooled, ScoreCell, pool, read_scores};
pub use study::{Study, StudyRow, study};
pub use table2::{Table2, Table2Cell, Table2Options, table2};
pub use welch::{ALPHA, BETTER, WORSE, welch_from_summary, welch_greater, welch_t_test};

/// Figure size in pixels: large enough for legible 14–16 px labels, small enough to embed.
pub const FIG_SIZE: (u32, u32) = (900, 600);

/// Writes `text` to `path` atomically.
fn write_text(path: &Path, text: &str) -> Result<()> {
    let f = crate::output::AtomicFile::create(path)?;
    f.handle()?.write_all(text.as_bytes()).with_context(|| format!("{}: write failed", path.display()))?;
    f.commit()
}

/// Creates the output folder (and its parents) if needed.
fn ensure_dir(dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("{}: cannot create the output folder", dir.display()))
}

/// A name safe in a file name: task names are already, but a `/` or space must not make a path.
fn file_safe(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect()
}

/// `x` with 3 decimals, or "n/a" when it is not a number (e.g. a std over one seed).
fn fmt3(x: f64) -> String {
    if x.is_finite() { format!("{x:.3}") } else { "n/a".to_string() }
}
