#!/usr/bin/env bash
# pgser on a GPU machine, in one run: the bundle's script (`make gpu-bundle` copies this file into
# target-gpu/bundle/ as run.sh; docs/gpu.md). Everything it needs is in the bundle: pgser-train
# with every GPU engine (the hand-written `cuda` and `cuda-tf32`, burn's `cuda-burn` and `wgpu`;
# xz; and pgser-etl, for `score` on the device), the CUDA engine's kernels as
# an sm_90 cubin built with NVRTC 13.0, MuJoCo's library, the Vulkan loader and libglvnd as
# Debian packages, FetchReach and FetchPush tables and Qs made on the CPU, and the benchmark
# peers' scripts. It installs nothing outside a temporary folder; cuBLAS comes from the machine
# (the nvidia-cublas wheel beside JAX and PyTorch, or a CUDA toolkit).
#
#   run.sh OUT_DIR [SECONDS]       (SECONDS: the time it may take, default 480)
#
# Steps, each written to OUT_DIR/run.log as it goes:
#  1. unpack; name the GPU (nvidia-smi) and the adapters pgser opens on it. A machine without an
#     NVIDIA GPU gets "no GPU" plainly, the one-line error of `--device cuda`, and a CPU run that
#     shows the binaries work; then it stops (exit 0).
#  2. correctness: a stack of three -mem agents (FetchReach, hidden 256, batch 256) trained 50
#     updates on cpu and on every GPU engine: their weights, and the losses and mean Q logged every
#     10 updates, compared with the CPU's (bench/gpu_compare.py): `cuda` (FP32) must be within
#     1e-5; the others are reported at 1e-4 (for `cuda-tf32` the distance is the measurement);
#     with pgser-etl in the bundle, `score`'s Q too.
#     The same seed twice on `cuda` (bit for bit?), and seed 0 alone against seed 0 of the stack
#     (within 1e-6: cuBLAS picks its kernel by the batch count). If the FP32 check fails, the run
#     is repeated with synchronous launches and no graphs, and under compute-sanitizer where the
#     machine has it, so that the failing launch is named (env.sh's cuda_diagnose).
#  3. speed: bench/bench_grid.py, agent-updates/s of pgser beside JAX and PyTorch (stacked, CUDA
#     graphs) in the same run, at each precision: FP32 (pgser `cuda`, JAX `highest`, PyTorch TF32
#     off) and TF32 (pgser `cuda-tf32`, JAX's default, PyTorch TF32 on); for A = 60, 1, 10, 30,
#     120 agents, in that order, each A only while enough of SECONDS is left. At A = 60 and 1 also
#     pgser without CUDA graphs (PGSER_CUDA_GRAPHS=0); wgpu at A = 60 if time is left.
#  4. the real thing: `pgser-train --seeds` stacks of 10 and 60 -mem agents on FetchPush data
#     (at 60 also with PGSER_CUDA_HOLD=0: whole batches sent instead of row numbers)
#     (sampling, priorities and staging included), against the bench's rate at the same A; and
#     before the bench, the host's half alone (`bench-sampler --stream`, 60 cells): the rate this
#     machine's CPUs can feed, as row numbers and as whole batches.
# Out: OUT_DIR/gpu.json (every figure), run.log, logs.tar.gz (each child's output): three files,
# within what a device run brings back.
set -uo pipefail

