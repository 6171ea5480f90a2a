//! Where pgser's Table 2 and the paper's agree: per task and learner, the ordering the paper
//! claims (mem ≥ swap ≥ baseline, in the means) and each comparison it marks (swap and mem above
//! the baseline, mem above swap), with pgser's Welch tests over seeds and over pooled episodes.
//!
//! The paper marks only "significantly above", so agreement is on that question: a comparison
//! agrees when pgser finds the difference significant and upward exactly where the paper marks
//! it. pgser's "significantly below" (▼) is shown where it occurs, and counts as "not above".

use serde::Serialize;

use super::cells::{AGENTS, Measured};
use super::paper::PaperCell;
use super::welch::{ALPHA, BETTER, WORSE, welch_from_summary};

/// A measured cell by task and row index.
type Lookup<'a> = &'a dyn Fn(&str, usize) -> Option<&'a Measured>;

/// The comparisons of a (task, learner) pair, in the order [`Agreement::by_comparison`] counts them.
pub const COMPARISONS: [&str; 3] = ["mem vs swap", "swap vs baseline", "mem vs baseline"];
pub const MEM_VS_SWAP: usize = 0;
pub const MEM_VS_BASELINE: usize = 2;

/// Counts of agreement with the paper over the measured tasks.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Agreement {
    /// (task, learner) pairs where the ordering holds or fails in both; of those the paper has.
    pub ordering_agree: usize,
    pub ordering_of: usize,
    /// Marked comparisons where pgser's test over seeds agrees with the paper's mark; of those.
    pub seeds_agree: usize,
    pub seeds_of: usize,
    /// The same over pooled episodes, and the comparisons without a pooled spread on one side.
    pub episodes_agree: usize,
    pub episodes_of: usize,
    pub episodes_unavailable: usize,
    /// (task, learner) pairs with all three variants measured.
    pub pairs: usize,
    /// Of those, where pgser's test over seeds finds mem significantly above swap, and where the
    /// paper marks it so (its bold).
    pub mem_above_swap: usize,
    pub paper_mem_above_swap: usize,
    /// The test over seeds agreeing with the paper's mark, per comparison ([`COMPARISONS`]):
    /// (agree, of).
    pub by_comparison: [(usize, usize); 3],
}

impl Agreement {
    pub fn summary(&self) -> String {
        let mut s = format!(
            "Against the paper: the ordering agrees in {} of {} (task, learner) pairs; the marks agree in {} of {} \
             comparisons by the test over seeds",
            self.ordering_agree, self.ordering_of, self.seeds_agree, self.seeds_of
        );
        if self.episodes_of > 0 {
            s += &format!(" and in {} of {} by the test over pooled episodes", self.episodes_agree, self.episodes_of);
        }
        if self.episodes_unavailable > 0 {
            s += &format!(
                " ({} comparisons have no pooled spread: their inputs kept no per-run spread)",
                self.episodes_unavailable
            );
        }
        let (mb, mbo) = self.by_comparison[MEM_VS_BASELINE];
        s + &format!(
            ". Of the marks, mem vs baseline agrees in {mb} of {mbo}; mem is significantly above swap in {} of {} \
             pairs (the paper marks {} of them).",
            self.mem_above_swap, self.pairs, self.paper_mem_above_swap
        )
    }
}

/// The paper's own marks recomputed by Welch's test from its printed mean ± std, as if each
/// were over `n` samples a side: (marks reproduced, marks compared). Which n reproduces them says
/// what its ± and its test were over, which the paper does not state.
pub fn paper_reproduced(paper: &[PaperCell], n: usize) -> (usize, usize) {
    let (mut agree, mut of) = (0, 0);
    for c in paper {
        let (algo, variant, _) = AGENTS[c.agent];
        let other = |v: &str| {
            let a = AGENTS.iter().position(|x| x.0 == algo && x.1 == v).expect("a known row");
            paper.iter().find(|p| p.task == c.task && p.agent == a)
        };
        let against = [(c.above_baseline, other("baseline")), (c.above_swap, other("swap"))];
        for (marked, o) in against.into_iter().filter(|_| variant != "baseline") {
            let (Some(marked), Some(o)) = (marked, o) else { continue };
            let Some((_, _, p)) = welch_from_summary((c.mean, c.std, n), (o.mean, o.std, n)) else { continue };
            of += 1;
            agree += usize::from((p < ALPHA && c.mean > o.mean) == marked);
        }
    }
    (agree, of)
}

