"""pgser.Sampler with `dataset_class="HGCDataset"` against both hierarchical classes' rules, in
OGBench's layout (`layout="ogbench"`: HIQL) and Horizon Reduction's (`layout="horizon_reduction"`:
SHARSA, double SHARSA, n-step SAC+BC, hierarchical flow BC). The peer is bench/hgc_peer.py, the
two classes re-implemented in numpy from their code, on the same shards loaded the way each
code loads them (OGBench's regular layout, Horizon Reduction's compact one). pgser and the peer
agree in keys and dtypes, every row's keys are the table's vectors at the steps the provenance
columns name (exact, given the draws), and the distributions of subgoal steps, targets and
successes agree within statistical bounds."""

import math
import sys

import numpy as np
import pytest

import pgser
from conftest import BIN, REPO, bench_module, run

NAME = "pointmaze-medium-navigate-v0"
T = 101
# OGBench's HIQL sampling settings (impls/agents/hiql.py), and Horizon Reduction's SHARSA's
# (agents/sharsa.py) with double SHARSA's low_discount placeholder: the key, at None.
HIQL = dict(agent_name="hiql", batch_size=1024, discount=0.99, dataset_class="HGCDataset", subgoal_steps=25,
            value_p_curgoal=0.2, value_p_trajgoal=0.5, value_p_randomgoal=0.3, value_geom_sample=True,
            actor_p_curgoal=0.0, actor_p_trajgoal=1.0, actor_p_randomgoal=0.0, actor_geom_sample=False,
            gc_negative=True, p_aug=0.0, frame_stack=None, encoder=None)
SHARSA = dict(agent_name="dsharsa", lr=3e-4, batch_size=1024, discount=0.999, low_discount=None,
              dataset_class="HGCDataset", subgoal_steps=25, value_p_curgoal=0.2, value_p_trajgoal=0.5,
              value_p_randomgoal=0.3, value_geom_sample=False, actor_p_curgoal=0.0, actor_p_trajgoal=0.5,
              actor_p_randomgoal=0.5, actor_geom_sample=True, gc_negative=False, action_dim=None)


def load_peer():
    return bench_module("hgc_peer")


@pytest.fixture(scope="module")
def folder(ogbench_folder):
    return ogbench_folder


def many(sampler, batches, n=1024):
    got = [sampler.sample(n) for _ in range(batches)]
    return {k: np.concatenate([b[k] for b in got]) for k in got[0]}


def peer_many(cls, batches, n=1024):
    got = [cls.sample(n) for _ in range(batches)]
    batch = {k: np.concatenate([b[0][k] for b in got]) for k in got[0][0]}
    index = {k: np.concatenate([b[1][k] for b in got]) for k in got[0][1]}
    return batch, index


def close(a, b, sd, what):
    """Two sample means within 5 standard errors of their difference."""
    assert abs(a - b) <= 5 * sd, f"{what}: pgser {a:.4f}, peer {b:.4f} (sd {sd:.4f})"


def share(x, y, what):
    """Two samples' shares of True within 5 standard errors."""
    p = (x.mean() + y.mean()) / 2
    close(x.mean(), y.mean(), np.sqrt(max(p * (1 - p), 1e-12) * (1 / len(x) + 1 / len(y))), what)


def mean(x, y, what):
    close(x.mean(), y.mean(), np.sqrt(x.var() / len(x) + y.var() / len(y)) + 1e-12, what)


def provenance(b):
    return {k for k in b if k in ("episode", "step", "scored_row") or k.endswith(("_episode", "_step", "_kind"))
            and k not in ("high_value_subgoal_steps",)}


