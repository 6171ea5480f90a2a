//! Training batches from the original data β: uniform transitions, HER "future" relabelling,
//! and (for the `-swap` variant) random goal swapping on the fly.
//!
//! Every row draws its own transition; the first `round(n · swap_ratio)` rows of a batch get a
//! swapped goal (Alg. 1), each other row is relabelled with probability `her_ratio` to the
//! achieved goal of a later step of its own episode (GoFAR's `future` strategy), and keeps its
//! original goal otherwise. Rewards are recomputed for the goal each row ends up with, with the
//! task's reward function, so relabelled and swapped rows are labelled exactly like original ones.

pub mod dump;
pub mod ogbench;
pub mod open;
pub mod pool;
pub mod priority;
pub mod replay;
pub mod scored;
pub mod stream;
pub mod view;

use clap::{Args, ValueEnum};
use serde::{Deserialize, Serialize};

use crate::agent::{Batch, Rows, Table};
use crate::nprandom::NpRandom;
use crate::trajectory::Episodes;
use view::View;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Swap {
    /// Original goals and HER only (the paper's baseline).
    None,
    /// Alg. 1 on the fly: a fraction of each batch gets a goal from anywhere in the data.
    Random,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Args)]
pub struct SamplerConfig {
    /// Goal swapping of the original data.
    #[arg(long, value_enum, default_value = "none")]
    pub swap: Swap,
    /// With `--swap random`: the fraction of each batch that gets a swapped goal.
    #[arg(long, default_value_t = 0.5)]
    pub swap_ratio: f64,
    /// Probability that a (non-swapped) row's goal is relabelled to a future achieved goal.
    #[arg(long, default_value_t = 0.5)]
    pub her_ratio: f64,
}

impl Default for SamplerConfig {
    fn default() -> Self {
        SamplerConfig { swap: Swap::None, swap_ratio: 0.5, her_ratio: 0.5 }
    }
}

/// Where each row's goal came from; kept so tests can check the sampler's bookkeeping.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GoalSource {
    Original,
    /// HER: the achieved goal of this step of the same episode (always later than the row's).
    Future(usize),
    /// Alg. 1: the achieved goal of a random source (its episode and step are table-wide).
    Swapped(view::RandomGoal),
}

pub use crate::score::RowKey;

impl RowKey {
    /// The key of a row drawn from β: `e` is the transition's table-wide episode number.
    pub fn of(e: u64, t: usize, source: GoalSource) -> RowKey {
        let (ge, gs) = match source {
            GoalSource::Original => (e, -1),
            GoalSource::Future(f) => (e, f as i32),
            GoalSource::Swapped(g) => (g.episode, g.step as i32),
        };
        RowKey { episode: e as u32, step: t as u32, goal_episode: ge as u32, goal_step: gs }
    }
}

/// Fills `out` with `n` rows sampled from `data`; returns each row's (episode, step, source).
pub fn sample(
    data: &Episodes,
    cfg: &SamplerConfig,
    rng: &mut NpRandom,
    n: usize,
    out: &mut Batch,
) -> Vec<(usize, usize, GoalSource)> {
    let drawn = draw(data, cfg, rng, n);
    *out = rows(data, drawn.iter().map(|&(e, t, s)| RowKey::of(e as u64, t, s))).gather(&table(data));
    drawn
}

/// `n` rows' (episode, step, goal source) drawn from `data`: the random half of `sample`. The
/// episode is the view's (resident) one; random goals come from the whole table
/// ([`View::random_goal`]). On a table in memory, the draws `sample` has always made.
pub fn draw(data: &dyn View, cfg: &SamplerConfig, rng: &mut NpRandom, n: usize) -> Vec<(usize, usize, GoalSource)> {
    let steps = data.t() - 1;
    let swapped = match cfg.swap {
        Swap::None => 0,
        Swap::Random => ((n as f64) * cfg.swap_ratio).round() as usize,
    };
    (0..n)
        .map(|i| {
            let (e, t) = (rng.below(data.episodes()), rng.below(steps));
            let source = if i < swapped {
                GoalSource::Swapped(data.random_goal(rng))
            } else if rng.random() < cfg.her_ratio {
                GoalSource::Future(t + 1 + rng.below(steps - t))
            } else {
                GoalSource::Original
            };
            (e, t, source)
        })
        .collect()
}

