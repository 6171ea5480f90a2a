#!/usr/bin/env python3
"""RESULTS.md, "SHARSA from pgser.Sampler": the final success of each (arm, goals, seed) run of
bench/sharsa_grid.sh, mean ± sd over seeds per arm, and Welch's t-test between arms over seeds
and a two-proportion test over their pooled evaluation episodes.

    .venv/bin/python bench/sharsa_table.py RUNS_DIR   (RUNS_DIR/ARM-GOALS-SEED/log.json)
"""
import glob
import json
import os
import statistics
import sys

from scipy import stats


def main():
    root = sys.argv[1]
    runs = {}
    for f in sorted(glob.glob(os.path.join(root, "*", "log.json"))):
        log = json.load(open(f))
        last = log["evals"][-1]
        if last["step"] != log["steps"]:
            continue
        runs.setdefault((log["arm"], log["goals"]), []).append((log["seed"], last, log))
    if not runs:
        sys.exit(f"{root}: no finished runs")
    episodes = None
    print("| arm | goals | seeds | success % (mean ± sd) | the seeds' values | per task (mean %) |")
    print("|---|---|---:|---:|---|---|")
    finals = {}
    for (arm, goals), rs in sorted(runs.items()):
        rs.sort()
        v = [100 * r[1]["success"] for r in rs]
        tasks = [100 * statistics.mean(r[1]["task_success"][t] for r in rs) for t in range(5)]
        episodes = 5 * rs[0][2].get("eval_episodes", 4) if episodes is None else episodes
        finals[(arm, goals)] = v
        sd = statistics.stdev(v) if len(v) > 1 else float("nan")
        print(f"| {arm} | {goals} | {len(v)} | {statistics.mean(v):.1f} ± {sd:.1f} | "
              f"{', '.join(f'{x:.0f}' for x in v)} | {', '.join(f'{x:.0f}' for x in tasks)} |")
    print()
    for a, b in [(("whole", "her"), ("window", "her")), (("whole", "pgser"), ("window", "pgser")),
                 (("whole", "pgser"), ("whole", "her")), (("window", "pgser"), ("window", "her"))]:
        if a not in finals or b not in finals or len(finals[a]) < 2 or len(finals[b]) < 2:
            continue
        x, y = finals[a], finals[b]
        t = stats.ttest_ind(x, y, equal_var=False)
        # Over episodes: each run's evaluation episodes, each a success or not, pooled per arm.
        n = episodes * len(x)
        kx, ky = (round(sum(v) / 100 * episodes) for v in (x, y))
        pool = (kx + ky) / (2 * n)
        z = (kx - ky) / n / ((pool * (1 - pool) * 2 / n) ** 0.5) if 0 < pool < 1 else 0.0
        p_eps = 2 * stats.norm.sf(abs(z))
        print(f"- {'-'.join(a)} vs {'-'.join(b)}: {statistics.mean(x) - statistics.mean(y):+.1f} points, "
              f"Welch p = {t.pvalue:.2f} over seeds, p = {p_eps:.2g} over {n} episodes each")


if __name__ == "__main__":
    main()
