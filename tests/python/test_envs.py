"""pgser's environments through Python: pgser.make equals gymnasium-robotics 1.4.2 step for step
on the same MuJoCo (the Rust parity test's rule: goals bit for bit, the rest of the observation
within 1e-6), VectorEnv equals n single environments under gymnasium's own SyncVectorEnv, and
Policy acts as `pgser-etl collect` does."""

import gymnasium as gym
import gymnasium_robotics
import numpy as np
import pytest

import pgser
from conftest import BIN, run

gym.register_envs(gymnasium_robotics)


def same_obs(a, b, what):
    for k in ("achieved_goal", "desired_goal"):
        assert np.array_equal(a[k], b[k]), f"{what}: {k} {a[k]} != {b[k]}"
    assert a["observation"].shape == b["observation"].shape, what
    d = np.abs(a["observation"] - b["observation"]).max()
    assert d <= 1e-6, f"{what}: observation differs by {d}"


@pytest.mark.parametrize("task", pgser.TASKS)
def test_make_equals_gymnasium_robotics(task):
    ours, theirs = pgser.make(task), gym.make(task)
    assert ours.spec.max_episode_steps == theirs.spec.max_episode_steps
    assert ours.action_space == theirs.action_space
    assert ours.observation_space["observation"].shape == theirs.observation_space["observation"].shape
    rng = np.random.default_rng(1)
    steps = ours.spec.max_episode_steps
    # Episode 1 seeded; episode 2 continues the generator (reset without a seed), as in Python.
    for ep, seed in enumerate((11, None)):
        a_obs, _ = ours.reset(seed=seed)
        b_obs, _ = theirs.reset(seed=seed)
        same_obs(a_obs, b_obs, f"{task} episode {ep} reset")
        for t in range(steps):
            act = rng.uniform(-1, 1, ours.action_space.shape).astype(np.float32)
            a = ours.step(act)
            b = theirs.step(act)
            what = f"{task} episode {ep} step {t}"
            same_obs(a[0], b[0], what)
            assert a[1] == b[1] and a[2] == b[2] and a[3] == b[3], what
            assert a[4]["is_success"] == b[4]["is_success"], what
        assert a[3], "the time limit truncates the episode"
        # Batched, as HER relabelling calls it (gymnasium-robotics' hand tasks take one batch axis).
        goals = np.concatenate([rng.uniform(-1, 1, (6, b_obs["desired_goal"].size)), [b_obs["achieved_goal"]] * 2])
        got = ours.unwrapped.compute_reward(goals, goals[::-1], {})
        want = theirs.unwrapped.compute_reward(goals, goals[::-1], {})
        assert got.shape == (8,) and got.dtype == want.dtype and np.array_equal(got, want), task


@pytest.mark.parametrize("task,n", [("FetchReach-v4", 3), ("FetchPush-v4", 4), ("HandManipulateEggRotate-v1", 2)])
def test_vector_env_equals_n_single_envs(task, n):
    ours = pgser.VectorEnv(task, n, seed=5)
    ref = gym.vector.SyncVectorEnv([lambda: pgser.make(task) for _ in range(n)])
    a_obs, _ = ours.reset()
    b_obs, _ = ref.reset(seed=5)
    rng = np.random.default_rng(2)
    steps = ours.spec.max_episode_steps * 2 + 3  # crosses two autoresets
    for t in range(steps):
        for k in a_obs:
            assert np.array_equal(a_obs[k], b_obs[k]), f"step {t} {k}"
        act = rng.uniform(-1, 1, ours.action_space.shape).astype(np.float32)
        a_obs, ar, at, atr, ai = ours.step(act)
        b_obs, br, bt, btr, bi = ref.step(act)
        assert np.array_equal(ar, br) and np.array_equal(at, bt) and np.array_equal(atr, btr), f"step {t}"
        assert ai.keys() == bi.keys(), f"step {t}"
        if ai:
            assert np.array_equal(ai["_is_success"], bi["_is_success"]), f"step {t}"
            assert np.array_equal(ai["is_success"][ai["_is_success"]], bi["is_success"][bi["_is_success"]]), f"step {t}"
    assert ours.observation_space == ref.observation_space and ours.action_space == ref.action_space


def test_vector_env_equals_gymnasium_robotics_sync_vector_env():
    ours = pgser.VectorEnv("FetchReach-v4", 2)
    ref = gym.vector.SyncVectorEnv([lambda: gym.make("FetchReach-v4") for _ in range(2)])
    a_obs, _ = ours.reset(seed=3)
    b_obs, _ = ref.reset(seed=3)
    rng = np.random.default_rng(3)
    for t in range(110):
        for k in a_obs:
            assert np.abs(a_obs[k] - b_obs[k]).max() <= 1e-6, f"step {t} {k}"
        act = rng.uniform(-1, 1, (2, 4)).astype(np.float32)
        a_obs, ar, _, atr, _ = ours.step(act)
        b_obs, br, _, btr, _ = ref.step(act)
        assert np.array_equal(ar, br) and np.array_equal(atr, btr), f"step {t}"


