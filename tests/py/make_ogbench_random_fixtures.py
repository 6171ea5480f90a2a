#!/usr/bin/env python3
"""Small OGBench dataset files of the environments pgser does not simulate, in OGBench's on-disk
format, from ogbench's own environments with uniform random actions.

    /tmp/ogvenv/bin/python tests/py/make_ogbench_random_fixtures.py tests/fixtures/ogbench [FOLDER | NAME ...]
    MUJOCO_GL=osmesa PYOPENGL_PLATFORM=osmesa /tmp/ogvenv/bin/python tests/py/make_ogbench_random_fixtures.py tests/fixtures/ogbench visual

(ogbench 1.2.2, mujoco 3.17.0, numpy<2; the visual sets render with MuJoCo, on CPU through OSMesa:
Debian's libosmesa6.)

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
  these for examples/ogbench_eval.py's test in OGBench's own environments (tests/python/test_ogbench.py);
- visual/visual-cube-single-play-v0.npz, visual/visual-puzzle-3x3-play-v0.npz,
  visual/visual-antmaze-medium-navigate-v0.npz, visual/visual-scene-play-v0.npz: 2 episodes of
  21 rows each of OGBench's visual
  datasets' format: `observations` the 64x64 RGB frames the env renders (uint8 [N, 64, 64, 3];
  camera `front_pixels` for the scenes, `back` for the maze), with the generator's other keys
  (actions, terminals, qpos, qvel, and button_states for the puzzle and the scene), made as its
  generators make
  a visual env: `gymnasium.make("visual-cube-single-v0", terminate_at_goal=False,
  mode="data_collection", max_episode_steps=21)` as `generate_manipspace.py` does (the scene
  randomized at each reset), `gymnasium.make("visual-antmaze-medium-v0", terminate_at_goal=False,
  max_episode_steps=21)` as `generate_locomaze.py` does; no `oracle_reps` (OGBench's visual
  datasets have none), but, in these files only, `state_observations`: each row's observation of
  the env's states twin (float32; `compute_observation()` with ob_type "states" for the scenes,
  `get_ob(ob_type="states")` for the maze).
Seeded (numpy seed 0, env seed 0): a second run writes the same arrays (the frames: with the same
Mesa, here 22.3.6's llvmpipe; about 0.2 s a frame for the scenes, 0.05 s for the maze).
"""
import gc
import os
import sys
import warnings

import gymnasium
import numpy as np

import ogbench.locomaze  # noqa: F401  (registers the mazes)
import ogbench.manipspace  # noqa: F401  (registers the scenes)

warnings.filterwarnings("ignore")


def state_observation(u):
    """The observation the env's states twin gives of its current state: a maze's get_ob(ob_type="states")
    (what generate_locomaze.py feeds its expert), a scene's compute_observation() with ob_type "states"."""
    if hasattr(u, "get_ob"):
        return u.get_ob(ob_type="states")
    u._ob_type = "states"
    try:
        return u.compute_observation()
    finally:
        u._ob_type = "pixels"


def rollout(env, episodes, rows, visual=False):
    u = env.unwrapped
    buttons = hasattr(u, "_cur_button_states")
    extra = ["state_observations"] if visual else ["oracle_reps"]
    keys = ["observations", "actions", "terminals", "qpos", "qvel"] + extra + (["button_states"] if buttons else [])
    data = {k: [] for k in keys}
    for ep in range(episodes):
        ob, _ = env.reset()
        for t in range(rows):
            # numpy's seeded generator: the cube scenes' action_space.sample() is not reproducible.
            action = np.random.uniform(env.action_space.low, env.action_space.high).astype(np.float32)
            if visual:
                data["state_observations"].append(state_observation(u))
            else:
                oracle = u.compute_oracle_observation if hasattr(u, "compute_oracle_observation") else u.get_xy
                data["oracle_reps"].append(oracle())
            next_ob, _, terminated, truncated, info = env.step(action)
            data["observations"].append(ob)
            data["actions"].append(action)
            data["terminals"].append(terminated or truncated)
            data["qpos"].append(info["prev_qpos"])
            data["qvel"].append(info["prev_qvel"])
            if buttons:
                data["button_states"].append(info["prev_button_states"])
            ob = next_ob
    # The generators' dtypes: uint8 frames, bool terminals, int64 button states, float32 the rest.
    dtypes = {"observations": np.uint8 if visual else np.float32, "terminals": bool, "button_states": np.int64}
    return {k: np.array(v, dtype=dtypes.get(k, np.float32)) for k, v in data.items()}


def main():
    out = sys.argv[1]
    collect = dict(mode="data_collection")  # generate_manipspace.py's env: a randomized scene
    sets = [("cube", "cube-single-v0", "cube-single-play-v0", 2, 21, {}),
            ("cube", "cube-double-v0", "cube-double-play-v0", 2, 21, {}),
            ("antmaze", "antmaze-medium-v0", "antmaze-medium-navigate-v0", 4, 51, {}),
            ("puzzle", "puzzle-3x3-v0", "puzzle-3x3-play-v0", 2, 21, {}),
            ("scene", "scene-v0", "scene-play-v0", 2, 21, {}),
            ("visual", "visual-cube-single-v0", "visual-cube-single-play-v0", 2, 21, collect),
            ("visual", "visual-puzzle-3x3-v0", "visual-puzzle-3x3-play-v0", 2, 21, collect),
            ("visual", "visual-antmaze-medium-v0", "visual-antmaze-medium-navigate-v0", 2, 21, {}),
            ("visual", "visual-scene-v0", "visual-scene-play-v0", 2, 21, collect)]
    only = sys.argv[2:]
    for folder, env_id, name, episodes, rows, kwargs in sets:
        if only and folder not in only and name not in only:
            continue
        os.makedirs(os.path.join(out, folder), exist_ok=True)
        np.random.seed(0)
        env = gymnasium.make(env_id, terminate_at_goal=False, max_episode_steps=rows, **kwargs)
        env.reset(seed=0)
        for suffix, n in [("", episodes), ("-val", 1)]:
            d = rollout(env, n, rows, visual=folder == "visual")
            path = os.path.join(out, folder, f"{name}{suffix}.npz")
            np.savez_compressed(path, **d)
            print(path, {k: (v.dtype.str, v.shape) for k, v in d.items()})
        # Free the env (its renderer) while its GL context is still the current one: mujoco's
        # Renderer.close() frees its MjrContext in whichever context is current, so an env collected
        # after the next one has made its renderer frees the new one's buffers (garbage frames).
        del env
        gc.collect()


if __name__ == "__main__":
    main()
