#!/bin/bash
# Two (or more) builds of pgser's Python module, side by side on one table: each wheel is
# installed in turn into .venv and pgser.Sampler(layout="ogbench") timed on the table
# (bench_scale.py's pgser side), alternating wheels round after round so that a drift in the
# machine's speed falls on all of them alike. `numpy` in place of a wheel folder times OGBench's
# sampler over one shard in RAM (bench/ogbench_peer.py) on NPZ's first shard.
#
# Usage: bench/ab_wheels.sh TABLE BATCHES ROUNDS WHEEL_DIR|numpy ...
#   WHEEL_DIR holds one pgser wheel (`make python`, then copy target/wheels/dev/pgser-*.whl there);
#   BUDGET (bytes, default 1000000000) is memory_budget, DRAWS (default 1) draws_per_row,
#   NPZ (default bench-out/hm10m) the shards the numpy side loads.
# Prints one line per run: batches/s, median, p99.9 and longest batch (ms), peak RSS (MiB), the
# pool's waits / swaps and seconds waited, and the load average after the run.
# The last wheel stays installed: reinstall the current build afterwards (`make python`).
set -euo pipefail
[ $# -ge 4 ] || { sed -n '2,14p' "$0"; exit 2; }
table=$1 batches=$2 rounds=$3
shift 3
py=.venv/bin/python
for _ in $(seq "$rounds"); do
  for side in "$@"; do
    if [ "$side" = numpy ]; then
      r=$($py bench/ogbench_peer.py "${NPZ:-bench-out/hm10m}" --scheme ram --batches "$batches" --warmup 20 \
        --batch-size 1024 --seed 0 2>/dev/null | tail -1)
    else
      $py -m pip install --quiet --force-reinstall --no-deps "$side"/*.whl
      r=$($py bench/bench_scale.py _pgser "$table" --budget-bytes "${BUDGET:-1000000000}" --batches "$batches" \
        --warmup 20 --batch-size 1024 --seed 0 --prefetch 4 --draws-per-row "${DRAWS:-1}" 2>/dev/null | tail -1)
    fi
    line=$(echo "$r" | $py -c '
import json, sys
d = json.load(sys.stdin)
p = d.get("pool") or {}
rss = (d.get("hwm_bytes") or d.get("peak_rss_bytes") or 0) >> 20
waits, swaps, waited = p.get("waits", 0), p.get("swaps", 0), p.get("waited_seconds", 0)
print("%.0f/s median %.3f p99.9 %.1f longest %.1f ms, peak RSS %d MiB, waits %d/%d (%.2f s)"
      % (d["batches_per_sec"], d["median_ms"], d["p999_ms"], d["max_ms"], rss, waits, swaps, waited))')
    echo "$side: $line, load $(cut -d' ' -f1 /proc/loadavg)"
  done
done