/// The batch of rows `drawn` from `data`, built on the host: what a view that no engine holds
/// (the out-of-core pool) trains on. Rewards are the task's, of s′'s achieved goal and the goal
/// each row is trained on, as in [`rows`]. Vectors are copied in parallel ([`gather_rows`]).
pub fn gather(data: &dyn View, drawn: &[(usize, usize, GoalSource)]) -> Batch {
    let task = data.task();
    let (od, gd, ad) = (task.obs_dim, task.goal_dim, task.act_dim);
    let goal = |&(e, t, source): &(usize, usize, GoalSource)| match source {
        GoalSource::Original => data.goal(e, t),
        GoalSource::Future(f) => data.ag(e, f),
        GoalSource::Swapped(g) => data.goal_ag(g),
    };
    let mut b = Batch {
        n: drawn.len(),
        obs: gather_rows(drawn, od, |r| data.obs(r.0, r.1)),
        next_obs: gather_rows(drawn, od, |r| data.obs(r.0, r.1 + 1)),
        action: gather_rows(drawn, ad, |r| data.action(r.0, r.1)),
        goal: gather_rows(drawn, gd, goal),
        ..Batch::default()
    };
    let next_ag = gather_rows(drawn, gd, |r| data.ag(r.0, r.1 + 1));
    b.reward = vec![0.0; b.n];
    task.rewards(&next_ag, &b.goal, &mut b.reward);
    b
}

/// Rows per parallel copy: enough that a task's overhead is small against its copies.
const GATHER_CHUNK: usize = 128;
/// Floats below which a vector is copied on the calling thread: on PointMaze's 2-float rows a
/// batch's copies take microseconds, and handing them to the thread pool cost more than it saved
/// (1,480 against 2,050 batches/s of 1024 on 2 cores, bench/bench_scale.py's pgser side).
const PARALLEL_FLOATS: usize = 1 << 16;

/// The vectors `of` each row gives, `dim` wide, concatenated in row order; copied in parallel when
/// they are many (wide observations: copying is then most of a batch's time) and the thread pool
/// has more than 2 threads. On 2 cores the out-of-core pool's loader and the drawing thread
/// already fill them, and copying on the thread pool measured 1,052 against 1,341 batches/s on
/// humanoidmaze's shape (in memory, with no loader, the two were alike). The same values at any
/// thread count. The output is never zeroed first: every value is written once (a `calloc`'s
/// memset of each key was 7 % of the drawing thread's time on humanoidmaze's shape).
pub(crate) fn gather_rows<'a, R: Sync>(rows: &[R], dim: usize, of: impl Fn(&R) -> &'a [f32] + Sync) -> Vec<f32> {
    use rayon::prelude::*;
    let n = rows.len() * dim;
    let mut out: Vec<f32> = Vec::with_capacity(n);
    let spare = &mut out.spare_capacity_mut()[..n];
    if n < PARALLEL_FLOATS || rayon::current_num_threads() <= 2 {
        copy_rows(spare, rows, dim, &of);
    } else {
        spare
            .par_chunks_mut(GATHER_CHUNK * dim)
            .zip(rows.par_chunks(GATHER_CHUNK))
            .for_each(|(o, rs)| copy_rows(o, rs, dim, &of));
    }
    // SAFETY: `copy_rows` wrote all `dim` values of each of the `rows.len()` rows, every one of
    // the first `n` (it asserts each row's vector is `dim` wide).
    unsafe { out.set_len(n) };
    out
}

/// Rows ahead of the copy whose vectors are prefetched: enough to keep several cache misses in
/// flight while one row is copied.
const PREFETCH_ROWS: usize = 8;

