//! The out-of-core pool (`src/sampler/pool.rs`): β drawn from a table folder larger than the
//! memory budget, with transitions and random goals from the whole table.
//!
//! The tables are coded (`Episodes::coded`): every observation and achieved goal of the folder's
//! episode e, step s is e·1000 + s, so every value in a batch says which row it came from. The
//! folder has four shards of unequal size cut into row groups of 5 episodes (96 blocks), and the
//! budget holds 6 of them, so at any time 30 of the 480 episodes are resident.

mod common;

use common::coded::{
    BATCH, BUDGET, EPISODES, GROUP_EPISODES, PASS_BATCHES, SHARDS, T, chi_square, decode, folder, shard_of,
    worst_share_gap,
};
use pgser::sampler::stream::{BatchSource, StreamConfig};
use pgser::sampler::view::Budget;
use pgser::sampler::{SamplerConfig, Swap};

fn config(swap: Swap, swap_ratio: f64, her_ratio: f64, seed: u64) -> StreamConfig {
    StreamConfig {
        sampler: SamplerConfig { swap, swap_ratio, her_ratio },
        batch_size: BATCH,
        aug_ratio: 0.5,
        priority: Default::default(),
        aug_in_memory: false,
        seed,
    }
}

#[test]
fn one_pass_gives_every_shard_its_share_and_episodes_and_steps_uniform_counts() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let cfg = config(Swap::None, 0.5, 0.0, 7);
    let mut s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    let pool = s.pool().expect("the table is larger than the budget");
    assert_eq!(pool.resident_episodes(), 6 * GROUP_EPISODES);
    let (mut by_episode, mut by_step) = (vec![0u64; EPISODES], vec![0u64; T - 1]);
    for _ in 0..PASS_BATCHES {
        let (b, ids) = s.next_batch().unwrap();
        for i in 0..b.n {
            // The row is what its ids say: o and o′ of that episode and step.
            let (e, t) = (ids.episode[i] as usize, ids.step[i] as usize);
            assert_eq!(decode(b.obs[i * 10]), (e, t));
            assert_eq!(decode(b.next_obs[i * 10]), (e, t + 1));
            by_episode[e] += 1;
            by_step[t] += 1;
        }
    }
    let gap = worst_share_gap(by_episode.iter().enumerate().flat_map(|(e, &c)| std::iter::repeat_n(e, c as usize)));
    assert!(gap < 2.0, "a shard's share of the draws is {gap:.2} points off its share of the rows");
    let (stat, bound) = chi_square(&by_episode);
    assert!(stat < bound, "episode counts: chi-square {stat:.0} over {bound:.0} ({} episodes)", EPISODES);
    assert!(by_episode.iter().all(|&c| c > 0), "an episode was never drawn in a pass");
    let (stat, bound) = chi_square(&by_step);
    assert!(stat < bound, "step counts: chi-square {stat:.1} over {bound:.1}");
    let stats = s.pool().unwrap().stats();
    assert_eq!(stats.rotations as usize, EPISODES / GROUP_EPISODES, "one pass swaps every block in once");
}

#[test]
fn random_goals_come_from_every_shard_in_proportion_and_her_goals_from_the_rows_episode() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    // Every row swapped.
    let cfg = config(Swap::Random, 1.0, 0.0, 3);
    let mut s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    let mut goal_episodes = Vec::new();
    let mut sources = std::collections::BTreeSet::new();
    for _ in 0..PASS_BATCHES {
        let (b, _) = s.next_batch().unwrap();
        for i in 0..b.n {
            let (ge, gs) = decode(b.goal[i * 3]);
            goal_episodes.push(ge);
            sources.insert((ge, gs));
        }
    }
    // The reservoir this budget affords is small (about 400 goals, refreshed as blocks enter),
    // so goals repeat across a pass; the steps of the distinct goals must be uniform.
    let mut goal_steps = vec![0u64; T];
    for &(_, gs) in &sources {
        goal_steps[gs] += 1;
    }
    let gap = worst_share_gap(goal_episodes.iter().copied());
    assert!(gap < 2.0, "a shard's share of the random goals is {gap:.2} points off its share of the rows");
    let distinct: std::collections::BTreeSet<usize> = goal_episodes.iter().copied().collect();
    assert!(distinct.len() > EPISODES / 2, "random goals came from {} episodes of {EPISODES}", distinct.len());
    let (stat, bound) = chi_square(&goal_steps);
    assert!(stat < bound, "random goals' steps: chi-square {stat:.1} over {bound:.1}");

    // HER: every relabelled goal is a later achieved goal of the row's own episode.
    let cfg = config(Swap::None, 0.5, 1.0, 4);
    let mut s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    for _ in 0..PASS_BATCHES / 4 {
        let (b, ids) = s.next_batch().unwrap();
        for i in 0..b.n {
            let (ge, gs) = decode(b.goal[i * 3]);
            assert_eq!(ge, ids.episode[i] as usize, "row {i}: HER goal from another episode");
            assert!(gs > ids.step[i] as usize && gs < T, "row {i}: HER goal step {gs} for step {}", ids.step[i]);
        }
    }
}

