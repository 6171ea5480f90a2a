#!/bin/sh
# Seeds for each fuzz target from the repository's own files (nothing is downloaded): the
# committed pickles, tables, pipelines and Minari fixture, and the files a tiny training run
# writes. libFuzzer keeps what it finds in corpus/TARGET beside them.
set -e
cd "$(dirname "$0")"
root=..
for t in pickle table scored checkpoint resume metrics pipeline minari wgcsl footer; do mkdir -p corpus/$t; done
cp $root/data/*.pkl corpus/pickle/
cp $root/data/*.pkl corpus/wgcsl/
cp $root/pipelines/*.toml corpus/pipeline/
for f in $root/tests/fixtures/minari/fetchreach-default-arrow-v0/data/metadata.json; do
  printf '\000' | cat - "$f" > corpus/minari/metadata.json
done
for f in $root/tests/fixtures/minari/fetchreach-default-arrow-v0/data/0/*.arrow; do
  printf '\001' | cat - "$f" > corpus/minari/episode0.arrow
done
# A table, a Q checkpoint with its resume state and metrics, and a scored table.
bin=$root/target/release
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
$bin/pgser-etl convert $root/data/fetch_reach_expert_50.pkl -o "$scratch/t.parquet" > /dev/null
cp "$scratch/t.parquet" corpus/table/
# The footer of a table with a passthrough column, as the footer target's base table has it.
$bin/pgser-etl convert $root/tests/fixtures/passthrough/wgcsl_info.pkl --task FetchReach -o "$scratch/p.parquet" > /dev/null
$bin/pgser-etl inspect --json "$scratch/p.parquet" |
  python3 -c 'import json, sys; print(json.dumps(json.load(sys.stdin)["footer"]))' > corpus/footer/passthrough.json
$bin/pgser-train --data "$scratch/t.parquet" -o "$scratch/q.ckpt" --updates 20 --batch-size 16 \
  --hidden 16 --layers 2 --eval-episodes 0 --save-every 10 > /dev/null 2>&1
cp "$scratch/q.ckpt" corpus/checkpoint/
cp "$scratch/q.ckpt.resume" corpus/resume/
cp "$scratch/q.ckpt.metrics.jsonl" corpus/metrics/
$bin/pgser-etl score --q "$scratch/q.ckpt" --data "$scratch/t.parquet" --swaps 1 -o "$scratch/s.parquet" > /dev/null
cp "$scratch/s.parquet" corpus/scored/
