#!/usr/bin/env python3
"""Small OGBench cube dataset files, in OGBench's on-disk format, from ogbench's own cube scenes.

    /tmp/ogvenv/bin/python tests/py/make_ogbench_cube_fixtures.py tests/fixtures/ogbench/cube

Writes cube-single-play-v0.npz and cube-double-play-v0.npz (and their -val.npz): 2 episodes (val:
1) of 21 rows each, uniform random actions (OGBench's play data come from a scripted arm, which
the format does not depend on), in `gymnasium.make("cube-single-v0", terminate_at_goal=False,
max_episode_steps=21)` as OGBench's `generate_manipspace.py` makes its env, with the keys it
stores for a cube scene (observations, actions, terminals, qpos, qvel; button_states only where
the scene has buttons) plus `oracle_reps`, each
row's `env.unwrapped.compute_oracle_observation()` (the cubes' positions, what OGBench's
oraclerep datasets hold): tests/ogbench.rs checks pgser's goal against it. Seeded: numpy
seed 0, env and action space seed 0.
"""
import os
import sys
import warnings

import gymnasium
import numpy as np

import ogbench.manipspace  # noqa: F401  (registers the scenes)

warnings.filterwarnings("ignore")


def rollout(env, episodes, rows):
    u = env.unwrapped
    data = {k: [] for k in ["observations", "actions", "terminals", "qpos", "qvel", "oracle_reps"]}
    for ep in range(episodes):
        ob, _ = env.reset()
        for t in range(rows):
            action = env.action_space.sample()
            rep = u.compute_oracle_observation()
            next_ob, _, terminated, truncated, info = env.step(action)
            data["observations"].append(ob)
            data["actions"].append(action)
            data["terminals"].append(terminated or truncated)
            data["qpos"].append(info["prev_qpos"])
            data["qvel"].append(info["prev_qvel"])
            data["oracle_reps"].append(rep)
            ob = next_ob
    return {k: np.array(v, dtype=bool if k == "terminals" else np.float32) for k, v in data.items()}


def main():
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    for scene in ["single", "double"]:
        np.random.seed(0)
        env = gymnasium.make(f"cube-{scene}-v0", terminate_at_goal=False, max_episode_steps=21)
        env.reset(seed=0)
        env.action_space.seed(0)
        for suffix, episodes in [("", 2), ("-val", 1)]:
            d = rollout(env, episodes, 21)
            path = os.path.join(out, f"cube-{scene}-play-v0{suffix}.npz")
            np.savez_compressed(path, **d)
            print(path, {k: (v.dtype.str, v.shape) for k, v in d.items()})


if __name__ == "__main__":
    main()
