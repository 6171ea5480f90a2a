#!/usr/bin/env python3
"""pgser's batches beside OGBench's and Horizon Reduction's own dataset classes, run from local
checkouts of their code (never committed, never needed by `make test`): for each agent's config
(their `get_config()`), the same statistics of a batch's keys from their `GCDataset` /
`HGCDataset` and from `pgser.Sampler(layout=..., config=config)`, side by side.

Their classes only index arrays, so they are given the shards' arrays with every observation
(and oracle representation) replaced by its own (episode, step) code: each key of their batch
then says which row it read, as pgser's provenance columns say it. The statistics are shares
(successes, masks, goals in the row's episode, at its step, each subgoal step count) and mean
step offsets of each goal key; the aim is every share within 0.01.

Each code runs in a child process of its own (both name their packages `agents` and `utils`).

Usage:
    hgc_parity.py --ogbench-src OGBENCH_CHECKOUT --hr-src HR_CHECKOUT --shards DIR --table DIR
                  [--batches 50] [--batch-size 1024] [--seed 0] [--memory-budget 64MB] [--json OUT]
(the table folder is `pgser-etl convert DIR` of the shards; the python that runs this needs pgser,
and jax, flax, ml_collections for their code.)
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
# The agents whose batches each code's classes draw, by `agent_name` (their agents/ modules).
AGENTS = {
    "ogbench": ["gciql", "crl", "hiql"],
    "horizon_reduction": ["sharsa", "dsharsa", "ngcsacbc", "hgcfbc", "hiql", "gcsacbc"],
}


def peer():
    spec = importlib.util.spec_from_file_location("hgc_peer", os.path.join(HERE, "hgc_peer.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def coded(shards: list[str], code: str) -> tuple[dict, int]:
    """The shards in `code`'s layout with observations and oracle reps replaced by their
    (episode, step): observations (e, s), reps (−1 − e, s), so either names its row."""
    p = peer()
    data = p.load(shards, code, oracle_reps=code == "horizon_reduction")
    ends = []
    for f in shards:
        with np.load(f) as z:
            ends.append(np.nonzero(z["terminals"])[0])
    t = int(ends[0][0]) + 1
    n = len(data["observations"])
    per = t if code == "horizon_reduction" else t - 1
    rows = np.arange(n)
    e, s = (rows // per).astype(np.float32), (rows % per).astype(np.float32)
    data["observations"] = np.stack([e, s], 1)
    if "next_observations" in data:
        data["next_observations"] = np.stack([e, s + 1], 1)
    if "oracle_reps" in data:
        data["oracle_reps"] = np.stack([-1 - e, s], 1)
    return data, t


def decode(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e = x[:, 0].astype(np.int64)
    return np.where(e < 0, -1 - e, e), x[:, 1].astype(np.int64)


POINT_KEYS = ["value_goals", "actor_goals", "low_actor_goals", "high_actor_goals", "high_actor_targets",
              "high_value_goals", "high_value_actions", "high_value_next_observations", "low_value_goals",
              "high_actor_actions", "high_actor_next_observations"]


def stats(batches: list[dict], where) -> dict[str, float]:
    """Shares and mean offsets of a class's keys; `where(b, key)` gives a point key's (episode,
    step) and `where(b, None)` the row's."""
    out: dict[str, list] = {}
    for b in batches:
        e, s = where(b, None)
        acc = lambda k, v: out.setdefault(k, []).append(v)  # noqa: E731
        for k in POINT_KEYS:
            if k not in b:
                continue
            ge, gs = where(b, k)
            same = ge == e
            acc(f"{k}: in the row's episode", same)
            acc(f"{k}: at the row's step", same & (gs == s))
            acc(f"{k}: mean steps ahead (same episode)", np.where(same, gs - s, np.nan))
        for k in ("masks", "high_value_masks", "low_value_masks"):
            if k in b:
                acc(f"{k} = 0", b[k] == 0)
        if "high_value_subgoal_steps" in b:
            for j in range(0, 26, 5):
                acc(f"high_value_subgoal_steps = {j}", b["high_value_subgoal_steps"] == j)
        for k in ("rewards", "high_value_rewards", "low_value_rewards"):
            if k in b:
                acc(f"mean {k}", b[k].astype(np.float64))
    return {k: float(np.nanmean(np.concatenate(v))) for k, v in out.items()}