here=$(cd "$(dirname "$0")" && pwd)
[ $# -ge 1 ] || { echo "usage: run.sh OUT_DIR [SECONDS]" >&2; exit 2; }
mkdir -p "$1" && out=$(cd "$1" && pwd)
budget=${2:-480}
work=$(mktemp -d)
logs=$work/logs
mkdir -p "$logs"
: >"$out/run.log"
say() { echo "gpu-run [$((SECONDS))s]: $*" | tee -a "$out/run.log" >&2; }
left() { echo $((budget - SECONDS)); }

# ---- 1. unpack, and what this machine is --------------------------------------------------------
. "$here/env.sh"
say "bundle $(cat "$here/VERSION" 2>/dev/null || echo '(no VERSION)'); host $(uname -n), $(nproc) CPUs"

summary() {  # gpu.json from the parts written so far (pgser / JAX per A and precision), and the logs
  python3 "$here/bench/gpu_summary.py" "$out" "$work" || say "could not write gpu.json"
  tar -czf "$out/logs.tar.gz" -C "$work" logs 2>/dev/null
}

gpu=$(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null | head -1)
if [ -z "$gpu" ]; then
  say "no GPU: nvidia-smi finds no NVIDIA GPU on this machine, so nothing is measured"
  err=$("$train" bench --task FetchReach --agents 1 --updates 2 --device cuda 2>&1 >/dev/null | tail -1)
  say "--device cuda says: $err"
  cpu=$("$train" bench --task FetchReach --agents 3 --updates 20 --device cpu --json 2>"$logs/cpu.log" | tail -1)
  say "the binaries run: pgser-train bench --device cpu, 3 agents: $cpu"
  python3 -c 'import json,sys; json.dump({"gpu": None, "cuda_error": sys.argv[1], "cpu_bench": sys.argv[2]}, open(sys.argv[3], "w"), indent=1)' \
    "$err" "$cpu" "$work/machine.json" 2>/dev/null
  summary
  exit 0
fi
say "GPU: $gpu; libdevice from ${CUDA_PATH:-/usr/local/cuda (default)}"

# ---- 2. correctness: every GPU engine against cpu -------------------------------------------------
# The device a pgser run names in its log ("--device cuda: running on NVIDIA H200"), if any.
running_on() { grep -m1 -- ": running on" "$1" 2>/dev/null | sed 's/.*running on //'; }
# One command of the check: under a time limit, its output in logs/NAME.out and .log, a line in
# run.log (with the device it names, if any), and its last lines there when it fails.
step() {
  local name=$1 t0=$SECONDS rc on
  shift
  # At most 240 s, and never past the run's own budget (a hung step must not eat the rest).
  local limit=$(($(left) - 20))
  [ $limit -gt 240 ] && limit=240
  [ $limit -lt 30 ] && limit=30
  timeout $limit "$@" >"$logs/$name.out" 2>"$logs/$name.log"
  rc=$?
  on=$(running_on "$logs/$name.log")
  local label=$name
  case $name in train-* | score-*) label=${name/-/ --device };; esac
  say "$label: rc $rc, $((SECONDS - t0)) s${on:+, on $on}"
  [ $rc -eq 0 ] || tail -3 "$logs/$name.log" | sed 's/^/    /' | tee -a "$out/run.log" >&2
}
devices="cpu cuda cuda-tf32"
[ -x "$burn" ] && devices="$devices cuda-burn wgpu"
for dev in $devices; do
  exe=$train
  case $dev in cuda-burn | wgpu) exe=$burn;; esac
  step "train-$dev" "$exe" --data "$data/scored.parquet" -o "$work/train-$dev" --seeds 0,1,2 --updates 50 \
    --batch-size 256 --eval-episodes 0 --log-every 10 --device "$dev"
  [ -x "$etl" ] && step "score-$dev" "$etl" score --q "$data/q.ckpt" --data "$data/reach.parquet" \
    -o "$work/score-$dev.parquet" --swaps 2 --device "$dev"
done
python3 - "$work/machine.json" "$gpu" "$(running_on "$logs/train-cuda.log")" "$(running_on "$logs/train-wgpu.log")" \
  "$(running_on "$logs/train-cuda-burn.log")" "${PGSER_CUDA_CUBIN:-compiled by the NVRTC of the machine}" <<'EOF'
