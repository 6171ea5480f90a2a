#!/usr/bin/env bash
# pgser on a GPU machine, in one run: the bundle's script (`make gpu-bundle` copies this file into
# target-gpu/bundle/ as run.sh; docs/gpu.md). Everything it needs is in the bundle: pgser-train
# built with `cuda` and `wgpu` (xz; pgser-etl too where the bundle was made with BUNDLE_ETL=1),
# MuJoCo's library, the Vulkan loader and libglvnd as Debian packages, FetchReach tables and a
# Q made on the CPU, and the benchmark peers' scripts. It installs nothing outside a temporary
# folder.
#
#   run.sh OUT_DIR [SECONDS]       (SECONDS: the time it may take, default 480)
#
# Steps, each written to OUT_DIR/run.log as it goes:
#  1. unpack; name the GPU (nvidia-smi) and the adapters pgser opens on it. A machine without an
#     NVIDIA GPU gets "no GPU" plainly, the one-line error of `--device cuda`, and a CPU run that
#     shows the binaries work; then it stops (exit 0).
#  2. correctness: a stack of three -mem agents (FetchReach, hidden 256, batch 256) trained 50
#     updates on cuda, wgpu and cpu: their weights, and the losses and mean Q logged every 10
#     updates, compared (bench/gpu_compare.py); with pgser-etl in the bundle, `score`'s Q too.
#  3. speed: bench/bench_grid.py, agent-updates/s of pgser on cuda beside JAX and PyTorch
#     (stacked, CUDA graphs) in the same run, for A = 60, 1, 120, 30, 10 agents, in that order,
#     each A only while enough of SECONDS is left; pgser on wgpu at A = 60.
# Out: OUT_DIR/gpu.json (every figure), run.log, logs.tar.gz (each child's output): three files,
# within what a device run brings back.
set -uo pipefail

