#!/usr/bin/env python3
"""OGBench's per-task table from `pgser-train eval --json` lines (RESULTS.md, "OGBench PointMaze").

    pgser-train eval --ckpt out/NAME/agents/td3bc_*_s*.ckpt --episodes 250 --json > results/NAME/ogbench_eval.jsonl
    python3 scripts/ogbench_table.py results/NAME/ogbench_eval.jsonl

Groups the checkpoints by arm (the agent file's name without its `_sN` seed), and prints one
Markdown row per arm: each task's success rate and the overall one, in percent, mean ± std over
the seeds (std with n − 1, as pgser's results tables). Descriptive only: the p values are the
pipeline's results.md's (pgser's Welch test).
"""
import json
import statistics
import sys
from collections import defaultdict
from pathlib import Path


def main():
    runs = defaultdict(list)
    for line in Path(sys.argv[1]).read_text().splitlines():
        r = json.loads(line)
        arm = Path(r["checkpoint"]).stem.rsplit("_s", 1)[0]
        runs[arm].append(r)
    order = sorted(runs, key=lambda a: (["baseline", "swap", "mem"].index(a.split("_")[-1])
                                        if a.split("_")[-1] in ("baseline", "swap", "mem") else 3, a))
    tasks = len(next(iter(runs.values()))[0]["task_success"])
    fmt = lambda xs: f"{100 * statistics.mean(xs):.1f} ± {100 * statistics.stdev(xs):.1f}" if len(xs) > 1 \
        else f"{100 * xs[0]:.1f}"
    print("| agent | " + " | ".join(f"task {k + 1}" for k in range(tasks)) + " | overall | seeds | episodes |")
    print("|---|" + "---:|" * (tasks + 3))
    for arm in order:
        rs = runs[arm]
        cells = [fmt([r["task_success"][k] for r in rs]) for k in range(tasks)]
        label = arm.replace("td3bc_", "TD3+BC ").replace("td3_", "TD3 ").replace("ddpg_", "DDPG ")
        print(f"| {label} | " + " | ".join(cells) +
              f" | {fmt([r['success_rate'] for r in rs])} | {len(rs)} | {rs[0]['episodes']} |")


if __name__ == "__main__":
    main()
