#!/usr/bin/env bash
# The wheel as a user gets it (make test-wheel; make test runs it): installed with pip into a new
# venv outside the clone, it must work without the clone. The commands it installs convert the
# sample data and a Minari dataset in HDF5 storage (the HDF5 compiled in), train on it with
# evaluation in MuJoCo, and run a hand task; the module makes every task, converts the same Minari
# dataset to the same table, reads tables and samples batches; tests/python's environment-parity (against
# gymnasium-robotics), table and Sampler tests pass against it. Each of the wheel's own runs is
# traced (strace), and none may open or even look for a file under the clone's .deps, target or
# python folders: what the wheel needs, it carries.
#
# With --demo it also runs `pgser-etl demo` (about 4 minutes on 2 cores) and checks its results
# table: tests/wheel/distro.sh (make test-wheel-distro) does, on Debian 13 and here.
#
#   tests/wheel/check.sh [--demo] target/wheels/pgser-VERSION-cp310-abi3-manylinux_2_28_x86_64.whl
set -euo pipefail
REPO=$(cd "$(dirname "$0")/../.." && pwd)
DEMO=0
[ "${1:-}" = --demo ] && { DEMO=1; shift; }
[ $# -eq 1 ] && [ -f "$1" ] || { echo "usage: tests/wheel/check.sh [--demo] WHEEL (one file; make wheel builds it)" >&2; exit 2; }
WHEEL=$(realpath "$1")
WORK=$(mktemp -d "${TMPDIR:-/tmp}/pgser-wheel.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
PYTHON=${PYTHON:-python3}
t0=$(date +%s)

"$PYTHON" -m venv "$WORK/venv"
V=$WORK/venv/bin
"$V/python" -m pip install --quiet --upgrade pip
"$V/python" -m pip install --quiet "$WHEEL" "pytest>=8" "mujoco==3.17.0" "gymnasium-robotics==1.4.2"
t1=$(date +%s)
cd "$WORK"
unset PGSER_ASSETS PGSER_ZIGGURAT LD_LIBRARY_PATH PYTHONPATH

traced() {  # traced NAME COMMAND...: run it under strace into $WORK/trace.NAME, checked below
  local name=$1; shift
  if command -v strace >/dev/null 2>&1; then
    strace -f -qq -e trace=open,openat,execve -o "$WORK/trace.$name" "$@"
  else
    "$@"
  fi
}

echo "check.sh: the installed commands"
traced version "$V/pgser-etl" --version | tee version.txt
grep -q "^pgser-etl [0-9.]* (MuJoCo 3.17.0)$" version.txt
traced version-train "$V/pgser-train" --version | grep -q "^pgser-train [0-9.]* (MuJoCo 3.17.0)$"
traced convert "$V/pgser-etl" convert "$REPO/data/fetch_reach_expert_50.pkl" "$REPO/data/fetch_reach_random_200.pkl" \
  --episodes 12,24 -o traj.parquet
traced verify "$V/pgser-etl" verify traj.parquet
traced train "$V/pgser-train" --data traj.parquet -o agent.ckpt --updates 100 --hidden 32 --batch-size 64 \
  --eval-episodes 2 --threads 2
traced score "$V/pgser-etl" score --q agent.ckpt --data traj.parquet -o scored.parquet --swaps 2
# Minari's HDF5 storage, through the HDF5 compiled into the binary (no system libhdf5).
traced minari "$V/pgser-etl" convert "$REPO/tests/fixtures/minari/fetchreach-hdf5-v0" -o minari.parquet
traced minari-verify "$V/pgser-etl" verify minari.parquet
traced hand "$V/pgser-train" eval --random --task HandManipulateEggRotate --episodes 1 --json > hand.json
grep -q '"episodes":1' hand.json

echo "check.sh: the module"
traced module "$V/python" - "$REPO" <<'PY'
import pathlib, sys
import pgser
venv = pathlib.Path(sys.prefix)
assert pathlib.Path(pgser.__file__).is_relative_to(venv), f"pgser from {pgser.__file__}, not the venv {venv}"
for task in pgser.TASKS:
    env = pgser.make(task)
    obs, _ = env.reset(seed=0)
    env.step(env.action_space.sample())
t = pgser.read_table("traj.parquet")
assert t.num_rows == 36 * 50, t.num_rows
# The module's own HDF5, on the same Minari dataset: the same table as the command wrote.
m = pgser.convert([sys.argv[1] + "/tests/fixtures/minari/fetchreach-hdf5-v0"], "minari-module.parquet")
assert m["episodes"] == 4 and m["rows"] == 200, m
assert pgser.read_table("minari-module.parquet").equals(pgser.read_table("minari.parquet"))
s = pgser.Sampler("scored.parquet", batch_size=32, seed=0)
b = next(iter(s))
assert b["obs"].shape[0] == 32
print("module ok:", pgser.long_version)
PY

if [ "$DEMO" = 1 ]; then
  echo "check.sh: pgser-etl demo (PGSER on 20 FetchReach episodes, from the wheel alone)"
  traced demo "$V/pgser-etl" demo pgser-demo | tee demo.txt
  # The results table with its three agents and the tests against the baseline, the random
  # policy for scale, and the figures where the summary says they are.
  grep -q '^| TD3+BC mem | ' demo.txt && grep -q '^| TD3+BC swap | ' demo.txt && grep -q '^| TD3+BC baseline | ' demo.txt
  grep -q '^for scale: random policy: 50 episodes of FetchReach' demo.txt
  for f in pgser-demo/demo.toml pgser-demo/results.md pgser-demo/report/fig5_q_hist.png; do
    [ -s "$f" ] || { echo "check.sh: FAIL: the demo left no $f" >&2; exit 1; }
  done
  ls pgser-demo/curves_*.png >/dev/null
fi

echo "check.sh: tests/python (environment parity, tables, Sampler) against the installed module and commands"
PGSER_BIN=$V traced pytest "$V/python" -m pytest -q -p no:cacheprovider "$REPO/tests/python/test_envs.py" "$REPO/tests/python/test_tables.py" \
  "$REPO/tests/python/test_sampler.py"

traces=("$WORK"/trace.*)
if [ -e "${traces[0]}" ]; then
  echo "check.sh: ${#traces[@]} traces: no file of the clone's .deps, target or python folders looked for"
  if grep -hE "\"$REPO/(\.deps|target|python)/" "${traces[@]}" | head -5 | grep .; then
    echo "check.sh: FAIL: the wheel looked for files in the clone it was built in (above)" >&2; exit 1
  fi
else
  echo "check.sh: strace is missing: the runs were not traced (make strace-deps installs it)"
fi

t2=$(date +%s)
echo "check.sh: ok ($(du -m "$WHEEL" | cut -f1) MB wheel; install $((t1 - t0)) s, checks $((t2 - t1)) s)"
