#!/usr/bin/env bash
# The 1B-row folder of issue 75 (BENCHMARKS.md, "1B transitions, measured"): 1000 shards of 1000
# random-walk episodes of 1001 rows of PointMaze's width (obs 2, act 2: pointmaze-large-navigate's
# shape; bench/make_shards.py --no-state, so no qpos/qvel), 1,001,000,000 rows. Synthetic rows:
# what is measured here (convert, verify, the pool's start, memory and draws) depends on the
# rows' count and width, not on what the agent did; making 1B of OGBench's own PointMaze rows
# with pgser's oracle collector would take about 10 hours on this machine. Prints the sizes
# before writing anything and refuses when the disk cannot hold the shards, their table and the
# benchmark's prefix table. Shards already present are kept (a killed run resumes when run
# again). Runs at low priority. Never for tests.
#
# Usage: bench/make_1b_data.sh [OUT] (default bench-out/pm1b)    env: SHARDS (1000), PY
#
# Sizes per row (measured on 4 shards): .npz (np.savez) observations 2 + actions 2 + terminals 1
# float32 = 20 B; table (pgser-etl convert, default row groups) about 19 B; float32 as the pool
# plans it (T (obs + goal) + (T - 1)(goal + act), goal = x, y) 32,016 B an episode, 32 B a row.
# 1000 shards: 20.0 GB of shards + about 19 GB of table + a 47-shard prefix table (0.9 GB) =
# about 40 GB; 32 GB as float32, 32x a 1 GB budget.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench-out/pm1b}
shards=${SHARDS:-1000}
py=${PY:-.venv/bin/python}
rows=$((shards * 1000 * 1001))
need=$((rows * 20 + rows * 19 + 47 * 1000 * 1001 * 19))
have=$(df -B1 --output=avail "$(dirname "$out")" | tail -1)
gb() { awk "BEGIN { printf \"%.2f GB\", $1 / 1e9 }"; }
echo "PointMaze-shaped: $shards shards x 1000 episodes x 1001 rows = $rows rows"
echo "  float32 (pgser's plan): $(gb $((shards * 1000 * 32016))); disk needed $(gb $need), free $(gb $have)"
if [ "$need" -gt "$have" ]; then
    echo "not enough disk: $(gb $need) needed, $(gb $have) free" >&2
    exit 1
fi
nice -n 19 "$py" bench/make_shards.py "$out" --name pointmaze-large-navigate-v0 --shards "$shards" \
    --episodes 1000 --rows 1001 --obs 2 --act 2 --no-state >/dev/null
echo "shards in $out. Then, on an idle machine:"
echo "  /usr/bin/time -v target/release/pgser-etl convert $out -o $out-table"
echo "  /usr/bin/time -v target/release/pgser-etl verify $out-table"
echo "  $py bench/bench_scale.py $out --converted $out-table --budget 1GB --batches 20000 --workdir bench-out/scale-pm1b"
