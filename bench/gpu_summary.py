#!/usr/bin/env python3
"""The GPU bundle's gpu.json, from the parts scripts/gpu_run.sh has written so far in WORK.

  machine, correctness, correctness-fp32, determinism, stacking, correctness-blocking
            as gpu_run.sh and gpu_compare.py wrote them (the last only when the FP32 check
            failed and was repeated with synchronous launches and no graphs);
  grid      each bench_grid.py cell, by NAME-A<agents> (fp32, tf32, nograph, wgpu);
  pgser_over_jax   per cell: pgser's and JAX's agent-updates/s and their ratio, at the same
            precision (fp32: pgser `cuda` against JAX `highest`; tf32: `cuda-tf32` against
            JAX's default);
  stacks    each real `pgser-train --seeds` stack: agent-updates/s, sampling included, and its
            share of the bench's pgser rate at the same A (FP32); `staged-A60` with whole
            batches sent (PGSER_CUDA_HOLD=0) instead of the data held on the GPU;
  holding   the held stack's bytes against the staged one's (a gather is a copy: tolerance 0);
  host      the host's half alone (bench-sampler --stream, 60 -mem cells): agent-updates/s of
            batches it can draw, as row numbers (host-rows) and built (host-gather).

Prints the ratios and the stacks' shares, the lines a reader wants first.

Usage: gpu_summary.py OUT_DIR WORK_DIR
"""
from __future__ import annotations

import glob
import json
import os
import sys


def rate(grid: dict, peer: str, agents) -> float | None:
    cell = (grid.get("cells", {}).get(peer, {}) or {}).get(str(agents)) or {}
    return cell.get("agent_updates_per_sec")


def main(out: str, work: str) -> None:
    doc: dict = {}
    for name in ("machine", "correctness", "correctness-fp32", "determinism", "stacking", "holding", "correctness-blocking"):
        path = os.path.join(work, name + ".json")
        if os.path.exists(path):
            doc[name] = json.load(open(path))
    doc["grid"] = {
        os.path.basename(p)[len("grid-"):-len(".json")]: json.load(open(p))
        for p in sorted(glob.glob(os.path.join(work, "grid-*.json")))
    }
    ratios = {}
    for key, grid in doc["grid"].items():
        _, agents = key.rsplit("-A", 1)
        p, j = rate(grid, "pgser", agents), rate(grid, "jax", agents)
        if p and j:
            ratios[key] = {"pgser": p, "jax": j, "pgser_over_jax": p / j}
    doc["pgser_over_jax"] = ratios
    stacks = {}
    for path in sorted(glob.glob(os.path.join(work, "stack-*A*.json"))):
        # stack-A60: the data held on the GPU (the default); stack-staged-A60: PGSER_CUDA_HOLD=0.
        name = os.path.basename(path)[len("stack-"):-len(".json")]
        agents = int(name.rsplit("A", 1)[1])
        try:
            runs = json.load(open(path))
        except (OSError, ValueError):
            continue
        ups = runs[0].get("updates_per_sec") if isinstance(runs, list) and runs else None
        bench = rate(doc["grid"].get(f"fp32-A{agents}", {}), "pgser", agents)
        stacks[name] = {
            "agents": agents,
            "agent_updates_per_sec": ups * agents if ups else None,
            "bench_agent_updates_per_sec": bench,
            "share_of_bench": ups * agents / bench if ups and bench else None,
        }
    doc["stacks"] = stacks
    # The host's half alone (bench-sampler --stream): rows = row numbers, gather = whole batches.
    host = {}
    for path in sorted(glob.glob(os.path.join(work, "host-*-A*.json"))):
        try:
            host[os.path.basename(path)[len("host-"):-len(".json")]] = json.load(open(path))
        except (OSError, ValueError):
            continue
    doc["host"] = host
    json.dump(doc, open(os.path.join(out, "gpu.json"), "w"), indent=1)
    for key, r in sorted(ratios.items()):
        print(f"  {key:12s} pgser {r['pgser']:10.0f}  jax {r['jax']:10.0f}  pgser/jax {r['pgser_over_jax']:.2f}")
    for key, h in sorted(host.items()):
        print(f"  host {key}: {h.get('agent_updates_per_sec', 0):.0f} agent-updates/s of batches drawn on {h.get('threads')} threads")
    for key, s in sorted(stacks.items()):
        share = s["share_of_bench"]
        print(f"  stack {key}: {s['agent_updates_per_sec']} agent-updates/s" + (f", {share:.0%} of the bench's" if share else ""))


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
