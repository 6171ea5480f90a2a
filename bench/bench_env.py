#!/usr/bin/env python3
"""Env steps/s: pgser's Rust Fetch and hand envs vs gymnasium-robotics 1.4.2 (mujoco 3.17.0), same run.

Rust side: `pgser-etl collect --policy random` (episodes run with rayon; RAYON_NUM_THREADS=1 for
the single-env figure, =N for parallel collect). Its time includes writing the Parquet output,
which is small next to simulation. Python side: `gym.make('<Task>-v4')` with its default
wrappers (`<Task>-v1` for the hand tasks), `reset(seed=S+i)` and uniform random actions for the
same number of steps per episode (T-1: 49 for Fetch, 99 for the hand tasks), one process for the single-env figure and a multiprocessing pool of N workers for
the parallel one. Prints steps/s, steps/s per core and the ratios.
"""
import argparse
import json
import multiprocessing as mp
import os
import subprocess
import sys
import tempfile
import time

def shape(task):
    """(gymnasium id, actions per episode = T - 1, action dimension)."""
    if task.startswith("Hand"):
        return f"{task}-v1", 99, 20
    return f"{task}-v4", 49, 4


def patched_gym():
    """gymnasium-robotics 1.4.2's mujoco_utils asserts fail with mujoco 3.17 (mjtJoint enum vs
    np.int32); give it plain ints. No number changes."""
    import types
    import gymnasium as gym
    import gymnasium_robotics  # noqa: F401  (registers the envs)
    import mujoco
    from gymnasium_robotics.utils import mujoco_utils
    shim = types.ModuleType("mujoco")
    shim.__dict__.update(mujoco.__dict__)
    shim.mjtJoint = types.SimpleNamespace(**{k: int(v) for k, v in mujoco.mjtJoint.__members__.items()})
    mujoco_utils.mujoco = shim
    return gym


def python_episodes(args):
    task, first, count = args
    import numpy as np
    gym = patched_gym()
    gym_id, steps, act_dim = shape(task)
    env = gym.make(gym_id)
    rng = np.random.default_rng(first)
    t0 = time.perf_counter()
    for i in range(first, first + count):
        env.reset(seed=i)
        for _ in range(steps):
            env.step(rng.uniform(-1, 1, act_dim).astype(np.float32))
    return time.perf_counter() - t0


def python_run(task, episodes, workers):
    t0 = time.perf_counter()
    if workers == 1:
        python_episodes((task, 0, episodes))
    else:
        per = episodes // workers
        with mp.get_context("spawn").Pool(workers) as pool:
            # Warm the workers (imports, model load) before timing: a fair steady-state figure.
            pool.map(python_episodes, [(task, 10**6 + w, 1) for w in range(workers)])
            t0 = time.perf_counter()
            pool.map(python_episodes, [(task, w * per, per) for w in range(workers)])
    return time.perf_counter() - t0


def rust_run(pgser, task, episodes, threads, out):
    env = dict(os.environ, RAYON_NUM_THREADS=str(threads))
    cmd = [pgser, "collect", "--task", task, "--policy", "random", "--episodes", str(episodes), "--seed", "0", "-o", out]
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, env=env, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pgser", required=True, help="path to pgser-etl")
    ap.add_argument("--tasks", default="FetchReach,FetchPush", help="comma-separated")
    ap.add_argument("--episodes", type=int, default=400)
    ap.add_argument("--threads", type=int, default=os.cpu_count())
    ap.add_argument("--json", help="also write the figures here")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "c.parquet")
        for task in a.tasks.split(","):
            python_episodes((task, 10**7, 2))  # warm imports and caches in this process
            steps = a.episodes * shape(task)[1]
            r1 = min(rust_run(a.pgser, task, a.episodes, 1, out) for _ in range(2))
            p1 = python_run(task, a.episodes, 1)
            rn = min(rust_run(a.pgser, task, a.episodes, a.threads, out) for _ in range(2))
            pn = python_run(task, a.episodes, a.threads)
            rows.append(dict(task=task, steps=steps, threads=a.threads,
                             rust_1=steps / r1, python_1=steps / p1, rust_n=steps / rn, python_n=steps / pn))
    print(f"env steps/s, random actions, {a.episodes} episodes (T-1 steps each), {a.threads} threads/processes "
          f"for the parallel figures (machine: {os.cpu_count()} cores)")
    print(f"{'task':<18} {'rust 1':>10} {'python 1':>10} {'ratio':>6} | {'rust N':>10} {'python N':>10} {'ratio':>6} "
          f"| {'rust/core':>10} {'py/core':>10}")
    for r in rows:
        print(f"{r['task']:<18} {r['rust_1']:>10.0f} {r['python_1']:>10.0f} {r['rust_1'] / r['python_1']:>5.2f}x | "
              f"{r['rust_n']:>10.0f} {r['python_n']:>10.0f} {r['rust_n'] / r['python_n']:>5.2f}x | "
              f"{r['rust_n'] / r['threads']:>10.0f} {r['python_n'] / r['threads']:>10.0f}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    sys.exit(main())
