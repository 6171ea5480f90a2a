//! PGSER at scale: a table folder scored shard by shard into a scored folder (`src/score/folder.rs`),
//! and `-mem` batches drawn within a memory budget from blocks that carry their scored rows
//! (`src/sampler/pool.rs`, "PGSER within a budget").
//!
//! The data is the coded folder of `common/coded.rs` (every observation and achieved goal of
//! episode e, step s is e·1000 + s), scored by a briefly trained FetchReach critic: every goal in a
//! batch then says which observation it came from, and every row which transition.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use arrow_array::cast::AsArray;
use arrow_array::types::{Float32Type, Int64Type};
use pgser::sampler::stream::{BatchSource, StreamConfig};
use pgser::sampler::view::Budget;
use pgser::sampler::{SamplerConfig, Swap};
use pgser::score::ScoreOptions;

use common::coded::{EPISODES, GROUP_EPISODES, SHARDS, T, decode, folder, worst_share_gap};

const SWAPS: usize = 4;
const BATCH: usize = 98;
/// Holds about 5 of the 96 blocks with their scored rows (an episode is 4.0 kB of β and 3.1 kB of
/// scored rows), beside the reservoir and the blocks in flight.
const BUDGET: u64 = 420_000;
/// One pass: as many draws as the table has transitions.
const PASS_BATCHES: usize = EPISODES * (T - 1) / BATCH;

/// The coded folder and a FetchReach critic trained on it for a few updates, in `dir`.
fn data_and_critic(dir: &Path) -> (PathBuf, PathBuf) {
    let data = folder(dir);
    let q = common::coded::critic(dir, &data);
    (data, q)
}

fn options(data: &Path, q: &Path, out: &Path, seed: u64, threads: usize, shard: Option<usize>) -> ScoreOptions {
    common::coded::score_options(data, q, out, (SWAPS, seed), threads, shard)
}

fn score(o: &ScoreOptions) -> anyhow::Result<pgser::score::ScoreSummary> {
    pgser::score::score(o, &indicatif::ProgressBar::hidden())
}

/// Every file of a folder, by name.
fn files(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| (p.file_name().unwrap().to_string_lossy().into_owned(), std::fs::read(&p).unwrap()))
        .collect()
}

fn config(aug_ratio: f64, seed: u64) -> StreamConfig {
    StreamConfig {
        sampler: SamplerConfig { swap: Swap::None, swap_ratio: 0.5, her_ratio: 0.5 },
        batch_size: BATCH,
        aug_ratio,
        priority: Default::default(),
        aug_in_memory: false,
        seed,
    }
}

/// Every scored row's (episode, goal's first value, q), read from a scored folder's shards.
fn scored_rows(dir: &Path) -> Vec<(i64, f32, f32)> {
    let mut out = Vec::new();
    let folder = pgser::score::folder::ScoredFolder::open(dir).unwrap();
    for path in folder.shard_paths() {
        let (batch, _) = common::read_table(&path);
        let ep = batch.column_by_name("episode").unwrap().as_primitive::<Int64Type>();
        let q = batch.column_by_name("q").unwrap().as_primitive::<Float32Type>();
        let goal = batch.column_by_name("goal").unwrap().as_fixed_size_list();
        let gv = goal.values().as_primitive::<Float32Type>();
        for i in 0..batch.num_rows() {
            out.push((ep.value(i), gv.value(i * 3), q.value(i)));
        }
    }
    out
}