/// Copies each row's vector into its place in `out` (every value of it written). A vector of a
/// few floats (PointMaze's 2, a Fetch goal's 3) is copied as a fixed-size array: a `memcpy` call
/// per row of 8 bytes was most of the out-of-core pool's drawing time (perf, bench_scale.py's
/// pgser side on 100M PointMaze rows). A wider one is prefetched [`PREFETCH_ROWS`] rows ahead:
/// rows drawn at random from a gigabyte of resident blocks each miss the cache, and copied one
/// after another their misses were waited for one at a time (the copies were 44 % of the drawing
/// thread's time on humanoidmaze's shape, 69 floats a row).
fn copy_rows<'a, R>(out: &mut [std::mem::MaybeUninit<f32>], rows: &[R], dim: usize, of: &impl Fn(&R) -> &'a [f32]) {
    fn fixed<'a, R, const D: usize>(out: &mut [std::mem::MaybeUninit<f32>], rows: &[R], of: &impl Fn(&R) -> &'a [f32]) {
        for (o, r) in out.chunks_exact_mut(D).zip(rows) {
            let v = <&[f32; D]>::try_from(of(r)).expect("a row's vector is D wide");
            for (o, v) in o.iter_mut().zip(v) {
                o.write(*v);
            }
        }
    }
    assert_eq!(out.len(), rows.len() * dim, "room for every row");
    match dim {
        0 => {}
        1 => fixed::<R, 1>(out, rows, of),
        2 => fixed::<R, 2>(out, rows, of),
        3 => fixed::<R, 3>(out, rows, of),
        4 => fixed::<R, 4>(out, rows, of),
        5 => fixed::<R, 5>(out, rows, of),
        6 => fixed::<R, 6>(out, rows, of),
        7 => fixed::<R, 7>(out, rows, of),
        8 => fixed::<R, 8>(out, rows, of),
        _ => {
            // The source of row i + PREFETCH_ROWS is looked up once, prefetched, and kept in a
            // ring until its copy.
            let mut ahead: [&[f32]; PREFETCH_ROWS] = [&[]; PREFETCH_ROWS];
            for (i, r) in rows.iter().take(PREFETCH_ROWS).enumerate() {
                ahead[i] = of(r);
                prefetch(ahead[i]);
            }
            for (i, o) in out.chunks_exact_mut(dim).enumerate() {
                let v = ahead[i % PREFETCH_ROWS];
                if let Some(r) = rows.get(i + PREFETCH_ROWS) {
                    let next = of(r);
                    prefetch(next);
                    ahead[i % PREFETCH_ROWS] = next;
                }
                assert_eq!(v.len(), dim, "a row's vector is dim wide");
                // SAFETY: `o` and `v` are `dim` values each (asserted), `f32` and
                // `MaybeUninit<f32>` have one layout, and `out` cannot overlap the shared `v`.
                unsafe { std::ptr::copy_nonoverlapping(v.as_ptr(), o.as_mut_ptr().cast::<f32>(), dim) };
            }
        }
    }
}

/// Asks the CPU to bring `v`'s cache lines in (a hint: it never faults, and does nothing where
/// the architecture has no such instruction here).
#[inline(always)]
fn prefetch(v: &[f32]) {
    #[cfg(target_arch = "x86_64")]
    {
        use std::arch::x86_64::{_MM_HINT_T0, _mm_prefetch};
        let p = v.as_ptr().cast::<i8>();
        let bytes = std::mem::size_of_val(v);
        // Every line from the first byte's to the last byte's (a row need not start a line).
        let mut at = 0;
        while at < bytes {
            // SAFETY: a prefetch reads nothing architecturally and cannot fault; the address is
            // within `v`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.add(at)) };
            at += 64;
        }
        if bytes > 0 {
            // SAFETY: as above; the last byte of `v`.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(p.add(bytes - 1)) };
        }
    }
    #[cfg(not(target_arch = "x86_64"))]
    let _ = v;
}

/// β as an engine holds it (`Engine::hold`).
pub fn table(data: &Episodes) -> Table<'_> {
    let task = &data.task;
    Table {
        obs_dim: task.obs_dim,
        goal_dim: task.goal_dim,
        act_dim: task.act_dim,
        obs: &data.obs,
        ag: &data.ag,
        g: &data.g,
        u: &data.u,
    }
}

