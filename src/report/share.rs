//! How sharply a priority setting favours the swapped rows that Q calls reachable.
//!
//! PGSER's `-mem` differs from `-swap` only in *which* swapped rows it draws, so what matters is
//! not Q's accuracy alone but how much of the sampler's mass the priority puts on rows Q likes.
//! With `--priority q` at α = 1 the priority is Q shifted to [ε, 1/(1−γ) + ε]: on FetchPush a
//! reachable-looking row (Q ≈ −5) weighs about twice a typical one (Q ≈ −30), so `-mem` draws
//! almost as `-swap` does. This module measures that, for any setting, in one number: the share
//! of the sampler's draws whose Q lies above the own-goal median (the median Q of expert
//! transitions with their own goals, Table 1's positives). Uniform drawing gives the plain
//! fraction of such rows; the further a setting's share rises above it, the more its batches
//! differ from `-swap`'s.
//!
//! The share is exact, not sampled, and streams: for `q` priorities it sums each row's priority,
//! and over the rows above the median; for `rank` the rows above the median are exactly the
//! ranks 1…n_above, so the share is H(n_above, α) / H(N, α) with H(n, α) = Σ_{r ≤ n} r^−α, and
//! only the counts are needed. Rows are every row the sampler draws from (the swapped rows, and
//! the own-goal rows of a table scored with `--include-original`).

use serde::{Deserialize, Serialize};

use anyhow::{Result, bail};

use crate::sampler::priority::{PriorityConfig, PriorityKind};

/// The share for each setting asked, beside the uniform share.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PriorityShares {
    /// The own-goal median: the median Q of the report's positives.
    pub threshold: f64,
    /// Rows the sampler draws from, and those of them with Q above `threshold`.
    pub rows: usize,
    pub above: usize,
    /// above / rows: the share under uniform drawing (`-swap`'s picture, or α = 0).
    pub uniform: f64,
    pub settings: Vec<Share>,
}

/// One priority setting's share of draws above the own-goal median.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Share {
    pub priority: PriorityKind,
    pub priority_alpha: f64,
    pub priority_eps: f64,
    pub share_above: f64,
}

impl Share {
    /// `q, α = 1` / `rank, α = 1` / `uniform`, as the tables print it.
    pub fn label(&self) -> String {
        match self.priority {
            PriorityKind::Uniform => "uniform".into(),
            PriorityKind::Q => format!("q, α = {}", self.priority_alpha),
            PriorityKind::Rank => format!("rank, α = {}", self.priority_alpha),
        }
    }
}

/// Streams the q column once, for several settings at once.
pub struct ShareCounter {
    threshold: f64,
    /// Q's lower bound −1/(1−γ), where `q` priorities start.
    lo: f64,
    settings: Vec<PriorityConfig>,
    /// Per setting (`q` only): Σ p over all rows, and over the rows above the threshold.
    total: Vec<f64>,
    above_mass: Vec<f64>,
    rows: usize,
    above: usize,
}

impl ShareCounter {
    /// Fails on a setting the sampler would refuse.
    pub fn new(threshold: f64, gamma: f64, settings: &[PriorityConfig]) -> Result<ShareCounter> {
        for s in settings {
            s.validate()?;
        }
        Ok(ShareCounter {
            threshold,
            lo: -1.0 / (1.0 - gamma),
            settings: settings.to_vec(),
            total: vec![0.0; settings.len()],
            above_mass: vec![0.0; settings.len()],
            rows: 0,
            above: 0,
        })
    }

    /// One row's q (finite: the caller has checked).
    pub fn add(&mut self, q: f64) {
        let is_above = q > self.threshold;
        self.rows += 1;
        self.above += usize::from(is_above);
        for (i, s) in self.settings.iter().enumerate() {
            if s.priority == PriorityKind::Q {
                let p = s.q_priority(q, self.lo);
                self.total[i] += p;
                if is_above {
                    self.above_mass[i] += p;
                }
            }
        }
    }

    pub fn finish(self) -> PriorityShares {
        let uniform = if self.rows == 0 { f64::NAN } else { self.above as f64 / self.rows as f64 };
        let settings = self
            .settings
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let share_above = match s.priority {
                    PriorityKind::Q => self.above_mass[i] / self.total[i],
                    PriorityKind::Rank => {
                        harmonic(self.above, s.priority_alpha) / harmonic(self.rows, s.priority_alpha)
                    }
                    PriorityKind::Uniform => uniform,
                };
                Share {
                    priority: s.priority,
                    priority_alpha: s.priority_alpha,
                    priority_eps: s.priority_eps,
                    share_above,
                }
            })
            .collect();
        PriorityShares { threshold: self.threshold, rows: self.rows, above: self.above, uniform, settings }
    }
}

