//! Table 1's negatives, under two definitions, from one pass over a scored table.
//!
//! - **The paper's**: a uniform sample of all goal-swapped rows (`goal_step >= 0`). In GoFAR's
//!   data mixes most rows are random-policy transitions (2000 of 2500 episodes), so these
//!   negatives differ from the expert positives in the transition (s, a) as well as in the goal,
//!   and a classifier on Q can score partly by telling expert data from random data.
//! - **Controlled**: for each positive transition, one of its own swapped rows: the same episode
//!   and step (the same s, a), another goal. Positives and negatives then differ only in the
//!   goal, so the accuracy measures how much Q depends on whether the goal is the transition's
//!   own, which is what PGSER's prioritized sampling relies on.
//!
//! Only the columns episode, step, goal_step and q are read; both samples come from the same
//! stream of rows, each with its own seeded random stream, so the paper's sample is the one the
//! report drew before the controlled one existed.

use std::path::Path;

use anyhow::{Context, Result, bail};
use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int32Type, Int64Type};
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;

use crate::nprandom::NpRandom;

/// Spawn keys of the two samples under the report's seed (1 and 3 are the positives' subsample
/// and the classifiers' train/test split).
const STREAM_NEGATIVES: u64 = 2;
const STREAM_CONTROLLED: u64 = 4;

/// Q of the negatives of Table 1 under both definitions.
#[derive(Debug, Clone, PartialEq)]
pub struct Negatives {
    /// The paper's: q of `k` swapped rows drawn uniformly from all of them (all when fewer).
    pub paper: Vec<f64>,
    /// Swapped rows in the table (what `paper` is drawn from).
    pub paper_available: usize,
    /// Controlled: `controlled[i]` is q of one swapped row of the positive transition `keys[i]`
    /// (the same episode and step), drawn uniformly among that transition's swapped rows.
    pub controlled: Vec<f64>,
    /// Swapped rows of the positive transitions (what `controlled` is drawn from).
    pub controlled_available: usize,
}

/// Reads `scored` once and draws both samples. `keys` are the positive transitions as (episode,
/// step), strictly increasing; every one must have at least one swapped row in the table.
/// `each_q` sees every row's q in table order (the priority shares, [`super::share`], come from
/// the same pass).
pub fn negatives(
    scored: &Path,
    keys: &[(i64, i32)],
    k: usize,
    seed: u64,
    each_q: &mut dyn FnMut(f64),
) -> Result<Negatives> {
    let at = scored.display();
    if let Some(w) = keys.windows(2).find(|w| w[0] >= w[1]) {
        bail!("{at}: positive transitions out of order at (episode {}, step {}); they must increase", w[1].0, w[1].1);
    }
    let file = crate::output::open_input(scored)?;
    let b = ParquetRecordBatchReaderBuilder::try_new(file).with_context(|| format!("{at}: not a Parquet file"))?;
    let verifier = crate::table::Verifier::new(scored, b.metadata())?;
    verifier.check(&verifier.columns_of(&["episode", "step", "goal_step", "q"]))?;
    let mask = ProjectionMask::columns(b.parquet_schema(), ["episode", "step", "goal_step", "q"]);
    let reader =
        b.with_projection(mask).with_batch_size(65_536).build().with_context(|| format!("{at}: cannot read"))?;
    let mut paper_rng = NpRandom::spawned(seed, &[STREAM_NEGATIVES]);
    let mut controlled_rng = NpRandom::spawned(seed, &[STREAM_CONTROLLED]);
    let mut paper = Vec::with_capacity(k);
    let mut paper_seen = 0usize;
    // Per positive: q of its chosen swapped row so far, and how many it has had.
    let mut controlled = vec![f64::NAN; keys.len()];
    let mut controlled_seen = vec![0usize; keys.len()];
    let last_episode = keys.last().map_or(-1, |k| k.0);
    let mut row = 0usize;
    for batch in reader {
        let batch = batch.with_context(|| format!("{at}: cannot read columns episode, step, goal_step, q"))?;
        let int64 = |name: &str| {
            batch
                .column_by_name(name)
                .and_then(|c| c.as_primitive_opt::<Int64Type>())
                .with_context(|| format!("{at}: no int64 column {name}"))
        };
        let int32 = |name: &str| {
            batch
                .column_by_name(name)
                .and_then(|c| c.as_primitive_opt::<Int32Type>())
                .with_context(|| format!("{at}: no int32 column {name}"))
        };
        let (episode, step, goal_step) = (int64("episode")?, int32("step")?, int32("goal_step")?);
        let q = batch
            .column_by_name("q")
            .and_then(|c| c.as_primitive_opt::<Float32Type>())
            .with_context(|| format!("{at}: no float32 column q"))?;
        for i in 0..batch.num_rows() {
            row += 1;
            let v = q.value(i);
            if !v.is_finite() {
                bail!("{at}: row {} has q = {v}; the table is damaged", row - 1);
            }
            let v = f64::from(v);
            each_q(v);
            if goal_step.value(i) < 0 {
                continue;
            }
            // Algorithm R over all swapped rows.
            if paper.len() < k {
                paper.push(v);
            } else {
                let j = paper_rng.below(paper_seen + 1);
                if j < k {
                    paper[j] = v;
                }
            }
            paper_seen += 1;
            // A reservoir of one per positive transition over its own swapped rows.
            let e = episode.value(i);
            if e > last_episode {
                continue;
            }
            if let Ok(p) = keys.binary_search(&(e, step.value(i))) {
                controlled_seen[p] += 1;
                if controlled_rng.below(controlled_seen[p]) == 0 {
                    controlled[p] = v;
                }
            }
        }
    }
    if paper_seen == 0 {
        bail!("{at}: no goal-swapped rows (goal_step >= 0); score with --swaps of at least 1");
    }
    if let Some(p) = controlled_seen.iter().position(|&n| n == 0) {
        bail!(
            "{at}: the positive transition (episode {}, step {}) has no goal-swapped row; the table was not scored from \
             the source it names, or with --swaps 0",
            keys[p].0,
            keys[p].1
        );
    }
    Ok(Negatives { paper, paper_available: paper_seen, controlled, controlled_available: controlled_seen.iter().sum() })
}
