#!/usr/bin/env python3
"""Small OGBench dataset files of the environments pgser does not simulate, in OGBench's on-disk
format, from ogbench's own environments with uniform random actions.

    /tmp/ogvenv/bin/python tests/py/make_ogbench_random_fixtures.py tests/fixtures/ogbench [FOLDER ...]

Writes, each with its -val.npz (1 episode):
- cube/cube-single-play-v0.npz, cube/cube-double-play-v0.npz: 2 episodes of 21 rows, in
  `gymnasium.make("cube-single-v0", terminate_at_goal=False, max_episode_steps=21)` as OGBench's
  `generate_manipspace.py` makes its env (its play data come from a scripted arm, which the
  format does not depend on), with the keys it stores for a cube scene (observations, actions,
  terminals, qpos, qvel; button_states only where the scene has buttons) plus `oracle_reps`, each
  row's `env.unwrapped.compute_oracle_observation()` (the cubes' positions, what OGBench's
  oraclerep datasets hold): tests/ogbench.rs checks pgser's goal against it;
- antmaze/antmaze-medium-navigate-v0.npz: 4 episodes of 51 rows in antmaze-medium-v0, the keys of
  `generate_locomaze.py` plus `oracle_reps` (the ant's x, y);
- puzzle/puzzle-3x3-play-v0.npz: 2 episodes of 21 rows in puzzle-3x3-v0, with `button_states`
  (int64, as `generate_manipspace.py` stores them) and `oracle_reps`, its
  `compute_oracle_observation()` (the buttons' states);
- scene/scene-play-v0.npz: 2 episodes of 21 rows in scene-v0 (a cube, two buttons, a drawer and
  a window), with `button_states` and `oracle_reps`, its `compute_oracle_observation()` (the
  cube's position, the buttons' states, the drawer's and the window's positions);
for examples/ogbench_eval.py's test in OGBench's own environments (tests/python/test_ogbench.py).
Seeded (numpy seed 0, env seed 0): a second run writes the same arrays.
"""
import os
import sys
import warnings

import gymnasium
import numpy as np

import ogbench.locomaze  # noqa: F401  (registers the mazes)
import ogbench.manipspace  # noqa: F401  (registers the scenes)

warnings.filterwarnings("ignore")


def rollout(env, episodes, rows):
    u = env.unwrapped
    buttons = hasattr(u, "_cur_button_states")
    keys = ["observations", "actions", "terminals", "qpos", "qvel", "oracle_reps"] + (["button_states"] if buttons else [])
    data = {k: [] for k in keys}
    for ep in range(episodes):
        ob, _ = env.reset()
        for t in range(rows):
            # numpy's seeded generator: the cube scenes' action_space.sample() is not reproducible.
            action = np.random.uniform(env.action_space.low, env.action_space.high).astype(np.float32)
            rep = u.compute_oracle_observation() if hasattr(u, "compute_oracle_observation") else u.get_xy()
            next_ob, _, terminated, truncated, info = env.step(action)
            data["observations"].append(ob)
            data["actions"].append(action)
            data["terminals"].append(terminated or truncated)
            data["qpos"].append(info["prev_qpos"])
            data["qvel"].append(info["prev_qvel"])
            data["oracle_reps"].append(rep)
            if buttons:
                data["button_states"].append(info["prev_button_states"])
            ob = next_ob
    dtypes = {"terminals": bool, "button_states": np.int64}
    return {k: np.array(v, dtype=dtypes.get(k, np.float32)) for k, v in data.items()}


def main():
    out = sys.argv[1]
    sets = [("cube", "cube-single-v0", "cube-single-play-v0", 2, 21),
            ("cube", "cube-double-v0", "cube-double-play-v0", 2, 21),
            ("antmaze", "antmaze-medium-v0", "antmaze-medium-navigate-v0", 4, 51),
            ("puzzle", "puzzle-3x3-v0", "puzzle-3x3-play-v0", 2, 21),
            ("scene", "scene-v0", "scene-play-v0", 2, 21)]
    only = sys.argv[2:]
    for folder, env_id, name, episodes, rows in sets:
        if only and folder not in only:
            continue
        os.makedirs(os.path.join(out, folder), exist_ok=True)
        np.random.seed(0)
        env = gymnasium.make(env_id, terminate_at_goal=False, max_episode_steps=rows)
        env.reset(seed=0)
        for suffix, n in [("", episodes), ("-val", 1)]:
            d = rollout(env, n, rows)
            path = os.path.join(out, folder, f"{name}{suffix}.npz")
            np.savez_compressed(path, **d)
            print(path, {k: (v.dtype.str, v.shape) for k, v in d.items()})


if __name__ == "__main__":
    main()
