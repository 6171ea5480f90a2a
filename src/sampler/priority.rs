//! Priorities of scored (goal-swapped) transitions and drawing rows in proportion to them.
//!
//! PGSER ranks swapped transitions by the pre-trained critic's Q(s, g_rand, a): a high Q means
//! the goal looks reachable from s, which is what makes a swapped transition informative
//! (Alg. 2; docs/domain.md). Priorities are computed from the stored `q` column when the sampler is
//! built, so changing `--priority` or `--priority-alpha` never needs re-scoring.
//!
//! Why the default is `rank` and not the paper's literal `q` at α = 1 (docs/domain.md has the
//! numbers): a Q pre-trained on a CPU's budget puts the swapped rows' values in a narrow band, so
//! proportional priorities on them are nearly flat and `-mem` samples almost like `-swap`; ranks
//! do not depend on that scale. `--priority q` keeps the paper's reading.

use anyhow::{Result, bail};
use clap::{Args, ValueEnum};
use serde::{Deserialize, Serialize};

use crate::nprandom::NpRandom;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum PriorityKind {
    /// p = (clip(q, q_lo, 0) − q_lo + ε)^α with q_lo = −1/(1−γ): Q's shift to [ε, 1/(1−γ) + ε],
    /// proportional prioritization (Schaul et al. 2016) on that scale.
    Q,
    /// p = 1 / rank^α, rank 1 for the highest Q (Schaul et al.'s rank-based variant): insensitive
    /// to the scale and outliers of Q.
    Rank,
    /// p = 1: uniform over the swapped rows (an ablation: swapping without prioritization).
    Uniform,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Args)]
pub struct PriorityConfig {
    /// How priorities are derived from the scored rows' q. rank is the default since pgser 0.4, in
    /// place of q (the paper's reading): a Q trained as briefly as a CPU affords spans a narrow band
    /// of values, so q barely prefers the rows it calls reachable and -mem draws almost like -swap;
    /// rank depends only on Q's order, not its scale. The measurements behind this, kept current:
    /// docs/domain.md, "Why rank is the default"
    #[arg(long, value_enum, default_value = "rank")]
    pub priority: PriorityKind,
    /// Exponent α of the priorities (0: uniform; larger: greedier).
    #[arg(long, default_value_t = 1.0)]
    pub priority_alpha: f64,
    /// ε of `--priority q`: keeps rows with Q at the lower bound sampleable.
    #[arg(long, default_value_t = 1e-2)]
    pub priority_eps: f64,
    /// Importance-sampling exponent β: weight swapped rows by (N·P(i))^−β / max (cpprb, TorchRL).
    /// Unset: no weights (the paper's setting).
    #[arg(long)]
    pub is_beta: Option<f64>,
}

impl Default for PriorityConfig {
    fn default() -> Self {
        PriorityConfig { priority: PriorityKind::Rank, priority_alpha: 1.0, priority_eps: 1e-2, is_beta: None }
    }
}

impl PriorityConfig {
    /// Settings that would give NaN, negative or all-zero priorities, or meaningless weights,
    /// are refused up front (a negative ε makes the lowest rows' priorities negative or NaN).
    pub fn validate(&self) -> Result<()> {
        let a = self.priority_alpha;
        if !(a.is_finite() && a >= 0.0) {
            bail!("--priority-alpha {a}: must be a finite number ≥ 0");
        }
        let e = self.priority_eps;
        if !(e.is_finite() && e >= 0.0) {
            bail!("--priority-eps {e}: must be a finite number ≥ 0 (it lifts rows at Q's lower bound above 0)");
        }
        if let Some(b) = self.is_beta
            && !(0.0..=1.0).contains(&b)
        {
            bail!("--is-beta {b}: must be in [0, 1] (0: no correction, 1: full correction)");
        }
        Ok(())
    }

    /// `--priority q`'s priority of a row with critic value `q`, for Q's lower bound `lo`
    /// = −1/(1−γ): (clip(q, lo, 0) − lo + ε)^α.
    pub fn q_priority(&self, q: f64, lo: f64) -> f64 {
        (q.clamp(lo, 0.0) - lo + self.priority_eps).powf(self.priority_alpha)
    }