#[test]
fn rows_of_a_batch_share_episodes_as_uniform_draws_from_the_resident_ones_do() {
    // Uniform draws of B rows from P episodes put C(B, 2)/P pairs in one episode, and C(B, 2)/(P·(T − 1))
    // pairs on one transition. The pool's rows must not cluster more than that (within 10 % and
    // 20 %: about 10 and 5 standard deviations over a pass); drawing from the whole table would
    // give N/P = 16 times fewer pairs, the price of the budget, which docs/ogbench.md states.
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let cfg = config(Swap::None, 0.5, 0.0, 11);
    let mut s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    let p = s.pool().unwrap().resident_episodes() as f64;
    let (mut same_episode, mut same_row) = (0u64, 0u64);
    for _ in 0..PASS_BATCHES {
        let (_, ids) = s.next_batch().unwrap();
        for i in 0..BATCH {
            for j in 0..i {
                if ids.episode[i] == ids.episode[j] {
                    same_episode += 1;
                    same_row += (ids.step[i] == ids.step[j]) as u64;
                }
            }
        }
    }
    let pairs = (BATCH * (BATCH - 1) / 2 * PASS_BATCHES) as f64;
    let (want_episode, want_row) = (pairs / p, pairs / (p * (T - 1) as f64));
    let r = same_episode as f64 / want_episode;
    assert!((0.9..1.1).contains(&r), "{same_episode} same-episode pairs where uniform draws give {want_episode:.0}");
    let r = same_row as f64 / want_row;
    assert!((0.8..1.2).contains(&r), "{same_row} repeated rows where uniform draws give {want_row:.0}");
}

#[test]
fn a_budget_that_holds_the_table_gives_the_in_memory_batches_number_for_number() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    for cfg in [config(Swap::None, 0.5, 0.5, 5), config(Swap::Random, 0.5, 0.5, 6)] {
        let mut whole = BatchSource::open(&data, &cfg).unwrap().start(&cfg).unwrap();
        let mut within = BatchSource::open_within(&data, &cfg, Budget::bytes(1 << 30)).unwrap().start(&cfg).unwrap();
        assert!(within.pool().is_none());
        for _ in 0..50 {
            assert_eq!(whole.next_batch().unwrap(), within.next_batch().unwrap());
        }
    }
}

#[test]
fn the_same_seed_gives_the_same_batches_and_another_seed_others() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let run = |seed| {
        let cfg = config(Swap::Random, 0.5, 0.5, seed);
        let mut s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
        (0..PASS_BATCHES).map(|_| s.next_batch().unwrap()).collect::<Vec<_>>()
    };
    let a = run(1);
    assert!(a == run(1), "the same seed drew other batches");
    assert!(a != run(2), "another seed drew the same batches");
}

#[test]
fn the_cli_draws_the_same_bytes_at_any_thread_count() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let out = |threads: &str, (count, rows): (&str, &str)| {
        let path = dir.path().join(format!("batches-{threads}-{rows}.parquet"));
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
            .args(["batches", "--data"])
            .arg(&data)
            .args(["--count", count, "--batch-size", rows, "--swap", "random", "--memory-budget", "240kB", "-o"])
            .arg(&path)
            .env("RAYON_NUM_THREADS", threads)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", common::text(&o.stderr));
        common::read_table(&path).0.columns().to_vec()
    };
    // The columns (the footer records the command line, which names each output).
    assert!(out("1", ("300", "98")) == out("2", ("300", "98")), "other batches on one thread than on two");
    // Batches of 8192 rows of 10 observation values (past `gather_rows`' 65,536 floats) on 4
    // threads copy their rows on the thread pool; on 1, on the drawing thread.
    assert!(out("1", ("12", "8192")) == out("4", ("12", "8192")), "other batches on four threads than on one");
}

#[test]
fn a_budget_too_small_is_refused_saying_what_would_do() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let cfg = config(Swap::None, 0.5, 0.5, 0);
    let e = BatchSource::open_within(&data, &cfg, Budget::bytes(60_000)).err().expect("refused").to_string();
    assert!(e.contains("fewer than two") && e.contains("give at least"), "{e}");
}

