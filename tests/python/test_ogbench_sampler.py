"""pgser.Sampler(layout="ogbench") against OGBench's GCDataset rules: on a table folder made from
OGBench shards (the committed PointMaze file OGBench's generator wrote, cut into one shard per
episode and converted by `pgser-etl convert DIR`), pgser's batches are compared with those of
bench/ogbench_peer.py (OGBench's `GCDataset.sample` / `sample_goals` in numpy: the `ogbench`
package does not ship its `impls/`) loaded from the same shards as OGBench's `load_dataset`
loads them. They agree in keys and shapes, in every row's contents (each row is the table's
transition and its goals the table's observations), and in distribution: success rates,
trajectory-goal offsets, the spread of transitions and random goals over episodes and steps."""

import argparse

import numpy as np
import pytest

import pgser
from conftest import BIN, REPO, bench_module, run

NAME = "pointmaze-medium-navigate-v0"
FIXTURE = REPO / "tests/fixtures/ogbench" / f"{NAME}.npz"
# OGBench's batch keys (GCDataset.sample on its regular layout) with the dtypes its code gives:
# float32 arrays from load_dataset, float64 rewards and masks from `successes.astype(float)`.
OGBENCH_DTYPES = {
    "observations": np.float32,
    "next_observations": np.float32,
    "actions": np.float32,
    "terminals": np.float32,
    "rewards": np.float64,
    "masks": np.float64,
    "value_goals": np.float32,
    "actor_goals": np.float32,
}
PROVENANCE = ("episode", "step", "value_goal_episode", "value_goal_step", "actor_goal_episode", "actor_goal_step",
              "scored_row")
KINDS = ("value_goal_kind", "actor_goal_kind")
# GCIQL's sampling defaults; the peer reads them as its command line does.
DEFAULTS = dict(discount=0.99, value_p_curgoal=0.2, value_p_trajgoal=0.5, actor_p_curgoal=0.0, actor_p_trajgoal=1.0)


def load_peer():
    return bench_module("ogbench_peer")


@pytest.fixture(scope="module")
def folder(ogbench_folder):
    return ogbench_folder


