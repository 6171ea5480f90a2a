#!/usr/bin/env python3
"""Statistics of PointMaze datasets, to check `pgser-etl collect --policy oracle` against OGBench's
own data generator in distribution (tests/ogbench.rs).

    ogbench_generator_stats.py reference GENERATE_LOCOMAZE_PY OUT.json
        Runs OGBench's `data_gen_scripts/generate_locomaze.py` itself (from a checkout of the ogbench
        repository; it is not in the wheel) for each dataset of DATASETS, with the flags of its
        `commands.sh` but fewer episodes, and writes each dataset's statistics to OUT.json. The
        script imports its SAC agent's modules (jax, flax), which PointMaze never uses: stand-ins
        are put in sys.modules so that it runs in a venv with `ogbench`, `absl-py` and `tqdm` only.
        The script never seeds numpy, so every run draws other episodes: the statistics carry their
        spread over episodes, which is what the comparison allows for.

    ogbench_generator_stats.py compare REFERENCE.json NAME GOT.npz
        The statistics of GOT.npz against REFERENCE.json's NAME: every statistic's mean over
        episodes must agree within 5 standard errors of the difference (a two-sample z-test, at
        once over ~20-110 statistics, so a chance failure is ~1e-5). Prints one JSON line with
        the largest |z|; exits non-zero naming the statistics that differ.

Statistics, per episode then averaged (an episode is M rows, `terminals` ends it):
  - cell/I_J: the share of its rows in free cell (I, J) (state coverage);
  - action_mean_x/y, action_sd_x/y, action_clipped (share of action values at +-1);
  - step_length: mean distance between consecutive observations;
  - wall_contact: share of rows after the first with a non-zero qvel (a wall pushed back);
  - span: distance from the first observation to the last.
"""

import json
import sys
import types
import warnings

import numpy as np

warnings.filterwarnings("ignore")

# (dataset, generator flags as in commands.sh except --num_episodes, episodes here)
DATASETS = [
    ("pointmaze-medium-navigate-v0", "pointmaze-medium-v0", "navigate", 1001, 200),
    ("pointmaze-medium-stitch-v0", "pointmaze-medium-v0", "stitch", 201, 1000),
    ("pointmaze-large-stitch-v0", "pointmaze-large-v0", "stitch", 201, 1000),
]
MAZE_UNIT = 4.0


def cell_of(xy):
    """ogbench's xy_to_ij for many points: (row i, column j)."""
    i = ((xy[:, 1] + 4 + MAZE_UNIT / 2) / MAZE_UNIT).astype(int)
    j = ((xy[:, 0] + 4 + MAZE_UNIT / 2) / MAZE_UNIT).astype(int)
    return i, j


def per_episode(path, maze_map):
    d = np.load(path)
    obs, act, term, qvel = d["observations"], d["actions"], d["terminals"], d["qvel"]
    ends = np.flatnonzero(term) + 1
    starts = np.r_[0, ends[:-1]]
    free = [(i, j) for i in range(maze_map.shape[0]) for j in range(maze_map.shape[1]) if maze_map[i, j] == 0]
    stats = {f"cell/{i}_{j}": [] for i, j in free}
    for k in ["action_mean_x", "action_mean_y", "action_sd_x", "action_sd_y", "action_clipped", "step_length",
              "wall_contact", "span"]:
        stats[k] = []
    for s, e in zip(starts, ends):
        o, a, v = obs[s:e].astype(np.float64), act[s:e].astype(np.float64), qvel[s:e]
        ci, cj = cell_of(o)
        for i, j in free:
            stats[f"cell/{i}_{j}"].append(float(np.mean((ci == i) & (cj == j))))
        stats["action_mean_x"].append(a[:, 0].mean())
        stats["action_mean_y"].append(a[:, 1].mean())
        stats["action_sd_x"].append(a[:, 0].std())
        stats["action_sd_y"].append(a[:, 1].std())
        stats["action_clipped"].append(float(np.mean(np.abs(a) == 1.0)))
        stats["step_length"].append(float(np.linalg.norm(np.diff(o, axis=0), axis=1).mean()))
        stats["wall_contact"].append(float(np.mean(np.any(v[1:] != 0, axis=1))))
        stats["span"].append(float(np.linalg.norm(o[-1] - o[0])))
    return {k: np.asarray(v, dtype=np.float64) for k, v in stats.items()}