@pytest.mark.parametrize("code,config", [("ogbench", HIQL), ("horizon_reduction", SHARSA)])
def test_keys_and_dtypes_are_their_classes(folder, code, config):
    table, src, _ = folder
    peer = load_peer()
    data = peer.load(peer.files(str(src)), code, oracle_reps=code == "horizon_reduction")
    theirs, _ = peer.CLASSES[code](data, dict(config), np.random.default_rng(0)).sample(64)
    kw = dict(env_name="pointmaze-medium-navigate-oraclerep-v0") if code == "horizon_reduction" else {}
    with pgser.Sampler(table, layout=code, config=config, seed=0, **kw) as s:
        ours = s.sample(64)
        assert (s.layout, s.batch_size) == (code, 1024)
    assert set(ours) - provenance(ours) == set(theirs)
    for k, v in theirs.items():
        assert (ours[k].dtype, ours[k].shape) == (v.dtype, v.shape), k
    for k in provenance(ours):
        assert ours[k].dtype == (np.uint8 if k.endswith("_kind") else np.int64), k
    with pgser.Sampler(table, layout=code, config=config, provenance=False, **kw) as s:
        assert set(s.sample(8)) == set(theirs)


def test_horizon_reductions_keys_are_the_tables_vectors_at_their_steps(folder):
    table, _, arrays = folder
    obs, qpos, actions = arrays["observations"], arrays["qpos"], arrays["actions"]
    cfg = dict(SHARSA, value_subgoal_steps=10, actor_subgoal_steps=30, low_discount=0.9, gc_negative=True)
    with pgser.Sampler(table, layout="horizon_reduction", config=cfg, oracle_reps=True, clip_actions=0.1,
                       seed=1) as s:
        b = many(s, 8)
    e, st = b["episode"], b["step"]
    row = e * T + st
    reps = qpos[:, :2].astype(np.float32)
    assert np.array_equal(b["observations"], obs[row]) and np.array_equal(b["next_observations"], obs[row + 1])
    assert np.array_equal(b["actions"], np.clip(actions[row], -1 + 0.1, 1 - 0.1))
    assert np.array_equal(b["oracle_reps"], reps[row]) and np.array_equal(b["high_value_reps"], reps[row])
    last = T - 2
    for stem, steps in (("high_value", 10), ("high_actor", 30)):
        ge, gs = b[f"{stem}_goal_episode"], b[f"{stem}_goal_step"]
        assert np.array_equal(b[f"{stem}_goals"], reps[ge * T + gs]), stem
        # compute_high_next_idxs on flat indices: to the episode's end, then to the goal.
        k = np.minimum(steps, last - st)
        diff = (ge * T + gs) - row
        k = np.where((diff >= 0) & (diff < k), diff, k)
        assert np.array_equal(b[f"{stem}_actions"], reps[row + k]), stem
        assert np.array_equal(b[f"{stem}_next_observations"], obs[row + k]), stem
        if stem == "high_value":
            assert np.array_equal(b["high_value_subgoal_steps"], k) and np.array_equal(b["high_value_offsets"], diff)
            reached = (k < 10).astype(float)
            assert np.array_equal(b["high_value_masks"], 1 - reached)
            # γ^k is C's pow (glibc's, correctly rounded, the same on every machine); numpy's own
            # power on AVX-512 CPUs differs from it in the last bit for some k.
            pow_c = np.array([math.pow(0.999, float(j)) for j in k])
            assert np.array_equal(b["high_value_rewards"], -(1 - pow_c) / (1 - 0.999))
            assert np.allclose(b["high_value_rewards"], -(1 - 0.999 ** k) / (1 - 0.999), rtol=1e-12, atol=0)
            assert 0 < reached.mean() < 1
    assert np.array_equal(b["low_actor_goals"], reps[e * T + np.minimum(st + 30, last)])
    le, ls = b["low_value_goal_episode"], b["low_value_goal_step"]
    low = (le == e) & (ls == st)
    assert np.array_equal(b["low_value_goals"], reps[le * T + ls])
    assert np.array_equal(b["low_value_masks"], 1.0 - low) and np.array_equal(b["low_value_rewards"], low - 1.0)


