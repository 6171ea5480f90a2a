#!/usr/bin/env bash
# --arithmetic native against portable (its AVX-512, AVX2 and scalar paths) on the CPU engine,
# interleaved in one run, three rounds: the figures of BENCHMARKS.md's "Portable arithmetic".
# Run on an idle machine after `make build`; prints the load before and after.
set -euo pipefail
cd "$(dirname "$0")/.."
bench() { target/release/pgser-train bench --task FetchPush --batch-size 512 --arithmetic "$@" 2>&1 | tail -1; }
uptime
for r in 1 2 3; do
  echo "round $r native: $(bench native --updates 300)"
  echo "round $r avx512: $(PGSER_ARITHMETIC_PATH=avx512 bench portable --updates 300)"
  echo "round $r avx2: $(PGSER_ARITHMETIC_PATH=avx2 bench portable --updates 300)"
done
echo "scalar: $(PGSER_ARITHMETIC_PATH=scalar bench portable --updates 20)"
uptime