def test_ids_are_registered_on_import():
    import subprocess
    import sys

    code = "import gymnasium, pgser; e = gymnasium.make('pgser/FetchSlide-v4'); print(e.spec.max_episode_steps)"
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert p.returncode == 0 and p.stdout.split()[-1] == "50", p.stderr


def test_passes_gymnasiums_env_checker():
    from gymnasium.utils.env_checker import check_env

    check_env(pgser.make("FetchPush-v4").unwrapped, skip_render_check=True)


def test_policy_acts_as_collect_does(tmp_path):
    out = tmp_path / "c.parquet"
    run(BIN / "pgser-etl", "collect", "--task", "FetchPush", "--policy", "expert", "--noise", "0.2",
        "--epsilon", "0.1", "--episodes", "2", "--seed", "40", "-o", out)
    t = pgser.read_table(out)
    actions = np.stack(t.column("action").to_numpy(zero_copy_only=False)[:-1][:49])
    env = pgser.make("FetchPush-v4")
    obs, _ = env.reset(seed=40)
    policy = pgser.Policy("FetchPush", "expert", seed=40, episode=0, noise=0.2, epsilon=0.1)
    for s in range(49):
        a = policy(obs)
        assert np.array_equal(np.clip(a.astype(np.float32), -1, 1), actions[s].astype(np.float32)), f"step {s}"
        obs, *_ = env.step(a)
    # The unperturbed expert solves FetchReach.
    env, successes = pgser.make("FetchReach-v4"), 0
    for ep in range(5):
        obs, _ = env.reset(seed=100 + ep)
        policy = pgser.Policy("FetchReach", "expert")
        for _ in range(50):
            obs, _, _, _, info = env.step(policy(obs))
        successes += info["is_success"]
    assert successes == 5


def test_bad_arguments_raise_value_errors():
    env = pgser.make("FetchReach-v4")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="4 values, got 3"):
        env.step(np.zeros(3, dtype=np.float32))
    with pytest.raises(ValueError, match="did you mean"):
        pgser.make("FetchPsh-v4")
    with pytest.raises(ValueError, match="v4 only"):
        pgser.make("FetchPush-v1")
    v = pgser.VectorEnv("FetchReach", 2)
    v.reset(seed=0)
    with pytest.raises(ValueError, match="actions for 2 environments, got 3"):
        v.step(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="num_envs"):
        pgser.VectorEnv("FetchReach", 0)
    with pytest.raises(ValueError, match="no scripted expert"):
        pgser.Policy("HandManipulateEggRotate", "expert")
    with pytest.raises(ValueError, match="unknown policy"):
        pgser.Policy("FetchReach", "greedy")
    with pytest.raises(ValueError, match="observation has 10 values, got 2"):
        pgser.Policy("FetchReach")({"observation": np.zeros(2), "achieved_goal": np.zeros(3), "desired_goal": np.zeros(3)})


@pytest.mark.parametrize("task", ["pointmaze-medium-v0", "pointmaze-teleport-navigate-v0"])
def test_pointmaze_equals_ogbench(task):
    """pgser's PointMaze through gymnasium equals OGBench's own environment: `reset(seed=s)` is
    `np.random.seed(s); env.reset(seed=s)` (OGBench draws start, goal and task from numpy's
    global generator), and steps of float32 actions give the same positions bit for bit; both end
    an episode at the goal."""
    import warnings

    # In the test venv (tests/requirements.txt); the wheel's own check (tests/wheel/check.sh)
    # installs only what the wheel needs, and skips this.
    pytest.importorskip("ogbench.locomaze")  # registers OGBench's ids
    warnings.filterwarnings("ignore")
    env_id = task.replace("-navigate", "")
    ours = pgser.make(task)
    theirs = gym.make(env_id)
    assert ours.spec.max_episode_steps == theirs.spec.max_episode_steps == 1000
    for seed in (0, 3):
        o, _ = ours.reset(seed=seed)
        np.random.seed(seed)
        t, info = theirs.reset(seed=seed)
        assert np.array_equal(o["observation"], t) and np.array_equal(o["desired_goal"], info["goal"])
        rng = np.random.default_rng(seed)
        for _ in range(100):
            d = info["goal"] - t
            a = np.clip(d / (np.linalg.norm(d) + 1e-6) + rng.normal(0, 0.5, 2), -1, 1).astype(np.float32)
            o, r, term, trunc, i = ours.step(a)
            t, r2, term2, trunc2, i2 = theirs.step(a)
            assert np.array_equal(o["observation"], t)
            assert (term, bool(i["is_success"])) == (term2, bool(i2["success"]))
            if term:
                break