@pytest.mark.parametrize("code,config", [("ogbench", HIQL), ("horizon_reduction", SHARSA)])
def test_distributions_match_their_classes(folder, code, config):
    table, src, _ = folder
    peer = load_peer()
    data = peer.load(peer.files(str(src)), code)
    cfg = dict(config, subgoal_steps=10, actor_p_trajgoal=0.6, actor_p_randomgoal=0.4)
    if code == "horizon_reduction":
        cfg["low_discount"] = 0.95
    theirs, idx = peer_many(peer.CLASSES[code](data, cfg, np.random.default_rng(3)), 40)
    with pgser.Sampler(table, layout=code, config=cfg, seed=3) as s:
        ours = many(s, 40)
    # The peer's flat indices as (episode, step): T rows an episode in the compact layout, T − 1
    # in the regular one.
    per = T if code == "horizon_reduction" else T - 1
    step = lambda i: i % per  # noqa: E731
    same = lambda i, j: (i // per) == (j // per)  # noqa: E731
    mean(ours["step"], step(idx["idx"]), "transition steps")
    share(ours["rewards"] == ours["rewards"].max(), theirs["rewards"] == theirs["rewards"].max(), "successes")
    if code == "ogbench":
        mean(ours["low_actor_goal_step"] - ours["step"], step(idx["low_actor_goal"]) - step(idx["idx"]), "low goals")
        share(ours["high_actor_goal_kind"] == 2, idx["high_random"], "random high-level goals")
        mean(ours["high_actor_target_step"] - ours["step"], step(idx["high_actor_target"]) - step(idx["idx"]),
             "high-level targets")
        return
    for k in range(11):
        share(ours["high_value_subgoal_steps"] == k, theirs["high_value_subgoal_steps"] == k, f"value subgoal {k}")
    mean(ours["high_value_rewards"], theirs["high_value_rewards"], "high-level rewards")
    share(ours["high_value_masks"] == 0, theirs["high_value_masks"] == 0, "high-level successes")
    share(ours["low_value_masks"] == 0, theirs["low_value_masks"] == 0, "low-level successes")
    ha = ours["high_actor_action_step"] - ours["step"]
    mean(ha, idx["high_actor_action"] - idx["idx"], "actor subgoal steps")
    same_ours = ours["high_actor_goal_episode"] == ours["episode"]
    share(same_ours, same(idx["high_actor_goal"], idx["idx"]), "actor goals in the row's episode")


def test_a_key_the_agent_sets_after_making_its_dataset_is_read(folder):
    """Double SHARSA sets `config['low_discount']` in `create`, after the dataset is made: their
    class reads the config at every sample, and so does pgser."""
    table, _, _ = folder
    config = dict(SHARSA, value_p_curgoal=0.0, value_p_trajgoal=1.0, value_p_randomgoal=0.0)
    with pgser.Sampler(table, layout="horizon_reduction", config=config, seed=4) as s:
        first = s.sample(1)
        assert "low_value_goals" in first
        before = many(s, 4)
        config["low_discount"] = 1 - 1 / 25
        after = many(s, 4)
        config["low_discount"] = 3.0
        with pytest.raises(ValueError, match="low_discount = 3: must be in"):
            s.sample()
    near = lambda b: b["step"] < 20  # noqa: E731
    off = lambda b: (b["low_value_goal_step"] - b["step"])[near(b)].mean()  # noqa: E731
    # At 0.999 (the discount, while low_discount is None) most offsets reach the episode's end;
    # at 0.96 the mean is 25.
    assert off(before) > 60 and abs(off(after) - 25) < 3, (off(before), off(after))


def test_bad_configs_and_arguments_are_refused_naming_them(folder, tables):
    table, _, _ = folder
    traj, _, _ = tables
    hr = dict(layout="horizon_reduction")
    cases = [
        (dict(config=dict(HIQL, dataset_class="FooDataset")), 'dataset_class"] = "FooDataset"'),
        (dict(config=dict(HIQL, subgoal_steps=0)), "subgoal steps = 0"),
        (dict(config=dict(HIQL, subgoal_steps=101)), "101: longer than this table's episodes \\(100 transitions"),
        (dict(config=dict(HIQL, subgoal_steps=2.5)), 'subgoal_steps"] = 2.5: not a whole number'),
        (dict(config=dict(HIQL, value_subgoal_steps=1)), "value_subgoal_steps = 1: a key of Horizon Reduction's"),
        (dict(config=SHARSA), "low_discount = None: a key of Horizon Reduction's"),
        (dict(config=dict(SHARSA, low_discount=1.5), **hr), "low_discount = 1.5: must be in"),
        (dict(config=dict(SHARSA, dataset_class="GCDataset"), **hr), "a key of HGCDataset, and dataset_class is GCDataset"),
        (dict(config=HIQL, oracle_reps=True), 'use layout="horizon_reduction"'),
        (dict(config=SHARSA, env_name="antmaze-large-navigate-oraclerep-v0", **hr),
         'names the environment "antmaze-large-v0", and the table holds "pointmaze-medium-v0"'),
        (dict(config=SHARSA, env_name="pointmaze-medium-navigate-oraclerep-v0", oracle_reps=False, **hr),
         "disagree"),
        (dict(config=SHARSA, clip_actions=2.0, **hr), "clip_actions = 2"),
    ]
    for kw, msg in cases:
        with pytest.raises(ValueError, match=msg.replace("[", r"\[")):
            pgser.Sampler(table, **{"layout": "ogbench", **kw})
    # Oracle representations only where the table's goals are them: FetchReach has none.
    with pytest.raises(ValueError, match="not OGBench's oracle representations"):
        pgser.Sampler(traj, layout="horizon_reduction", oracle_reps=True)


def test_hierarchical_batches_within_a_budget_are_exact_and_the_same_bytes(tmp_path):
    # 12 PointMaze episodes of OGBench's recipe (T = 1001), one a shard: 12 row groups of 32 kB.
    data, src, table = tmp_path / f"{NAME}.npz", tmp_path / "src", tmp_path / "table"
    run(BIN / "pgser-etl", "collect", "--task", NAME, "--policy", "oracle", "--episodes", "12", "-o", data)
    run(sys.executable, REPO / "tests/py/make_ogbench_shards.py", data, src, 1)
    run(BIN / "pgser-etl", "convert", src, "-o", table)
    with np.load(data) as f:
        obs, t = f["observations"], 1001
    kw = dict(layout="horizon_reduction", config=dict(SHARSA, low_discount=0.96), seed=7, oracle_reps=True)
    with pgser.Sampler(table, memory_budget="260kB", **kw) as s:
        b = many(s, 12, 512)
        assert s.pool_stats()["rotations"] > 0
    with pgser.Sampler(table, memory_budget="260kB", **kw) as s:
        again = many(s, 12, 512)
    assert all(np.array_equal(b[k], again[k]) for k in b)
    row = b["episode"] * t + b["step"]
    assert np.array_equal(b["observations"], obs[row])
    assert np.array_equal(b["high_value_next_observations"], obs[row + b["high_value_subgoal_steps"]])
    assert np.array_equal(b["high_actor_next_observations"], obs[row + b["high_actor_action_step"] - b["step"]])
    assert np.array_equal(b["low_actor_goals"], obs[b["episode"] * t + np.minimum(b["step"] + 25, t - 2)])
    ge, gs = b["high_value_goal_episode"], b["high_value_goal_step"]
    assert np.array_equal(b["high_value_goals"], obs[ge * t + gs])
    # Random goals come from the whole folder, not only the resident episodes.
    assert len(np.unique(ge[b["high_value_goal_kind"] == 2])) == 12


def test_pgsers_swapped_goals_are_the_high_level_goals(folder, tmp_path):
    table, _, arrays = folder
    reps = arrays["qpos"][:, :2].astype(np.float32)
    ckpt, scored = tmp_path / "q.ckpt", tmp_path / "scored"
    run(BIN / "pgser-train", "--data", table, "-o", ckpt, "--updates", "10", "--hidden", "16", "--batch-size", "64",
        "--eval-episodes", "0", "--swap", "random")
    pgser.score(ckpt, table, scored, swaps=4)
    for code, config in (("ogbench", HIQL), ("horizon_reduction", dict(SHARSA, low_discount=0.96))):
        kw = dict(oracle_reps=True) if code == "horizon_reduction" else {}
        with pgser.Sampler(scored, layout=code, config=dict(config, p_swapgoal=0.5), priority="q", seed=2, **kw) as s:
            b = many(s, 3)
        sw = b["scored_row"] >= 0
        n = len(sw)
        assert abs(sw.mean() - 0.5) < 4 * np.sqrt(0.25 / n)
        value = "value_goal" if code == "ogbench" else "high_value_goal"
        assert np.all(b[f"{value}_kind"][sw] == 3) and np.all(b[f"{value}_kind"][~sw] != 3)
        # With swap_actor_goals (the default) the high-level actor goal is the swapped goal.
        assert np.all(b["high_actor_goal_kind"][sw] == 3)
        for k in ("episode", "step"):
            assert np.array_equal(b[f"high_actor_goal_{k}"][sw], b[f"{value}_{k}"][sw])
        ge, gs = b[f"{value}_episode"], b[f"{value}_step"]
        assert np.array_equal(b[f"{value}s"], reps[ge * T + gs])
        e, st = b["episode"], b["step"]
        if code == "ogbench":
            # A swapped goal's target is min(s + k, L), as a random goal's.
            target = np.minimum(st + 25, T - 2)
            assert np.array_equal(b["high_actor_target_step"][sw], target[sw])
        else:
            k = np.minimum(25, T - 2 - st)
            diff = (ge * T + gs) - (e * T + st)
            k = np.where((diff >= 0) & (diff < k), diff, k)
            assert np.array_equal(b["high_value_subgoal_steps"], k)
            # Low-level goals stay the rules' own, in the row's episode.
            assert np.all(b["low_value_goal_kind"] != 3) and np.all(b["low_actor_goal_kind"] != 3)


@pytest.mark.parametrize("name,width", [("puzzle-3x3-play-v0", 9), ("scene-play-v0", 7)])
def test_oracle_reps_of_puzzles_and_scenes(name, width, tmp_path):
    """A puzzle's and a scene's table (ogbench's own puzzle-3x3 and scene environments,
    tests/fixtures/ogbench): its goals are OGBench's oracle representation (a puzzle's button
    states; a scene's cube, buttons, drawer and window), and Horizon Reduction's batches take them
    as goals and high-level actions."""
    src = REPO / f"tests/fixtures/ogbench/{name.split('-')[0]}/{name}.npz"
    table = tmp_path / "p.parquet"
    run(BIN / "pgser-etl", "convert", src, "-o", table)
    with np.load(src) as f:
        reps, obs = f["oracle_reps"], f["observations"]
    t = 21
    cfg = dict(SHARSA, subgoal_steps=5, low_discount=0.9)
    with pgser.Sampler(table, layout="horizon_reduction", config=cfg,
                       env_name=name.replace("-v0", "-oraclerep-v0"), seed=3) as s:
        b = s.sample(512)
    row = b["episode"] * t + b["step"]
    assert np.array_equal(b["oracle_reps"], reps[row]) and np.array_equal(b["observations"], obs[row])
    for stem in ("high_value_goal", "high_actor_goal", "low_value_goal", "high_value_action", "low_actor_goal"):
        assert np.array_equal(b[f"{stem}s"], reps[b[f"{stem}_episode"] * t + b[f"{stem}_step"]]), stem
    assert b["high_value_goals"].shape == (512, width)
