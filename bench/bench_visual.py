#!/usr/bin/env python3
"""Visual batches side by side in one run: OGBench's visual GCIQL batches (`GCDataset`, uint8
64 x 64 x 3 images, `p_aug = 0.5` random crops) from pgser on disk, a table folder within a
memory budget, against OGBench's own sampler over what fits in RAM: its `GCDataset` on the
compact dataset `ogbench.load_dataset(..., compact_dataset=True)` makes, numpy indexing and its
jitted JAX crop (`batched_random_crop`). Each side runs in a process of its own, one after the
other, so its peak RSS is its own.

The peer is OGBench's code itself when `--ogbench-src` names a checkout (its `impls/` is put on
the path and `utils.datasets.GCDataset` used as main.py uses it; it needs jax and flax); without
one, `PeerGCDataset` below, which follows that code line for line (numpy draws, JAX crop when
jax imports, else numpy's).

Usage:
    bench_visual.py SHARDS TABLE --budget 2GB [--peer-shards 1] [--batches 2000]
                    [--batch-size 1024] [--p-aug 0.5] [--frame-stack K] [--ogbench-src DIR] [--json OUT]
(SHARDS: `bench/make_shards.py OUT --visual 64 ...`; TABLE: `pgser-etl convert SHARDS -o TABLE`.)

Prints one JSON line per side: batches_per_sec, median_ms, p999_ms, max_ms, peak_rss_bytes
(ru_maxrss), and the pool's disk waits for pgser; the peer's load time and rows held.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import re
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_hgc import timed  # noqa: E402  (the same timing as the hierarchical side by side)

# OGBench's visual GCIQL (impls/agents/gciql.py defaults; hyperparameters.sh adds p_aug = 0.5).
CONFIG = dict(discount=0.99, value_p_curgoal=0.2, value_p_trajgoal=0.5, value_p_randomgoal=0.3,
              value_geom_sample=True, actor_p_curgoal=0.0, actor_p_trajgoal=1.0, actor_p_randomgoal=0.0,
              actor_geom_sample=False, gc_negative=True, p_aug=0.5, frame_stack=None)


def shard_files(shards):
    files = [f for f in glob.glob(os.path.join(shards, "*.npz")) if not f.endswith("-val.npz")]
    return sorted(files, key=lambda f: int(re.search(r"-(\d+)\.npz$", f).group(1)))


def load_compact(files):
    """`ogbench.utils.load_dataset(path, compact_dataset=True)` over `files`, concatenated:
    observations kept as uint8, `valids` 0 on each trajectory's last step, `terminals` 1 on its
    last two."""
    import numpy as np

    parts = {"observations": [], "actions": [], "terminals": []}
    for f in files:
        with np.load(f) as d:
            for k in parts:
                parts[k].append(d[k])
    data = {k: np.concatenate(v) for k, v in parts.items()}
    data["actions"] = data["actions"].astype(np.float32)
    terminals = data["terminals"].astype(np.float32)
    data["valids"] = 1.0 - terminals
    data["terminals"] = np.minimum(terminals + np.concatenate([terminals[1:], [1.0]]), 1.0).astype(np.float32)
    return data


class PeerGCDataset:
    """OGBench's `GCDataset.sample` (impls/utils/datasets.py) on a compact dataset, as its code
    does it: numpy's global generator, fancy indexing, and the crop of 3 pixels of edge padding
    jitted in JAX (numpy's pad and slicing when jax is not installed)."""

    def __init__(self, data, config):
        import numpy as np

        self.d, self.config = data, config
        self.size = len(data["observations"])
        (self.valid_idxs,) = np.nonzero(data["valids"] > 0)
        (self.terminal_locs,) = np.nonzero(data["terminals"] > 0)
        self.initial_locs = np.concatenate([[0], self.terminal_locs[:-1] + 1])
        try:
            import jax
            import jax.numpy as jnp

            def random_crop(img, crop_from, padding):
                padded = jnp.pad(img, ((padding, padding), (padding, padding), (0, 0)), mode="edge")
                return jax.lax.dynamic_slice(padded, crop_from, img.shape)

            self.crop = jax.jit(jax.vmap(random_crop, (0, 0, None)), static_argnums=(2,))
            self.crop_with = "jax"
        except ImportError:
            def crop(imgs, crop_froms, padding):
                p = np.pad(imgs, ((0, 0), (padding, padding), (padding, padding), (0, 0)), mode="edge")
                h, w = imgs.shape[1:3]
                return np.stack([q[y:y + h, x:x + w] for q, (y, x, _) in zip(p, crop_froms)])

            self.crop = crop
            self.crop_with = "numpy"
        if config["frame_stack"] is not None:
            self.d = dict(self.d, observations=self.stacked(np.arange(self.size)))

    def stacked(self, idxs):
        import numpy as np

        initial = self.initial_locs[np.searchsorted(self.initial_locs, idxs, side="right") - 1]
        frames = [self.d["observations"][np.maximum(idxs - i, initial)] for i in reversed(range(self.config["frame_stack"]))]
        return np.concatenate(frames, axis=-1)

    def sample_goals(self, idxs, p_cur, p_traj, p_random, geom):
        import numpy as np

        n = len(idxs)
        random_goal_idxs = self.valid_idxs[np.random.randint(len(self.valid_idxs), size=n)]
        final = self.terminal_locs[np.searchsorted(self.terminal_locs, idxs)]
        if geom:
            offsets = np.random.geometric(p=1 - self.config["discount"], size=n)
            traj = np.minimum(idxs + offsets, final)
        else:
            d = np.random.rand(n)
            traj = np.round(np.minimum(idxs + 1, final) * d + final * (1 - d)).astype(int)
        if p_cur == 1.0:
            return idxs
        goal = np.where(np.random.rand(n) < p_traj / (1.0 - p_cur), traj, random_goal_idxs)
        return np.where(np.random.rand(n) < p_cur, idxs, goal)

    def sample(self, batch_size):
        import numpy as np

        c = self.config
        idxs = self.valid_idxs[np.random.randint(len(self.valid_idxs), size=batch_size)]
        obs = self.d["observations"]
        batch = {k: v[idxs] for k, v in self.d.items()}
        batch["next_observations"] = obs[np.minimum(idxs + 1, self.size - 1)]
        v = self.sample_goals(idxs, c["value_p_curgoal"], c["value_p_trajgoal"], c["value_p_randomgoal"],
                              c["value_geom_sample"])
        a = self.sample_goals(idxs, c["actor_p_curgoal"], c["actor_p_trajgoal"], c["actor_p_randomgoal"],
                              c["actor_geom_sample"])
        batch["value_goals"], batch["actor_goals"] = obs[v], obs[a]
        successes = (idxs == v).astype(float)
        batch["masks"] = 1.0 - successes
        batch["rewards"] = successes - (1.0 if c["gc_negative"] else 0.0)
        if np.random.rand() < c["p_aug"]:
            crop_froms = np.random.randint(0, 7, (batch_size, 2))
            crop_froms = np.concatenate([crop_froms, np.zeros((batch_size, 1), dtype=np.int64)], axis=1)
            for k in ["observations", "next_observations", "value_goals", "actor_goals"]:
                batch[k] = np.array(self.crop(batch[k], crop_froms, 3))
        return batch


def side(a):
    import numpy as np

    cfg = dict(CONFIG, p_aug=a.p_aug, frame_stack=a.frame_stack)
    if a.side == "pgser":
        import pgser

        with pgser.Sampler(a.table, layout="ogbench", config=cfg, memory_budget=a.budget, batch_size=a.batch_size,
                           provenance=False) as s:
            b = s.sample()
            assert b["observations"].dtype == np.uint8, b["observations"].dtype
            out = timed(s.sample, a.batches)
            out["pool"] = s.pool_stats()
    else:
        np.random.seed(0)
        t0 = time.perf_counter()
        data = load_compact(shard_files(a.shards)[: a.peer_shards])
        if a.ogbench_src:
            sys.path.insert(0, os.path.join(a.ogbench_src, "impls"))
            from utils.datasets import Dataset, GCDataset  # OGBench's own code

            ds = GCDataset(Dataset.create(**data), cfg)
            crop_with = "ogbench"
        else:
            ds = PeerGCDataset(data, cfg)
            crop_with = ds.crop_with
        load = time.perf_counter() - t0
        out = timed(lambda: ds.sample(a.batch_size), a.batches)
        out.update(load_seconds=load, rows_loaded=len(data["observations"]), peer=crop_with)
    out.update(side=a.side, batch_size=a.batch_size, p_aug=a.p_aug, frame_stack=a.frame_stack)
    print(json.dumps(out))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("shards")
    p.add_argument("table")
    p.add_argument("--budget", default="2GB")
    p.add_argument("--batches", type=int, default=2000)
    p.add_argument("--batch-size", type=int, default=1024)
    p.add_argument("--p-aug", type=float, default=0.5)
    p.add_argument("--frame-stack", type=int)
    p.add_argument("--peer-shards", type=int, default=1, help="shards the peer holds in RAM")
    p.add_argument("--ogbench-src", help="a checkout of OGBench: run its own GCDataset (needs jax, flax)")
    p.add_argument("--peer-python", default=sys.executable, help="the interpreter of the peer's side")
    p.add_argument("--sides", default="pgser,peer")
    p.add_argument("--json")
    p.add_argument("--side", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.side:
        return side(a)
    results = []
    for s in a.sides.split(","):
        cmd = [a.peer_python if s == "peer" else sys.executable, __file__, a.shards, a.table, "--budget", a.budget,
               "--batches", str(a.batches), "--batch-size", str(a.batch_size), "--p-aug", str(a.p_aug),
               "--peer-shards", str(a.peer_shards), "--side", s]
        if a.frame_stack:
            cmd += ["--frame-stack", str(a.frame_stack)]
        if a.ogbench_src:
            cmd += ["--ogbench-src", a.ogbench_src]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            sys.exit(f"{s}: {r.stderr[-3000:]}")
        results.append(json.loads(r.stdout.strip().splitlines()[-1]))
        print(json.dumps(results[-1]), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(results, f)


if __name__ == "__main__":
    main()
