#!/usr/bin/env bash
# The paper's budget on a GPU, in one run: the bundle's grid.sh (`make gpu-bundle` copies this file
# into target-gpu/bundle/; docs/gpu.md). It runs pipelines/fetch_push_td3bc_gpu.toml from the
# repository (which travels with every device run): FetchPush's data collected on this machine's
# cores (the same bytes as here: checked against the data the Q was trained on), scored with the
# Q pre-trained for the paper's 1M updates (results/fetch_push_q1m/q.ckpt), then TD3+BC ×
# {baseline, swap, mem} × 10 seeds × 500k updates as one stack of 30 on DEVICE.
#
#   grid.sh OUT_DIR [SECONDS] [DEVICE] [PIPELINE]
#       SECONDS   the time it may take, default 560 (a device run's limit is 600)
#       DEVICE    cuda (FP32, default) or cuda-tf32; cpu runs it here (for a check, with a small
#                 pipeline)
#       PIPELINE  default: pipelines/fetch_push_td3bc_gpu.toml of the repository it runs in;
#                 pipelines/fetch_push_td3_gpu.toml is the grid's TD3 half
#
# It starts with run.sh's check of the engine against the CPU (30 s; an FP32 engine off by more
# than 1e-5 stops it there). The grid stops itself (SIGTERM: the trainer saves every agent where it is and exits) when
# SECONDS − 45 have passed, so that what it reached comes back: the curves of every agent up to
# its last evaluation. A run that finishes also brings the pipeline's results (results.md, .csv,
# scores, curves). Out: OUT_DIR/grid.json (the machine, the data check, each agent's updates
# and evaluations, the wall time and the rate), grid.log, results/ (the pipeline's results and
# each agent's metrics), logs.tar.gz. Checkpoints stay behind: 30 agents are 200 MB.
set -uo pipefail

here=$(cd "$(dirname "$0")" && pwd)
[ $# -ge 1 ] || { echo "usage: grid.sh OUT_DIR [SECONDS] [DEVICE] [PIPELINE]" >&2; exit 2; }
mkdir -p "$1" && out=$(cd "$1" && pwd)
budget=${2:-560}
device=${3:-cuda}
repo=$(git rev-parse --show-toplevel 2>/dev/null || pwd)
pipeline=$(realpath "${4:-$repo/pipelines/fetch_push_td3bc_gpu.toml}")
work=$(mktemp -d)
logs=$work/logs
mkdir -p "$logs" "$out/results"
: >"$out/grid.log"
say() { echo "gpu-grid [$((SECONDS))s]: $*" | tee -a "$out/grid.log" >&2; }
. "$here/env.sh"
say "bundle $(cat "$here/VERSION" 2>/dev/null || echo '(no VERSION)'); host $(uname -n), $(nproc) CPUs; $pipeline on $device"
[ -x "$etl" ] || { say "this bundle has no pgser-etl: rebuild it with make gpu-bundle"; exit 1; }

gpu=$(nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader 2>/dev/null | head -1)
case $device in
  cuda*) if [ -z "$gpu" ]; then
      say "no GPU: nvidia-smi finds no NVIDIA GPU on this machine, so the grid does not run"
      python3 -c 'import json,sys; json.dump({"gpu": None, "device": sys.argv[1]}, open(sys.argv[2], "w"), indent=1)' \
        "$device" "$out/grid.json"
      exit 0
    fi;;
esac
say "GPU: ${gpu:-none}"

# First the engine's check from run.sh, in ~30 s, so that a session that runs only the grid does
# not train 30 agents on a wrong engine: a stack of three -mem agents, 50 updates, on the CPU and
# on DEVICE, every weight and logged loss compared (bench/gpu_compare.py). FP32 (`cuda`) must be
# within 1e-5 or the grid does not start (GRID_FORCE=1 starts it anyway); TF32 is reported.
case $device in cuda*)
  for d in cpu "$device"; do
    timeout 240 "$train" --data "$data/scored.parquet" -o "$work/check-$d" --seeds 0,1,2 --updates 50 --batch-size 256 \
      --eval-episodes 0 --log-every 10 --device "$d" >"$logs/check-$d.out" 2>"$logs/check-$d.log" ||
      say "the check's $d run failed: $(tail -1 "$logs/check-$d.log")"
  done
  tol=1e-5; [ "$device" = cuda ] || tol=1e-4
  python3 "$here/bench/gpu_compare.py" --tol $tol --cpu-train "$work/check-cpu" --backend "$device" "$work/check-$device" - \
    --json "$out/check.json" 2>&1 | tee -a "$out/grid.log"
  ok=$(compare_ok "$out/check.json")
  if [ "$ok" != 1 ] && [ "$device" = cuda ] && [ "${GRID_FORCE:-0}" != 1 ]; then
    say "the engine is not within $tol of the CPU here: the grid does not start (GRID_FORCE=1 to start it anyway)"
    cuda_diagnose check-cuda "$work/check-cpu" --data "$data/scored.parquet" --seeds 0,1,2 --batch-size 256 \
      --eval-episodes 0 --log-every 10 --device cuda
    tar -czf "$out/logs.tar.gz" -C "$work" logs 2>/dev/null
    exit 1
  fi;;
esac

