#!/usr/bin/env python3
"""The hierarchical agents' batches, side by side in one run: SHARSA's (Horizon Reduction's
HGCDataset, oracle reps) and HIQL's (OGBench's HGCDataset) batches of 1024 from pgser on disk,
a table folder within a memory budget, against the same class over one shard in RAM
(bench/hgc_peer.py, their code re-implemented in numpy). Each side runs in a process of its own,
one after the other, so its peak RSS is its own.

Usage:
    bench_hgc.py SHARDS TABLE --budget 1GB [--batches 20000] [--json OUT]
(TABLE is `pgser-etl convert SHARDS`; bench/make_scale_data.sh makes humanoidmaze-giant-shaped
shards and prints the convert line.)

Prints one JSON line per side and class: batches_per_sec, median_ms, p999_ms, max_ms,
peak_rss_bytes (ru_maxrss), and the pool's disk waits for pgser.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
# SHARSA's sampling settings (Horizon Reduction's agents/sharsa.py) and HIQL's (OGBench's
# impls/agents/hiql.py): what each class draws for them.
CONFIGS = {
    "horizon_reduction": dict(discount=0.999, dataset_class="HGCDataset", subgoal_steps=25, value_p_curgoal=0.2,
                              value_p_trajgoal=0.5, value_p_randomgoal=0.3, value_geom_sample=False,
                              actor_p_curgoal=0.0, actor_p_trajgoal=0.5, actor_p_randomgoal=0.5,
                              actor_geom_sample=True, gc_negative=False),
    "ogbench": dict(discount=0.99, dataset_class="HGCDataset", subgoal_steps=25, value_p_curgoal=0.2,
                    value_p_trajgoal=0.5, value_p_randomgoal=0.3, value_geom_sample=True, actor_p_curgoal=0.0,
                    actor_p_trajgoal=1.0, actor_p_randomgoal=0.0, actor_geom_sample=False, gc_negative=True),
}


def timed(sample, batches, warmup=50):
    import numpy as np

    for _ in range(warmup):
        sample()
    times = np.empty(batches)
    start = time.perf_counter()
    for i in range(batches):
        t = time.perf_counter()
        sample()
        times[i] = time.perf_counter() - t
    seconds = time.perf_counter() - start
    ms = times * 1e3
    return {"batches": batches, "seconds": seconds, "batches_per_sec": batches / seconds,
            "median_ms": float(np.median(ms)), "p999_ms": float(np.quantile(ms, 0.999)), "max_ms": float(ms.max()),
            "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}


def side(a):
    code = a.code
    cfg = CONFIGS[code]
    if a.side == "pgser":
        import pgser

        kw = dict(oracle_reps=True) if code == "horizon_reduction" else {}
        with pgser.Sampler(a.table, layout=code, config=cfg, memory_budget=a.budget, batch_size=1024,
                           provenance=False, **kw) as s:
            out = timed(s.sample, a.batches)
            out["pool"] = s.pool_stats()
    else:
        import importlib.util

        import numpy as np

        spec = importlib.util.spec_from_file_location("hgc_peer", os.path.join(HERE, "hgc_peer.py"))
        peer = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(peer)
        t0 = time.perf_counter()
        data = peer.load(peer.files(a.shards)[:1], code, oracle_reps=code == "horizon_reduction")
        load = time.perf_counter() - t0
        ds = peer.CLASSES[code](data, cfg, np.random.default_rng(0))
        out = timed(lambda: ds.sample(1024), a.batches)
        out.update(load_seconds=load, rows_loaded=ds.size)
    out.update(side=a.side, code=code)
    print(json.dumps(out))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("shards")
    p.add_argument("table")
    p.add_argument("--budget", default="1GB")
    p.add_argument("--batches", type=int, default=20000)
    p.add_argument("--json")
    p.add_argument("--side", help=argparse.SUPPRESS)
    p.add_argument("--code", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.side:
        return side(a)
    results = []
    for code in ("horizon_reduction", "ogbench"):
        for s in ("pgser", "peer"):
            cmd = [sys.executable, __file__, a.shards, a.table, "--budget", a.budget, "--batches", str(a.batches),
                   "--side", s, "--code", code]
            r = subprocess.run(cmd, capture_output=True, text=True)
            if r.returncode != 0:
                sys.exit(f"{s} {code}: {r.stderr[-3000:]}")
            results.append(json.loads(r.stdout.strip().splitlines()[-1]))
            print(json.dumps(results[-1]), flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(results, f)


if __name__ == "__main__":
    main()
