#!/usr/bin/env python3
"""The peers of pgser's sharded sampler (issue 65): OGBench's goal-conditioned batches, drawn
the way OGBench's and Horizon Reduction's trainers draw them, written here from OGBench's
documented sampling rules (nothing of theirs is imported, so the peer needs only numpy).

A dataset is a folder of `.npz` shards in Horizon Reduction's layout (`NAME-0.npz`,
`NAME-1.npz`, ...; `-val.npz` files are skipped, as their trainer skips them): `observations`,
`actions` and `terminals` (1 on each episode's last row), one row per step. A shard is loaded as
OGBench's `load_dataset` does by default (the regular layout): each episode's last row is
dropped and its observation becomes the previous row's `next_observations`, so row i is the
transition (s_i, a_i, s_{i+1}) and `terminals` marks each episode's last transition.

A batch of B rows (OGBench's GCDataset rules):
- rows i are uniform over the loaded transitions;
- a goal is, per row, the row's own state with probability p_curgoal; a state of the row's own
  episode after it with p_trajgoal (a geometric offset of parameter 1 - discount, clipped to the
  episode's last state, when geometric; else uniform between the next state and the last); or
  a uniformly random row's state with p_randomgoal;
- value goals and actor goals are drawn apart, each with its own fractions;
- rewards = success - 1 (`gc_negative`) and masks = 1 - success, success being goal row == row.

Two schemes, each on the machine alone, timed per batch:
- `ram`: one shard held in memory, every goal from it (what OGBench's trainer does with one
  file; the in-RAM reference of "as fast as numpy").
- `reload`: Horizon Reduction's trainer over a folder: one shard in memory, the next loaded
  synchronously every `--replace-interval` batches (their `dataset_replace_interval`: 1000, or
  4000 for humanoidmaze), every goal, the random ones too, from the loaded shard. The batch that
  triggers a reload pays for it: that is the pause a learner sees.

Prints one JSON line (or writes --json): batches, batch_size, seconds, batches_per_sec,
median_ms, p999_ms, max_ms (the longest batch, pauses included), reloads, load_seconds (the
first shard), peak_rss_bytes (ru_maxrss), rows_loaded (transitions of the shard held last).

Usage:
    ogbench_peer.py DIR [--scheme ram|reload] [--batches 3000] [--batch-size 1024]
                    [--replace-interval 1000] [--seed 0] [--json OUT]
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import resource
import sys
import time

import numpy as np


def shards(folder: str) -> list[str]:
    """The training shards of a folder, in name order as Horizon Reduction's trainer lists them."""
    files = [f for f in sorted(glob.glob(os.path.join(folder, "*.npz"))) if not f.endswith("-val.npz")]
    if not files:
        sys.exit(f"{folder}: no .npz shards")
    return files


def load_regular(path: str) -> dict[str, np.ndarray]:
    """One shard as OGBench's default (regular) layout: last rows dropped, next states kept."""
    with np.load(path) as f:
        obs = f["observations"].astype(np.float32, copy=False)
        actions = f["actions"].astype(np.float32, copy=False)
        terminals = f["terminals"].astype(np.float32, copy=False)
    keep = terminals == 0
    next_keep = np.concatenate([[False], keep[:-1]])
    # The regular layout's terminals: 1 on each episode's last kept transition.
    shifted = np.concatenate([terminals[1:], [1.0]]).astype(np.float32)
    return {
        "observations": obs[keep],
        "next_observations": obs[next_keep],
        "actions": actions[keep],
        "terminals": shifted[keep],
    }


