//! Fig. 5 and Table 1 of the paper: does the pre-trained critic's Q separate expert transitions
//! with their own goals (reachable: positives) from randomly goal-swapped transitions (mostly
//! unreachable: negatives)? PGSER's prioritized sampling is only as good as this separation.
//!
//! Inputs come from one scored table: its footer names the checkpoint that scored it and the
//! trajectory table β it came from. Positives are re-scored here with that checkpoint (the
//! scored table holds swapped goals, and own goals only with `--include-original`, so this works
//! for every scored table); negatives are the table's own `q` of its swapped rows, streamed four
//! columns at a time. Both sha256s are checked against the footer so the figure cannot silently
//! mix a retrained checkpoint with old scores.
//!
//! Table 1 comes twice (see [`super::negatives`]): with the paper's negatives, swapped rows of
//! the whole table, and with controlled ones, swapped rows of the positive transitions
//! themselves. The first is what the paper reports; the second removes what the first owes to
//! telling expert (s, a) from random (s, a), leaving what Q knows about the goal.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use serde::Serialize;

use super::classify::{ClassifierScore, classify};
use super::negatives::{Negatives, negatives};
use super::plot::{self, HistSeries, PALETTE};
use super::share::{PriorityShares, ShareCounter, median, shares_markdown};
use super::{FIG_SIZE, ensure_dir, write_text};
use crate::agent::{Backend, checkpoint};
use crate::nprandom::NpRandom;
use crate::sampler::priority::PriorityConfig;
use crate::score::{self, Q_BATCH};
use crate::trajectory::{self, Episodes};

/// Bins of Fig. 5 over [−1/(1−γ), 0].
pub const HIST_BINS: usize = 50;
/// Spawn key of the positives' subsample under the report's seed (2, 3 and 4: the negatives'
/// samples and the classifiers' split).
const STREAM_POSITIVES: u64 = 1;

#[derive(Debug, Clone)]
pub struct QReportOptions {
    /// A transition table from `pgser-etl score`.
    pub scored: PathBuf,
    /// Where fig5_q_hist.png, table1.md and table1.json go (created if missing).
    pub out_dir: PathBuf,
    /// Positives come from the first N episodes of β; None: the first source's episodes when β
    /// was converted from ≥ 2 files (expert first, as in GoFAR's mixes).
    pub positive_episodes: Option<usize>,
    /// Held-out fraction of the (shuffled) samples for the classifiers' accuracy.
    pub test_fraction: f64,
    /// At most this many samples per class (seeded subsample).
    pub max_samples: usize,
    /// At most this many training rows for the SVC. Kernel SVMs cost O(n²) and more in the
    /// training set, and most when the classes overlap (every point becomes a support vector):
    /// 2000 overlapping rows take ≈ 12 s on one core, well separated ones well under 1 s.
    pub svm_max_train: usize,
    pub seed: u64,
    /// Priority settings whose share of draws above the own-goal median the report gives
    /// ([`super::share`]): the `-mem` arms' (the pipeline passes them), `q` at α = 1 by default.
    pub priorities: Vec<PriorityConfig>,
}

impl Default for QReportOptions {
    fn default() -> Self {
        QReportOptions {
            scored: PathBuf::new(),
            out_dir: PathBuf::from("."),
            positive_episodes: None,
            test_fraction: 0.3,
            max_samples: 20_000,
            svm_max_train: 2_000,
            seed: 0,
            priorities: vec![PriorityConfig::default()],
        }
    }
}

/// What `q_report` found and wrote (`--json` prints it; table1.json holds it).
#[derive(Debug, Clone, Serialize)]
pub struct QReport {
    pub task: String,
    /// The scored table the report is about.
    pub scored: PathBuf,
    /// Episodes of β whose transitions are the positives.
    pub positive_episodes: usize,
    pub positives: usize,
    pub negatives: usize,
    /// Swapped rows in the scored table (the negatives are drawn from these).
    pub negatives_available: usize,
    pub positive_q_mean: f64,
    pub negative_q_mean: f64,
    pub gamma: f64,
    /// The paper's Table 1: negatives drawn from all swapped rows.
    pub classifiers: Vec<ClassifierScore>,
    /// Table 1 with controlled negatives: the positive transitions with swapped goals.
    pub controlled: ControlledTable1,
    /// How much of each priority setting's draws lies above the positives' median Q.
    pub priority: PriorityShares,
    /// Fig. 5's two histograms as drawn, so a figure across tasks (`pgser-etl fig5`) is drawn
    /// from the reports' table1.json alone, without their scored tables and checkpoints.
    pub fig5_hist: Fig5Hist,
    pub fig5: PathBuf,
    pub table1_md: PathBuf,
    pub json: PathBuf,
}