#[test]
fn a_corrupt_block_is_named_by_file_and_row_group() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    // Flip a byte in the middle of shard 2's data pages.
    let shard = data.join("coded-2.parquet");
    let mut bytes = std::fs::read(&shard).unwrap();
    let i = bytes.len() / 3;
    bytes[i] ^= 0x40;
    std::fs::write(&shard, &bytes).unwrap();
    // The manifest's sizes still agree, so the folder opens; the block read finds the fault,
    // at the first fill (observations and goals) or when the loader reaches it.
    let cfg = config(Swap::None, 0.5, 0.5, 0);
    let e = common::coded::first_failure(&data, &cfg, Budget::bytes(BUDGET), 3 * PASS_BATCHES);
    assert!(e.contains("coded-2.parquet") && e.contains("row group"), "{e}");
}

#[test]
fn a_resumed_stream_draws_what_an_uninterrupted_one_does() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let cfg = config(Swap::Random, 0.5, 0.5, 9);
    let open = || BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap();
    let mut whole = open().start(&cfg).unwrap();
    // Stopped past more than a pass (swaps, reservoir refreshes and a new pass's order replayed).
    let stop = PASS_BATCHES as u64 + 37;
    for _ in 0..stop {
        whole.next_batch().unwrap();
    }
    let rng = whole.rng().clone();
    // A pool opened for a fresh stream is refused for a resumed one: resuming it would read a
    // second pool while the first still held its blocks (twice the budget, seen at 297 MB for a
    // 150 MB one). It is opened where the stream resumes instead.
    let e = open().resume(&cfg, rng.clone(), stop).err().expect("a pool opened at batch 0 resumed at another");
    assert!(e.to_string().contains("opened for batch 0") && e.to_string().contains("open_resuming"), "{e}");
    let mut resumed =
        BatchSource::open_resuming(&data, &cfg, Budget::bytes(BUDGET), stop).unwrap().resume(&cfg, rng, stop).unwrap();
    for _ in 0..PASS_BATCHES {
        assert_eq!(whole.next_batch().unwrap(), resumed.next_batch().unwrap());
    }
}

#[test]
fn blocks_kept_for_two_draws_a_row_read_half_as_much_and_keep_every_shards_share() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let cfg = config(Swap::Random, 0.5, 0.5, 11);
    let budget = Budget::Bytes { bytes: BUDGET, draws_per_row: 2 };
    let open = || BatchSource::open_within(&data, &cfg, budget).unwrap();
    let mut s = open().start(&cfg).unwrap();
    let mut by_episode = vec![0u64; EPISODES];
    for k in 0..2 * PASS_BATCHES {
        let (b, ids) = s.next_batch().unwrap();
        for i in 0..b.n {
            let (e, t) = (ids.episode[i] as usize, ids.step[i] as usize);
            assert_eq!(decode(b.obs[i * 10]), (e, t), "batch {k}, row {i}");
            by_episode[e] += 1;
        }
        if k + 1 == PASS_BATCHES {
            let swaps = s.pool().unwrap().stats().rotations as usize;
            assert_eq!(swaps, EPISODES / GROUP_EPISODES / 2, "a pass of draws reads half the blocks");
        }
    }
    // Two passes of draws are one pass of reading: every block swapped in once, and every shard,
    // episode and step drawn in its share.
    assert_eq!(s.pool().unwrap().stats().rotations as usize, EPISODES / GROUP_EPISODES);
    let gap = worst_share_gap(by_episode.iter().enumerate().flat_map(|(e, &c)| std::iter::repeat_n(e, c as usize)));
    assert!(gap < 2.0, "a shard's share of the draws is {gap:.2} points off its share of the rows");
    let (stat, bound) = chi_square(&by_episode);
    assert!(stat < bound, "episode counts: chi-square {stat:.0} over {bound:.0}");
    // Resumed, it replays the same longer stays.
    let stop = PASS_BATCHES as u64 + 21;
    let mut whole = open().start(&cfg).unwrap();
    for _ in 0..stop {
        whole.next_batch().unwrap();
    }
    let resuming = BatchSource::open_resuming(&data, &cfg, budget, stop).unwrap();
    let mut resumed = resuming.resume(&cfg, whole.rng().clone(), stop).unwrap();
    for _ in 0..PASS_BATCHES / 2 {
        assert_eq!(whole.next_batch().unwrap(), resumed.next_batch().unwrap());
    }
    // The trainer's flag needs a budget.
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .arg("--data")
        .arg(&data)
        .args(["-o", "x.ckpt", "--draws-per-row", "2"])
        .current_dir(dir.path())
        .output()
        .unwrap();
    assert!(!o.status.success());
    assert!(common::text(&o.stderr).contains("--memory-budget"), "{}", common::text(&o.stderr));
}

