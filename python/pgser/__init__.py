"""pgser for Python: pgser's tables, its prioritized goal-swapping sampler, and its Fetch and
Shadow Hand environments, from the same Rust library as the `pgser-etl` / `pgser-train` CLIs.

- ``read_table(path)`` / ``read_footer(path)``: any pgser table as a ``pyarrow.Table``; its footer.
- ``convert(...)`` / ``score(...)``: ``pgser-etl convert`` and ``pgser-etl score``.
- ``Sampler(path, ...)``: the batches ``pgser-train`` trains on, as dicts of numpy arrays;
  ``Sampler(path, layout="ogbench", config=agent_config)``: OGBench's goal-conditioned batches
  (``GCDataset`` / ``HGCDataset.sample(batch_size)``'s dict), the one object an OGBench JAX
  agent replaces; ``layout="horizon_reduction"``: Horizon Reduction's classes (SHARSA, ...).
- ``make(task)`` / ``VectorEnv(task, n)``: gymnasium environments (ids ``pgser/FetchPush-v4`` ...).
- ``Policy(task, "expert")``: the scripted experts, random actions, or a checkpoint's actor;
  ``Policy("run.ckpt").act(observations, goals)``: a checkpoint's actor on batches.
- ``ogbench_goal(env, observations)``: OGBench's goal map (x, y; the cubes' positions).

docs/python.md in the repository describes each, with the settings they share with the CLI.
"""

import os as _os
from pathlib import Path as _Path

# An installed wheel carries the model assets and numpy's ziggurat tables in the package; the
# compiled module finds them through these variables (its own executable is python, so the
# binaries' lookup beside the executable does not apply). A variable already set wins.
for _var, _rel in (("PGSER_ASSETS", "assets"), ("PGSER_ZIGGURAT", "data/numpy_ziggurat.bin")):
    if not _os.environ.get(_var) and (_Path(__file__).parent / _rel).exists():
        _os.environ[_var] = str(_Path(__file__).parent / _rel)

from . import _pgser  # noqa: E402
from ._pgser import Sampler, Policy, convert, ogbench_goal, read_footer, read_table, score, task_info

# Registers the pgser/<task> ids with gymnasium on import, so gymnasium.make("pgser/FetchPush-v4")
# works after `import pgser` as it does through pgser.make.
from . import envs  # noqa: E402,F401

__version__ = _pgser.__version__
long_version = _pgser.long_version

# What a batch's `*_kind` codes (uint8) name: where a goal came from.
GOAL_KINDS = ("current", "trajectory", "random", "swapped")

TASKS = (
    "FetchReach-v4",
    "FetchPush-v4",
    "FetchPickAndPlace-v4",
    "FetchSlide-v4",
    "HandManipulateBlockRotateZ-v1",
    "HandManipulateEggRotate-v1",
)


def make(task, **kwargs):
    """``gymnasium.make("pgser/" + task)``: a pgser environment with gymnasium's wrappers
    (time limit, order enforcing, checker), as ``gym.make(task)`` gives gymnasium-robotics' own."""
    import gymnasium

    from . import envs  # registers the pgser/ ids

    return gymnasium.make(envs.env_id(task), **kwargs)


def VectorEnv(task, num_envs, seed=None):  # noqa: N802 (a class to its users)
    """``num_envs`` pgser environments stepped together in native threads (gymnasium's
    ``VectorEnv`` API, next-step autoreset). ``seed`` seeds the first ``reset()``."""
    from .envs import PgserVectorEnv

    return PgserVectorEnv(task, num_envs, seed=seed)


__all__ = [
    "GOAL_KINDS",
    "Policy",
    "ogbench_goal",
    "Sampler",
    "TASKS",
    "VectorEnv",
    "convert",
    "long_version",
    "make",
    "read_footer",
    "read_table",
    "score",
    "task_info",
]