@pytest.fixture(scope="module")
def peer_data(folder):
    """The peer's regular layout of every shard, concatenated in shard order."""
    _, src, _ = folder
    peer = load_peer()
    parts = [peer.load_regular(str(p)) for p in peer.shards(str(src))]
    return peer, {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def many(sampler, batches, n=1024):
    """`batches` batches of `n`, concatenated."""
    got = [sampler.sample(n) for _ in range(batches)]
    return {k: np.concatenate([b[k] for b in got]) for k in got[0]}


def within(count, n, p, sigmas=4.0):
    sd = np.sqrt(n * p * (1 - p))
    assert abs(count - n * p) <= sigmas * sd, f"{count} of {n} where p = {p} (sd {sd:.1f})"


def chi_square_uniform(counts):
    """Pearson's χ² of counts against a uniform, and a bound (df + 5 sd) a uniform sample stays under."""
    counts = np.asarray(counts, float)
    e = counts.sum() / len(counts)
    chi, df = ((counts - e) ** 2 / e).sum(), len(counts) - 1
    return chi, df + 5 * np.sqrt(2 * df)


def test_keys_shapes_and_dtypes_are_ogbenchs(folder, peer_data):
    table, _, _ = folder
    peer, data = peer_data
    theirs = peer.GoalSampler(data, argparse.Namespace(**DEFAULTS), np.random.default_rng(0)).sample(256)
    with pgser.Sampler(table, layout="ogbench", seed=0) as s:
        ours = s.sample(256)
        assert (s.layout, s.task, s.batch_size) == ("ogbench", "pointmaze-medium-v0", 512)
    assert set(ours) == set(OGBENCH_DTYPES) | set(PROVENANCE) | set(KINDS)
    # The peer's dict is OGBench's less `terminals`; every key of it is here with its shape.
    assert set(theirs) <= set(ours)
    for k, v in theirs.items():
        assert ours[k].shape == v.shape, k
    for k, dtype in OGBENCH_DTYPES.items():
        assert ours[k].dtype == dtype, k
    for k in PROVENANCE:
        assert ours[k].dtype == np.int64 and ours[k].shape == (256,), k
    for k in KINDS:
        assert ours[k].dtype == np.uint8 and set(np.unique(ours[k])) <= {0, 1, 2}, k
    assert pgser.GOAL_KINDS[ours["value_goal_kind"][0]] in ("current", "trajectory", "random")


def test_rows_are_the_tables_transitions_and_goals_its_observations(folder):
    table, _, arrays = folder
    t = 101
    obs, actions = arrays["observations"], arrays["actions"]
    with pgser.Sampler(table, layout="ogbench", seed=1) as s:
        b = many(s, 4)
    # Episodes are numbered across the folder in shard order: shard k holds episode k.
    row = b["episode"] * t + b["step"]
    assert b["step"].max() <= t - 2 and set(np.unique(b["episode"])) == {0, 1, 2, 3}
    assert np.array_equal(b["observations"], obs[row])
    assert np.array_equal(b["next_observations"], obs[row + 1])
    assert np.array_equal(b["actions"], actions[row])
    assert np.array_equal(b["terminals"], (b["step"] == t - 2).astype(np.float32))
    for who in ("value", "actor"):
        e, st = b[f"{who}_goal_episode"], b[f"{who}_goal_step"]
        assert st.max() <= t - 2, f"{who} goals are transitions' observations"
        assert np.array_equal(b[f"{who}_goals"], obs[e * t + st]), who
    # Success is OGBench's `idx == value_goal_idx`: rewards and masks say it, with gc_negative.
    success = (b["value_goal_episode"] == b["episode"]) & (b["value_goal_step"] == b["step"])
    assert np.array_equal(b["masks"], 1.0 - success) and np.array_equal(b["rewards"], success - 1.0)
    # The actor's default goals: uniform later steps of the row's own episode.
    assert np.array_equal(b["actor_goal_episode"], b["episode"])
    assert np.all(b["actor_goal_step"] >= np.minimum(b["step"] + 1, t - 2))
    with pgser.Sampler(table, layout="ogbench", seed=1, gc_negative=False) as s:
        b = s.sample(2048)
    success = (b["value_goal_episode"] == b["episode"]) & (b["value_goal_step"] == b["step"])
    assert np.array_equal(b["rewards"], success.astype(np.float64)) and success.any()


def test_success_rates_match_ogbench(folder, peer_data):
    """P(success) = p_cur + p_traj · P(s is the last transition) + p_random · P(the row itself):
    0.2 + 0.5/100 + 0.3/400, for pgser and the peer alike."""
    table, _, _ = folder
    peer, data = peer_data
    p = 0.2 + 0.5 / 100 + 0.3 / 400
    with pgser.Sampler(table, layout="ogbench", seed=2) as s:
        ours = many(s, 50)
    sampler = peer.GoalSampler(data, argparse.Namespace(**DEFAULTS), np.random.default_rng(2))
    batches = [sampler.sample(1024) for _ in range(50)]
    theirs = {k: np.concatenate([b[k] for b in batches]) for k in ("rewards", "masks")}
    for b in (ours, theirs):
        n = len(b["rewards"])
        within(int((b["rewards"] == 0).sum()), n, p)
        assert np.array_equal(b["masks"], -b["rewards"])


def mean_geometric_offset(discount, last):
    """E[min(k, L − s)] for k ~ Geometric(1 − discount) on 1, 2, … and s uniform in 0..L:
    Σ_{j<m} discount^j = (1 − discount^m) / (1 − discount) for m = L − s."""
    m = np.arange(last + 1)
    return float(np.mean((1 - discount**m) / (1 - discount)))


@pytest.mark.parametrize("discount", [0.99, 0.9])
def test_trajectory_goal_offsets_match_ogbench(folder, peer_data, discount):
    table, _, _ = folder
    peer, data = peer_data
    last = 99
    # Every value goal from the trajectory (geometric), every actor goal too (uniform, OGBench's default).
    cfg = dict(DEFAULTS, discount=discount, value_p_curgoal=0.0, value_p_trajgoal=1.0)
    with pgser.Sampler(table, layout="ogbench", seed=3, value_p_curgoal=0.0, value_p_trajgoal=1.0,
                       value_p_randomgoal=0.0, discount=discount) as s:
        b = many(s, 30)
    ours_v = b["value_goal_step"] - b["step"]
    ours_a = b["actor_goal_step"] - b["step"]
    assert np.array_equal(b["value_goal_episode"], b["episode"])
    sampler = peer.GoalSampler(data, argparse.Namespace(**cfg), np.random.default_rng(3))
    idx = np.random.default_rng(4).integers(0, sampler.size, len(ours_v))
    theirs_v = sampler.goals(idx, 0.0, 1.0, True) - idx
    theirs_a = sampler.goals(idx, 0.0, 1.0, False) - idx
    want_v = mean_geometric_offset(discount, last)
    # Uniform goals: round(lo·d + L·(1 − d)) with lo = min(s + 1, L) has mean (lo + L)/2.
    s = np.arange(last + 1)
    want_a = float(np.mean((np.minimum(s + 1, last) + last) / 2 - s))
    for name, x, want in (("pgser value", ours_v, want_v), ("peer value", theirs_v, want_v),
                          ("pgser actor", ours_a, want_a), ("peer actor", theirs_a, want_a)):
        sd = x.std() / np.sqrt(len(x))
        assert abs(x.mean() - want) < 4 * sd, f"{name}: mean offset {x.mean():.3f}, want {want:.3f} ± {sd:.3f}"
    # And the two in distribution: a two-sample χ² over offset bins.
    bins = np.array([0, 1, 2, 3, 5, 8, 13, 21, 34, 55, 100])
    for a, c in ((ours_v, theirs_v), (ours_a, theirs_a)):
        ca, cc = np.histogram(a, bins)[0].astype(float), np.histogram(c, bins)[0].astype(float)
        keep = ca + cc > 0
        ca, cc = ca[keep], cc[keep]
        chi = (((ca - cc) ** 2) / (ca + cc)).sum()
        df = len(ca) - 1
        assert chi < df + 5 * np.sqrt(2 * df), f"two-sample χ² {chi:.1f} over {df} degrees of freedom"


def test_transitions_and_random_goals_are_uniform_over_the_folder(folder):
    table, _, _ = folder
    with pgser.Sampler(table, layout="ogbench", seed=5, value_p_curgoal=0.0, value_p_trajgoal=0.0,
                       value_p_randomgoal=1.0) as s:
        b = many(s, 40)
    for what, e, st in (("transitions", b["episode"], b["step"]),
                        ("random goals", b["value_goal_episode"], b["value_goal_step"])):
        # A random goal is a transition's observation (step ≤ T − 2), as OGBench draws them.
        assert st.min() >= 0 and st.max() == 99, what
        for counts in (np.bincount(e, minlength=4), np.bincount(st, minlength=100)):
            chi, bound = chi_square_uniform(counts)
            assert chi < bound, f"{what}: χ² {chi:.1f} over {len(counts)} bins"
    # Drawn apart from the row: a goal lands on the row itself 1 time in 400.
    within(int((b["rewards"] == 0).sum()), len(b["rewards"]), 1 / 400)


def test_an_ogbench_agent_config_is_taken_unchanged(folder):
    table, _, _ = folder
    # OGBench's GCIQL get_config() as a dict (ConfigDict placeholders are None).
    config = dict(agent_name="gciql", lr=3e-4, batch_size=1024, actor_hidden_dims=(512, 512, 512),
                  value_hidden_dims=(512, 512, 512), layer_norm=True, discount=0.99, tau=0.005, expectile=0.9,
                  actor_loss="ddpgbc", alpha=0.3, const_std=True, discrete=False, encoder=None,
                  dataset_class="GCDataset", value_p_curgoal=0.2, value_p_trajgoal=0.5, value_p_randomgoal=0.3,
                  value_geom_sample=True, actor_p_curgoal=0.0, actor_p_trajgoal=1.0, actor_p_randomgoal=0.0,
                  actor_geom_sample=False, gc_negative=True, p_aug=0.0, frame_stack=None)
    with pgser.Sampler(table, layout="ogbench", config=config, seed=6) as s, \
            pgser.Sampler(table, layout="ogbench", seed=6, batch_size=1024) as plain:
        assert s.batch_size == 1024
        a, b = s.sample(), plain.sample()
    # The config is GCIQL's defaults: the same batches as no config at all.
    assert all(np.array_equal(a[k], b[k]) for k in a)
    # Its keys are read: a config whose value goals are all current ones.
    cur = dict(config, value_p_curgoal=1.0, value_p_trajgoal=0.0, value_p_randomgoal=0.0)
    with pgser.Sampler(table, layout="ogbench", config=cur) as s:
        c = s.sample(512)
    assert np.all(c["rewards"] == 0) and np.array_equal(c["value_goals"], c["observations"])
    # Keyword arguments win over the config.
    with pgser.Sampler(table, layout="ogbench", config=cur, value_p_curgoal=0.0, value_p_randomgoal=1.0) as s:
        assert (s.sample(512)["rewards"] == -1).mean() > 0.9
    bad = [
        (dict(config, frame_stack=3), "frame_stack"),
        (dict(config, p_aug=0.5), "p_aug"),
        (dict(config, dataset_class="HGCDataset"), "HGCDataset needs subgoal_steps"),
        (dict(config, dataset_class="WGCSLDataset"), "pgser draws GCDataset's and HGCDataset's"),
        (dict(config, value_p_randomgoal=0.4), "must be 1"),
        (dict(config, discount=1.0), "discount = 1"),
        (dict(config, actor_p_curgoal="a lot"), "not a number"),
    ]
    for cfg, msg in bad:
        with pytest.raises(ValueError, match=msg):
            pgser.Sampler(table, layout="ogbench", config=cfg)


def test_bad_arguments_raise_naming_them(folder, tables):
    table, _, _ = folder
    traj, _, _ = tables
    with pytest.raises(ValueError, match='her= is a setting of layout="pgser"'):
        pgser.Sampler(table, layout="ogbench", her=0.3)
    with pytest.raises(ValueError, match='value_p_curgoal= is a setting of layout="ogbench"'):
        pgser.Sampler(traj, value_p_curgoal=0.3)
    with pytest.raises(ValueError, match="layout="):
        pgser.Sampler(table, layout="minari")
    for budget, msg in (("2XB", "unknown unit"), (-5, "memory_budget=-5"), (0, "memory_budget=0"),
                        ("1kB", "fewer than two")):
        with pytest.raises(ValueError, match=msg):
            pgser.Sampler(table, layout="ogbench", memory_budget=budget)
    with pgser.Sampler(traj, batch_size=8) as s:
        with pytest.raises(ValueError, match="batch_size=9"):
            s.sample(9)
        assert s.sample()["obs"].shape == (8, 10)
    with pgser.Sampler(table, layout="ogbench") as s:
        with pytest.raises(ValueError, match="batch_size=0"):
            s.sample(0)


def test_pgsers_swapped_rows_come_in_their_fraction_with_their_goals_observation(folder, tmp_path):
    table, _, arrays = folder
    t, obs = 101, arrays["observations"]
    ckpt, scored = tmp_path / "q.ckpt", tmp_path / "scored"
    run(BIN / "pgser-train", "--data", table, "-o", ckpt, "--updates", "10", "--hidden", "16", "--batch-size", "64",
        "--eval-episodes", "0", "--swap", "random")
    pgser.score(ckpt, table, scored, swaps=4)
    with pgser.Sampler(scored, layout="ogbench", p_swapgoal=0.4, priority="q", seed=2) as s:
        assert s.scored
        b = many(s, 3)
    swapped = b["scored_row"] >= 0
    within(int(swapped.sum()), len(swapped), 0.4)
    # A swapped row is the transition its scored row scored (4 rows per transition, in order),
    # its goals the observation its scored goal was taken from.
    rows = b["scored_row"][swapped]
    assert np.array_equal(rows // 4, (b["episode"] * (t - 1) + b["step"])[swapped])
    e, st = b["value_goal_episode"], b["value_goal_step"]
    assert np.array_equal(b["value_goals"], obs[e * t + st])
    assert np.array_equal(b["actor_goals"][swapped], b["value_goals"][swapped])
    # Read from an agent's config too; without swaps a scored folder gives its data's batches.
    with pgser.Sampler(scored, layout="ogbench", config=dict(p_swapgoal=1.0), seed=2) as s:
        assert (s.sample(64)["scored_row"] >= 0).all()
    with pgser.Sampler(scored, layout="ogbench", seed=5) as s, pgser.Sampler(table, layout="ogbench", seed=5) as p:
        assert not s.scored
        x, y = s.sample(256), p.sample(256)
        assert all(np.array_equal(x[k], y[k]) for k in x)
    with pytest.raises(ValueError, match="p_swapgoal = 0.2 draws swapped goals by priority from a scored table"):
        pgser.Sampler(table, layout="ogbench", p_swapgoal=0.2)
    with pytest.raises(ValueError, match="is_beta= is a setting of layout=\"pgser\""):
        pgser.Sampler(scored, layout="ogbench", p_swapgoal=0.2, is_beta=0.4)


def test_pool_stats_count_the_disk_waits_of_a_pool_and_none_when_held_whole(tables, tmp_path):
    # The FetchReach sample in row groups of 10 episodes (25 of them), and a budget that holds 3.
    small = tmp_path / "small.parquet"
    data = REPO / "data"
    pgser.convert([data / "fetch_reach_expert_50.pkl", data / "fetch_reach_random_200.pkl"], small,
                  row_group_rows=500)
    for layout in ("ogbench", "pgser"):
        with pgser.Sampler(small, layout=layout, memory_budget=350_000, batch_size=256, seed=1) as s:
            for _ in range(60):
                s.sample()
            st = s.pool_stats()
        # 60 batches of 256 draws are 15,360, and a block leaves after its 490 transitions.
        assert st["rotations"] >= 25, (layout, st)
        assert 0 <= st["waits"] <= st["rotations"] and st["longest_wait_seconds"] <= st["waited_seconds"], st
        assert 0 < st["longest_rotation_seconds"] < 1.0, st
        with pgser.Sampler(small, layout=layout, batch_size=256) as s:
            s.sample()
            assert s.pool_stats() is None
        # Blocks kept for two draws per transition: half the swaps for the same batches asked.
        with pgser.Sampler(small, layout=layout, memory_budget=350_000, batch_size=256, seed=1, prefetch=1,
                           draws_per_row=2) as s:
            for _ in range(60):
                s.sample()
            twice = s.pool_stats()["rotations"]
        assert abs(twice - st["rotations"] / 2) <= 3, (layout, twice, st)
    for kw, msg in ((dict(draws_per_row=0), "draws_per_row=0"), (dict(draws_per_row=2), "needs memory_budget")):
        with pytest.raises(ValueError, match=msg):
            pgser.Sampler(small, layout="ogbench", **kw)
    # With a pool, what is resident depends on the batches drawn before: the same calls give the
    # same bytes whether they come back to back (the queue never full) or after it has filled,
    # and whatever the queue's length (batches drawn ahead and dropped for another size once
    # moved the pool on by as many as the queue held). Sizes cross many swaps (a block leaves
    # after 490 draws).
    import time
    sizes = [256, 256, 100, 256, 300, 256, 256, 50, 256, 256, 256, 400, 256, 256]

    def run(pause, prefetch):
        with pgser.Sampler(small, layout="ogbench", memory_budget=350_000, batch_size=256, seed=4,
                           prefetch=prefetch) as s:
            out = []
            for n in sizes:
                time.sleep(pause)
                out.append(s.sample(n))
            return out

    want = run(0.0, 4)
    for pause, prefetch in ((0.02, 4), (0.02, 1), (0.02, 16), (0.0, 16)):
        for i, (a, b) in enumerate(zip(want, run(pause, prefetch))):
            assert all(np.array_equal(a[k], b[k]) for k in a), (pause, prefetch, i)


def test_same_seed_same_bytes_whatever_the_sizes_asked(folder):
    table, _, _ = folder
    # A table that fits its budget is held whole: the same batches as without one.
    with pgser.Sampler(table, layout="ogbench", seed=7, batch_size=64) as a, \
            pgser.Sampler(table, layout="ogbench", seed=7, batch_size=64, memory_budget="1GB", prefetch=1) as b:
        first = [a.sample() for _ in range(3)]
        for x in first:
            y = b.sample()
            assert all(np.array_equal(x[k], y[k]) for k in x)
    # Batch k depends on (seed, k, its size) only: asking for another size first changes no other batch.
    with pgser.Sampler(table, layout="ogbench", seed=7, batch_size=64) as c:
        one = c.sample(1)
        assert one["observations"].shape == (1, 2)
        second = c.sample()
    assert all(np.array_equal(second[k], first[1][k]) for k in second)
    assert not np.array_equal(first[0]["step"], first[1]["step"])
    # Iteration: batches of batch_size, num_batches of them (sample() counts too).
    with pgser.Sampler(table, layout="ogbench", seed=7, batch_size=64, num_batches=3) as d:
        got = list(d)
        assert len(got) == 3 and all(np.array_equal(g[k], f[k]) for g, f in zip(got, first) for k in g)
    d.close()
    with pytest.raises(ValueError, match="closed"):
        d.sample()


def test_read_table_takes_a_folder_as_one_table(folder, tmp_path):
    """pgser.read_table of a table folder is the single file of the same episodes, episodes
    numbered across the shards, with the manifest's footer (the folder's totals)."""
    table, _, _ = folder
    single = tmp_path / "single.parquet"
    run(BIN / "pgser-etl", "convert", FIXTURE, "-o", single)
    a, b = pgser.read_table(table), pgser.read_table(single)
    for name in ["episode", "step", "obs", "achieved_goal", "action"]:
        assert a.column(name).to_pylist() == b.column(name).to_pylist(), name
    footer = pgser.read_footer(table)
    assert footer["episodes"] == pgser.read_footer(single)["episodes"] == 4
    obs = pgser.read_table(table, columns=["episode", "obs"])
    assert obs.column_names == ["episode", "obs"]


@pytest.mark.parametrize("layout,config", [("ogbench", None),
                                           ("horizon_reduction", dict(dataset_class="HGCDataset", subgoal_steps=10))])
def test_a_shard_window_holds_one_shard_at_a_time_and_every_goal_from_it(folder, layout, config):
    """Horizon Reduction's loading, to compare with: `shard_window=2` holds one shard at a time,
    the next in folder order every two batches of `batch_size` (the first shard one batch fewer,
    as pgser-train's --shard-window), and draws every goal, random ones too, from the held shard
    (one episode a shard here)."""
    table, _, _ = folder
    with pgser.Sampler(table, layout=layout, config=config, batch_size=64, shard_window=2, seed=3,
                       value_p_curgoal=0.0, value_p_trajgoal=0.0, value_p_randomgoal=1.0) as s:
        batches = [s.sample() for _ in range(10)]
    goal = "value_goal" if layout == "ogbench" else "high_value_goal"
    for k, b in enumerate(batches):
        held = ((k + 1) // 2) % 4
        assert set(np.unique(b["episode"])) == {held}, k
        assert set(np.unique(b[f"{goal}_episode"])) == {held}, k
    with pytest.raises(ValueError, match="two ways of holding a folder"):
        pgser.Sampler(table, layout=layout, shard_window=2, memory_budget="1GB")
    with pytest.raises(ValueError, match="shard_window=0"):
        pgser.Sampler(table, layout=layout, shard_window=0)
