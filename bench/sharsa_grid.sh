#!/usr/bin/env bash
# The SHARSA learning check of issue 74 (RESULTS.md, "SHARSA from pgser.Sampler"): every
# (arm, goals, seed) of bench/sharsa_learning.py at one CPU budget fixed here, one run after
# another at low priority. Runs that finished are skipped and a killed run resumes from its last
# checkpoint, so run it again to go on. Never for tests.
#
# Usage: bench/sharsa_grid.sh HR_CHECKOUT DIR [PYTHON]
#   DIR holds `table/` (pgser-etl convert of 100 OGBench shards) and `scored/` (pgser-etl score of
#   it); runs go to DIR/runs/ARM-GOALS-SEED. PYTHON needs pgser, ogbench and their jax stack.
set -euo pipefail
hr=$1 dir=$2 py=${3:-python3}
# The budget, fixed before any run: 5,000 updates of 256, SHARSA's hidden layers 256 x 2,
# subgoal_steps 25, evaluation at the end, 4 episodes of each of OGBench's 5 tasks; the whole
# folder within 16 MB (about half its float32 size); a shard window of 1,000 updates (Horizon
# Reduction's dataset_replace_interval); PGSER's swapped rows a quarter of each batch.
budget=(--steps 5000 --eval-every 5000 --eval-episodes 4 --batch-size 256 --hidden 256 --subgoal-steps 25
        --memory-budget 16MB --window 1000 --p-swapgoal 0.25)
for seed in 0 1 2; do
  for arm in whole window; do
    for goals in her pgser; do
      out=$dir/runs/$arm-$goals-$seed
      if [ -f "$out/log.json" ] && grep -q '"step": 5000' "$out/log.json"; then continue; fi
      echo "== $arm $goals seed $seed"
      MUJOCO_GL=egl nice -n 19 "$py" "$(dirname "$0")/sharsa_learning.py" --hr-src "$hr" --table "$dir/table" \
        --scored "$dir/scored" --arm "$arm" --goals "$goals" --seed "$seed" --out "$out" "${budget[@]}" \
        2>&1 | grep -v "it/s" | grep '^{' || true
    done
  done
done
