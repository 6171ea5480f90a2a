#!/usr/bin/env python3
"""Make the committed Minari fixtures in tests/fixtures/minari/ with the real `minari` package.

Every dataset is recorded by Minari's own DataCollector around a Gymnasium environment, run
here: nothing comes from a dataset hub. The DataCollector needs jax (`minari[create]`), which
the test venv leaves out (the tests only open datasets), so make them in a scratch venv:

  python3 -m venv /tmp/minari-venv
  /tmp/minari-venv/bin/pip install 'minari[create,hdf5,arrow]==0.5.4' mujoco==3.17.0 gymnasium-robotics==1.4.2
  /tmp/minari-venv/bin/python tests/py/make_minari_fixtures.py tests/fixtures/minari [ID ...]

With IDs, only those datasets are made.

Datasets (each one folder `ID/data/` as `minari.load_dataset(ID)` finds it under
MINARI_DATASETS_PATH):

- fetchreach-hdf5-v0, fetchreach-arrow-v0: FetchReach-v4 with max_episode_steps=49, so every
  episode has 50 observations and 49 actions: pgser's FetchReach (T = 50, WGCSL's convention).
  4 episodes each, seeds 0..3, a noisy proportional reacher (some episodes succeed, some not),
  no infos (Fetch's reset info has no is_success, and Minari 0.5 needs the same keys on every
  step). HDF5 (Minari's default storage) and Arrow storage, the same episodes in both.
- fetchreach-short-arrow-v0: as the Arrow one, but the collector is reset in the middle of
  episode 2 (after 20 steps), which Minari stores as a truncated 20-step episode: episodes of
  unequal length, which one pgser table cannot hold.
- fetchreach-default-arrow-v0: FetchReach-v4 with gymnasium-robotics' default time limit, as
  Python users record it (`minari.DataCollector(gym.make("FetchReach-v4"))`): 3 episodes of 50
  steps, 51 observations, one more than pgser's FetchReach T; `convert` drops the last step.
- pendulum-hdf5-v0: Pendulum-v1 (a plain Box observation, no goals), 2 episodes of 10 steps:
  a dataset that is not goal-conditioned.
- fetchreach-infos-hdf5-v0, fetchreach-infos-arrow-v0: as fetchreach-{hdf5,arrow}-v0 (3
  episodes), recorded with `record_infos=True` around a wrapper that gives the reset the step's
  info keys (gymnasium-robotics' `is_success` float, and a per-step `distance` float32 [1]), as
  Minari needs the same keys on every step: a Minari dataset with infos, for the lossless round
  trip.
- fetchreach-image-hdf5-v0, fetchreach-image-arrow-v0: as those, with a fourth key in the Dict
  observation, `image`, a uint8 Box of shape (2, 2) (the gripper's x, y, z and the goal's x
  quantized): an observation key a table keeps beside the goals.

Existing folders are replaced. HDF5 files carry creation times, so regenerated files differ
in bytes but not in content.
"""
import os
import shutil
import sys
import tempfile

import types

import mujoco
import numpy as np
from gymnasium_robotics.utils import mujoco_utils

# The same workaround as env_parity.py, no numbers change: with mujoco 3.17 the enum `mjtJoint`
# no longer compares equal to the np.int32 in `model.jnt_type`, so mujoco_utils' joint-type
# asserts fail; give mujoco_utils a mujoco whose mjtJoint members are plain ints.
_mj = types.ModuleType("mujoco")
_mj.__dict__.update(mujoco.__dict__)
_mj.mjtJoint = types.SimpleNamespace(**{k: int(v) for k, v in mujoco.mjtJoint.__members__.items()})
mujoco_utils.mujoco = _mj

import gymnasium as gym  # noqa: E402
import gymnasium_robotics  # noqa: E402

gym.register_envs(gymnasium_robotics)


def reacher(obs, rng):
    """Move the gripper toward the goal, with noise: a mix of successes and misses."""
    a = np.zeros(4, dtype=np.float32)
    a[:3] = np.clip(6.0 * (obs["desired_goal"] - obs["achieved_goal"]) + rng.normal(0, 0.6, 3), -1, 1)
    a[3] = rng.uniform(-1, 1)
    return a


def fetch(minari, data_format, dataset_id, reset_at=None, steps=49, episodes=4):
    limit = {} if steps == 50 else {"max_episode_steps": steps}  # 50: gymnasium-robotics' default
    env = minari.DataCollector(gym.make("FetchReach-v4", **limit), record_infos=False, data_format=data_format)
    rng = np.random.default_rng(7)
    for ep in range(episodes):
        obs, _ = env.reset(seed=ep)
        for step in range(steps):
            if reset_at == (ep, step):
                break  # the next reset stores this episode as truncated after `step` steps
            obs, _, terminated, truncated, _ = env.step(reacher(obs, rng))
            if terminated or truncated:
                break
    return env.create_dataset(
        dataset_id=dataset_id,
        algorithm_name="noisy proportional reacher (tests/py/make_minari_fixtures.py)",
        author="pgser tests",
        author_email="pgser@example.invalid",
        code_permalink="tests/py/make_minari_fixtures.py",
    )