#[test]
fn a_folder_scores_shard_by_shard_to_the_same_bytes_in_any_order_and_at_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q) = data_and_critic(dir.path());
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    let s = score(&options(&data, &q, &a, 5, 2, None)).unwrap();
    assert_eq!(s.rows, EPISODES * (T - 1) * SWAPS);
    // As a cluster's array tasks would: one shard each, in any order, then the manifest.
    for i in [3, 1, 0, 2] {
        score(&options(&data, &q, &b, 5, 1, Some(i))).unwrap();
        assert!(!b.join("manifest.json").exists(), "a --shard run writes no manifest");
    }
    score(&options(&data, &q, &b, 5, 1, None)).unwrap();
    assert_eq!(files(&a), files(&b));
    let m = pgser::score::folder::ScoredFolder::open(&a).unwrap().manifest;
    assert_eq!(m.shards.len(), SHARDS.len());
    assert_eq!(m.rows, s.rows);
    let total: u64 =
        m.footer.q.histogram.counts.iter().sum::<u64>() + m.footer.q.histogram.below + m.footer.q.histogram.above;
    assert_eq!(total as usize, m.rows, "the manifest's histogram counts every shard's rows");
    // Goals of shard 0's rows come from every shard, in proportion to its rows.
    let rows = scored_rows(&a);
    let shard0 = SHARDS[0] * (T - 1) * SWAPS;
    assert!(rows[..shard0].iter().all(|r| (r.0 as usize) < SHARDS[0]), "shard 0's file holds shard 0's transitions");
    let gap = worst_share_gap(rows[..shard0].iter().map(|r| decode(r.1).0));
    assert!(gap < 2.0, "a shard's share of shard 0's goals is {gap:.2} points off its share of the rows");
}

#[test]
fn a_goal_sample_holds_k_goals_drawn_from_every_shard_the_same_whoever_scores() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q) = data_and_critic(dir.path());
    const K: usize = 2000;
    let sampled = |out: &Path, threads: usize, shard: Option<usize>| {
        let o = ScoreOptions { goal_sample: Some(K), ..options(&data, &q, out, 5, threads, shard) };
        score(&o)
    };
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    let summary = sampled(&a, 2, None).unwrap();
    assert_eq!(summary.goal_sample, Some(K), "the summary (and `score`'s line) names the sample");
    // Shard by shard on one thread (as array tasks, each drawing the sample again): the same bytes.
    for i in [3, 1, 0, 2] {
        sampled(&b, 1, Some(i)).unwrap();
    }
    sampled(&b, 1, None).unwrap();
    assert_eq!(files(&a), files(&b));
    let m = pgser::score::folder::ScoredFolder::open(&a).unwrap().manifest;
    assert_eq!(m.footer.goal_sample, Some(K));
    // Every goal is the achieved goal its (goal_episode, goal_step) names, one of at most K; a
    // sample of K draws from 24,000 observations has about K·(1 − K/48,000) = 1,917 distinct ones.
    let mut distinct = std::collections::BTreeSet::new();
    for path in pgser::score::folder::ScoredFolder::open(&a).unwrap().shard_paths() {
        let (batch, _) = common::read_table(&path);
        let ge = batch.column_by_name("goal_episode").unwrap().as_primitive::<Int64Type>();
        let gs = batch.column_by_name("goal_step").unwrap().as_primitive::<arrow_array::types::Int32Type>();
        let gv = batch.column_by_name("goal").unwrap().as_fixed_size_list().values().as_primitive::<Float32Type>();
        for i in 0..batch.num_rows() {
            let at = (ge.value(i) as usize, gs.value(i) as usize);
            assert_eq!(decode(gv.value(i * 3)), at, "row {i} of {}", path.display());
            distinct.insert(at);
        }
    }
    assert!((1850..=1980).contains(&distinct.len()), "{} distinct goals", distinct.len());
    // The sample comes from every shard in proportion to its rows (K draws: within 4 points).
    let gap = worst_share_gap(distinct.iter().map(|g| g.0));
    assert!(gap < 4.0, "a shard's share of the sampled goals is {gap:.2} points off its share of the rows");
    // Scored from every goal instead: other settings, so every shard is scored again.
    score(&options(&data, &q, &a, 5, 2, None)).unwrap();
    assert_eq!(pgser::score::folder::ScoredFolder::open(&a).unwrap().manifest.footer.goal_sample, None);
    let e = score(&ScoreOptions { goal_sample: Some(0), ..options(&data, &q, &b, 5, 1, None) }).unwrap_err();
    assert!(e.to_string().contains("--goal-sample must be at least 1"), "{e}");
}

