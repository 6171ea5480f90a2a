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
