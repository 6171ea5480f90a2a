#!/usr/bin/env bash
# `make gpu-bundle`: target-gpu/bundle/, one folder that measures pgser on a GPU machine in one
# run (its run.sh is scripts/gpu_run.sh; docs/gpu.md). Our GPU machines start bare, reach no
# package registry and receive at most 64 MiB of files per run, so the folder holds everything
# and, with the repo's own files (which travel with every run), stays under 64 MiB (checked here):
#   bin/    pgser-train and pgser-etl from `make build` (cpu and the hand-written cuda engine: in
#           every build), and, where `make build-cuda` was run, its pgser-train as
#           pgser-train-burn (burn's cuda-burn and wgpu, the GPU references), stripped, xz
#           (5.4 and 21 MB, measured 2026-11-27). pgser-etl runs `score` on the device and the
#           grid's pipeline (grid.sh); BUNDLE_ETL=0 leaves it out.
#   lib/    MuJoCo 3.17.0's library, xz (the binaries link it)
#   debs/   the Vulkan loader and libglvnd (Debian packages), for wgpu
#   kernels/ the CUDA engine's kernels as an sm_90 cubin (H100, H200), compiled here by NVRTC 13.0
#           (`pgser-train cuda-kernels`), so the GPU machine needs no NVRTC of its own
#   data/   FetchReach tables and a Q (the correctness check), and a FetchPush -mem table (100
#           expert + 400 random episodes, a 200-update Q, K = 4: the real stacks' timing), made
#           here on the CPU by the same binaries
#   bench/  bench_grid.py and the JAX / PyTorch peers it runs, gpu_compare.py
#   run.sh  the measurements (scripts/gpu_run.sh); grid.sh: FetchPush's TD3+BC grid at the
#           paper's scale (scripts/gpu_grid.sh: its data are collected on the device, its Q is
#           the repository's results/fetch_push_q1m); env.sh: what both source
#   VERSION
# Built beside its place and moved there, so an interrupted build leaves the previous bundle.
set -euo pipefail
cd "$(dirname "$0")/.."
rel=${BUNDLE_REL:-target/release}
burn=${BUNDLE_BURN:-target-gpu/release}
dest=${BUNDLE_DEST:-target-gpu/bundle}
tmp=$dest.tmp
bins=(pgser-train)
[ "${BUNDLE_ETL:-1}" = 1 ] && bins+=(pgser-etl)
for x in pgser-train pgser-etl; do
  [ -x "$rel/$x" ] || { echo "gpu-bundle: $rel/$x is missing: run make build first" >&2; exit 1; }
done
rm -rf "$tmp"
mkdir -p "$tmp"/{bin,lib,debs,data,bench,kernels}

# The GPU machine starts bare: a binary may need only glibc's libraries, libgcc_s, libstdc++ (the
# image's PyTorch needs it too) and the MuJoCo the bundle carries. Until pgser 0.3.0 compiled HDF5 in, pgser-train and pgser-etl needed
# Debian's libhdf5_serial.so.103, which such a machine does not have: the bundle would have
# failed at its first command (found 2026-11-28, before any run used it).
runs_bare() {
  local extra
  extra=$(readelf -d "$1" | sed -n 's/.*(NEEDED).*\[\(.*\)\]/\1/p' |
    grep -v -E '^(libc|libm|libdl|librt|libpthread|libgcc_s|libstdc\+\+)\.so\.[0-9]+$|^ld-linux-x86-64\.so\.2$|^libmujoco\.so\.3\.17\.0$' || true)
  [ -z "$extra" ] || { echo "gpu-bundle: $1 needs $(echo $extra) beyond glibc, libgcc_s, libstdc++ and the bundled MuJoCo: a bare GPU machine lacks it" >&2; exit 1; }
}
for x in "${bins[@]}"; do
  runs_bare "$rel/$x"
  strip -o "$tmp/bin/$x" "$rel/$x"
  xz -6 -T0 "$tmp/bin/$x"
done
if [ -x "$burn/pgser-train" ]; then
  runs_bare "$burn/pgser-train"
  strip -o "$tmp/bin/pgser-train-burn" "$burn/pgser-train"
  xz -6 -T0 "$tmp/bin/pgser-train-burn"
else
  echo "gpu-bundle: no $burn/pgser-train (make build-cuda): burn's cuda-burn and wgpu are left out"
fi
xz -6 -c .deps/mujoco/libmujoco.so.3.17.0 >"$tmp/lib/libmujoco.so.3.17.0.xz"