here=$(cd "$(dirname "$0")" && pwd)
[ $# -ge 1 ] || { echo "usage: run.sh OUT_DIR [SECONDS]" >&2; exit 2; }
mkdir -p "$1" && out=$(cd "$1" && pwd)
budget=${2:-480}
work=$(mktemp -d)
logs=$work/logs
mkdir -p "$logs" "$work/bin" "$work/lib" "$work/vk"
: >"$out/run.log"
say() { echo "gpu-run [$((SECONDS))s]: $*" | tee -a "$out/run.log" >&2; }
left() { echo $((budget - SECONDS)); }

# ---- 1. unpack, and what this machine is --------------------------------------------------------
for f in "$here"/bin/*.xz; do xz -dc "$f" >"$work/bin/$(basename "$f" .xz)" && chmod +x "$work/bin/$(basename "$f" .xz)"; done
for f in "$here"/lib/*.xz; do xz -dc "$f" >"$work/lib/$(basename "$f" .xz)"; done
ln -sf libmujoco.so.3.17.0 "$work/lib/libmujoco.so"
# The Vulkan loader and libglvnd in a private folder: wgpu opens libvulkan.so.1 by name, the
# NVIDIA driver brings its own ICD (in libGLX_nvidia, which needs libglvnd), and the loader finds
# it through VK_DRIVER_FILES where the image does not register it.
for d in "$here"/debs/*.deb; do [ -e "$d" ] && dpkg-deb -x "$d" "$work/vk"; done
export LD_LIBRARY_PATH="$work/lib:$work/vk/usr/lib/x86_64-linux-gnu${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -f "$icd" ] && ! grep -qs nvidia /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json; then
  export VK_DRIVER_FILES=$icd
fi
# cubecl compiles pgser's kernels through LLVM's NVPTX and links math functions (tanh, exp) from
# the CUDA toolkit's libdevice.10.bc, which it looks for under $CUDA_PATH, then /usr/local/cuda,
# /opt/cuda, /usr/lib/cuda, /usr. Where none has it, the first one found on the machine is used.
if [ -z "${CUDA_PATH:-}" ] && ! ls /usr/local/cuda/nvvm/libdevice /opt/cuda/nvvm/libdevice /usr/lib/cuda/nvvm/libdevice \
    /usr/nvvm/libdevice >/dev/null 2>&1; then
  bc=$(find /usr/local /opt /usr/lib -name libdevice.10.bc -path '*nvvm/libdevice/*' 2>/dev/null | head -1)
  [ -n "$bc" ] && export CUDA_PATH=${bc%/nvvm/libdevice/libdevice.10.bc}
fi
export XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-$work}
export PYTHONUNBUFFERED=1
# JAX's Triton GEMM autotuning costs ~40 s per A and changes its speed by ~2 % (bench_grid.py).
export XLA_FLAGS=${XLA_FLAGS:---xla_gpu_enable_triton_gemm=false}
train=$work/bin/pgser-train
etl=$work/bin/pgser-etl
data=$here/data
say "bundle $(cat "$here/VERSION" 2>/dev/null || echo '(no VERSION)'); host $(uname -n), $(nproc) CPUs"

summary() {  # gpu.json from the parts written so far, and the logs
  python3 - "$out" "$work" <<'EOF' || say "could not write gpu.json"
import json, sys, glob, os
out, work = sys.argv[1], sys.argv[2]
doc = {}
for name in ("machine", "correctness"):
    p = os.path.join(work, name + ".json")
    if os.path.exists(p):
        doc[name] = json.load(open(p))
doc["grid"] = {os.path.basename(p)[5:-5]: json.load(open(p)) for p in sorted(glob.glob(os.path.join(work, "grid-*.json")))}
json.dump(doc, open(os.path.join(out, "gpu.json"), "w"), indent=1)
EOF
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

# ---- 2. correctness: cuda and wgpu against cpu ----------------------------------------------------
# The device a pgser run names in its log ("--device cuda: running on NVIDIA H200"), if any.
running_on() { grep -m1 -- ": running on" "$1" | sed 's/.*running on //'; }
# One command of the check: under a time limit, its output in logs/NAME.out and .log, a line in
# run.log (with the device it names, if any), and its last lines there when it fails.
step() {
  local name=$1 t0=$SECONDS rc on
  shift
  timeout 240 "$@" >"$logs/$name.out" 2>"$logs/$name.log"
  rc=$?
  on=$(running_on "$logs/$name.log")
  say "${name/-/ --device }: rc $rc, $((SECONDS - t0)) s${on:+, on $on}"
  [ $rc -eq 0 ] || tail -3 "$logs/$name.log" | sed 's/^/    /' | tee -a "$out/run.log" >&2
}
for dev in cpu cuda wgpu; do
  step "train-$dev" "$train" --data "$data/scored.parquet" -o "$work/train-$dev" --seeds 0,1,2 --updates 50 \
    --batch-size 256 --eval-episodes 0 --log-every 10 --device "$dev"
  [ -x "$etl" ] && step "score-$dev" "$etl" score --q "$data/q.ckpt" --data "$data/reach.parquet" \
    -o "$work/score-$dev.parquet" --swaps 2 --device "$dev"
done
python3 - "$work/machine.json" "$gpu" "$(running_on "$logs/train-cuda.log")" "$(running_on "$logs/train-wgpu.log")" <<'EOF'
import json, sys
json.dump({"gpu": sys.argv[2], "cuda_device": sys.argv[3], "wgpu_adapter": sys.argv[4]}, open(sys.argv[1], "w"), indent=1)
EOF
# wgpu is timed only on the GPU itself: where it opened a software adapter (or none), its
# figures would be the CPU's under a GPU's name.
wgpu_on_gpu=1
case "$(running_on "$logs/train-wgpu.log")" in
  "") wgpu_on_gpu=0; say "wgpu opened no adapter: it is not timed";;
  *"no GPU"*) wgpu_on_gpu=0; say "wgpu opened a software adapter, not the GPU: it is not timed";;
esac
sc() { if [ -x "$etl" ]; then echo "$work/score-$1.parquet"; else echo -; fi; }
python3 "$here/bench/gpu_compare.py" --tol 1e-4 --cpu-train "$work/train-cpu" --cpu-score "$work/score-cpu.parquet" \
  --backend cuda "$work/train-cuda" "$(sc cuda)" --backend wgpu "$work/train-wgpu" "$(sc wgpu)" \
  --json "$work/correctness.json" 2>&1 | tee -a "$out/run.log"
summary

# ---- 3. speed: pgser beside JAX and PyTorch, the same run -----------------------------------------
for A in 60 1 120 30 10; do
  # A cell takes up to ~2 min (each child's start, compilation and autotuning are untimed).
  if [ "$(left)" -lt 120 ]; then say "A = $A and after: skipped, $(left) s left of $budget"; break; fi
  python3 "$here/bench/bench_grid.py" --device cuda --python python3 --jax-python python3 --pgser "$train" \
    --pgser-device cuda --peers pgser,jax,stacked-graph --agents "$A" --seconds 3 --timeout 150 \
    --workdir "$work/bench" --json "$work/grid-cuda-A$A.json" 2>&1 | tee "$logs/grid-cuda-A$A.txt" | tee -a "$out/run.log"
  # wgpu at A = 60 only: its rate hardly depends on A below that (BENCHMARKS.md, H200 2026-11-26),
  # and the time is better spent on cuda's other A values.
  [ "$A" = 60 ] && [ $wgpu_on_gpu = 1 ] || { summary; continue; }
  if [ "$(left)" -lt 45 ]; then say "wgpu at A = $A: skipped, $(left) s left"; continue; fi
  python3 "$here/bench/bench_grid.py" --device cuda --python python3 --pgser "$train" --pgser-device wgpu \
    --peers pgser --agents "$A" --seconds 3 --timeout 120 --workdir "$work/bench" \
    --json "$work/grid-wgpu-A$A.json" 2>&1 | tee "$logs/grid-wgpu-A$A.txt" | tee -a "$out/run.log"
  summary
done
cp -r "$work/bench/grid-logs" "$logs/" 2>/dev/null
summary
say "done: $out/gpu.json"