    /// Priorities of rows with critic values `q`, for a critic trained with discount `gamma`,
    /// computed in place: a scored table of 80M rows must not need a second array of them.
    /// Fails on invalid settings, on a q that is not a number (naming its row), and when no row
    /// could ever be drawn (every priority 0, e.g. `--priority-eps 0` with every Q at its bound).
    pub fn priorities(&self, mut q: Vec<f32>, gamma: f64) -> Result<Vec<f32>> {
        self.validate()?;
        if let Some(i) = q.iter().position(|x| x.is_nan()) {
            bail!("row {i}: q is NaN");
        }
        let a = self.priority_alpha;
        match self.priority {
            PriorityKind::Q => {
                let lo = -1.0 / (1.0 - gamma);
                for x in q.iter_mut() {
                    *x = self.q_priority(*x as f64, lo) as f32;
                }
            }
            PriorityKind::Rank => {
                assert!(q.len() <= u32::MAX as usize, "more than 2^32 rows");
                let mut order: Vec<u32> = (0..q.len() as u32).collect();
                // Highest q first; ties keep row order so the result is deterministic.
                order.sort_unstable_by(|&i, &j| q[j as usize].total_cmp(&q[i as usize]).then(i.cmp(&j)));
                for (rank, i) in order.into_iter().enumerate() {
                    q[i as usize] = ((rank + 1) as f64).powf(-a) as f32;
                }
            }
            PriorityKind::Uniform => q.fill(1.0),
        }
        if !q.is_empty() && q.iter().all(|&p| p == 0.0) {
            bail!(
                "every one of the {} swapped rows has priority 0 (all Q at the lower bound −1/(1−γ) with --priority-eps 0); \
                 raise --priority-eps",
                q.len()
            );
        }
        Ok(q)
    }
}

/// Leaves per block of the sum tree: the tree sums blocks, a draw scans one block's leaves.
const BLOCK: usize = 64;

/// Priorities with O(log n) prefix-sum search, in 4 bytes a row: the leaves are float32 (the
/// precision of the q they come from) and the tree above them, in float64 so that sums over
/// tens of millions of rows keep their small terms, has one leaf per block of `BLOCK` rows.
/// (A tree over every row, padded to a power of two, took 2.1 GB for 82M rows.) Node i's
/// children are 2i and 2i+1, the root is node 1.
#[derive(Debug, Clone)]
pub struct SumTree {
    priorities: Vec<f32>,
    /// Tree leaves (blocks) padded to a power of two.
    blocks: usize,
    nodes: Vec<f64>,
    min: f64,
}

impl SumTree {
    /// Panics on a negative or non-finite priority (a caller bug: priorities come from
    /// `PriorityConfig::priorities`, which only makes finite positive values from finite q).
    pub fn new(priorities: Vec<f32>) -> SumTree {
        let blocks = priorities.len().div_ceil(BLOCK).next_power_of_two().max(1);
        let mut nodes = vec![0.0; 2 * blocks];
        let mut min = f64::INFINITY;
        for (b, chunk) in priorities.chunks(BLOCK).enumerate() {
            let mut sum = 0.0;
            for (j, &p) in chunk.iter().enumerate() {
                assert!(p.is_finite() && p >= 0.0, "priority {p} of row {}", b * BLOCK + j);
                sum += p as f64;
                if p > 0.0 {
                    // The IS normaliser is the least likely row that can be drawn; a row of
                    // priority 0 never is, and would make the largest weight infinite.
                    min = min.min(p as f64);
                }
            }
            nodes[blocks + b] = sum;
        }
        for i in (1..blocks).rev() {
            nodes[i] = nodes[2 * i] + nodes[2 * i + 1];
        }
        SumTree { priorities, blocks, nodes, min }
    }

    pub fn len(&self) -> usize {
        self.priorities.len()
    }

    pub fn is_empty(&self) -> bool {
        self.priorities.is_empty()
    }

    pub fn total(&self) -> f64 {
        self.nodes[1]
    }

    pub fn priority(&self, i: usize) -> f64 {
        self.priorities[i] as f64
    }

    /// The probability row i is drawn with.
    pub fn probability(&self, i: usize) -> f64 {
        self.priority(i) / self.total()
    }