/// A setting as the command line gives it: `KIND[:ALPHA[:EPS]]` (`q:3`, `rank:1`, `uniform`),
/// with `--priority-alpha`'s and `--priority-eps`'s defaults.
pub fn parse_setting(s: &str) -> Result<PriorityConfig> {
    use clap::ValueEnum;
    let mut parts = s.split(':');
    let kind = parts.next().unwrap_or_default();
    let mut c = PriorityConfig {
        priority: PriorityKind::from_str(kind, true)
            .map_err(|_| anyhow::anyhow!("{s:?}: the priority is q, rank or uniform, as in KIND[:ALPHA[:EPS]]"))?,
        ..PriorityConfig::default()
    };
    let mut number = |what: &str| -> Result<Option<f64>> {
        parts.next().map(|x| x.parse().map_err(|_| anyhow::anyhow!("{s:?}: {what} {x:?} is not a number"))).transpose()
    };
    if let Some(a) = number("α")? {
        c.priority_alpha = a;
    }
    if let Some(e) = number("ε")? {
        c.priority_eps = e;
    }
    if parts.next().is_some() {
        bail!("{s:?}: expected KIND[:ALPHA[:EPS]]");
    }
    c.validate()?;
    Ok(c)
}

/// H(n, α) = Σ_{r=1..n} r^−α, the total rank priority of the n highest rows.
fn harmonic(n: usize, alpha: f64) -> f64 {
    (1..=n).map(|r| (r as f64).powf(-alpha)).sum()
}

/// The median of `v` (the mean of the middle two for an even count); NaN when empty.
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_unstable_by(f64::total_cmp);
    match s.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => s[n / 2],
        n => 0.5 * (s[n / 2 - 1] + s[n / 2]),
    }
}

/// The shares as a markdown section under Table 1.
pub fn shares_markdown(s: &PriorityShares) -> String {
    let mut out = format!(
        "\n## How sharply the priority draws what Q calls reachable\n\n\
         Share of the sampler's draws whose Q lies above the own-goal median (Q = {:.3}, the positives' median), \
         over the {} rows it draws from; uniform drawing (`-swap`'s picture) gives {:.4} ({} rows above).\n\n\
         | priority | share above the own-goal median | × uniform |\n|---|---:|---:|\n",
        s.threshold, s.rows, s.uniform, s.above
    );
    for x in &s.settings {
        out += &format!("| {} | {:.4} | {:.2} |\n", x.label(), x.share_above, x.share_above / s.uniform);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nprandom::NpRandom;

    fn cfg(priority: PriorityKind, alpha: f64) -> PriorityConfig {
        PriorityConfig { priority, priority_alpha: alpha, ..PriorityConfig::default() }
    }

    /// The streamed shares equal the probability mass the sampler's own priorities give the rows
    /// above the threshold, for each kind (the sampler computes them in float32).
    #[test]
    fn shares_are_the_samplers_mass_above_the_median() {
        let mut rng = NpRandom::new(7);
        let q: Vec<f32> = (0..5000).map(|_| (-50.0 * rng.random()) as f32).collect();
        let threshold = -12.5;
        let settings = [cfg(PriorityKind::Q, 1.0), cfg(PriorityKind::Q, 3.0), cfg(PriorityKind::Rank, 1.0)];
        let mut c = ShareCounter::new(threshold, 0.98, &settings).unwrap();
        q.iter().for_each(|&x| c.add(f64::from(x)));
        let s = c.finish();
        let above: Vec<bool> = q.iter().map(|&x| f64::from(x) > threshold).collect();
        assert_eq!(s.above, above.iter().filter(|&&a| a).count());
        assert!((s.uniform - 0.25).abs() < 0.03, "{}", s.uniform);
        for (setting, got) in settings.iter().zip(&s.settings) {
            let p = setting.priorities(q.clone(), 0.98).unwrap();
            let mass: f64 = p.iter().zip(&above).filter(|(_, a)| **a).map(|(p, _)| f64::from(*p)).sum();
            let total: f64 = p.iter().map(|&p| f64::from(p)).sum();
            assert!(
                (got.share_above - mass / total).abs() < 1e-5,
                "{}: {} vs {}",
                got.label(),
                got.share_above,
                mass / total
            );
        }
        // Sharper settings draw more of the rows above: q α=3 over q α=1 over uniform.
        assert!(s.settings[1].share_above > s.settings[0].share_above && s.settings[0].share_above > s.uniform);
    }

    #[test]
    fn settings_parse_from_the_command_line() {
        let p = |s: &str| parse_setting(s).map(|c| (c.priority, c.priority_alpha, c.priority_eps));
        assert_eq!(p("q").unwrap(), (PriorityKind::Q, 1.0, 1e-2));
        assert_eq!(p("q:3").unwrap(), (PriorityKind::Q, 3.0, 1e-2));
        assert_eq!(p("rank:0.7:0.5").unwrap(), (PriorityKind::Rank, 0.7, 0.5));
        assert!(p("greedy").unwrap_err().to_string().contains("q, rank or uniform"));
        assert!(p("q:x").unwrap_err().to_string().contains("α \"x\" is not a number"));
        assert!(p("q:1:0.1:2").is_err());
        assert!(p("q:-1").unwrap_err().to_string().contains("--priority-alpha -1"));
    }

    #[test]
    fn the_median_and_a_bad_setting() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(&[]).is_nan());
        let bad = PriorityConfig { priority_alpha: -1.0, ..PriorityConfig::default() };
        assert!(ShareCounter::new(0.0, 0.98, &[bad]).is_err());
    }
}