/// One task's line: for each learner, the ordering here and in the paper, and each comparison's
/// tests beside the paper's mark.
pub(super) fn task_line(task: &str, short: &str, find: Lookup, paper: &[PaperCell], tally: &mut Agreement) -> String {
    let mut parts = Vec::new();
    for (algo, learner) in [("td3bc", "TD3BC"), ("td3", "TD3")] {
        let row = |v: &str| AGENTS.iter().position(|a| a.0 == algo && a.1 == v).expect("a known row");
        let (im, is, ib) = (row("mem"), row("swap"), row("baseline"));
        let (Some(m), Some(s), Some(b)) = (find(task, im), find(task, is), find(task, ib)) else { continue };
        let theirs = |a: usize| paper.iter().find(|p| p.task == task && p.agent == a);
        tally.pairs += 1;
        tally.paper_mem_above_swap += usize::from(theirs(im).and_then(|p| p.above_swap) == Some(true));
        let holds = |x: bool| if x { "holds" } else { "does not hold" };
        let ours = m.mean >= s.mean && s.mean >= b.mean;
        let mut text =
            format!("{learner}: mem ≥ swap ≥ baseline {} ({:.2} / {:.2} / {:.2})", holds(ours), m.mean, s.mean, b.mean);
        match (theirs(im), theirs(is), theirs(ib)) {
            (Some(pm), Some(ps), Some(pb)) => {
                let p = pm.mean >= ps.mean && ps.mean >= pb.mean;
                tally.ordering_of += 1;
                tally.ordering_agree += usize::from(p == ours);
                text += &format!(
                    "; in the paper it {} ({} / {} / {}): {}",
                    holds(p),
                    pm.mean,
                    ps.mean,
                    pb.mean,
                    if p == ours { "agree" } else { "differ" }
                );
            }
            _ => text += "; the paper's values: —",
        }
        let mut tests = Vec::new();
        let comparisons = [
            (m, s, theirs(im).and_then(|p| p.above_swap)),
            (s, b, theirs(is).and_then(|p| p.above_baseline)),
            (m, b, theirs(im).and_then(|p| p.above_baseline)),
        ];
        for (k, (x, y, paper_mark)) in comparisons.into_iter().enumerate() {
            let names = COMPARISONS[k];
            let above = x.mean > y.mean;
            let over_seeds = welch_from_summary(x.seeds_side(), y.seeds_side()).map(|t| t.2);
            let pooled = x.episodes_side().zip(y.episodes_side());
            let over_episodes = pooled.and_then(|(a, b)| welch_from_summary(a, b)).map(|t| t.2);
            let mut t = format!("{names} {}", test(over_seeds, above));
            if pooled.is_some() {
                t += &format!(", over episodes {}", test(over_episodes, above));
            }
            // The paper's mark and, where it has one, whether each test agrees.
            let significant = |p: Option<f64>| p.is_some_and(|p| p < ALPHA) && above;
            if k == MEM_VS_SWAP && significant(over_seeds) {
                tally.mem_above_swap += 1;
            }
            match paper_mark {
                None => t += ", the paper: —",
                Some(marked) => {
                    let verdict = |ok: bool| if ok { "agree" } else { "differ" };
                    let ok = significant(over_seeds) == marked;
                    tally.seeds_of += 1;
                    tally.seeds_agree += usize::from(ok);
                    tally.by_comparison[k].1 += 1;
                    tally.by_comparison[k].0 += usize::from(ok);
                    t += &format!(", the paper {}: {}", if marked { BETTER } else { "unmarked" }, verdict(ok));
                    if pooled.is_some() {
                        let ok = significant(over_episodes) == marked;
                        tally.episodes_of += 1;
                        tally.episodes_agree += usize::from(ok);
                        t += &format!(" (over episodes: {})", verdict(ok));
                    } else {
                        tally.episodes_unavailable += 1;
                    }
                }
            }
            tests.push(t);
        }
        parts.push(format!("{text}. {}", tests.join("; ")));
    }
    format!("**{short}**: {}.", parts.join(". "))
}

/// A test's outcome in words: `▲ p = 0.003`, `not significant (p = 0.577)`, or why untested.
fn test(p: Option<f64>, above: bool) -> String {
    match p {
        Some(p) if p < ALPHA => format!("{} p = {}", if above { BETTER } else { WORSE }, fmt_p(p)),
        Some(p) => format!("not significant (p = {})", fmt_p(p)),
        None => "untested (fewer than 2 samples or no spread)".to_string(),
    }
}

pub(super) fn fmt_p(p: f64) -> String {
    if p < 1e-3 { format!("{p:.1e}") } else { format!("{p:.3}") }
}
