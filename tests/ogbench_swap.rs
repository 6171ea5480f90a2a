//! PGSER's swapped rows in OGBench's layout (`p_swapgoal`; src/sampler/ogbench/swapped.rs): a
//! fraction of each batch's rows are scored rows drawn by priority, whose value (and actor) goal is
//! the observation the scored goal was taken from.
//!
//! The data are the coded folders of `common/coded.rs` (every observation and achieved goal of
//! episode e, step s is e·1000 + s), scored by a briefly trained critic, so every goal in a batch
//! says which observation it is and every swapped row which scored row it was.

mod common;

use std::path::{Path, PathBuf};

use arrow_array::cast::AsArray;
use arrow_array::types::Float32Type;
use pgser::sampler::ogbench::{GoalKind, OgbenchBatch, OgbenchConfig, OgbenchStream};
use pgser::sampler::priority::PriorityConfig;
use pgser::sampler::view::Budget;
use pgser::task::Task;

use common::coded::{EPISODES, T, critic, decode, folder_of, point_task, score_options, worst_share_gap};

const SWAPS: usize = 4;
const BATCH: usize = 98;
const P_SWAP: f64 = 0.3;
/// Holds 5 of the 96 blocks of the PointMaze-shaped folder with their scored rows and goal sources
/// (an episode is 1.6 kB of β and 3.9 kB of scored rows), beside the reservoir and blocks in flight.
const POINT_BUDGET: u64 = 300_000;

/// The coded folder of `task`, a critic trained on it, and its scored folder, in `dir`.
fn scored(dir: &Path, task: &Task) -> (PathBuf, PathBuf, PathBuf) {
    let data = folder_of(dir, task);
    let q = critic(dir, &data);
    let out = dir.join("scored");
    pgser::score::score(&score_options(&data, &q, &out, (SWAPS, 5), 2, None), &indicatif::ProgressBar::hidden())
        .unwrap();
    (data, q, out)
}

fn with_swaps(p: f64) -> OgbenchConfig {
    OgbenchConfig { p_swapgoal: p, ..OgbenchConfig::default() }
}

fn open(path: &Path, budget: Budget, cfg: OgbenchConfig) -> anyhow::Result<OgbenchStream> {
    OgbenchStream::open(path, budget, cfg, &PriorityConfig::default(), 7)
}

/// Every scored row's goal (as the coded (episode, step) it is) and q, in table order.
fn scored_rows(dir: &Path) -> Vec<((usize, usize), f32)> {
    let folder = pgser::score::folder::ScoredFolder::open(dir).unwrap();
    let mut out = Vec::new();
    for path in folder.shard_paths() {
        let (batch, _) = common::read_table(&path);
        let q = batch.column_by_name("q").unwrap().as_primitive::<Float32Type>();
        let goal = batch.column_by_name("goal").unwrap().as_fixed_size_list();
        let (gv, gd) = (goal.values().as_primitive::<Float32Type>(), goal.value_length() as usize);
        out.extend((0..batch.num_rows()).map(|i| (decode(gv.value(i * gd)), q.value(i))));
    }
    out
}

/// Checks every row of `b` names its own transition and goals, and every swapped row the scored
/// row it was: its transition, its goal's observation, and (with `swap_actor_goals`) the same
/// actor goal. Returns the swapped rows' scored rows.
fn check_rows(b: &OgbenchBatch, rows: &[((usize, usize), f32)]) -> Vec<usize> {
    let int = |k: &str, i: usize| b.i64(k).unwrap_or_else(|| panic!("no {k}"))[i];
    let first = |k: &str, i: usize| b.row(k, i).unwrap_or_else(|| panic!("no {k}"))[0];
    let kind = |k: &str, i: usize| b.kinds(k).unwrap_or_else(|| panic!("no {k}"))[i];
    let mut swapped = Vec::new();
    for i in 0..b.n {
        let (e, s) = (int("episode", i) as usize, int("step", i) as usize);
        assert_eq!(decode(first("observations", i)), (e, s));
        assert_eq!(decode(first("next_observations", i)), (e, s + 1));
        let value_goal = (int("value_goal_episode", i) as usize, int("value_goal_step", i) as usize);
        assert_eq!(decode(first("value_goals", i)), value_goal, "row {i}'s value goal is the observation it names");
        let actor_goal = (int("actor_goal_episode", i) as usize, int("actor_goal_step", i) as usize);
        assert_eq!(decode(first("actor_goals", i)), actor_goal);
        let success = value_goal == (e, s);
        assert_eq!(b.f64("masks").unwrap()[i], if success { 0.0 } else { 1.0 });
        let Ok(r) = usize::try_from(int("scored_row", i)) else {
            assert_ne!(kind("value_goal_kind", i), GoalKind::Swapped);
            continue;
        };
        assert_eq!(kind("value_goal_kind", i), GoalKind::Swapped);
        assert_eq!(r / SWAPS, e * (T - 1) + s, "scored row {r} is the transition of episode {e} step {s}");
        assert_eq!(value_goal, rows[r].0, "scored row {r}'s goal");
        assert_eq!((kind("actor_goal_kind", i), actor_goal), (GoalKind::Swapped, value_goal));
        swapped.push(r);
    }
    swapped
}

/// `count` of `n` within 4 σ of a fraction `p`.
fn within_4_sigma(count: usize, n: usize, p: f64) {
    let sd = (n as f64 * p * (1.0 - p)).sqrt();
    assert!((count as f64 - n as f64 * p).abs() < 4.0 * sd, "{count} of {n}, expected {p}");
}

/// The share of draws rank priorities at α = 1 put on the top tenth of `n` rows: H(n/10)/H(n).
fn top_tenth_share(n: usize) -> f64 {
    let h = |n: usize| (1..=n).map(|k| 1.0 / k as f64).sum::<f64>();
    h(n / 10) / h(n)
}