/// Fig. 5's histograms: [`HIST_BINS`] densities of Q over [lo, hi] for the positives (own goals)
/// and the paper's negatives (random goal swaps); [lo, hi] is where their Q lie
/// ([`plot::fitted_range`]), inside Q's range [−1/(1−γ), 0] unless the critic overshoots it.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct Fig5Hist {
    pub lo: f64,
    pub hi: f64,
    pub positives: Vec<f64>,
    pub negatives: Vec<f64>,
}

/// Table 1 with controlled negatives (the `controlled` key of table1.json): one swapped row of
/// each positive transition, so positives and negatives share every (s, a) and differ in the
/// goal alone. Same positives, classifiers, seed and split as the paper's table.
#[derive(Debug, Clone, Serialize)]
pub struct ControlledTable1 {
    pub negatives: usize,
    /// Swapped rows of the positive transitions (the negatives are drawn from these).
    pub negatives_available: usize,
    pub negative_q_mean: f64,
    pub classifiers: Vec<ClassifierScore>,
}

/// Both Table 1s for positives already scored, before anything is written.
#[derive(Debug, Clone)]
pub struct Table1 {
    pub negatives: Negatives,
    /// The priority shares of `o.priorities` over the same pass.
    pub shares: PriorityShares,
    /// Classifiers of positives vs the paper's negatives.
    pub paper: Vec<ClassifierScore>,
    /// Classifiers of positives vs the controlled negatives.
    pub controlled: Vec<ClassifierScore>,
}

/// Draws both sets of negatives from `scored` for the positive transitions `keys` (episode,
/// step; strictly increasing) whose Q is `positives`, as many of each as there are positives,
/// and runs the classifiers on each with `o`'s seed, split and SVC size.
/// `gamma` is the critic's discount (the `q` priorities' scale).
pub fn table1(scored: &Path, positives: &[f64], keys: &[(i64, i32)], gamma: f64, o: &QReportOptions) -> Result<Table1> {
    if positives.len() != keys.len() {
        bail!("{}: {} positive Q values for {} transitions", scored.display(), positives.len(), keys.len());
    }
    let mut shares = ShareCounter::new(median(positives), gamma, &o.priorities)?;
    let negatives = negatives(scored, keys, positives.len(), o.seed, &mut |q| shares.add(q))?;
    let paper = classify(positives, &negatives.paper, o.test_fraction, o.svm_max_train, o.seed)?;
    let controlled = classify(positives, &negatives.controlled, o.test_fraction, o.svm_max_train, o.seed)?;
    Ok(Table1 { negatives, shares: shares.finish(), paper, controlled })
}

