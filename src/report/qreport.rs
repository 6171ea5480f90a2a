//! Fig. 5 and Table 1 of the paper: does the pre-trained critic's Q separate expert transitions
//! with their own goals (reachable: positives) from randomly goal-swapped transitions (mostly
//! unreachable: negatives)? PGSER's prioritized sampling is only as good as this separation.
//!
//! Inputs come from one scored table: its footer names the checkpoint that scored it and the
//! trajectory table β it came from. Positives are re-scored here with that checkpoint (the
//! scored table holds swapped goals, and own goals only with `--include-original`, so this works
//! for every scored table); negatives are the table's own `q` of its swapped rows, streamed two
//! columns at a time. Both sha256s are checked against the footer so the figure cannot silently
//! mix a retrained checkpoint with old scores.

use std::fs::File;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int32Type};
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use serde::Serialize;
use smartcore::linalg::basic::matrix::DenseMatrix;
use smartcore::linear::logistic_regression::LogisticRegression;
use smartcore::naive_bayes::gaussian::{GaussianNB, GaussianNBParameters};
use smartcore::neighbors::knn_classifier::{KNNClassifier, KNNClassifierParameters};
use smartcore::svm::Kernels;
use smartcore::svm::svc::{SVC, SVCParameters};

use super::plot::{self, HistSeries, PALETTE};
use super::{FIG_SIZE, ensure_dir, write_text};
use crate::agent::{Backend, checkpoint};
use crate::env::rng::NpRandom;
use crate::output::sha256_file;
use crate::score::{self, Q_BATCH};
use crate::trajectory::{self, Episodes};

/// Bins of Fig. 5 over [−1/(1−γ), 0].
pub const HIST_BINS: usize = 50;
/// k of the k-NN classifier.
pub const KNN_K: usize = 5;
/// At most this many training rows for k-NN: prediction costs a neighbour search per test row,
/// and on one feature a few thousand neighbours already pin the decision boundary.
pub const KNN_MAX_TRAIN: usize = 5_000;
/// Spawn keys of the report's random streams under `seed`.
const STREAM_POSITIVES: u64 = 1;
const STREAM_NEGATIVES: u64 = 2;
const STREAM_SPLIT: u64 = 3;

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
        }
    }
}

/// One classifier's held-out accuracy at telling positives (1) from negatives (0) by Q alone.
#[derive(Debug, Clone, Serialize)]
pub struct ClassifierScore {
    pub name: String,
    pub train: usize,
    pub test: usize,
    pub accuracy: f64,
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
    pub classifiers: Vec<ClassifierScore>,
    pub fig5: PathBuf,
    pub table1_md: PathBuf,
    pub json: PathBuf,
}

