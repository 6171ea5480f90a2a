#!/usr/bin/env bash
# The humanoidmaze-shaped folder for bench/bench_scale.py (BENCHMARKS.md, "Datasets larger than
# memory"): SHARDS shards of EPISODES random-walk episodes of 4001 rows, obs 69, act 21
# (bench/make_shards.py: humanoidmaze-giant-navigate-v0's shape), sized to be 3x or more the
# memory budget it is benchmarked with. Prints the sizes before writing anything, refuses when
# the disk cannot hold the shards, their table and the benchmark's prefix table, then prints the
# benchmark's command line. Shards already present are kept (a killed run is resumed by running
# it again). Runs at low priority. Never for tests.
#
# Usage: bench/make_scale_data.sh [OUT] (default bench-out/hm10m)
#   env: SHARDS (25), EPISODES (100), BUDGET_GB (1), PY (.venv/bin/python)
#
# Sizes, per row of 4001-row episodes (exact for the shards; measured for the table):
#   .npz shard (np.savez, uncompressed): observations 69 + actions 21 + terminals 1 + qpos 34
#     + qvel 34 float32 = 636 B
#   table (pgser-etl convert, every array kept, default row groups): 502 B (random walks
#     compress little)
#   float32 as pgser's pool plans it (src/sampler/pool.rs Layout::bytes: T (obs + goal) +
#     (T - 1)(goal + act), goal = x, y): 1,504,284 B an episode, 376 B a row
# Default, 25 x 100 episodes = 10,002,500 rows: 3.76 GB as float32, 3.76x a 1 GB budget;
# on disk 6.36 GB of shards + 5.02 GB table + 2.0 GB prefix table (the first 10 shards, the
# fewest that are 1.5x the budget) = about 13.5 GB. It does not exceed this machine's memory
# (24 GiB): that would take 69M rows, 78 GB of shards and table, more than the disk holds; the
# budget, not the machine, is what the table is larger than. Horizon Reduction's own shards
# hold 1000 episodes (compressed): the reload peer here holds and reloads a tenth of that, so
# its memory and its pauses are smaller than theirs.
#
# Timings on this 2-core machine (loaded): make_shards.py about 2 s a shard (25 shards: 1-2
# minutes); convert 200-330k rows/s (10M rows: under a minute; peak RSS about 0.8 GB for each
# 100-episode shard in flight); the benchmark (bench_scale.py, 40,000 batches a side, so that
# the reload peer reloads 9 times) 4-6 minutes. About 8 minutes in all.
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-bench-out/hm10m}
shards=${SHARDS:-25} episodes=${EPISODES:-100} budget_gb=${BUDGET_GB:-1}
py=${PY:-.venv/bin/python}
rows=$((shards * episodes * 4001))
f32=$((shards * episodes * 1504284))
npz=$((rows * 636))
table=$((rows * 502))
budget=$(awk "BEGIN { printf \"%d\", $budget_gb * 1e9 }")
# The benchmark's prefix: the fewest shards whose float32 size is 1.5x the budget.
per_shard=$((episodes * 1504284))
k=$(( (budget * 3 / 2 + per_shard - 1) / per_shard ))
[ "$k" -ge "$shards" ] && k=0
prefix=$((k * episodes * 4001 * 502))
need=$((npz + table + prefix))
have=$(df -B1 --output=avail "$(dirname "$out")" | tail -1)
gb() { awk "BEGIN { printf \"%.2f GB\", $1 / 1e9 }"; }
echo "humanoidmaze-shaped: $shards shards x $episodes episodes x 4001 rows = $rows rows"
echo "  float32 (pgser's plan): $(gb $f32) = $(awk "BEGIN { printf \"%.2f\", $f32 / $budget }")x a budget of $(gb $budget)"
echo "  disk: shards $(gb $npz) + table $(gb $table) + prefix table ($k shards) $(gb $prefix) = $(gb $need); free $(gb $have)"
if [ "$f32" -lt $((3 * budget)) ]; then
    echo "note: the table is less than 3x the budget: raise SHARDS or EPISODES, or lower BUDGET_GB" >&2
fi
if [ "$need" -gt "$have" ]; then
    echo "not enough disk: $(gb $need) needed, $(gb $have) free" >&2
    exit 1
fi
nice -n 19 "$py" bench/make_shards.py "$out" --shards "$shards" --episodes "$episodes" --rows 4001 --obs 69 --act 21
echo "shards in $out. The benchmark (on an idle machine):"
echo "  $py bench/bench_scale.py $out --budget ${budget_gb}GB --batches 40000 --workdir bench-out/scale-$(basename "$out")"
