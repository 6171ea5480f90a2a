//! The two spreads of a Table 2 cell, and the per-run scores file both are recomputed from.
//!
//! A cell is a few seeds, each evaluated on E episodes. Its spread can be the std of the seeds'
//! mean scores (n = seeds: the runs are the independent replicates, and pgser's marks test
//! this), or the std of all seeds × E episode scores pooled (n = seeds × E: what the paper's
//! ± 11–37 most likely is; it does not say). The second needs more than the seeds' means: each
//! run's evaluation reports its episodes' mean and std (`EvalReport::return_std`, over episodes,
//! n not n − 1), and those two with the count give the pooled std exactly, since the pooled sum
//! of squares is each run's own sum of squares plus its count times its mean's squared distance
//! from the grand mean. So a run's (episodes, mean, std) is as good as its episode scores, and a
//! row per episode (episodes 1, std 0) is the special case.
//!
//! `scores.csv`, which a pipeline's results step writes beside `results.csv`, holds those rows:
//! `task,algo,variant,seed,episodes,paper_score,episode_std`, a row per run (or finer). Without
//! the `episodes` and `episode_std` columns each row is one episode's score.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Result, anyhow, bail};
use polars::prelude::DataType;

use crate::query::first_line;

/// A block of evaluation episodes: how many, their mean score, and their std (over the block's
/// episodes, n not n − 1; 0 for one episode).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Block {
    pub episodes: usize,
    pub mean: f64,
    pub std: f64,
}

/// All episodes of some blocks taken as one sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pooled {
    pub episodes: usize,
    pub mean: f64,
    /// Sample std (n − 1) over the pooled episodes; NaN for one episode.
    pub std: f64,
}

/// The blocks' episodes pooled: exact, whatever the blocks' sizes (see the module's note).
pub fn pool(blocks: &[Block]) -> Option<Pooled> {
    let n: usize = blocks.iter().map(|b| b.episodes).sum();
    if n == 0 {
        return None;
    }
    let mean = blocks.iter().map(|b| b.episodes as f64 * b.mean).sum::<f64>() / n as f64;
    let ss: f64 = blocks.iter().map(|b| b.episodes as f64 * (b.std * b.std + (b.mean - mean) * (b.mean - mean))).sum();
    let std = if n < 2 { f64::NAN } else { (ss / (n - 1) as f64).sqrt() };
    // Round-off is not spread (as in welch::mean_std): constant scores have std 0.
    let std = if std < 1e-12 * mean.abs().max(1.0) { 0.0 } else { std };
    Some(Pooled { episodes: n, mean, std })
}

/// One row of scores.csv: a run's final evaluation (or a part of it).
#[derive(Debug, Clone, PartialEq)]
pub struct ScoreRow {
    pub task: String,
    pub algo: String,
    pub variant: String,
    pub seed: u64,
    pub block: Block,
}

/// The header of scores.csv.
pub const SCORES_HEADER: &str = "task,algo,variant,seed,episodes,paper_score,episode_std";

/// scores.csv's text.
pub fn scores_csv(rows: &[ScoreRow]) -> String {
    let mut s = format!("{SCORES_HEADER}\n");
    for r in rows {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{}",
            r.task, r.algo, r.variant, r.seed, r.block.episodes, r.block.mean, r.block.std
        );
    }
    s
}

/// A cell of scores.csv: its (task, algo, variant), the seeds' mean scores in seed order, and
/// every episode pooled; `line` is the file line of its first row (for errors).
#[derive(Debug, Clone)]
pub struct ScoreCell {
    pub task: String,
    pub algo: String,
    pub variant: String,
    pub seed_means: Vec<f64>,
    pub pooled: Pooled,
    pub line: usize,
}

/// The cells of a scores.csv, in the order of their first rows.
pub fn read_scores(path: &Path) -> Result<Vec<ScoreCell>> {
    let at = path.display();
    let df = crate::query::scan(path)?.collect().map_err(|e| anyhow!("{at}: {}", first_line(&e)))?;
    let has = |name: &str| df.column(name).is_ok();
    let column = |name: &str, ty: DataType| {
        let c = df.column(name).map_err(|_| anyhow!("{at}: no column {name} (is it a scores.csv?)"))?;
        c.strict_cast(&ty).map_err(|_| anyhow!("{at}: column {name} holds something that is not a {ty}"))
    };
    let text = |name: &str| -> Result<Vec<Option<String>>> {
        Ok(column(name, DataType::String)?.str()?.iter().map(|v| v.map(str::to_string)).collect())
    };
    let float =
        |name: &str| -> Result<Vec<Option<f64>>> { Ok(column(name, DataType::Float64)?.f64()?.iter().collect()) };
    let (task, algo, variant) = (text("task")?, text("algo")?, text("variant")?);
    let (seed, score) = (float("seed")?, float("paper_score")?);
    // Without these columns, a row per episode.
    let episodes = if has("episodes") { float("episodes")? } else { vec![Some(1.0); df.height()] };
    let std = if has("episode_std") { float("episode_std")? } else { vec![Some(0.0); df.height()] };
    // Per cell: its first line, and (seed, block) in file order.
    type Cell = (String, String, String, usize, Vec<(u64, Block)>);
    let mut cells: Vec<Cell> = Vec::new();
    for i in 0..df.height() {
        let pos = format!("{at}:{}", i + 2);
        let field = |v: &Option<String>, name: &str| v.clone().ok_or_else(|| anyhow!("{pos}: no {name}"));
        let (t, a, v) = (field(&task[i], "task")?, field(&algo[i], "algo")?, field(&variant[i], "variant")?);
        let s = seed[i].filter(|s| *s >= 0.0 && s.fract() == 0.0).ok_or_else(|| anyhow!("{pos}: no seed"))?;
        let n = episodes[i]
            .filter(|n| *n >= 1.0 && n.fract() == 0.0)
            .ok_or_else(|| anyhow!("{pos}: episodes must be a count ≥ 1"))?;
        let m = score[i].filter(|x| x.is_finite()).ok_or_else(|| anyhow!("{pos}: paper_score is not a number"))?;
        let sd = std[i]
            .filter(|x| x.is_finite() && *x >= 0.0)
            .ok_or_else(|| anyhow!("{pos}: episode_std must be a finite std ≥ 0"))?;
        if n == 1.0 && sd != 0.0 {
            bail!("{pos}: one episode has no spread, but episode_std is {sd}");
        }
        let block = (s as u64, Block { episodes: n as usize, mean: m, std: sd });
        match cells.iter_mut().find(|c| (&c.0, &c.1, &c.2) == (&t, &a, &v)) {
            Some(c) => c.4.push(block),
            None => cells.push((t, a, v, i + 2, vec![block])),
        }
    }
    if cells.is_empty() {
        bail!("{at}: no rows (an empty scores.csv)");
    }
    Ok(cells
        .into_iter()
        .map(|(task, algo, variant, line, blocks)| {
            let mut seeds: Vec<u64> = blocks.iter().map(|b| b.0).collect();
            seeds.sort_unstable();
            seeds.dedup();
            let seed_means = seeds
                .iter()
                .map(|s| {
                    let mine: Vec<Block> = blocks.iter().filter(|b| b.0 == *s).map(|b| b.1).collect();
                    pool(&mine).expect("at least one episode").mean
                })
                .collect();
            let all: Vec<Block> = blocks.iter().map(|b| b.1).collect();
            ScoreCell { task, algo, variant, seed_means, pooled: pool(&all).expect("at least one episode"), line }
        })
        .collect())
}
