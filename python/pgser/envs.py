"""gymnasium interfaces over pgser's environments (the engines are in ``pgser._pgser``).

``PgserEnv`` is a ``gymnasium.Env`` with the GoalEnv dict observation and ``compute_reward``,
registered as ``pgser/<task>`` with gymnasium-robotics' episode limits (50 steps for Fetch, 100
for the hand tasks), so ``gymnasium.make("pgser/FetchPush-v4")`` wraps it as
``gymnasium.make("FetchPush-v4")`` wraps gymnasium-robotics' own. With the same seed and actions
it returns the same observations, bit for bit (tests/python/test_envs.py).

``PgserVectorEnv`` steps n environments in one native call (``pgser._pgser.VecEnv``) and speaks
gymnasium 1.x's ``VectorEnv`` API with next-step autoreset, like ``SyncVectorEnv`` over n
``gymnasium.make`` environments, whose results it equals.
"""

import numpy as np
import gymnasium
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from . import _pgser

NAMESPACE = "pgser"


def _canonical(task):
    """'FetchPush', 'FetchPush-v4' or 'pgser/FetchPush-v4' -> 'FetchPush-v4' (others refused);
    OGBench's PointMaze ids and dataset names -> the environment's id ('pointmaze-medium-v0')."""
    name = task.split("/", 1)[1] if task.startswith(NAMESPACE + "/") else task
    if name.startswith("pointmaze-"):
        info = _pgser.task_info(name)  # ValueError naming the id if unknown
        return info["name"], info
    info = _pgser.task_info(name.split("-v", 1)[0])  # ValueError naming the task if unknown
    hand = info["name"].startswith("Hand")
    version = "-v1" if hand else "-v4"
    if "-v" in name and not name.endswith(version):
        raise ValueError(f"{task}: pgser simulates {info['name']}{version} only")
    return info["name"] + version, info


def _compute_reward(task, achieved_goal, desired_goal):
    """Batched sparse reward of `task` (gymnasium-robotics' compute_reward): float32, 0 or -1."""
    ag = np.asarray(achieved_goal, dtype=np.float64)
    g = np.asarray(desired_goal, dtype=np.float64)
    return _pgser.compute_reward(task.split("-v", 1)[0], ag, g)


def env_id(task):
    """The registered gymnasium id of a task: ``pgser/FetchPush-v4``."""
    return f"{NAMESPACE}/{_canonical(task)[0]}"


def _spaces(info):
    box = lambda n: spaces.Box(-np.inf, np.inf, shape=(n,), dtype=np.float64)  # noqa: E731
    obs = spaces.Dict(
        {
            "observation": box(info["obs_dim"]),
            "achieved_goal": box(info["goal_dim"]),
            "desired_goal": box(info["goal_dim"]),
        }
    )
    act = spaces.Box(-1.0, 1.0, shape=(info["act_dim"],), dtype=np.float32)
    return obs, act


class PgserEnv(gymnasium.Env):
    """One pgser environment as a gymnasium goal environment."""

    metadata = {"render_modes": []}

    def __init__(self, task="FetchPush-v4"):
        self.task_id, self.info = _canonical(task)
        self._env = _pgser.Env(self.task_id)
        self.observation_space, self.action_space = _spaces(self.info)
        self._seeded = False

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        # gymnasium seeds from OS entropy when never seeded; pgser runs are reproducible, so an
        # environment never seeded behaves as if seeded with 0 (its Rust engine's rule).
        obs = self._env.reset(seed)
        return obs, {}

    def step(self, action):
        a = np.asarray(action, dtype=np.float64).reshape(-1)
        obs, reward, success = self._env.step(a)
        # OGBench's mazes end an episode at its success; the Fetch and hand tasks never do.
        terminated = bool(success) and self._env.ends_at_success
        return obs, float(reward), terminated, False, {"is_success": np.float32(success)}

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        return _compute_reward(self.task_id, achieved_goal, desired_goal)


class PgserVectorEnv(VectorEnv):
    """n pgser environments of one task, stepped in native threads with the GIL released."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, task, num_envs, seed=None):
        self.task_id, self.info = _canonical(task)
        self.num_envs = int(num_envs)
        self.spec = gymnasium.spec(env_id(self.task_id))
        self._engine = _pgser.VecEnv(self.task_id, self.num_envs, self.spec.max_episode_steps)
        self.single_observation_space, self.single_action_space = _spaces(self.info)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._first_seed = seed

    def reset(self, *, seed=None, options=None):
        if seed is None and self._first_seed is not None:
            seed, self._first_seed = self._first_seed, None
        if isinstance(seed, (list, tuple)):
            raise ValueError("pgser.VectorEnv.reset takes one int seed (environment i gets seed + i) or None")
        self._first_seed = None
        return self._engine.reset(seed), {}

    def step(self, actions):
        a = np.ascontiguousarray(actions, dtype=np.float64)
        if a.ndim != 2:
            raise ValueError(f"{self.task_id}: actions must be (num_envs, act_dim), got shape {a.shape}")
        obs, reward, terminated, truncated, success, was_reset = self._engine.step(a)
        stepped = ~was_reset
        # As SyncVectorEnv: an environment that was reset this step has no step info (its entry
        # is masked out), and a step where every environment was reset has no info at all.
        info = {"is_success": np.where(stepped, success, 0.0).astype(np.float32), "_is_success": stepped}
        return obs, reward, terminated, truncated, info if stepped.any() else {}

    def compute_reward(self, achieved_goal, desired_goal, info=None):
        return _compute_reward(self.task_id, achieved_goal, desired_goal)


def _register():
    for task in (
        "FetchReach",
        "FetchPush",
        "FetchPickAndPlace",
        "FetchSlide",
        "HandManipulateBlockRotateZ",
        "HandManipulateEggRotate",
    ):
        tid, info = _canonical(task)
        name = f"{NAMESPACE}/{tid}"
        if name not in gymnasium.registry:
            steps = 100 if task.startswith("Hand") else 50
            gymnasium.register(name, entry_point=PgserEnv, kwargs={"task": tid}, max_episode_steps=steps)
    # OGBench's PointMaze, its episodes of 1000 steps ending at the goal.
    for tid in ("pointmaze-medium-v0", "pointmaze-large-v0", "pointmaze-giant-v0", "pointmaze-teleport-v0"):
        name = f"{NAMESPACE}/{tid}"
        if name not in gymnasium.registry:
            gymnasium.register(name, entry_point=PgserEnv, kwargs={"task": tid}, max_episode_steps=1000)


_register()
