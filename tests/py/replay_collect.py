"""Replay episodes of a `pgser-etl collect` table in gymnasium-robotics and compare.

    replay_collect.py TABLE.parquet --episodes 0,1,5 [--tol 1e-6]

For each episode i: `env.reset(seed=S+i)` (S and the task from the table's `pgser` footer),
then step with the recorded actions as float32 (the action space's dtype; collect stores
actions exactly as the environment applied them). Every observation, achieved goal and desired
goal must match the table within --tol. For the random policy the actions themselves are
recomputed too: episode i's are `default_rng(SeedSequence(S, spawn_key=(i,))).uniform(-1, 1)`,
four per step, as float32, and must be equal. Prints one JSON line with the largest differences
and exits 1 if any exceeds the tolerance.
"""

import argparse
import json
import sys

import numpy as np
import pyarrow.parquet as pq

import env_parity  # noqa: F401  (its import patches mujoco_utils for mujoco 3.17; see there)
import gymnasium as gym


def main():
    p = argparse.ArgumentParser()
    p.add_argument("table")
    p.add_argument("--episodes", type=lambda s: [int(x) for x in s.split(",")], required=True)
    p.add_argument("--tol", type=float, default=1e-6)
    args = p.parse_args()

    pf = pq.ParquetFile(args.table)
    footer = json.loads(pf.metadata.metadata[b"pgser"])
    table = pf.read()
    T = footer["T"]

    def column(name):
        """A FixedSizeList column as a (rows, dim) float64 array, NaN on null rows."""
        arr = table.column(name).combine_chunks()
        dim = arr.type.list_size
        values = arr.values.to_numpy(zero_copy_only=False).astype(np.float64).reshape(len(arr), dim)
        values[arr.is_null().to_numpy(zero_copy_only=False)] = np.nan
        return values

    obs, ag, g, u = (column(n) for n in ("obs", "achieved_goal", "desired_goal", "action"))
    episode = table.column("episode").to_numpy()

    env = gym.make(f"{footer['task']}-v4").unwrapped
    worst = {"observation": 0.0, "achieved_goal": 0.0, "desired_goal": 0.0, "random_action": 0.0}

    def compare(got, row):
        """Observation row `row` of the table against what gymnasium returned."""
        for key, want in (("observation", obs[row]), ("achieved_goal", ag[row]), ("desired_goal", g[row])):
            if not np.isnan(want).any():  # desired_goal is null on the last step
                worst[key] = max(worst[key], float(np.max(np.abs(got[key] - want))))

    for i in args.episodes:
        rows = np.flatnonzero(episode == i)
        assert len(rows) == T, f"episode {i} has {len(rows)} rows, want {T}"
        if footer.get("policy") == "random":
            rng = np.random.default_rng(np.random.SeedSequence(footer["seed"], spawn_key=(i,)))
            want = rng.uniform(-1, 1, size=(T - 1, u.shape[1])).astype(np.float32)
            worst["random_action"] = max(worst["random_action"], float(np.max(np.abs(u[rows[:-1]] - want))))
        o, _ = env.reset(seed=footer["seed"] + i)
        compare(o, rows[0])
        for t in range(T - 1):
            o, *_ = env.step(u[rows[t]].astype(np.float32))
            compare(o, rows[t + 1])
    env.close()
    print(json.dumps({"episodes": args.episodes, "max_abs_diff": worst}))
    sys.exit(0 if max(worst.values()) <= args.tol else 1)


if __name__ == "__main__":
    main()