import json, sys
json.dump({"gpu": sys.argv[2], "cuda_device": sys.argv[3], "wgpu_adapter": sys.argv[4], "cuda_burn_device": sys.argv[5],
           "kernels": sys.argv[6]}, open(sys.argv[1], "w"), indent=1)
EOF
# wgpu is timed only on the GPU itself: where it opened a software adapter (or none), its
# figures would be the CPU's under a GPU's name.
wgpu_on_gpu=1
[ -x "$burn" ] || { wgpu_on_gpu=0; say "no pgser-train-burn in the bundle: cuda-burn and wgpu are not run"; }
[ $wgpu_on_gpu = 0 ] || case "$(running_on "$logs/train-wgpu.log")" in
  "") wgpu_on_gpu=0; say "wgpu opened no adapter: it is not timed";;
  *"no GPU"*) wgpu_on_gpu=0; say "wgpu opened a software adapter, not the GPU: it is not timed";;
esac
sc() { if [ -x "$etl" ]; then echo "$work/score-$1.parquet"; else echo -; fi; }
python3 "$here/bench/gpu_compare.py" --tol 1e-5 --cpu-train "$work/train-cpu" --cpu-score "$(sc cpu)" \
  --backend cuda "$work/train-cuda" "$(sc cuda)" --json "$work/correctness-fp32.json" 2>&1 | tee -a "$out/run.log"
# A failed check is run again so that the failing launch names itself (env.sh: cuda_diagnose).
if [ "$(compare_ok "$work/correctness-fp32.json")" != 1 ]; then
  cuda_diagnose train-cuda "$work/train-cpu" --data "$data/scored.parquet" --seeds 0,1,2 --batch-size 256 \
    --eval-episodes 0 --log-every 10 --device cuda
fi
# The same seed, the same bytes (a second run: tolerance 0), and an agent's bytes whatever stack
# it trains in (seed 0 alone against seed 0 of the stack of three). The CPU engine gives the same
# bits for both; on the GPU the second is compared at 1e-6, as cuBLAS chooses its kernel, and with
# it its order of summation, by the batch count: a stack of 1 and a stack of 3 may round apart
# without a fault.
step cuda-rerun "$train" --data "$data/scored.parquet" -o "$work/train-cuda-again" --seeds 0,1,2 --updates 50 \
  --batch-size 256 --eval-episodes 0 --log-every 10 --device cuda
step cuda-alone "$train" --data "$data/scored.parquet" -o "$work/train-cuda-alone" --seeds 0 --updates 50 \
  --batch-size 256 --eval-episodes 0 --log-every 10 --device cuda
python3 "$here/bench/gpu_compare.py" --tol 0 --cpu-train "$work/train-cuda" --backend cuda-rerun "$work/train-cuda-again" - \
  --json "$work/determinism.json" 2>&1 | tee -a "$out/run.log"
python3 "$here/bench/gpu_compare.py" --tol 1e-6 --cpu-train "$work/train-cuda-alone" --backend cuda-in-a-stack "$work/train-cuda" - \
  --json "$work/stacking.json" 2>&1 | tee -a "$out/run.log"
# The engine holds the data on the GPU and gathers each batch there (pgser_gather); with
# PGSER_CUDA_HOLD=0 the host sends whole batches instead. A gather is a copy: the same bytes.
PGSER_CUDA_HOLD=0 step cuda-staged "$train" --data "$data/scored.parquet" -o "$work/train-cuda-staged" --seeds 0,1,2 \
  --updates 50 --batch-size 256 --eval-episodes 0 --log-every 10 --device cuda
python3 "$here/bench/gpu_compare.py" --tol 0 --cpu-train "$work/train-cuda-staged" --backend cuda-held "$work/train-cuda" - \
  --json "$work/holding.json" 2>&1 | tee -a "$out/run.log"