/// The rows `keys` name in `table(data)`, with their rewards for the goals they are trained on
/// (the task's reward of s′'s achieved goal): a batch that `Rows::gather` builds on the host, or
/// an engine on its device.
pub fn rows(data: &Episodes, keys: impl IntoIterator<Item = RowKey>) -> Rows {
    let (t, tab) = (data.t, table(data));
    let ag_rows = data.n * t;
    // Row numbers are u32 (12 bytes a row to a GPU): 4 billion goal rows, far past any data set.
    assert!(tab.goal_rows() <= u32::MAX as usize, "{} goal rows: more than u32 row numbers hold", tab.goal_rows());
    let (mut r, mut next_ag, mut goal) = (Rows::default(), Vec::new(), Vec::new());
    for k in keys {
        let (e, s) = (k.episode as usize, k.step as usize);
        r.obs.push((e * t + s) as u32);
        r.action.push((e * (t - 1) + s) as u32);
        let g = match k.goal_step {
            -1 => ag_rows + e * (t - 1) + s,
            gs => k.goal_episode as usize * t + gs as usize,
        };
        r.goal.push(g as u32);
        next_ag.extend_from_slice(data.ag(e, s + 1));
        goal.extend_from_slice(tab.goal(g));
    }
    r.reward = vec![0.0; r.len()];
    data.task.rewards(&next_ag, &goal, &mut r.reward);
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every row's vector lands whole in its place, in row order, whatever the width (the
    /// fixed-size copies, and the prefetching ring beyond them) and however many rows there are
    /// against the ring's length; on one thread and on four.
    #[test]
    fn gathered_rows_are_each_rows_vector_in_order() {
        let source: Vec<f32> = (0..300 * 80).map(|i| i as f32).collect();
        for threads in [1, 4] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            for dim in (0..=12).chain([69, 80]) {
                for n in [0, 1, 7, 8, 9, 17, 300, 1000] {
                    // Rows in a scrambled order, some repeated.
                    let rows: Vec<usize> = (0..n).map(|i| (i * 7919 + 13) % 300).collect();
                    let got = pool.install(|| gather_rows(&rows, dim, |&r| &source[r * 80..r * 80 + dim]));
                    let want: Vec<f32> =
                        rows.iter().flat_map(|&r| source[r * 80..r * 80 + dim].iter().copied()).collect();
                    assert_eq!(got, want, "dim {dim}, {n} rows, {threads} threads");
                }
            }
        }
    }

    /// A table whose values say where they are (`Episodes::coded`); desired goals are reached
    /// (equal to the next achieved goal) on even steps.
    fn table(n: usize) -> Episodes {
        Episodes::coded(0, n, |e, s| if s % 2 == 0 { (e * 1000 + s + 1) as f32 } else { -1.0 })
    }

    fn draw(cfg: &SamplerConfig, n: usize) -> (Episodes, Batch, Vec<(usize, usize, GoalSource)>) {
        let data = table(20);
        let mut batch = Batch::default();
        let rows = sample(&data, cfg, &mut NpRandom::new(11), n, &mut batch);
        (data, batch, rows)
    }

    #[test]
    fn rows_are_consistent_transitions_with_recomputed_rewards() {
        let cfg = SamplerConfig { swap: Swap::Random, ..SamplerConfig::default() };
        let (data, b, rows) = draw(&cfg, 4000);
        let (od, gd, ad) = (data.task.obs_dim, data.task.goal_dim, data.task.act_dim);
        for (i, &(e, t, source)) in rows.iter().enumerate() {
            assert!(t + 1 < data.t);
            assert_eq!(&b.obs[i * od..(i + 1) * od], data.obs(e, t));
            assert_eq!(&b.next_obs[i * od..(i + 1) * od], data.obs(e, t + 1));
            assert_eq!(&b.action[i * ad..(i + 1) * ad], data.action(e, t));
            let goal = &b.goal[i * gd..(i + 1) * gd];
            match source {
                GoalSource::Original => assert_eq!(goal, data.goal(e, t)),
                GoalSource::Future(f) => {
                    // HER: same episode, a strictly later step, up to the last observation.
                    assert!(f > t && f < data.t, "future step {f} for step {t}");
                    assert_eq!(goal, data.ag(e, f));
                }
                GoalSource::Swapped(g) => assert_eq!(goal, data.ag(g.episode as usize, g.step as usize)),
            }
            assert_eq!(b.reward[i], data.task.reward(data.ag(e, t + 1), goal), "row {i}");
        }
        // Both reward values occur, so the check above is not vacuous.
        assert!(b.reward.contains(&0.0) && b.reward.contains(&-1.0));
    }

    #[test]
    fn goal_source_frequencies_match_the_ratios() {
        let n = 20_000;
        let cfg = SamplerConfig { swap: Swap::Random, swap_ratio: 0.25, her_ratio: 0.5 };
        let (_, _, rows) = draw(&cfg, n);
        let swapped = rows.iter().filter(|r| matches!(r.2, GoalSource::Swapped(..))).count();
        assert_eq!(swapped, n / 4, "the swapped fraction is exact");
        let her = rows.iter().filter(|r| matches!(r.2, GoalSource::Future(_))).count() as f64;
        // Binomial(15000, 0.5): std ≈ 61; 5 std is a bound a correct sampler never fails.
        assert!((her - 7500.0).abs() < 5.0 * 61.3, "HER rows {her}");
        // Without swapping no row is swapped.
        let (_, _, rows) = draw(&SamplerConfig::default(), 1000);
        assert!(rows.iter().all(|r| !matches!(r.2, GoalSource::Swapped(..))));
    }

    #[test]
    fn future_steps_are_uniform_over_the_later_steps() {
        // Rows at step 45 of T = 50 relabel to one of steps 46..=49, each with p = 1/4.
        let (_, _, rows) = draw(&SamplerConfig { her_ratio: 1.0, ..SamplerConfig::default() }, 200_000);
        let mut counts = [0f64; 4];
        for &(_, t, source) in &rows {
            if let (45, GoalSource::Future(f)) = (t, source) {
                counts[f - 46] += 1.0;
            }
        }
        let total: f64 = counts.iter().sum();
        let sd = (total * 0.25 * 0.75).sqrt();
        for c in counts {
            assert!((c - total / 4.0).abs() < 5.0 * sd, "{counts:?}");
        }
    }

    #[test]
    fn same_seed_same_batch() {
        let cfg = SamplerConfig { swap: Swap::Random, ..SamplerConfig::default() };
        assert_eq!(draw(&cfg, 256).1, draw(&cfg, 256).1);
    }
}
