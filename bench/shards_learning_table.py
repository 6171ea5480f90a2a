#!/usr/bin/env python3
"""RESULTS.md, "The whole dataset or one shard at a time": final success per arm and seed of
pipelines/pointmaze_medium_stitch_shards_cpu.toml, with Welch's t-tests between arms.

    .venv/bin/python bench/shards_learning_table.py [AGENTS_DIR]
"""
import json, glob, statistics, sys
from scipy import stats
import os
# The agents' metrics files: the pipeline's out/…/agents, or results/…/td3bc once committed.
root = sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), "..", "out", "pointmaze_medium_stitch_shards_cpu", "agents")
def final(algo, arm):
    out = []
    for s in range(5):
        f = f"{root}/{algo}_{arm}_s{s}.ckpt.metrics.jsonl"
        try:
            L = [json.loads(l) for l in open(f) if '"eval"' in l]
        except FileNotFoundError:
            return None
        L = [l for l in L if l["updates"] == 20000]
        if not L:
            return None
        out.append(100 * L[-1]["eval"]["success_rate"])
    return out
for algo in ["td3bc", "td3"]:
    rows = {arm: final(algo, arm) for arm in ["baseline_whole", "baseline_window", "mem_whole", "mem_window"]}
    for arm, v in rows.items():
        if v: print(f"| {algo} {arm} | {statistics.mean(v):.1f} ± {statistics.stdev(v):.1f} | {', '.join(f'{x:.0f}' for x in v)} |")
    for a, b in [("baseline_whole", "baseline_window"), ("mem_whole", "mem_window"), ("mem_whole", "baseline_whole"), ("mem_window", "baseline_window")]:
        if rows[a] and rows[b]:
            t = stats.ttest_ind(rows[a], rows[b], equal_var=False)
            # Over episodes: 50 per seed, each a success or not, the arms' 250 pooled.
            n = 50 * len(rows[a])
            ka, kb = (round(sum(rows[x]) / 100 * 50) for x in (a, b))
            pool = (ka + kb) / (2 * n)
            z = (ka - kb) / n / ((pool * (1 - pool) * 2 / n) ** 0.5)
            p_eps = 2 * stats.norm.sf(abs(z))
            print(f"  {algo}: {a} vs {b}: diff {statistics.mean(rows[a]) - statistics.mean(rows[b]):+.1f}, "
                  f"Welch p = {t.pvalue:.3f} over seeds, p = {p_eps:.2g} over {n} episodes each")