#[test]
fn swapped_rows_with_beta_in_memory_are_scored_rows_by_priority_with_their_goals_observation() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q, out) = scored(dir.path(), &Task::known("FetchReach").unwrap());
    let rows = scored_rows(&out);
    assert_eq!(rows.len(), EPISODES * (T - 1) * SWAPS);
    // Table-wide ranks by q, highest first, ties by row: as `--priority rank` ranks them.
    let mut order: Vec<usize> = (0..rows.len()).collect();
    order.sort_by(|&i, &j| rows[j].1.total_cmp(&rows[i].1).then(i.cmp(&j)));
    let mut top = vec![false; rows.len()];
    for &i in &order[..rows.len() / 10] {
        top[i] = true;
    }
    let mut s = open(&out, Budget::Unbounded, with_swaps(P_SWAP)).unwrap();
    assert!(s.is_scored());
    let (batches, mut swapped) = (300, Vec::new());
    for _ in 0..batches {
        swapped.extend(check_rows(&s.next_batch(BATCH).unwrap(), &rows));
    }
    within_4_sigma(swapped.len(), batches * BATCH, P_SWAP);
    let hits = swapped.iter().filter(|&&r| top[r]).count();
    within_4_sigma(hits, swapped.len(), top_tenth_share(rows.len()));

    // p_swapgoal = 0 from the scored folder: its original data's batches, number for number.
    let mut plain = open(&data, Budget::Unbounded, OgbenchConfig::default()).unwrap();
    let mut none = open(&out, Budget::Unbounded, OgbenchConfig::default()).unwrap();
    assert!(!none.is_scored());
    for _ in 0..3 {
        assert_eq!(plain.next_batch(BATCH).unwrap(), none.next_batch(BATCH).unwrap());
    }
    // swap_actor_goals = false: a swapped row's actor goal is the actor's own (by default a
    // trajectory goal of the row's episode).
    let cfg = OgbenchConfig { swap_actor_goals: false, ..with_swaps(P_SWAP) };
    let b = open(&out, Budget::Unbounded, cfg).unwrap().next_batch(2000).unwrap();
    let int = |k: &str| b.i64(k).unwrap();
    let own = (0..b.n).filter(|&i| int("scored_row")[i] >= 0).collect::<Vec<_>>();
    assert!(!own.is_empty());
    for i in own {
        let kind = b.kinds("actor_goal_kind").unwrap()[i];
        assert_eq!((kind, int("actor_goal_episode")[i]), (GoalKind::Trajectory, int("episode")[i]));
        assert!(int("actor_goal_step")[i] >= int("step")[i]);
    }

    // Refused, naming why: swapped goals without a scored table; weights; goals that are not
    // observations within a budget; rows that keep their own desired goal.
    let e = open(&data, Budget::Unbounded, with_swaps(P_SWAP)).err().unwrap().to_string();
    assert!(e.contains("p_swapgoal") && e.contains("trajectory table"), "{e}");
    let weights = PriorityConfig { is_beta: Some(0.4), ..PriorityConfig::default() };
    let e = OgbenchStream::open(&out, Budget::Unbounded, with_swaps(P_SWAP), &weights, 7).err().unwrap().to_string();
    assert!(e.contains("importance weights"), "{e}");
    let e = open(&out, Budget::bytes(420_000), with_swaps(P_SWAP)).err().unwrap().to_string();
    assert!(e.contains("whole observations") && e.contains("3 of its 10"), "{e}");
    let orig = dir.path().join("with-original");
    let mut o = score_options(&data, &q, &orig, (SWAPS, 5), 2, None);
    o.include_original = true;
    pgser::score::score(&o, &indicatif::ProgressBar::hidden()).unwrap();
    let e = open(&orig, Budget::Unbounded, with_swaps(P_SWAP)).err().unwrap().to_string();
    assert!(e.contains("--include-original"), "{e}");
    let e = open(&out, Budget::Unbounded, with_swaps(1.5)).err().unwrap().to_string();
    assert!(e.contains("p_swapgoal = 1.5"), "{e}");
}

#[test]
fn within_a_budget_swapped_rows_come_from_resident_blocks_when_goals_are_observations() {
    let dir = tempfile::tempdir().unwrap();
    let (_, _, out) = scored(dir.path(), &point_task());
    let rows = scored_rows(&out);
    let mut s = open(&out, Budget::bytes(POINT_BUDGET), with_swaps(P_SWAP)).unwrap();
    let resident = s.view().episodes();
    assert!(resident < EPISODES / 10, "{resident} episodes resident: the budget should make a pool");
    // One pass: as many draws as the table has transitions.
    let batches = EPISODES * (T - 1) / BATCH;
    let (mut swapped, mut episodes) = (Vec::new(), Vec::new());
    for _ in 0..batches {
        let b = s.next_batch(BATCH).unwrap();
        for r in check_rows(&b, &rows) {
            episodes.push(r / SWAPS / (T - 1));
            swapped.push(r);
        }
    }
    within_4_sigma(swapped.len(), batches * BATCH, P_SWAP);
    let gap = worst_share_gap(episodes.into_iter());
    assert!(gap < 2.0, "a shard's share of the swapped rows is {gap:.2} points off its share of the rows");
    // The same seed, the same batches.
    let mut again = open(&out, Budget::bytes(POINT_BUDGET), with_swaps(P_SWAP)).unwrap();
    let mut first = open(&out, Budget::bytes(POINT_BUDGET), with_swaps(P_SWAP)).unwrap();
    for _ in 0..5 {
        assert_eq!(first.next_batch(BATCH).unwrap(), again.next_batch(BATCH).unwrap());
    }
}