class StepInfo(gym.Wrapper):
    """Every info, the reset's included, with the keys a Fetch step's has: `is_success` and the
    goal distance, so that Minari records infos (it needs the same keys on every step)."""

    def _info(self, obs, info):
        d = np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"])
        return {"is_success": np.float64(d < 0.05), "distance": np.array([d], dtype=np.float32)}

    def reset(self, **kw):
        obs, info = self.env.reset(**kw)
        return obs, self._info(obs, info)

    def step(self, action):
        obs, r, term, trunc, info = self.env.step(action)
        return obs, r, term, trunc, self._info(obs, info)


class WithImage(gym.ObservationWrapper):
    """FetchReach's Dict observation with an `image` key beside the goals: uint8 (2, 2)."""

    def __init__(self, env):
        super().__init__(env)
        spaces = dict(env.observation_space.spaces)
        spaces["image"] = gym.spaces.Box(0, 255, (2, 2), np.uint8)
        self.observation_space = gym.spaces.Dict(spaces)

    def observation(self, obs):
        v = np.concatenate([obs["observation"][:3], obs["desired_goal"][:1]])
        obs = dict(obs)
        obs["image"] = np.clip((v * 100) % 256, 0, 255).astype(np.uint8).reshape(2, 2)
        return obs


def fetch_infos(minari, data_format, dataset_id, image=False):
    """FetchReach with infos on every step (StepInfo), and with `image=True` an image key in the
    Dict observation (WithImage): 3 episodes (seed 11), or 2 with the image (seed 13)."""
    env = gym.make("FetchReach-v4", max_episode_steps=49)
    env = minari.DataCollector(StepInfo(WithImage(env) if image else env), record_infos=True, data_format=data_format)
    rng = np.random.default_rng(13 if image else 11)
    for ep in range(2 if image else 3):
        obs, _ = env.reset(seed=ep)
        for _ in range(49):
            obs, _, terminated, truncated, _ = env.step(reacher(obs, rng))
            if terminated or truncated:
                break
    what = "reacher with an image key" if image else "noisy proportional reacher with infos (tests/py/make_minari_fixtures.py)"
    return env.create_dataset(
        dataset_id=dataset_id,
        algorithm_name=what,
        author="pgser tests",
        author_email="pgser@example.invalid",
        code_permalink="tests/py/make_minari_fixtures.py",
    )


def pendulum(minari, dataset_id):
    """A dataset that is not goal-conditioned."""
    env = minari.DataCollector(gym.make("Pendulum-v1", max_episode_steps=10), data_format="hdf5")
    env.action_space.seed(0)
    for ep in range(2):
        env.reset(seed=ep)
        for _ in range(10):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                break
    return env.create_dataset(dataset_id=dataset_id, algorithm_name="random", author="pgser tests")


DATASETS = {
    "fetchreach-hdf5-v0": lambda m, i: fetch(m, "hdf5", i),
    "fetchreach-arrow-v0": lambda m, i: fetch(m, "arrow", i),
    "fetchreach-short-arrow-v0": lambda m, i: fetch(m, "arrow", i, reset_at=(2, 20)),
    "fetchreach-default-arrow-v0": lambda m, i: fetch(m, "arrow", i, steps=50, episodes=3),
    "pendulum-hdf5-v0": lambda m, i: pendulum(m, i),
    "fetchreach-infos-hdf5-v0": lambda m, i: fetch_infos(m, "hdf5", i),
    "fetchreach-infos-arrow-v0": lambda m, i: fetch_infos(m, "arrow", i),
    "fetchreach-image-hdf5-v0": lambda m, i: fetch_infos(m, "hdf5", i, image=True),
    "fetchreach-image-arrow-v0": lambda m, i: fetch_infos(m, "arrow", i, image=True),
}


def main(out_dir, only=None):
    """Make every dataset, or only those named (the others' committed files stay as they are)."""
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["MINARI_DATASETS_PATH"] = tmp
        import minari

        made = [make(minari, name) for name, make in DATASETS.items() if not only or name in only]
        os.makedirs(out_dir, exist_ok=True)
        for ds in made:
            name = ds.spec.dataset_id
            lengths = [len(e.actions) for e in ds.iterate_episodes()]
            print(f"{name}: {ds.spec.total_episodes} episodes, steps {lengths}")
            dest = os.path.join(out_dir, name)
            shutil.rmtree(dest, ignore_errors=True)
            shutil.copytree(os.path.join(tmp, name), dest)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2:])
