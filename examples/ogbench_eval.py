#!/usr/bin/env python3
"""Train on an OGBench dataset file with pgser, evaluate in OGBench's own environment.

    python examples/ogbench_eval.py ~/.ogbench/data/antmaze-large-navigate-v0.npz --out /tmp/ant
    python examples/ogbench_eval.py pointmaze-medium-stitch-v0.npz --updates 20000 --swap random

For any OGBench locomotion-maze or cube dataset (pointmaze, antmaze, humanoidmaze, cube-*; pgser
simulates only PointMaze, so this is how the others are evaluated). Steps:
1. `pgser-etl convert DATASET.npz`: the trajectory table (goal = the x, y or the cubes' positions; docs/ogbench.md);
2. `pgser-train`: TD3+BC (optionally with random goal swapping) at gamma 0.99, OGBench's agents'
   discount, as the PointMaze pipelines train;
3. OGBench's protocol in `ogbench.make_env_and_datasets(NAME, env_only=True)`: each of the 5
   evaluation tasks for --episodes episodes, `env.reset(options=dict(task_id=k))`, the goal what
   `pgser.ogbench_goal` maps `info["goal"]` (the goal state's whole observation) to, as the table's
   goals were mapped (the x, y; the cubes' positions), actions from `pgser.Policy(checkpoint).act`
   (batched, float32), until the episode terminates at its goal or the time limit truncates it;
   success is `info["success"]` of the last step. Prints each task's success rate and their mean,
   then one JSON line. With --full-goal the table's goals are whole observations, and so is the
   goal given to the agent.

The dataset's name (its file name, as OGBench names its files) gives the environment. The
`-val.npz` file is not needed. Nothing is downloaded: get the file with OGBench's own loader, or
make a PointMaze one with `pgser-etl collect --policy oracle`.
"""

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

import pgser


def tool(name, given):
    """pgser's command `name`: --pgser-etl/--pgser-train, else the one on PATH (the wheel's)."""
    path = given or shutil.which(name)
    if path is None:
        sys.exit(f"{name} not found: install the pgser wheel, or pass --{name}")
    return str(path)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("dataset", type=Path, help="an OGBench dataset file, named after its dataset")
    p.add_argument("--out", type=Path, default=Path("ogbench-run"))
    p.add_argument("--updates", type=int, default=20000)
    p.add_argument("--batch-size", type=int, default=256)
    p.add_argument("--swap", choices=["none", "random"], default="none")
    p.add_argument("--episodes", type=int, default=50, help="evaluation episodes per task (OGBench: 50)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--full-goal", type=float, metavar="THRESHOLD",
                   help="train on whole-observation goals (convert --full-goal), reached within THRESHOLD")
    p.add_argument("--pgser-etl")
    p.add_argument("--pgser-train")
    a = p.parse_args()

    import ogbench  # the evaluation is OGBench's own environment

    name = a.dataset.name.removesuffix(".npz")
    a.out.mkdir(parents=True, exist_ok=True)
    table, ckpt = a.out / "traj.parquet", a.out / "agent.ckpt"
    full = [] if a.full_goal is None else ["--full-goal", "--threshold", str(a.full_goal)]
    subprocess.run([tool("pgser-etl", a.pgser_etl), "convert", a.dataset, "-o", table, *full], check=True)
    subprocess.run(
        [tool("pgser-train", a.pgser_train), "--data", table, "-o", ckpt, "--updates", str(a.updates),
         "--batch-size", str(a.batch_size), "--gamma", "0.99", "--swap", a.swap, "--seed", str(a.seed),
         "--eval-episodes", "0", "--save-every", str(a.updates)],
        check=True,
    )

    policy = pgser.Policy(str(ckpt))
    env_name, obs_dim, goal_dim, _ = policy.task  # the environment the table was made for (cube-double-v0, ...)
    env = ogbench.make_env_and_datasets(name, env_only=True)
    tasks = env.unwrapped.task_infos
    success = []
    for k in range(1, len(tasks) + 1):
        reached = 0
        for ep in range(a.episodes):
            # OGBench draws start and goal noise from numpy's global generator, which reset's
            # seed leaves alone: seeded here so that a run repeats.
            np.random.seed(a.seed * 1000 + ep)
            ob, info = env.reset(seed=a.seed * 1000 + ep, options=dict(task_id=k))
            goal = np.asarray(info["goal"])
            if a.full_goal is None:
                goal = pgser.ogbench_goal(env_name, goal)
            done = False
            while not done:
                action = policy.act(ob[None], goal[None])[0]
                ob, _, terminated, truncated, info = env.step(action)
                done = terminated or truncated
            reached += float(info["success"])
        success.append(reached / a.episodes)
        print(f"{tasks[k - 1]['task_name']}: success {success[-1]:.3f} over {a.episodes} episodes", file=sys.stderr)
    env.close()
    overall = float(np.mean(success))
    print(f"{name}: success {overall:.3f} (mean over {len(success)} tasks)", file=sys.stderr)
    print(json.dumps({"dataset": name, "success": overall, "task_success": success, "episodes": a.episodes,
                      "updates": a.updates, "checkpoint": str(ckpt)}))


if __name__ == "__main__":
    main()