#[test]
fn a_killed_score_redoes_only_missing_shards_and_other_settings_rescore_them() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q) = data_and_critic(dir.path());
    let out = dir.path().join("scored");
    score(&options(&data, &q, &out, 5, 2, None)).unwrap();
    let before = files(&out);
    let name = |i: usize| format!("coded-{i}.parquet");
    let mtime = |i: usize| std::fs::metadata(out.join(name(i))).unwrap().modified().unwrap();
    let kept: Vec<_> = [0, 1, 3].map(mtime).to_vec();
    // As a run killed after three shards leaves it: one shard and the manifest missing.
    std::fs::remove_file(out.join(name(2))).unwrap();
    std::fs::remove_file(out.join("manifest.json")).unwrap();
    let e = pgser::score::folder::ScoredFolder::open(&out).unwrap_err().to_string();
    assert!(e.contains("unfinished"), "{e}");
    score(&options(&data, &q, &out, 5, 2, None)).unwrap();
    assert_eq!(files(&out), before);
    assert_eq!([0, 1, 3].map(mtime).to_vec(), kept, "finished shards are kept, not scored again");
    // Another seed: a shard scored anew takes the manifest away until every shard agrees again.
    score(&options(&data, &q, &out, 6, 2, Some(0))).unwrap();
    assert!(!out.join("manifest.json").exists());
    let e =
        pgser::score::folder::Manifest::of(&out, &pgser::trajectory::folder::TableFolder::open(&data).unwrap(), "t");
    let e = e.unwrap_err().to_string();
    assert!(e.contains("coded-1.parquet") && e.contains("another source, critic or settings"), "{e}");
    score(&options(&data, &q, &out, 6, 2, None)).unwrap();
    assert_eq!(pgser::score::folder::ScoredFolder::open(&out).unwrap().manifest.footer.seed, 6);
}

#[test]
fn bad_shards_and_changed_data_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q) = data_and_critic(dir.path());
    let out = dir.path().join("scored");
    let e = score(&options(&data, &q, &out, 5, 1, Some(4))).unwrap_err().to_string();
    assert!(e.contains("--shard 4") && e.contains("has 4 shards"), "{e}");
    let e = score(&options(&data, &q, &dir.path().join("one.parquet"), 5, 1, Some(0))).unwrap_err().to_string();
    assert!(e.contains("--shard 0") && e.contains("without .parquet"), "{e}");
    score(&options(&data, &q, &out, 5, 2, None)).unwrap();
    let train = |data: &Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
            .arg("--data")
            .arg(data)
            .arg("-o")
            .arg(dir.path().join("agent.ckpt"))
            .args(["--updates", "5", "--batch-size", "98", "--hidden", "16", "--eval-episodes", "0"])
            .output()
            .unwrap()
    };
    // A shard that changed after the manifest was written.
    let shard = out.join("coded-2.parquet");
    let mut bytes = std::fs::read(&shard).unwrap();
    bytes.push(0);
    std::fs::write(&shard, &bytes).unwrap();
    let o = train(&out);
    let e = common::text(&o.stderr);
    assert!(!o.status.success() && e.contains("coded-2.parquet") && e.contains("the file changed"), "{e}");
    bytes.pop();
    std::fs::write(&shard, &bytes).unwrap();
    assert!(train(&out).status.success());
    // Original data changed since scoring.
    let m = data.join("manifest.json");
    let text = std::fs::read_to_string(&m).unwrap();
    std::fs::write(&m, text.replace("\"command\": \"test\"", "\"command\": \"test again\"")).unwrap();
    let o = train(&out);
    let e = common::text(&o.stderr);
    assert!(!o.status.success() && e.contains("has changed since scoring"), "{e}");
}