others=(--backend cuda-tf32 "$work/train-cuda-tf32" "$(sc cuda-tf32)")
[ -x "$burn" ] && others+=(--backend cuda-burn "$work/train-cuda-burn" "$(sc cuda-burn)" --backend wgpu "$work/train-wgpu" "$(sc wgpu)")
python3 "$here/bench/gpu_compare.py" --tol 1e-4 --cpu-train "$work/train-cpu" --cpu-score "$(sc cpu)" "${others[@]}" \
  --json "$work/correctness.json" 2>&1 | tee -a "$out/run.log"
summary

# ---- the host's half of an update, alone: can this machine's CPUs feed the GPU? ------------------
# A stack of 60 -mem cells drawing their batches as row numbers (what the engine is sent when it
# holds the data) and built on the host (what it is sent otherwise), in agent-updates/s.
for g in rows gather; do
  flag=; [ $g = gather ] && flag=--gather
  step "host-$g-A60" "$train" bench-sampler --stream --agents 60 --batch-size 512 --batches 1500 \
    --data "$data/push_scored.parquet" --in-memory $flag --json
  tail -1 "$logs/host-$g-A60.out" >"$work/host-$g-A60.json" 2>/dev/null
done

# ---- 3. speed: pgser beside JAX and PyTorch, the same run, at each precision ---------------------
grid() {  # grid NAME A [bench_grid args...]: one cell of the speed grid, logged and kept as JSON
  local name=$1 A=$2
  shift 2
  python3 "$here/bench/bench_grid.py" --device cuda --python python3 --jax-python python3 --pgser "$train" \
    --agents "$A" --seconds 3 --timeout 150 --workdir "$work/bench" --json "$work/grid-$name-A$A.json" "$@" 2>&1 |
    tee "$logs/grid-$name-A$A.txt" | tee -a "$out/run.log"
}
for A in 60 1 10 30 120; do
  # A cell takes up to ~2 min (each child's start, compilation and autotuning are untimed).
  if [ "$(left)" -lt 150 ]; then say "A = $A and after: skipped, $(left) s left of $budget"; break; fi
  grid fp32 "$A" --pgser-device cuda --peers pgser,jax,stacked-graph
  grid tf32 "$A" --pgser-device cuda-tf32 --tf32 --peers pgser,jax,stacked-graph
  if [ "$A" = 60 ] || [ "$A" = 1 ]; then
    PGSER_CUDA_GRAPHS=0 grid nograph "$A" --pgser-device cuda --peers pgser
  fi
  summary
  # ---- 4. the real stacks, once their A's bench is in: sampling, priorities, staging included --
  if [ "$A" = 10 ] || [ "$A" = 60 ]; then
    step "stack-A$A" "$train" --data "$data/push_scored.parquet" -o "$work/stack-A$A" --seeds "$(seq -s, 0 $((A - 1)))" \
      --updates 3000 --batch-size 512 --eval-episodes 0 --log-every 1000 --device cuda --json
    tail -1 "$logs/stack-A$A.out" >"$work/stack-A$A.json" 2>/dev/null
    if [ "$A" = 60 ] && [ "$(left)" -gt 120 ]; then  # what holding the data saves: whole batches sent instead
      PGSER_CUDA_HOLD=0 step "stack-staged-A$A" "$train" --data "$data/push_scored.parquet" -o "$work/stack-staged-A$A" \
        --seeds "$(seq -s, 0 $((A - 1)))" --updates 3000 --batch-size 512 --eval-episodes 0 --log-every 1000 --device cuda --json
      tail -1 "$logs/stack-staged-A$A.out" >"$work/stack-staged-A$A.json" 2>/dev/null
    fi
    summary
  fi
done
if [ $wgpu_on_gpu = 1 ] && [ "$(left)" -gt 60 ]; then
  grid wgpu 60 --pgser "$burn" --pgser-device wgpu --peers pgser
fi
cp -r "$work/bench/grid-logs" "$logs/" 2>/dev/null
summary
say "done: $out/gpu.json"