    /// The row whose cumulative-priority interval contains `mass` ∈ [0, total).
    pub fn find(&self, mut mass: f64) -> usize {
        let mut i = 1;
        while i < self.blocks {
            let left = self.nodes[2 * i];
            if mass < left {
                i *= 2;
            } else {
                mass -= left;
                i = 2 * i + 1;
            }
        }
        let start = ((i - self.blocks) * BLOCK).min(self.len() - 1);
        let end = (start + BLOCK).min(self.len());
        for (r, &p) in self.priorities[start..end].iter().enumerate() {
            let p = p as f64;
            if mass < p {
                return start + r;
            }
            mass -= p;
        }
        // Rounding can walk past a block's last positive row by a hair: that row is meant.
        let mut row = end - 1;
        while self.priorities[row] == 0.0 && row > 0 {
            row -= 1;
        }
        row
    }

    /// `k` rows by stratified sampling: the total mass is cut into k equal strata and one row is
    /// drawn uniformly within each (Schaul et al.), which lowers the batch-to-batch variance of
    /// the mix while each draw keeps probability p_i / Σp.
    pub fn sample(&self, k: usize, rng: &mut NpRandom, out: &mut Vec<usize>) {
        let stratum = self.total() / k as f64;
        out.clear();
        out.extend((0..k).map(|j| self.find((j as f64 + rng.random()) * stratum)));
    }