#[test]
fn mem_within_a_budget_draws_scored_rows_of_resident_blocks_by_their_priority_within_the_block() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q) = data_and_critic(dir.path());
    let out = dir.path().join("scored");
    score(&options(&data, &q, &out, 5, 2, None)).unwrap();
    let rows = scored_rows(&out);
    let cfg = config(0.5, 9);
    let mut s = BatchSource::open_within(&out, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    let pool = s.pool().expect("the scored data are larger than the budget");
    assert!((4..10).contains(&pool.blocks().0), "{:?} blocks resident", pool.blocks());
    // Each block's rows ranked by q, highest first (ties by row), as the pool ranks them.
    let per_block = GROUP_EPISODES * (T - 1) * SWAPS;
    let mut rank = vec![0usize; rows.len()];
    for start in (0..rows.len()).step_by(per_block) {
        let mut order: Vec<usize> = (start..start + per_block).collect();
        order.sort_by(|&i, &j| rows[j].2.total_cmp(&rows[i].2).then(i.cmp(&j)));
        for (r, i) in order.into_iter().enumerate() {
            rank[i] = r + 1;
        }
    }
    let (mut aug_episodes, mut top_tenth, mut aug) = (Vec::new(), 0usize, 0usize);
    for _ in 0..PASS_BATCHES {
        let (b, ids) = s.next_batch().unwrap();
        assert_eq!(b.n, BATCH);
        for i in 0..b.n {
            let (e, t) = (ids.episode[i] as usize, ids.step[i] as usize);
            assert_eq!(decode(b.obs[i * 10]), (e, t));
            assert_eq!(decode(b.next_obs[i * 10]), (e, t + 1));
            let r = ids.scored_row[i];
            if r < 0 {
                continue;
            }
            // A scored row: the transition it scored, with the goal it was scored with.
            let r = r as usize;
            assert_eq!(r / SWAPS, e * (T - 1) + t, "scored row {r} is the transition of episode {e} step {t}");
            assert_eq!(b.goal[i * 3], rows[r].1, "scored row {r}'s goal");
            aug += 1;
            aug_episodes.push(e);
            top_tenth += (rank[r] <= per_block / 10) as usize;
        }
    }
    assert_eq!(aug, PASS_BATCHES * BATCH / 2);
    let gap = worst_share_gap(aug_episodes.iter().copied());
    assert!(gap < 2.0, "a shard's share of the prioritized rows is {gap:.2} points off its share of the rows");
    // Rank priorities at α = 1 within a block of n rows put H(n/10)/H(n) of the draws on its top
    // tenth (0.69 for n = 980; uniform draws would put 0.10 there).
    let h = |n: usize| (1..=n).map(|k| 1.0 / k as f64).sum::<f64>();
    let want = h(per_block / 10) / h(per_block);
    let got = top_tenth as f64 / aug as f64;
    let sd = (want * (1.0 - want) / aug as f64).sqrt();
    assert!((got - want).abs() < 5.0 * sd, "top tenth drew {got:.3} of the prioritized rows, expected {want:.3}");
}

