# Sourced by the GPU bundle's run.sh and grid.sh (`make gpu-bundle` copies it as env.sh): unpacks
# the bundle's binaries and libraries into $work and sets the environment every GPU run needs.
# Expects $here (the bundle) and $work (a temporary folder); sets $train, $burn, $etl, $data.
mkdir -p "$work/bin" "$work/lib" "$work/vk"
for f in "$here"/bin/*.xz; do xz -dc "$f" >"$work/bin/$(basename "$f" .xz)" && chmod +x "$work/bin/$(basename "$f" .xz)"; done
for f in "$here"/lib/*.xz; do xz -dc "$f" >"$work/lib/$(basename "$f" .xz)"; done
ln -sf libmujoco.so.3.17.0 "$work/lib/libmujoco.so"
# The Vulkan loader and libglvnd in a private folder: wgpu opens libvulkan.so.1 by name, the
# NVIDIA driver brings its own ICD (in libGLX_nvidia, which needs libglvnd), and the loader finds
# it through VK_DRIVER_FILES where the image does not register it.
for d in "$here"/debs/*.deb; do [ -e "$d" ] && dpkg-deb -x "$d" "$work/vk"; done
export LD_LIBRARY_PATH="$work/lib:$work/vk/usr/lib/x86_64-linux-gnu${LD_LIBRARY_PATH:+:$LD_LIBRARY_PATH}"
# CUDA 13's cuBLAS and NVRTC from the pip wheels (nvidia-cublas, nvidia-cuda-nvrtc: the ones JAX
# and PyTorch bring), named explicitly and first on the loader's path: cudarc tries the
# unversioned and CUDA 12 names before libcublas.so.13, so a CUDA 12 toolkit on the path would
# otherwise be taken silently. The engine prints the libraries it loaded, and refuses a cuBLAS
# that is not 13.
if [ -z "${PGSER_CUDA_LIBS:-}" ]; then
  cu13=$(python3 -c 'import nvidia, os
for p in nvidia.__path__:
    d = os.path.join(p, "cu13", "lib")
    if os.path.exists(os.path.join(d, "libcublas.so.13")): print(d); break' 2>/dev/null)
  [ -n "$cu13" ] && export PGSER_CUDA_LIBS=$cu13
fi
[ -n "${PGSER_CUDA_LIBS:-}" ] && export LD_LIBRARY_PATH="$PGSER_CUDA_LIBS:$LD_LIBRARY_PATH"
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
# The CUDA engine's kernels: on an sm_90 GPU the cubin built with the bundle (NVRTC 13.0, as
# `make test` checks it); elsewhere the engine compiles them with the machine's own NVRTC.
if [ "$(nvidia-smi --query-gpu=compute_cap --format=csv,noheader 2>/dev/null | head -1)" = "9.0" ] &&
  [ -f "$here/kernels/kernels_sm90.cubin" ]; then
  export PGSER_CUDA_CUBIN=$here/kernels/kernels_sm90.cubin
fi
train=$work/bin/pgser-train
# burn's GPU backends (cuda-burn, wgpu) are in their own build, where the bundle has it.
burn=$work/bin/pgser-train-burn
etl=$work/bin/pgser-etl
data=$here/data

# Whether every figure of a bench/gpu_compare.py JSON is within its tolerance: 1, else 0.
compare_ok() {
  python3 -c 'import json,sys; d=json.load(open(sys.argv[1])); print(int(bool(d) and all(v.get("ok") for b in d.values() if isinstance(b, dict) for v in b.values() if isinstance(v, dict) and "ok" in v)))' "$1" 2>/dev/null || echo 0
}
# After a failed check of the CUDA engine (run.sh's and grid.sh's): the same training once more
# with every launch synchronous and no graphs, where a kernel's fault surfaces at its own launch,
# under its name (with graphs and a queue it surfaces later, as "staging" or "download"), compared
# with the CPU's run again; then a few updates under compute-sanitizer's memcheck where the machine
# has it. Needs say, $train, $work, $logs.
#   cuda_diagnose NAME CPU_RUN_DIR TRAIN_ARGS...   (TRAIN_ARGS without -o and --updates)
cuda_diagnose() {
  local name=$1 cpu_dir=$2 rc san
  shift 2
  say "$name: once more with CUDA_LAUNCH_BLOCKING=1 and PGSER_CUDA_GRAPHS=0, so that a failing launch names itself"
  PGSER_CUDA_GRAPHS=0 CUDA_LAUNCH_BLOCKING=1 timeout 240 "$train" "$@" --updates 50 -o "$work/$name-blocking" \
    >"$logs/$name-blocking.out" 2>"$logs/$name-blocking.log"
  rc=$?
  say "  rc $rc: $(tail -1 "$logs/$name-blocking.log")"
  [ $rc -eq 0 ] && python3 "$here/bench/gpu_compare.py" --tol 1e-5 --cpu-train "$cpu_dir" \
    --backend cuda-blocking "$work/$name-blocking" - --json "$work/correctness-blocking.json" 2>&1 | while IFS= read -r l; do say "  $l"; done
  san=$(command -v compute-sanitizer || ls /usr/local/cuda*/bin/compute-sanitizer /usr/local/cuda*/compute-sanitizer/compute-sanitizer 2>/dev/null | head -1)
  if [ -z "$san" ]; then say "  no compute-sanitizer on this machine"; return; fi
  PGSER_CUDA_GRAPHS=0 timeout 240 "$san" --tool memcheck --print-limit 10 "$train" "$@" --updates 3 \
    -o "$work/$name-sanitizer" >"$logs/$name-sanitizer.out" 2>"$logs/$name-sanitizer.log"
  say "  compute-sanitizer memcheck, 3 updates: rc $?; $(grep -h -m4 -e 'Invalid' -e 'ERROR SUMMARY' -e 'at 0x' "$logs/$name-sanitizer.out" "$logs/$name-sanitizer.log" | tr '\n' ' ')"
}