# Debian's Vulkan loader (libvulkan1) and GL dispatch libraries (libglvnd and the rest) for amd64,
# whatever this machine's own architecture and package lists. NVIDIA's Vulkan driver lives in
# libGLX_nvidia, which needs libglvnd: with the loader alone, wgpu found no adapter on an H200
# (2026-11-27), and with these it ran on the GPU.
lists=$(mktemp -d)
mkdir -p "$lists/partial"
apt=(-oAPT::Architecture=amd64 -oAPT::Architectures=amd64 -oDir::State::Lists="$lists")
apt-get "${apt[@]}" update >/dev/null
(cd "$tmp/debs" && apt-get "${apt[@]}" download libvulkan1 libglvnd0 libglx0 libegl1 libgl1 libopengl0 libgles2 2>&1 | grep -v '^W: Download is performed unsandboxed' || true)
rm -rf "$lists"
for p in libvulkan1 libglvnd0 libglx0 libegl1 libgl1 libopengl0 libgles2; do
  ls "$tmp/debs/${p}"_*.deb >/dev/null 2>&1 || { echo "gpu-bundle: could not download $p" >&2; exit 1; }
done

# The tables: the committed FetchReach sample (50 expert + 200 random episodes), a Q trained 200
# updates on it, and its scored swaps (K = 4, with the original rows: what -mem trains on).
d=$tmp/data
"$rel/pgser-etl" convert data/fetch_reach_expert_50.pkl data/fetch_reach_random_200.pkl -o "$d/reach.parquet"
"$rel/pgser-train" --data "$d/reach.parquet" -o "$d/q.ckpt" --updates 200 --batch-size 256 \
  --eval-episodes 0 --device cpu >/dev/null
rm -f "$d"/q.ckpt.* "$d"/q.metrics* 2>/dev/null || true
"$rel/pgser-etl" score --q "$d/q.ckpt" --data "$d/reach.parquet" -o "$d/scored.parquet" --swaps 4 --include-original
# FetchPush for the real stacks' timing: the sampler's and stager's work at the paper's dimensions.
"$rel/pgser-etl" collect --task FetchPush --policy expert --episodes 100 --seed 0 -o "$d/push_expert.pkl"
"$rel/pgser-etl" collect --task FetchPush --policy random --episodes 400 --seed 100 -o "$d/push_random.pkl"
"$rel/pgser-etl" convert "$d/push_expert.pkl" "$d/push_random.pkl" -o "$d/push.parquet" --task FetchPush
"$rel/pgser-train" --data "$d/push.parquet" -o "$d/push_q.ckpt" --updates 200 --batch-size 256 --swap random \
  --eval-episodes 0 --device cpu >/dev/null
"$rel/pgser-etl" score --q "$d/push_q.ckpt" --data "$d/push.parquet" -o "$d/push_scored.parquet" --swaps 4 --include-original
# push.parquet stays: the scored table names it, and the stacks read their β from it.
rm -f "$d"/push_*.pkl "$d"/push_q.ckpt*
"$rel/pgser-train" cuda-kernels --arch sm_90 --cubin "$tmp/kernels/kernels_sm90.cubin"

cp bench/bench_grid.py bench/train_peer.py bench/train_peer_stacked.py bench/train_peer_jax.py \
  bench/train_flops.py bench/peer_python.py bench/sgemm_peak.py bench/gpu_compare.py bench/gpu_summary.py "$tmp/bench/"
cp scripts/gpu_run.sh "$tmp/run.sh"
cp scripts/gpu_grid.sh "$tmp/grid.sh"
cp scripts/gpu_env.sh "$tmp/env.sh"
chmod +x "$tmp/run.sh" "$tmp/grid.sh"
echo "pgser $(git describe --always --dirty 2>/dev/null || echo unknown), bundled $(date -u +%FT%TZ)" >"$tmp/VERSION"

size=$(du -sb "$tmp" | cut -f1)
repo=$(git ls-files -z | xargs -0 du -cb 2>/dev/null | tail -1 | cut -f1)
if [ $((size + repo)) -gt $((63 * 1024 * 1024)) ]; then
  du -ab "$tmp" | sort -n | tail -5 >&2
  echo "gpu-bundle: $((size / 1024 / 1024)) MiB, and the repo $((repo / 1024 / 1024)) MiB: over the 64 MiB a GPU run can receive" >&2
  exit 1
fi
rm -rf "$dest"
mv "$tmp" "$dest"
echo "gpu-bundle: $dest, $((size / 1024 / 1024)) MiB (+ $((repo / 1024 / 1024)) MiB of repo) ($(cat "$dest/VERSION")); on a GPU machine: $dest/run.sh OUT_DIR"