    /// Importance-sampling weights (N·P(i))^−β normalised by their maximum, which belongs to
    /// the least likely row: every weight is in (0, 1], so they only ever shrink a loss term.
    pub fn is_weights(&self, rows: &[usize], beta: f64) -> Vec<f32> {
        let n = self.len() as f64;
        let max = (n * self.min / self.total()).powf(-beta);
        rows.iter().map(|&i| ((n * self.probability(i)).powf(-beta) / max) as f32).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Chi-square statistic of observed counts against expected ones.
    fn chi_square(observed: &[u64], expected: &[f64]) -> f64 {
        observed.iter().zip(expected).map(|(&o, &e)| (o as f64 - e).powi(2) / e).sum()
    }

    #[test]
    fn draw_frequencies_match_priorities() {
        // 50 rows with priorities over two orders of magnitude; 400k draws in batches of 256.
        let p: Vec<f64> = (0..50).map(|i| 0.1 + (i as f64 * 0.37).sin().abs() * 10.0 + (i % 7) as f64).collect();
        let tree = SumTree::new(p.iter().map(|&x| x as f32).collect());
        let p: Vec<f64> = (0..p.len()).map(|i| tree.priority(i)).collect();
        let mut rng = NpRandom::new(42);
        let mut counts = vec![0u64; p.len()];
        let mut rows = Vec::new();
        let batches = 1600;
        for _ in 0..batches {
            tree.sample(256, &mut rng, &mut rows);
            for &r in &rows {
                counts[r] += 1;
            }
        }
        let draws = (batches * 256) as f64;
        let expected: Vec<f64> = p.iter().map(|x| x / tree.total() * draws).collect();
        // χ² with 49 degrees of freedom: the 0.999 quantile is 85.4. Stratification only makes
        // the counts tighter than multinomial, so a correct sampler stays far below it.
        let chi2 = chi_square(&counts, &expected);
        assert!(chi2 < 85.4, "chi2 {chi2}, counts {counts:?}");
    }

    #[test]
    fn draw_frequencies_match_priorities_across_blocks() {
        // 300 rows over 5 blocks of the tree (the last one partial), every 7th row at zero.
        let p: Vec<f32> = (0..300).map(|i| if i % 7 == 3 { 0.0 } else { 0.5 + ((i * 13) % 17) as f32 }).collect();
        let tree = SumTree::new(p.clone());
        let mut rng = NpRandom::new(7);
        let mut counts = vec![0u64; p.len()];
        let mut rows = Vec::new();
        for _ in 0..2000 {
            tree.sample(256, &mut rng, &mut rows);
            for &r in &rows {
                counts[r] += 1;
            }
        }
        let draws = 2000.0 * 256.0;
        let (mut obs, mut exp) = (Vec::new(), Vec::new());
        for (i, &c) in counts.iter().enumerate() {
            if p[i] == 0.0 {
                assert_eq!(c, 0, "row {i} has priority 0");
            } else {
                obs.push(c);
                exp.push(tree.probability(i) * draws);
            }
        }
        // 257 positive rows: df 256, whose 0.999 quantile is ≈ 330 (Wilson–Hilferty).
        let chi2 = chi_square(&obs, &exp);
        assert!(chi2 < 330.0, "chi2 {chi2}");
    }

    #[test]
    fn zero_priority_rows_are_never_drawn() {
        let tree = SumTree::new(vec![0.0, 1.0, 0.0, 3.0, 0.0]);
        let mut rng = NpRandom::new(1);
        let mut rows = Vec::new();
        for _ in 0..1000 {
            tree.sample(8, &mut rng, &mut rows);
            assert!(rows.iter().all(|&r| r == 1 || r == 3), "{rows:?}");
        }
    }

    #[test]
    fn is_weights_are_normalised_inverse_probabilities() {
        let tree = SumTree::new(vec![1.0, 2.0, 4.0, 1.0]);
        let w = tree.is_weights(&[0, 1, 2, 3], 1.0);
        // (N·P)^−1 = total/(N·p) = 8/(4p): 2, 1, 0.5, 2; divided by the max 2.
        assert_eq!(w, vec![1.0, 0.5, 0.25, 1.0]);
        let w = tree.is_weights(&[2], 0.5);
        assert!((w[0] - 0.5f32).abs() < 1e-7); // sqrt(0.25)
    }

    #[test]
    fn q_priorities_follow_q_and_rank_priorities_follow_order() {
        let cfg = PriorityConfig { priority: PriorityKind::Q, ..PriorityConfig::default() }; // α = 1, ε = 0.01
        let p = cfg.priorities(vec![0.0, -50.0, -60.0, -25.0], 0.98).unwrap();
        for (got, want) in p.iter().zip([50.01f32, 0.01, 0.01, 25.01]) {
            assert_eq!(*got, want, "{p:?}");
        }
        let rank = PriorityConfig { priority: PriorityKind::Rank, ..cfg.clone() };
        assert_eq!(rank.priorities(vec![-3.0, -1.0, -2.0], 0.98).unwrap(), vec![1.0 / 3.0, 1.0, 0.5]);
        let alpha0 = PriorityConfig { priority_alpha: 0.0, ..cfg };
        assert!(alpha0.priorities(vec![-3.0, -1.0], 0.98).unwrap().iter().all(|&x| x == 1.0));
    }

    #[test]
    fn zero_priority_rows_do_not_break_the_is_weights() {
        // --priority-eps 0: the rows at Q's lower bound get priority 0 and are never drawn; the
        // weights are normalised over the rows that can be drawn (here the 1.0 row is the max).
        let cfg = PriorityConfig {
            priority: PriorityKind::Q,
            priority_eps: 0.0,
            is_beta: Some(1.0),
            ..PriorityConfig::default()
        };
        let p = cfg.priorities(vec![-50.0, -49.0, -48.0, -60.0], 0.98).unwrap();
        assert_eq!(p, vec![0.0, 1.0, 2.0, 0.0]);
        let tree = SumTree::new(p);
        let w = tree.is_weights(&[1, 2], 1.0);
        assert_eq!(w, vec![1.0, 0.5]);
        assert!(w.iter().all(|x| x.is_finite() && *x > 0.0));
    }

    #[test]
    fn bad_priority_settings_and_values_are_refused() {
        let base = PriorityConfig { priority: PriorityKind::Q, ..PriorityConfig::default() };
        for (cfg, says) in [
            (PriorityConfig { priority_eps: -0.5, ..base.clone() }, "--priority-eps -0.5"),
            (PriorityConfig { priority_eps: f64::NAN, ..base.clone() }, "--priority-eps NaN"),
            (PriorityConfig { priority_alpha: -1.0, ..base.clone() }, "--priority-alpha -1"),
            (PriorityConfig { is_beta: Some(1.5), ..base.clone() }, "--is-beta 1.5"),
        ] {
            let e = cfg.priorities(vec![-1.0, -2.0], 0.98).unwrap_err().to_string();
            assert!(e.starts_with(says), "{says}: {e}");
        }
        let e = base.priorities(vec![-1.0, f32::NAN], 0.98).unwrap_err().to_string();
        assert!(e.contains("row 1: q is NaN"), "{e}");
        let zero = PriorityConfig { priority_eps: 0.0, ..base };
        let e = zero.priorities(vec![-50.0, -70.0], 0.98).unwrap_err().to_string();
        assert!(e.contains("priority 0"), "{e}");
    }

    #[test]
    fn same_seed_same_rows() {
        let tree = SumTree::new(vec![1.0, 5.0, 2.0, 0.5, 9.0]);
        let draw = |s| {
            let mut rows = Vec::new();
            tree.sample(64, &mut NpRandom::new(s), &mut rows);
            rows
        };
        assert_eq!(draw(3), draw(3));
        assert_ne!(draw(3), draw(4));
    }
}