/// Writes `out_dir/fig5_q_hist.png`, `out_dir/table1.md` and `out_dir/table1.json`.
pub fn q_report(o: &QReportOptions) -> Result<QReport> {
    if !(o.test_fraction > 0.0 && o.test_fraction < 1.0) {
        bail!("test fraction {} must lie strictly between 0 and 1", o.test_fraction);
    }
    if o.max_samples < 10 {
        bail!("max samples {} per class is too few to train and test classifiers (at least 10)", o.max_samples);
    }
    let footer = score::read_footer(&o.scored)?;

    // The checkpoint and β, as the footer recorded them.
    let ckpt = footer.checkpoint_file(&o.scored);
    check_sha(&ckpt, &footer.checkpoint.sha256, &o.scored, "checkpoint")?;
    let beta = footer.source_table(&o.scored);
    check_sha(&beta, &footer.source.sha256, &o.scored, "source table")?;
    let beta_footer = trajectory::folder::footer(&beta)?;
    let episodes = positive_episodes(o.positive_episodes, &beta_footer, &beta)?;

    // Positives: (o, u) of the first episodes with their own desired goals, scored now.
    let (agent, _) = checkpoint::load(&ckpt, Backend::Cpu.device()?)?;
    let data = Episodes::load(&beta)?;
    let t1 = data.t - 1;
    let mut rng = NpRandom::spawned(o.seed, &[STREAM_POSITIVES]);
    let chosen = sample_indices(episodes * t1, o.max_samples, &mut rng);
    let positives = positive_q(&agent, &data, &chosen);
    // Sorted indices give increasing (episode, step), as `negatives` needs.
    let keys: Vec<(i64, i32)> = chosen
        .iter()
        .map(|&i| {
            let (e, s) = data.transition(i);
            (e as i64, s as i32)
        })
        .collect();
    drop(data);
    if let Some(v) = positives.iter().find(|v| !v.is_finite()) {
        bail!("{}: the critic gives Q = {v} on {}; the checkpoint is damaged", ckpt.display(), beta.display());
    }

    // Negatives: the table's q of its swapped rows, as many as positives, both ways.
    let t = table1(&o.scored, &positives, &keys, footer.gamma, o)?;
    let negatives = &t.negatives.paper;

    ensure_dir(&o.out_dir)?;
    let fig5 = o.out_dir.join("fig5_q_hist.png");
    let (lo, hi) = plot::fitted_range(&[&positives, negatives], (-1.0 / (1.0 - footer.gamma), 0.0));
    plot::density_histograms(
        &fig5,
        FIG_SIZE,
        &format!("{}: Q of own vs swapped goals", footer.task),
        "Q(s, g, a)",
        "density",
        (lo, hi),
        HIST_BINS,
        &[
            HistSeries {
                label: format!("expert, own goal (n={})", positives.len()),
                values: &positives,
                color: PALETTE[0],
            },
            HistSeries {
                label: format!("random goal swap (n={})", negatives.len()),
                values: negatives,
                color: PALETTE[1],
            },
        ],
    )?;

    let table1_md = o.out_dir.join("table1.md");
    let json = o.out_dir.join("table1.json");
    let report = QReport {
        task: footer.task.clone(),
        scored: o.scored.clone(),
        positive_episodes: episodes,
        positives: positives.len(),
        negatives: negatives.len(),
        negatives_available: t.negatives.paper_available,
        positive_q_mean: mean(&positives),
        negative_q_mean: mean(negatives),
        gamma: footer.gamma,
        classifiers: t.paper,
        controlled: ControlledTable1 {
            negatives: t.negatives.controlled.len(),
            negatives_available: t.negatives.controlled_available,
            negative_q_mean: mean(&t.negatives.controlled),
            classifiers: t.controlled,
        },
        priority: t.shares,
        fig5_hist: Fig5Hist {
            lo,
            hi,
            positives: plot::densities(&positives, lo, hi, HIST_BINS),
            negatives: plot::densities(negatives, lo, hi, HIST_BINS),
        },
        fig5,
        table1_md,
        json,
    };
    write_text(&report.table1_md, &table1_markdown(&report))?;
    write_text(&report.json, &(serde_json::to_string_pretty(&report)? + "\n"))?;
    Ok(report)
}