# The pipeline's folders: its `out` is relative to the pipeline file, unless it is absolute.
rel_out=$(sed -n 's/^out *= *"\(.*\)"/\1/p' "$pipeline" | head -1)
case $rel_out in
  /*) dest=$(realpath -m "$rel_out");;
  *) dest=$(realpath -m "$(dirname "$pipeline")/$rel_out");;
esac
t0=$SECONDS
timeout -s TERM -k 90 $((budget - 45 - SECONDS)) "$etl" pipeline run "$pipeline" --device "$device" --no-measure \
  >"$logs/pipeline.out" 2>"$logs/pipeline.log" &
pid=$!
# A line of progress a minute, so that a run cut short still says where it was.
next=$((SECONDS + 60))
while kill -0 $pid 2>/dev/null; do
  sleep 2
  if [ $SECONDS -ge $next ]; then
    next=$((SECONDS + 60))
    last=$(grep -a -E 'ran in|saved|running' "$logs/pipeline.log" 2>/dev/null | tail -1)
    [ -n "$last" ] && say "${last:0:200}"
  fi
done
wait $pid
rc=$?
wall=$((SECONDS - t0))
case $rc in
  0) say "the pipeline finished in $wall s";;
  124) say "stopped at the time limit after $wall s (SIGTERM: every agent saved where it was)";;
  *) say "the pipeline failed (rc $rc) after $wall s:"; tail -5 "$logs/pipeline.log" | sed 's/^/    /' | tee -a "$out/grid.log" >&2;;
esac

# What comes back: the pipeline's results (when it got that far) and every agent's metrics.
for f in results.md results.csv scores.csv report/table1.md report/table1.json; do
  [ -f "$dest/$f" ] && cp "$dest/$f" "$out/results/"
done
cp "$dest"/curves_*.png "$out/results/" 2>/dev/null
mkdir -p "$out/results/agents"
cp "$dest"/agents/*.metrics.jsonl "$out/results/agents/" 2>/dev/null
# The data check applies to pipelines that score with the committed 1M-update Q: their data must be
# the data it was trained on.
shas=-
grep -q 'results/fetch_push_q1m/q.ckpt' "$pipeline" && shas=$repo/results/fetch_push_q1m/data.sha256
python3 - "$out/grid.json" "$dest" "$shas" "$device" "${gpu:-}" "$rc" "$wall" \
  "$logs/pipeline.log" <<'EOF'
import glob, hashlib, json, os, re, sys

path, dest, shas, device, gpu, rc, wall, log = sys.argv[1:]
doc = {"device": device, "gpu": gpu or None, "rc": int(rc), "wall_s": int(wall)}
# The data collected here against the data the Q was trained on (collect is deterministic).
check = {}
if os.path.exists(shas):
    for line in open(shas):
        want, name = line.split()
        got = os.path.join(dest, "data", name)
        check[name] = {"expected": want,
                       "here": hashlib.sha256(open(got, "rb").read()).hexdigest() if os.path.exists(got) else None}
        check[name]["same"] = check[name]["here"] == want
doc["data_check"] = check
agents = {}
for m in sorted(glob.glob(os.path.join(dest, "agents", "*.metrics.jsonl"))):
    name = os.path.basename(m)[: -len(".ckpt.metrics.jsonl")]
    lines = [json.loads(l) for l in open(m) if l.strip()]
    evals = [(l["updates"], l["eval"]) for l in lines if l.get("eval")]
    agents[name] = {
        "updates": max((l["updates"] for l in lines), default=0),
        "evals": [{"updates": u, "paper_score": e.get("paper_score"), "success_rate": e.get("success_rate")}
                  for u, e in evals],
    }
doc["agents"] = agents
reached = [a["updates"] for a in agents.values()]
doc["updates_reached"] = min(reached) if reached else 0
# The steps' times; the stack's rate over its wall time (evaluations and saves included): from
# its "ran in" line, or, stopped at the limit, from the time the other steps left it.
text = open(log, errors="replace").read() if os.path.exists(log) else ""
steps = [(name, float(s)) for name, s in re.findall(r"\] ([^:\n]+): ran in ([0-9.]+) s", text)]
doc["steps_s"] = dict(steps)
stack_s = sum(s for name, s in steps if name.startswith("agent "))
if not stack_s:
    stack_s = int(wall) - sum(s for name, s in steps if not name.startswith("agent "))
done = sum(a["updates"] for a in agents.values())
# Stopped between logging steps, the metrics lag the checkpoints: the trainer's own last words
# ("stopped by SIGTERM at update 721 of 500000") say where every agent of the stack saved.
stopped = re.findall(r"stopped by SIGTERM at update (\d+) of (\d+)", text)
if stopped and agents:
    doc["stopped_at"] = int(stopped[-1][0])
    doc["updates_reached"] = max(doc["updates_reached"], doc["stopped_at"])
    done = max(done, doc["stopped_at"] * len(agents))
doc["stack_s"] = stack_s
doc["agent_updates_per_s"] = done / stack_s if done and stack_s > 0 else None
json.dump(doc, open(path, "w"), indent=1)
print(f"  {len(agents)} agents, {doc['updates_reached']} updates reached in {wall} s on {device}"
      + (f", {doc['agent_updates_per_s']:.0f} agent-updates/s" if doc["agent_updates_per_s"] else "")
      + " (evaluations and saves included)")
for name, c in check.items():
    said = "the same bytes as" if c["same"] else "DIFFERS from" if c["here"] else "MISSING here, so not checked against"
    print(f"  data {name}: {said} the data the Q was trained on")
EOF
tar -czf "$out/logs.tar.gz" -C "$work" logs 2>/dev/null
say "done: $out/grid.json"