/// Writes `out_dir/fig5_q_hist.png`, `out_dir/table1.md` and `out_dir/table1.json`.
pub fn q_report(o: &QReportOptions) -> Result<QReport> {
    if !(o.test_fraction > 0.0 && o.test_fraction < 1.0) {
        bail!("test fraction {} must lie strictly between 0 and 1", o.test_fraction);
    }
    if o.max_samples < 10 {
        bail!("max samples {} per class is too few to train and test classifiers (at least 10)", o.max_samples);
    }
    let at = o.scored.display();
    let footer = score::read_footer(&o.scored)?;

    // The checkpoint and β, as the footer recorded them.
    let ckpt = footer.checkpoint_file(&o.scored);
    check_sha(&ckpt, &footer.checkpoint.sha256, &o.scored, "checkpoint")?;
    let beta = footer.source_table(&o.scored);
    check_sha(&beta, &footer.source.sha256, &o.scored, "source table")?;
    let beta_footer: trajectory::Footer = serde_json::from_value(crate::table::read_footer(&beta)?)
        .with_context(|| format!("{}: malformed trajectory footer", beta.display()))?;
    let episodes = positive_episodes(o.positive_episodes, &beta_footer, &beta)?;

    // Positives: (o, u) of the first episodes with their own desired goals, scored now.
    let (agent, _) = checkpoint::load(&ckpt, Backend::Cpu.device()?)?;
    let data = Episodes::load(&beta)?;
    let t1 = data.t - 1;
    let mut rng = NpRandom::spawned(o.seed, &[STREAM_POSITIVES]);
    let chosen = sample_indices(episodes * t1, o.max_samples, &mut rng);
    let positives = positive_q(&agent, &data, &chosen);
    drop(data);
    if let Some(v) = positives.iter().find(|v| !v.is_finite()) {
        bail!("{}: the critic gives Q = {v} on {}; the checkpoint is damaged", ckpt.display(), beta.display());
    }

    // Negatives: the table's q of its swapped rows, as many as positives.
    let (negatives, available) = negative_q(&o.scored, positives.len(), o.seed)?;
    if negatives.is_empty() {
        bail!("{at}: no goal-swapped rows (goal_step >= 0); score with --swaps of at least 1");
    }

    ensure_dir(&o.out_dir)?;
    let fig5 = o.out_dir.join("fig5_q_hist.png");
    let lo = -1.0 / (1.0 - footer.gamma);
    plot::density_histograms(
        &fig5,
        FIG_SIZE,
        &format!("{}: Q of own vs swapped goals", footer.task),
        "Q(s, g, a)",
        "density",
        (lo, 0.0),
        HIST_BINS,
        &[
            HistSeries {
                label: format!("expert, own goal (n={})", positives.len()),
                values: &positives,
                color: PALETTE[0],
            },
            HistSeries {
                label: format!("random goal swap (n={})", negatives.len()),
                values: &negatives,
                color: PALETTE[1],
            },
        ],
    )?;

    let classifiers = classify(&positives, &negatives, o.test_fraction, o.svm_max_train, o.seed)?;
    let table1_md = o.out_dir.join("table1.md");
    let json = o.out_dir.join("table1.json");
    let report = QReport {
        task: footer.task.clone(),
        scored: o.scored.clone(),
        positive_episodes: episodes,
        positives: positives.len(),
        negatives: negatives.len(),
        negatives_available: available,
        positive_q_mean: mean(&positives),
        negative_q_mean: mean(&negatives),
        gamma: footer.gamma,
        classifiers,
        fig5,
        table1_md,
        json,
    };
    write_text(&report.table1_md, &table1_markdown(&report))?;
    write_text(&report.json, &(serde_json::to_string_pretty(&report)? + "\n"))?;
    Ok(report)
}

/// Table 1 as markdown: class counts and Q means, then one row per classifier.
pub fn table1_markdown(r: &QReport) -> String {
    let mut s = format!("# Table 1: {} — separating own goals from swapped goals by Q\n\n", r.task);
    s += &format!(
        "Positives: {} transitions of the first {} episodes with their own goals (mean Q {:.3}).  \n\
         Negatives: {} of {} randomly goal-swapped rows (mean Q {:.3}). Feature: Q(s, g, a) only.\n\n",
        r.positives, r.positive_episodes, r.positive_q_mean, r.negatives, r.negatives_available, r.negative_q_mean
    );
    s += "| classifier | train | test | accuracy |\n|---|---:|---:|---:|\n";
    for c in &r.classifiers {
        s += &format!("| {} | {} | {} | {:.4} |\n", c.name, c.train, c.test, c.accuracy);
    }
    s
}