/// Table 1 as markdown: the positives, then the paper's table and the controlled one, each with
/// its negatives' counts and Q mean, and a sentence on what their difference means.
pub fn table1_markdown(r: &QReport) -> String {
    let c = &r.controlled;
    let mut s = format!("# Table 1: {} — separating own goals from swapped goals by Q\n\n", r.task);
    s += &format!(
        "Positives: {} transitions of the first {} episodes with their own goals (mean Q {:.3}). \
         Feature: Q(s, g, a) only.\n\n",
        r.positives, r.positive_episodes, r.positive_q_mean
    );
    s += &format!(
        "## The paper's negatives: swapped rows of the whole table\n\n\
         Negatives: {} of {} randomly goal-swapped rows (mean Q {:.3}).\n\n",
        r.negatives, r.negatives_available, r.negative_q_mean
    );
    s += &classifier_table(&r.classifiers);
    s += &format!(
        "\n## Controlled negatives: the same transitions with swapped goals\n\n\
         Negatives: {} rows, one per positive transition (same s, a; another goal), of the {} swapped rows of \
         those transitions (mean Q {:.3}).\n\n",
        c.negatives, c.negatives_available, c.negative_q_mean
    );
    s += &classifier_table(&c.classifiers);
    s += "\nThe paper's negatives are other transitions as well as other goals (in a mix of expert and random \
          data, mostly random-policy transitions), so its accuracy can come from the goal or from telling expert \
          (s, a) from random (s, a); the controlled negatives are the positives' own transitions with another goal, \
          so the controlled accuracy is what Q knows about the goal alone, and the gap between the two tables is \
          what the data source adds.\n";
    s += &shares_markdown(&r.priority);
    s
}

fn classifier_table(rows: &[ClassifierScore]) -> String {
    let mut s = String::from("| classifier | train | test | accuracy |\n|---|---:|---:|---:|\n");
    for c in rows {
        s += &format!("| {} | {} | {} | {:.4} |\n", c.name, c.train, c.test, c.accuracy);
    }
    s
}

/// A path from a footer, relative to the scored table's folder (as `Footer::source_table`).
fn check_sha(file: &Path, want: &str, scored: &Path, what: &str) -> Result<()> {
    // A table folder's digest is its manifest's, as `score` recorded it.
    let got = trajectory::folder::digest(file)
        .with_context(|| format!("{}: the {what} of {}", file.display(), scored.display()))?;
    if got != want {
        bail!(
            "{}: sha256 {got} differs from the {want} recorded in {}; the {what} changed since scoring (re-score it)",
            file.display(),
            scored.display()
        );
    }
    Ok(())
}

fn positive_episodes(given: Option<usize>, f: &trajectory::Footer, beta: &Path) -> Result<usize> {
    let n = match given {
        Some(n) => n,
        None if f.sources.len() >= 2 => f.sources[0].episodes_taken,
        None => bail!(
            "{}: made from {} source file(s), so which episodes are expert is unknown; pass --positive-episodes N",
            beta.display(),
            f.sources.len()
        ),
    };
    if n == 0 || n > f.episodes {
        bail!("{}: {n} positive episodes asked for, but the table holds {}", beta.display(), f.episodes);
    }
    Ok(n)
}

/// All of `0..n` when n ≤ k, else k of them drawn without replacement (sorted, for locality).
fn sample_indices(n: usize, k: usize, rng: &mut NpRandom) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..n).collect();
    if n > k {
        // Partial Fisher–Yates: the first k entries become a uniform sample.
        for i in 0..k {
            let j = i + rng.below(n - i);
            idx.swap(i, j);
        }
        idx.truncate(k);
        idx.sort_unstable();
    }
    idx
}

/// min(Q1, Q2)(o, g, u) of the chosen transitions, `Q_BATCH` per critic call.
fn positive_q(agent: &crate::agent::Agent, data: &Episodes, chosen: &[usize]) -> Vec<f64> {
    let mut q = Vec::with_capacity(chosen.len());
    for block in chosen.chunks(Q_BATCH) {
        let (mut obs, mut goal, mut act) = (Vec::new(), Vec::new(), Vec::new());
        for &i in block {
            let (e, s) = data.transition(i);
            obs.extend_from_slice(data.obs(e, s));
            goal.extend_from_slice(data.goal(e, s));
            act.extend_from_slice(data.action(e, s));
        }
        q.extend(agent.q(&obs, &goal, &act, block.len()).into_iter().map(f64::from));
    }
    q
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn index_samples_are_unique_and_in_range() {
        let mut rng = NpRandom::new(1);
        let s = sample_indices(1000, 100, &mut rng);
        assert_eq!(s.len(), 100);
        assert!(s.windows(2).all(|w| w[0] < w[1]) && *s.last().unwrap() < 1000);
        assert_eq!(sample_indices(5, 100, &mut rng), vec![0, 1, 2, 3, 4]);
    }
}