#[test]
fn mem_within_a_budget_resumes_to_the_same_batches_and_refuses_weights() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q) = data_and_critic(dir.path());
    let out = dir.path().join("scored");
    score(&options(&data, &q, &out, 5, 2, None)).unwrap();
    let cfg = config(0.25, 4);
    let open = || BatchSource::open_within(&out, &cfg, Budget::bytes(BUDGET)).unwrap();
    let mut whole = open().start(&cfg).unwrap();
    let again: Vec<_> = {
        let mut s = open().start(&cfg).unwrap();
        (0..20).map(|_| s.next_batch().unwrap()).collect()
    };
    let first: Vec<_> = (0..20).map(|_| whole.next_batch().unwrap()).collect();
    assert_eq!(first, again, "the same seed gives the same batches");
    let stop = PASS_BATCHES as u64 + 13;
    for _ in 20..stop {
        whole.next_batch().unwrap();
    }
    let resuming = BatchSource::open_resuming(&out, &cfg, Budget::bytes(BUDGET), stop).unwrap();
    let mut resumed = resuming.resume(&cfg, whole.rng().clone(), stop).unwrap();
    for _ in 0..40 {
        assert_eq!(whole.next_batch().unwrap(), resumed.next_batch().unwrap());
    }
    let mut weighted = config(0.25, 4);
    weighted.priority.is_beta = Some(0.4);
    let e = BatchSource::open_within(&out, &weighted, Budget::bytes(BUDGET)).map(|_| ()).unwrap_err().to_string();
    assert!(e.contains("--is-beta 0.4 within --memory-budget"), "{e}");
    // A budget that holds β and its scored rows: β whole, the prioritized rows drawn from the
    // whole scored table, as without a budget.
    let (mut a, mut b) = (
        BatchSource::open_within(&out, &cfg, Budget::bytes(1 << 30)).unwrap().start(&cfg).unwrap(),
        BatchSource::open_within(&out, &cfg, Budget::Unbounded).unwrap().start(&cfg).unwrap(),
    );
    assert!(a.pool().is_none());
    for _ in 0..5 {
        assert_eq!(a.next_batch().unwrap(), b.next_batch().unwrap());
    }
    drop((a, b));
    // The stored goals, which the pool trains on, are checked when their block is read: a flipped
    // bit in the last row group's `goal` chunk of the last shard is met in a pass, by name.
    let folder = pgser::score::folder::ScoredFolder::open(&out).unwrap();
    let shard = folder.shard_paths().pop().unwrap();
    common::coded::flip_in_last_chunk(&shard, "goal.", 0x04);
    let e = common::coded::first_failure(&out, &cfg, Budget::bytes(BUDGET), 2 * PASS_BATCHES);
    assert!(e.contains(&*shard.file_name().unwrap().to_string_lossy()) && e.contains("column goal"), "{e}");
    assert!(e.contains("checksum mismatch"), "{e}");
}

#[test]
fn the_cli_scores_a_shard_and_draws_mem_batches_within_a_budget_alike_at_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q) = data_and_critic(dir.path());
    let out = dir.path().join("scored");
    let o = common::etl()
        .args(["score", "--q"])
        .arg(&q)
        .arg("--data")
        .arg(&data)
        .arg("-o")
        .arg(&out)
        .args(["--shard", "1"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", common::text(&o.stderr));
    assert!(common::text(&o.stderr).contains("coded-1.parquet"), "{}", common::text(&o.stderr));
    score(&options(&data, &q, &out, 0, 2, None)).unwrap();
    let batches = |threads: &str| {
        let table = dir.path().join(format!("batches-{threads}.parquet"));
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
            .args(["batches", "--data"])
            .arg(&out)
            .arg("-o")
            .arg(&table)
            .args(["--count", "300", "--batch-size", "98", "--memory-budget", "420kB", "--threads", threads])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", common::text(&o.stderr));
        // The columns: the footer names the command, threads included.
        common::read_table(&table).0.columns().to_vec()
    };
    assert!(batches("1") == batches("2"), "other batches on one thread than on two");
}

#[test]
fn mem_in_a_shard_window_draws_scored_rows_of_the_held_shard_only() {
    let dir = tempfile::tempdir().unwrap();
    let (data, q) = data_and_critic(dir.path());
    let out = dir.path().join("scored");
    score(&options(&data, &q, &out, 5, 2, None)).unwrap();
    let rows = scored_rows(&out);
    let cfg = config(0.5, 2);
    let mut s =
        BatchSource::open_within(&out, &cfg, Budget::ShardWindow(30 * BATCH as u64)).unwrap().start(&cfg).unwrap();
    let first_episode = |i: usize| SHARDS[..i].iter().sum::<usize>();
    for k in 0..150 {
        let held = ((k + 1) / 30) % SHARDS.len();
        let (b, ids) = s.next_batch().unwrap();
        let held_episodes = first_episode(held)..first_episode(held + 1);
        for i in 0..b.n {
            assert!(held_episodes.contains(&(ids.episode[i] as usize)), "batch {k}: a row outside shard {held}");
            if ids.scored_row[i] >= 0 {
                assert_eq!(b.goal[i * 3], rows[ids.scored_row[i] as usize].1);
            }
        }
    }
}