#[test]
fn pgser_train_resumes_a_pool_run_to_the_uninterrupted_weights() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let train = |name: &str, updates: &str, resume: bool| {
        let ckpt = dir.path().join(name);
        let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"));
        cmd.arg("--data").arg(&data).arg("-o").arg(&ckpt);
        cmd.args(["--updates", updates, "--batch-size", "98", "--hidden", "32", "--eval-episodes", "0"]);
        cmd.args(["--log-every", "50", "--swap", "random", "--memory-budget", "240kB", "--seed", "2"]);
        if resume {
            cmd.arg("--resume");
        }
        let o = cmd.output().unwrap();
        assert!(o.status.success(), "{}", common::text(&o.stderr));
        assert!(common::text(&o.stderr).contains("row groups resident"), "{}", common::text(&o.stderr));
        ckpt
    };
    // 300 updates of 98 rows: past a pass (240 batches) of the 96 blocks.
    let straight = train("straight.ckpt", "300", false);
    let split = train("split.ckpt", "170", false);
    assert_ne!(common::checkpoint_weights(&straight), common::checkpoint_weights(&split));
    train("split.ckpt", "300", true);
    assert_eq!(common::checkpoint_weights(&straight), common::checkpoint_weights(&split));
}

#[test]
fn a_shard_window_holds_one_shard_in_folder_order_and_draws_every_goal_from_it() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    // Every row swapped or HER: random goals must come from the held shard too.
    let cfg = config(Swap::Random, 0.5, 1.0, 3);
    let window = 40u64;
    let open = || BatchSource::open_within(&data, &cfg, Budget::ShardWindow(window * BATCH as u64)).unwrap();
    let mut s = open().start(&cfg).unwrap();
    assert!(s.pool().unwrap().is_window());
    let mut goal_shards = std::collections::BTreeSet::new();
    for k in 0..(window * 6) as usize {
        let (b, ids) = s.next_batch().unwrap();
        // As in Horizon Reduction's loop (a reload before update i when i % N == 0, i from 1), the
        // first shard serves N − 1 batches and every later one N.
        let held = ((k + 1) / window as usize) % SHARDS.len();
        for i in 0..b.n {
            assert_eq!(shard_of(ids.episode[i] as usize), held, "batch {k}: a transition outside shard {held}");
            let (ge, gs) = decode(b.goal[i * 3]);
            assert_eq!(shard_of(ge), held, "batch {k}: a goal outside shard {held}");
            assert!(gs < T);
            goal_shards.insert(shard_of(ge));
        }
    }
    assert_eq!(goal_shards.len(), SHARDS.len(), "over 6 windows every shard was held");
    // A resumed window draws what an uninterrupted one does.
    let stop = 97;
    let mut whole = open().start(&cfg).unwrap();
    for _ in 0..stop {
        whole.next_batch().unwrap();
    }
    let resuming = BatchSource::open_resuming(&data, &cfg, Budget::ShardWindow(window * BATCH as u64), stop).unwrap();
    let mut resumed = resuming.resume(&cfg, whole.rng().clone(), stop).unwrap();
    for _ in 0..100 {
        assert_eq!(whole.next_batch().unwrap(), resumed.next_batch().unwrap());
    }
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_pgser-train"))
        .arg("--data")
        .arg(&data)
        .args(["-o", "x.ckpt", "--shard-window", "10", "--memory-budget", "1GB"])
        .output()
        .unwrap();
    let e = common::text(&o.stderr);
    assert!(!o.status.success() && e.contains("--shard-window") && e.contains("--memory-budget"), "{e}");
}