def summary(stats):
    return {k: {"mean": float(v.mean()), "sd": float(v.std(ddof=1)), "n": int(len(v))} for k, v in stats.items()}


def maze_map_of(env_name):
    import gymnasium
    import ogbench.locomaze  # noqa: F401

    env = gymnasium.make(env_name)
    m = np.array(env.unwrapped.maze_map)
    env.close()
    return m


def run_generator(generator, *flags):
    """Runs the generator script as `python generate_locomaze.py FLAGS...` would, with stand-ins
    for the SAC expert's modules, which it imports for the ant and humanoid only."""
    import runpy

    for name, attrs in [("agents", ["SACAgent"]), ("utils", []), ("utils.evaluation", ["supply_rng"]),
                        ("utils.flax_utils", ["restore_agent"])]:
        m = types.ModuleType(name)
        for a in attrs:
            setattr(m, a, None)
        sys.modules[name] = m
    sys.modules["utils"].evaluation = sys.modules["utils.evaluation"]
    sys.modules["utils"].flax_utils = sys.modules["utils.flax_utils"]
    sys.argv = [generator, *flags]
    runpy.run_path(generator, run_name="__main__")


def reference(generator, out):
    import os
    import subprocess
    import tempfile

    result = {"generator": os.path.basename(generator), "datasets": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for name, env_name, kind, rows, episodes in DATASETS:
            path = os.path.join(tmp, f"{name}.npz")
            flags = [f"--env_name={env_name}", f"--save_path={path}", f"--dataset_type={kind}",
                     f"--num_episodes={episodes}", f"--max_episode_steps={rows}", "--noise=0.5"]
            subprocess.run([sys.executable, __file__, "run-generator", generator, *flags], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            result["datasets"][name] = summary(per_episode(path, maze_map_of(env_name)))
            print(f"{name}: {episodes} episodes of {rows} rows", file=sys.stderr)
    with open(out, "w") as f:
        json.dump(result, f, indent=1, sort_keys=True)
        f.write("\n")


def compare(ref_path, name, got_path):
    ref = json.load(open(ref_path))["datasets"][name]
    env_name = "-".join(name.split("-")[:2] + name.split("-")[-1:])
    got = summary(per_episode(got_path, maze_map_of(env_name)))
    if sorted(got) != sorted(ref):
        sys.exit(f"{got_path}: statistics {sorted(set(got) ^ set(ref))} are not in both")
    z = {}
    for k, r in ref.items():
        g = got[k]
        se = np.sqrt(r["sd"] ** 2 / r["n"] + g["sd"] ** 2 / g["n"])
        diff = g["mean"] - r["mean"]
        z[k] = 0.0 if se == 0 and diff == 0 else (np.inf if se == 0 else abs(diff) / se)
    bad = {k: (got[k]["mean"], ref[k]["mean"], z[k]) for k in z if z[k] > 5}
    worst = max(z, key=z.get)
    print(json.dumps({"statistics": len(z), "max_z": round(float(z[worst]), 2), "worst": worst,
                      "episodes": got[worst]["n"], "reference_episodes": ref[worst]["n"]}))
    if bad:
        sys.exit(f"{got_path}: differs from OGBench's generator in " +
                 ", ".join(f"{k} ({g:.4f} vs {r:.4f}, z = {zz:.1f})" for k, (g, r, zz) in bad.items()))


if __name__ == "__main__":
    if sys.argv[1] == "reference":
        reference(*sys.argv[2:4])
    elif sys.argv[1] == "run-generator":
        run_generator(*sys.argv[2:])
    elif sys.argv[1] == "compare":
        compare(*sys.argv[2:5])
    else:
        sys.exit(__doc__)