/// A path from a footer, relative to the scored table's folder (as `Footer::source_table`).
fn check_sha(file: &Path, want: &str, scored: &Path, what: &str) -> Result<()> {
    let got = sha256_file(file).with_context(|| format!("{}: the {what} of {}", file.display(), scored.display()))?;
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

/// Reservoir sample (Algorithm R) of `k` q values of the rows with goal_step ≥ 0, reading only
/// those two columns; also returns how many such rows there are.
fn negative_q(scored: &Path, k: usize, seed: u64) -> Result<(Vec<f64>, usize)> {
    let at = scored.display();
    let file = File::open(scored).with_context(|| format!("{at}: cannot open"))?;
    let b = ParquetRecordBatchReaderBuilder::try_new(file).with_context(|| format!("{at}: not a Parquet file"))?;
    let mask = ProjectionMask::columns(b.parquet_schema(), ["goal_step", "q"]);
    let reader =
        b.with_projection(mask).with_batch_size(65_536).build().with_context(|| format!("{at}: cannot read"))?;
    let mut rng = NpRandom::spawned(seed, &[STREAM_NEGATIVES]);
    let mut sample = Vec::with_capacity(k);
    let mut seen = 0usize;
    for batch in reader {
        let batch = batch.with_context(|| format!("{at}: cannot read columns goal_step, q"))?;
        let gs = batch
            .column_by_name("goal_step")
            .and_then(|c| c.as_primitive_opt::<Int32Type>())
            .with_context(|| format!("{at}: no int32 column goal_step"))?;
        let q = batch
            .column_by_name("q")
            .and_then(|c| c.as_primitive_opt::<Float32Type>())
            .with_context(|| format!("{at}: no float32 column q"))?;
        for (g, v) in gs.values().iter().zip(q.values().iter()) {
            if *g < 0 {
                continue;
            }
            if !v.is_finite() {
                bail!("{at}: row with q = {v}; the table is damaged");
            }
            if sample.len() < k {
                sample.push(f64::from(*v));
            } else {
                let j = rng.below(seen + 1);
                if j < k {
                    sample[j] = f64::from(*v);
                }
            }
            seen += 1;
        }
    }
    Ok((sample, seen))
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Trains the four classifiers on a seeded shuffle-split of (q, label) and scores each on the
/// held-out part.
///
/// The feature is standardized with the training part's mean and std: the accuracy of all four
/// is invariant to that, but logistic regression's optimiser and the RBF kernel's width
/// (γ = 1, scikit-learn's `gamma="scale"` for one standardized feature) are not. The SVC uses
/// an RBF kernel rather than a linear one because Q need not be monotone in "reachability"
/// everywhere (the positives sit in a band near 0, and a band is what an RBF can carve out).
pub(crate) fn classify(
    positives: &[f64],
    negatives: &[f64],
    test_fraction: f64,
    svm_max_train: usize,
    seed: u64,
) -> Result<Vec<ClassifierScore>> {
    let mut rows: Vec<(f64, u32)> =
        positives.iter().map(|&q| (q, 1)).chain(negatives.iter().map(|&q| (q, 0))).collect();
    let mut rng = NpRandom::spawned(seed, &[STREAM_SPLIT]);
    for i in (1..rows.len()).rev() {
        let j = rng.below(i + 1);
        rows.swap(i, j);
    }
    let n_test = ((rows.len() as f64) * test_fraction).round() as usize;
    let (test, train) = rows.split_at(n_test.min(rows.len()));
    for (part, name) in [(train, "training"), (test, "test")] {
        let pos = part.iter().filter(|r| r.1 == 1).count();
        if pos == 0 || pos == part.len() {
            bail!(
                "the {name} split holds {} rows of only one class ({} positives, {} negatives in all); more samples are needed",
                part.len(),
                positives.len(),
                negatives.len()
            );
        }
    }
    let m = train.iter().map(|r| r.0).sum::<f64>() / train.len() as f64;
    let sd = (train.iter().map(|r| (r.0 - m).powi(2)).sum::<f64>() / train.len() as f64).sqrt();
    let sd = if sd > 0.0 { sd } else { 1.0 };
    let matrix = |part: &[(f64, u32)]| -> Result<(DenseMatrix<f64>, Vec<u32>)> {
        let x = DenseMatrix::new(part.len(), 1, part.iter().map(|r| (r.0 - m) / sd).collect(), true)
            .map_err(|e| anyhow!("{e}"))?;
        Ok((x, part.iter().map(|r| r.1).collect()))
    };
    let (x_test, y_test) = matrix(test)?;
    let accuracy = |pred: &[f64]| {
        pred.iter().zip(&y_test).filter(|(p, y)| (**p - f64::from(**y)).abs() < 0.5).count() as f64
            / y_test.len() as f64
    };
    let accuracy_u =
        |pred: &[u32]| pred.iter().zip(&y_test).filter(|(p, y)| p == y).count() as f64 / y_test.len() as f64;
    fn fail(name: &'static str) -> impl Fn(smartcore::error::Failed) -> anyhow::Error {
        move |e| anyhow!("{name}: {e}")
    }
    let mut out = Vec::new();

    let (x, y) = matrix(train)?;
    let lr = LogisticRegression::fit(&x, &y, Default::default()).map_err(fail("logistic regression"))?;
    let pred: Vec<u32> = lr.predict(&x_test).map_err(fail("logistic regression"))?;
    out.push(score("logistic regression", train.len(), test.len(), accuracy_u(&pred)));

    let nb = GaussianNB::fit(&x, &y, GaussianNBParameters::default()).map_err(fail("Gaussian naive Bayes"))?;
    let pred: Vec<u32> = nb.predict(&x_test).map_err(fail("Gaussian naive Bayes"))?;
    out.push(score("Gaussian naive Bayes", train.len(), test.len(), accuracy_u(&pred)));

    // The training split is already a uniform shuffle, so its head is a uniform subsample.
    let knn_train = &train[..train.len().min(KNN_MAX_TRAIN)];
    let (x, y) = matrix(knn_train)?;
    let knn = KNNClassifier::fit(&x, &y, KNNClassifierParameters::default().with_k(KNN_K)).map_err(fail("k-NN"))?;
    let pred: Vec<u32> = knn.predict(&x_test).map_err(fail("k-NN"))?;
    out.push(score(&format!("k-NN (k={KNN_K})"), knn_train.len(), test.len(), accuracy_u(&pred)));

    let svm_train = &train[..train.len().min(svm_max_train.max(2))];
    if svm_train.iter().all(|r| r.1 == svm_train[0].1) {
        bail!("SVC: its {} training rows hold one class only; raise the SVM training size", svm_train.len());
    }
    let (x, y) = matrix(svm_train)?;
    let params = SVCParameters::default().with_c(1.0).with_kernel(Kernels::rbf().with_gamma(1.0)).with_seed(Some(seed));
    let svc = SVC::fit(&x, &y, &params).map_err(fail("SVC"))?;
    let pred = svc.predict(&x_test).map_err(fail("SVC"))?;
    out.push(score("SVC (RBF, C=1, γ=1)", svm_train.len(), test.len(), accuracy(&pred)));
    Ok(out)
}

fn score(name: &str, train: usize, test: usize, accuracy: f64) -> ClassifierScore {
    ClassifierScore { name: name.to_string(), train, test, accuracy }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Q of positives around −1, negatives around −30: every classifier must separate them.
    #[test]
    fn separable_q_is_classified_almost_perfectly() {
        let mut rng = NpRandom::new(7);
        let pos: Vec<f64> = (0..1500).map(|_| -1.0 + 0.5 * rng.standard_normal()).collect();
        let neg: Vec<f64> = (0..1500).map(|_| -30.0 + 5.0 * rng.standard_normal()).collect();
        let scores = classify(&pos, &neg, 0.3, 500, 3).unwrap();
        assert_eq!(scores.len(), 4);
        for s in &scores {
            assert!(s.accuracy > 0.95, "{}: accuracy {}", s.name, s.accuracy);
            assert_eq!(s.test, 900);
        }
        assert_eq!(scores.iter().find(|s| s.name.starts_with("SVC")).unwrap().train, 500);
    }

    /// Identical distributions: no classifier can beat chance by much (guards against a leak of
    /// the labels into the features).
    #[test]
    fn indistinguishable_q_gives_chance_accuracy() {
        let mut rng = NpRandom::new(8);
        let pos: Vec<f64> = (0..1000).map(|_| rng.standard_normal()).collect();
        let neg: Vec<f64> = (0..1000).map(|_| rng.standard_normal()).collect();
        for s in classify(&pos, &neg, 0.3, 500, 3).unwrap() {
            assert!(s.accuracy < 0.62, "{}: accuracy {}", s.name, s.accuracy);
        }
    }

    #[test]
    fn index_samples_are_unique_and_in_range() {
        let mut rng = NpRandom::new(1);
        let s = sample_indices(1000, 100, &mut rng);
        assert_eq!(s.len(), 100);
        assert!(s.windows(2).all(|w| w[0] < w[1]) && *s.last().unwrap() < 1000);
        assert_eq!(sample_indices(5, 100, &mut rng), vec![0, 1, 2, 3, 4]);
    }
}