#[test]
fn a_pool_drawn_while_every_rayon_worker_is_held_still_reads_its_blocks() {
    // pgser-train draws each cell's batch inside the global pool (a `par_iter_mut`), so a draw
    // that waits for a block holds a worker. Here every worker is held: one draws a pass (96
    // swaps), the others wait for it. A loader that needed a worker (to check a block's chunks
    // in parallel, as it once did) would never deliver, and the draw would wait for ever.
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let cfg = config(Swap::Random, 0.5, 0.5, 12);
    let s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    let stream = std::sync::Mutex::new(s);
    let drawn = std::sync::atomic::AtomicBool::new(false);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let swaps = rayon::broadcast(|ctx| {
            if ctx.index() == 0 {
                let mut s = stream.lock().unwrap();
                for _ in 0..PASS_BATCHES {
                    s.next_batch().unwrap();
                }
                drawn.store(true, std::sync::atomic::Ordering::SeqCst);
                Some(s.pool().unwrap().stats().rotations)
            } else {
                while !drawn.load(std::sync::atomic::Ordering::SeqCst) {
                    std::thread::sleep(std::time::Duration::from_millis(1));
                }
                None
            }
        });
        tx.send(swaps[0]).unwrap();
    });
    let Ok(swaps) = rx.recv_timeout(std::time::Duration::from_secs(120)) else {
        // The global pool stays held, so every other test of this binary would wait too: end it.
        eprintln!("a_pool_drawn_while_every_rayon_worker_is_held: the draws hang with every worker held");
        std::process::exit(1);
    };
    assert_eq!(swaps, Some((EPISODES / GROUP_EPISODES) as u64));
}

#[test]
fn a_failed_block_read_fails_every_later_batch_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    // The actions of shard 3's last row group: a column the first fill does not read, of a block
    // not resident at the start for this seed, so the fault is met by the loader mid-stream.
    let last = common::coded::flip_in_last_chunk(&data.join("coded-3.parquet"), "action", 0x10);
    let cfg = config(Swap::None, 0.5, 0.5, 1);
    let mut s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    let first = (0..2 * PASS_BATCHES).find_map(|_| s.next_batch().err()).expect("the corrupt block is read");
    let first = format!("{first:#}");
    assert!(first.contains("coded-3.parquet") && first.contains(&format!("row group {last}")), "{first}");
    // No batch from blocks that should have left: every later call fails with the same fault.
    for _ in 0..3 {
        let again = s.next_batch().expect_err("a batch drawn after the pool failed");
        assert_eq!(format!("{again:#}"), first);
    }
}

#[test]
fn a_shard_replaced_after_the_pool_opened_is_refused_as_changed_not_corrupt() {
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let cfg = config(Swap::None, 0.5, 0.5, 1);
    let mut s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    // A shard of the same size put in its place: one byte of its data changed, written beside
    // it and renamed over it, as a re-run of convert or a copy would.
    let shard = data.join("coded-1.parquet");
    let mut bytes = std::fs::read(&shard).unwrap();
    let i = bytes.len() / 2;
    bytes[i] ^= 0x01;
    std::fs::write(data.join("coded-1.parquet.new"), &bytes).unwrap();
    std::fs::rename(data.join("coded-1.parquet.new"), &shard).unwrap();
    let e = (0..2 * PASS_BATCHES).find_map(|_| s.next_batch().err()).expect("a block of the replaced shard is read");
    let e = format!("{e:#}");
    assert!(e.contains("coded-1.parquet") && e.contains("changed since it was opened"), "{e}");
}

/// Every goal the reservoir holds is the achieved goal and the observation of the (episode,
/// step) it names: after the first fill (from resident blocks and from blocks read for it alone)
/// and after half a pass of rotations (from the blocks that entered).
#[test]
fn reservoir_goals_are_the_rows_they_name() {
    use pgser::nprandom::NpRandom;
    use pgser::sampler::view::View;
    let dir = tempfile::tempdir().unwrap();
    let data = folder(dir.path());
    let cfg = config(Swap::Random, 0.5, 0.0, 3);
    let mut s = BatchSource::open_within(&data, &cfg, Budget::bytes(BUDGET)).unwrap().start(&cfg).unwrap();
    let check = |pool: &pgser::sampler::pool::Pool| {
        assert!(pool.reservoir() > 100, "{}", pool.reservoir());
        let mut rng = NpRandom::new(5);
        let mut outside = 0;
        for _ in 0..4 * pool.reservoir() {
            let g = pool.random_goal(&mut rng);
            let at = (g.episode as usize, g.step as usize);
            assert_eq!(decode(pool.goal_obs(g)[0]), at, "slot {}: the observation is another row's", g.slot);
            assert_eq!(decode(pool.goal_ag(g)[0]), at, "slot {}: the achieved goal is another row's", g.slot);
            let resident = (0..pool.resident_episodes()).any(|e| pool.episode_number(e) == g.episode);
            outside += usize::from(!resident);
        }
        // Most goals come from blocks that are not resident: the reservoir is the table's.
        assert!(
            outside > 2 * pool.reservoir(),
            "{outside} of {} draws outside the resident blocks",
            4 * pool.reservoir()
        );
    };
    check(s.pool().unwrap());
    for _ in 0..PASS_BATCHES / 2 {
        s.next_batch().unwrap();
    }
    check(s.pool().unwrap());
}
