#!/usr/bin/env python3
"""The Python module against its peers, each in the same run:

1. env steps/s: `pgser.VectorEnv("FetchPush-v4", 16)` against gymnasium's `SyncVectorEnv` and
   `AsyncVectorEnv` over 16 `gym.make("FetchPush-v4")` of gymnasium-robotics 1.4.2 (same MuJoCo
   3.17.0 library, same uniform random actions, next-step autoreset on every side);
2. prioritized batches/s from Python: `pgser.Sampler` (every row drawn by priority:
   aug_ratio 1, IS beta 0.4, batch 256; from disk and in memory) against cpprb's
   `PrioritizedReplayBuffer` on the same scored table with the same priorities
   (bench/sampler_peer.py, run by --peer-python, which needs cpprb).

The scored table is made here with the CLI: FetchPush, 400 expert + 400 random episodes, a
critic of 200 updates, 4 swaps per transition (156,800 rows).

    .venv/bin/python bench/bench_python.py --peer-python bench-out/torch-venv/bin/python --json out.json

Run it in a Python that has `pgser` (make python), gymnasium-robotics and numpy.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def patched_gym():
    """gymnasium-robotics 1.4.2's joint-type asserts fail with mujoco 3.17 (mjtJoint enum vs
    np.int32); give its helpers plain ints. No number changes (bench_env.py does the same)."""
    import gymnasium as gym
    import gymnasium_robotics
    import mujoco
    from gymnasium_robotics.utils import mujoco_utils

    shim = types.ModuleType("mujoco")
    shim.__dict__.update(mujoco.__dict__)
    shim.mjtJoint = types.SimpleNamespace(**{k: int(v) for k, v in mujoco.mjtJoint.__members__.items()})
    mujoco_utils.mujoco = shim
    gym.register_envs(gymnasium_robotics)
    return gym


def make_fetch_push():
    # In the worker processes of AsyncVectorEnv too: the patch is per process.
    return patched_gym().make("FetchPush-v4")


def time_vector(env, actions):
    env.reset(seed=0)
    env.step(actions[0])  # warm-up
    t0 = time.perf_counter()
    for a in actions:
        env.step(a)
    return time.perf_counter() - t0


def bench_envs(n, steps, rounds, seed=0):
    """Each side `rounds` times, in rotating order; medians (as the other benchmarks do)."""
    import pgser

    gym = patched_gym()
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-1, 1, (steps, n, 4)).astype(np.float32)
    out = {"task": "FetchPush-v4", "envs": n, "vector_steps": steps, "env_steps": steps * n, "rounds": rounds}
    sides = {
        "pgser": lambda: pgser.VectorEnv("FetchPush-v4", n),
        "sync": lambda: gym.vector.SyncVectorEnv([make_fetch_push] * n),
        "async": lambda: gym.vector.AsyncVectorEnv([make_fetch_push] * n),
    }
    names = list(sides)
    times = {name: [] for name in names}
    for r in range(rounds):
        for name in names[r % len(names):] + names[: r % len(names)]:
            env = sides[name]()
            times[name].append(time_vector(env, actions))
            env.close()
    for name in names:
        seconds = float(np.median(times[name]))
        out[name] = {"seconds": seconds, "steps_per_sec": steps * n / seconds, "all_seconds": times[name]}
    best = max(out["sync"]["steps_per_sec"], out["async"]["steps_per_sec"])
    out["ratio_vs_faster_peer"] = out["pgser"]["steps_per_sec"] / best
    return out


def cli(*args):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"{args[0]} failed: {p.stderr}")
    return p.stdout


def scored_table(d, etl, train):
    pickles = [d / "expert.pkl", d / "random.pkl"]
    cli(etl, "collect", "--task", "FetchPush", "--policy", "expert", "--episodes", "400", "--seed", "0", "-o", pickles[0])
    cli(etl, "collect", "--task", "FetchPush", "--policy", "random", "--episodes", "400", "--seed", "1000", "-o", pickles[1])
    data = d / "push.parquet"
    cli(etl, "convert", *pickles, "-o", data, "--task", "FetchPush")
    ckpt = d / "q.ckpt"
    cli(train, "--data", data, "-o", ckpt, "--updates", "200", "--batch-size", "256", "--eval-episodes", "0")
    scored = d / "scored.parquet"
    cli(etl, "score", "--q", ckpt, "--data", data, "-o", scored, "--swaps", "4")
    return scored


def time_sampler(scored, batch_size, batches, in_memory):
    import pgser

    t0 = time.perf_counter()
    # q at α = 1 on both sides, named: the peer's default, and the setting of BENCHMARKS.md's figures
    s = pgser.Sampler(scored, batch_size=batch_size, aug_ratio=1.0, priority="q", alpha=1.0, is_beta=0.4,
                      in_memory=in_memory, num_batches=batches + 50)
    for _ in range(50):  # warm-up, as the peer's
        next(s)
    setup = time.perf_counter() - t0
    t0 = time.perf_counter()
    n = sum(1 for _ in s)
    seconds = time.perf_counter() - t0
    return {"batches": n, "seconds": seconds, "batches_per_sec": n / seconds,
            "samples_per_sec": n * batch_size / seconds, "setup_seconds": setup}


def bench_sampler(etl, train, peer_python, batch_size, batches):
    with tempfile.TemporaryDirectory() as tmp:
        scored = scored_table(Path(tmp), etl, train)
        import pgser

        out = {"rows": pgser.read_footer(scored)["rows"], "batch_size": batch_size}
        out["pgser_disk"] = time_sampler(scored, batch_size, batches, False)
        out["pgser_memory"] = time_sampler(scored, batch_size, batches, True)
        peer = cli(peer_python, REPO / "bench/sampler_peer.py", "--data", scored, "--batch-size", batch_size,
                   "--batches", batches, "--beta", "0.4", "--json")
        out["cpprb"] = json.loads(peer.strip().splitlines()[-1])
        for side in ("pgser_disk", "pgser_memory"):
            out[f"ratio_{side}_vs_cpprb"] = out[side]["batches_per_sec"] / out["cpprb"]["batches_per_sec"]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pgser-etl", default=str(REPO / "target/release/pgser-etl"))
    ap.add_argument("--pgser-train", default=str(REPO / "target/release/pgser-train"))
    ap.add_argument("--peer-python", help="a Python with cpprb, numpy, pyarrow (the sampler's peer)")
    ap.add_argument("--envs", type=int, default=16)
    ap.add_argument("--steps", type=int, default=500, help="vector steps per side and round")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--batches", type=int, default=3000)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    report = {"cores": os.cpu_count(), "envs": bench_envs(args.envs, args.steps, args.rounds)}
    e = report["envs"]
    print(f"VectorEnv FetchPush-v4 x{args.envs}: pgser {e['pgser']['steps_per_sec']:.0f} env-steps/s, "
          f"SyncVectorEnv {e['sync']['steps_per_sec']:.0f}, AsyncVectorEnv {e['async']['steps_per_sec']:.0f}: "
          f"{e['ratio_vs_faster_peer']:.2f}x the faster", flush=True)
    if args.peer_python:
        s = bench_sampler(args.pgser_etl, args.pgser_train, args.peer_python, args.batch_size, args.batches)
        report["sampler"] = s
        print(f"Sampler, {s['rows']} rows, batch {s['batch_size']}: pgser disk {s['pgser_disk']['batches_per_sec']:.0f} "
              f"batches/s, memory {s['pgser_memory']['batches_per_sec']:.0f}, cpprb {s['cpprb']['batches_per_sec']:.0f}: "
              f"{s['ratio_pgser_disk_vs_cpprb']:.2f}x / {s['ratio_pgser_memory_vs_cpprb']:.2f}x")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
