#!/usr/bin/env bash
# A folder of OGBench PointMaze shards in Horizon Reduction's layout, made by pgser's oracle
# collector (OGBench's recipe, docs/ogbench.md): NAME-0.npz .. NAME-(K-1).npz plus one
# NAME-val.npz, for the sharded-data benchmarks (BENCHMARKS.md, "Datasets larger than memory").
# Never for tests, which use small folders made in the test.
#
# Shard i holds E episodes seeded (i·E .. i·E + E − 1), so no two shards share an episode; the
# validation file is shard 0's own -val.npz (OGBench keeps one). Shards already present are
# kept, each is written under a temporary name and renamed, so a killed run is resumed by
# running it again. Runs J collectors at once (default: the cores), at low priority.
#
# Usage: bench/make_pointmaze_shards.sh OUT NAME SHARDS EPISODES [JOBS]
#   bench/make_pointmaze_shards.sh bench-out/pm100m pointmaze-large-stitch-v0 100 4975
#   (stitch episodes are 201 rows: 100 × 4975 × 201 ≈ 100M transitions)
set -euo pipefail
out=$1 name=$2 shards=$3 episodes=$4 jobs=${5:-$(nproc)}
etl=${PGSER_ETL:-$(dirname "$0")/../target/release/pgser-etl}
mkdir -p "$out"
one() {
    local i=$1
    local dest="$out/$name-$i.npz" tmp="$out/.tmp-$1"
    [ -f "$dest" ] && return 0
    rm -rf "$tmp" && mkdir -p "$tmp"
    nice -n 19 "$etl" collect --task "$name" --policy oracle --episodes "$episodes" \
        --seed $((i * episodes)) -o "$tmp/$name.npz" >/dev/null
    if [ "$i" = 0 ]; then mv "$tmp/$name-val.npz" "$out/$name-val.npz"; fi
    mv "$tmp/$name.npz" "$dest" && rm -rf "$tmp"
}
export -f one && export out name episodes etl
seq 0 $((shards - 1)) | xargs -P "$jobs" -I{} bash -c 'set -euo pipefail; one {}'
ls "$out" | grep -c "^$name-[0-9]*\.npz$" | xargs echo "shards:"