class GoalSampler:
    """OGBench's GCDataset rules over one loaded shard (the module doc)."""

    def __init__(self, data: dict[str, np.ndarray], cfg: argparse.Namespace, rng: np.random.Generator):
        self.d = data
        self.cfg = cfg
        self.rng = rng
        self.size = len(data["observations"])
        (self.last,) = np.nonzero(data["terminals"] > 0)
        if len(self.last) == 0 or self.last[-1] != self.size - 1:
            raise ValueError("the shard's last row does not end an episode")

    def goals(self, idx: np.ndarray, p_cur: float, p_traj: float, geometric: bool) -> np.ndarray:
        n = len(idx)
        random = self.rng.integers(0, self.size, n)
        final = self.last[np.searchsorted(self.last, idx)]
        if geometric:
            future = np.minimum(idx + self.rng.geometric(1.0 - self.cfg.discount, n), final)
        else:
            u = self.rng.random(n)
            future = np.round(np.minimum(idx + 1, final) * u + final * (1.0 - u)).astype(np.int64)
        if p_cur >= 1.0:
            return idx
        goal = np.where(self.rng.random(n) < p_traj / (1.0 - p_cur), future, random)
        return np.where(self.rng.random(n) < p_cur, idx, goal)

    def sample(self, b: int) -> dict[str, np.ndarray]:
        c = self.cfg
        idx = self.rng.integers(0, self.size, b)
        vg = self.goals(idx, c.value_p_curgoal, c.value_p_trajgoal, True)
        ag = self.goals(idx, c.actor_p_curgoal, c.actor_p_trajgoal, False)
        success = (idx == vg).astype(np.float32)
        obs = self.d["observations"]
        return {
            "observations": obs[idx],
            "next_observations": self.d["next_observations"][idx],
            "actions": self.d["actions"][idx],
            "rewards": success - 1.0,
            "masks": 1.0 - success,
            "value_goals": obs[vg],
            "actor_goals": obs[ag],
        }


def run(args: argparse.Namespace) -> dict:
    files = shards(args.folder)
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    sampler = GoalSampler(load_regular(files[0]), args, rng)
    load_seconds = time.perf_counter() - t0
    for _ in range(args.warmup):
        sampler.sample(args.batch_size)
    times = np.empty(args.batches)
    which, reloads = 0, 0
    start = time.perf_counter()
    for i in range(args.batches):
        t = time.perf_counter()
        if args.scheme == "reload" and i > 0 and i % args.replace_interval == 0 and len(files) > 1:
            which = (which + 1) % len(files)
            sampler = GoalSampler(load_regular(files[which]), args, rng)
            reloads += 1
        sampler.sample(args.batch_size)
        times[i] = time.perf_counter() - t
    seconds = time.perf_counter() - start
    ms = times * 1e3
    return {
        "peer": f"ogbench-numpy-{args.scheme}",
        "numpy": np.__version__,
        "shards": len(files),
        "batches": args.batches,
        "batch_size": args.batch_size,
        "seconds": seconds,
        "batches_per_sec": args.batches / seconds,
        "median_ms": float(np.median(ms)),
        "p999_ms": float(np.quantile(ms, 0.999)),
        "max_ms": float(ms.max()),
        "reloads": reloads,
        "load_seconds": load_seconds,
        "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "rows_loaded": sampler.size,
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder")
    p.add_argument("--scheme", choices=["ram", "reload"], default="ram")
    p.add_argument("--batches", type=int, default=3000)
    p.add_argument("--warmup", type=int, default=20)
    p.add_argument("--batch-size", type=int, default=1024)
    p.add_argument("--replace-interval", type=int, default=1000)
    p.add_argument("--seed", type=int, default=0)
    # OGBench's GCIQL defaults.
    p.add_argument("--discount", type=float, default=0.99)
    p.add_argument("--value-p-curgoal", type=float, default=0.2)
    p.add_argument("--value-p-trajgoal", type=float, default=0.5)
    p.add_argument("--actor-p-curgoal", type=float, default=0.0)
    p.add_argument("--actor-p-trajgoal", type=float, default=1.0)
    p.add_argument("--json")
    args = p.parse_args()
    out = run(args)
    line = json.dumps(out)
    if args.json:
        with open(args.json, "w") as f:
            f.write(line + "\n")
    print(line)


if __name__ == "__main__":
    main()