def worker(a: argparse.Namespace) -> None:
    code = a.worker
    root = os.path.join(a.src, "impls") if code == "ogbench" else a.src
    sys.path.insert(0, root)
    import pgser
    from utils.datasets import Dataset, GCDataset, HGCDataset  # theirs

    shards = [os.path.join(a.shards, f) for f in sorted(os.listdir(a.shards))
              if f.endswith(".npz") and not f.endswith("-val.npz")]
    data, t = coded(shards, code)
    results = {}
    for name in AGENTS[code]:
        spec = importlib.util.spec_from_file_location(f"agent_{name}", os.path.join(root, "agents", f"{name}.py"))
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        config = mod.get_config()
        cls = {"GCDataset": GCDataset, "HGCDataset": HGCDataset}[config["dataset_class"]]
        theirs = cls(Dataset.create(**{k: v.copy() for k, v in data.items()}), config)
        np.random.seed(a.seed)
        their = [theirs.sample(a.batch_size) for _ in range(a.batches)]
        kw = dict(env_name="pointmaze-medium-navigate-oraclerep-v0") if code == "horizon_reduction" else {}
        with pgser.Sampler(a.table, layout=code, config=config, seed=a.seed, memory_budget=a.memory_budget,
                           **kw) as s:
            ours = [s.sample(a.batch_size) for _ in range(a.batches)]

        def their_where(b, k):
            return decode(b["observations"] if k is None else b[k])

        def our_where(b, k):
            if k is None:
                return b["episode"], b["step"]
            stem = k[:-1]
            return b[f"{stem}_episode"], b[f"{stem}_step"]

        keys_theirs = sorted(their[0])
        keys_ours = sorted(k for k in ours[0] if k in their[0])
        missing = sorted(set(their[0]) - set(ours[0]))
        dtypes = {k: [str(their[0][k].dtype), str(ours[0][k].dtype)] for k in keys_ours
                  if their[0][k].dtype != ours[0][k].dtype or their[0][k].shape[1:] != ours[0][k].shape[1:]}
        results[name] = dict(dataset_class=config["dataset_class"], theirs=stats(their, their_where),
                             ours=stats(ours, our_where), keys=keys_theirs, missing=missing, dtypes=dtypes,
                             rows=a.batches * a.batch_size)
    json.dump(results, sys.stdout)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ogbench-src")
    p.add_argument("--hr-src")
    p.add_argument("--shards", required=True)
    p.add_argument("--table", required=True)
    p.add_argument("--batches", type=int, default=50)
    p.add_argument("--batch-size", type=int, default=1024)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--memory-budget")
    p.add_argument("--json")
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument("--src", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.worker:
        worker(a)
        return
    out = {}
    for code, src in (("ogbench", a.ogbench_src), ("horizon_reduction", a.hr_src)):
        if not src:
            continue
        cmd = [sys.executable, __file__, "--worker", code, "--src", src, "--shards", a.shards, "--table", a.table,
               "--batches", str(a.batches), "--batch-size", str(a.batch_size), "--seed", str(a.seed)]
        if a.memory_budget:
            cmd += ["--memory-budget", a.memory_budget]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"{code}: {r.stderr[-3000:]}")
        out[code] = json.loads(r.stdout)
    worst = 0.0
    for code, agents in out.items():
        for name, r in agents.items():
            print(f"\n{code} {name} ({r['dataset_class']}, {r['rows']} rows each)")
            if r["missing"] or r["dtypes"]:
                print(f"  KEYS: missing from pgser {r['missing']}; dtype or width differs {r['dtypes']}")
            print(f"  {'statistic':58s} {'theirs':>9s} {'pgser':>9s} {'diff':>8s}")
            for k in sorted(r["theirs"]):
                th, us = r["theirs"][k], r["ours"].get(k, float("nan"))
                d = us - th
                if "mean" not in k:
                    worst = max(worst, abs(d))
                print(f"  {k:58s} {th:9.4f} {us:9.4f} {d:+8.4f}")
    print(f"\nlargest difference of a share: {worst:.4f} (aim: 0.01)")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(dict(results=out, worst_share_difference=worst), f)


if __name__ == "__main__":
    main()
