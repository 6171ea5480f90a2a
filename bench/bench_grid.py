#!/usr/bin/env python3
"""Many agents per process (issue 12): agent-updates/s of the Python peers for A agents, A in a list.

For each A (default 1,3,10,30 on CPU; 1,10,30,60 with --device cuda) it measures, each peer in
its own child process:

  pgser         `pgser-train bench --agents A` (--pgser, default target/release/pgser-train): the A
                agents as one stack, on pgser's hand-written CPU update (`--device cpu`);
                on --device cuda it runs with --pgser-device (default: cuda, pgser's CUDA engine;
                cuda-tf32 with tensor cores; wgpu or cuda-burn for burn's GPU backends).
  pgser-burn    the same on burn's flex backend (`--device cpu-burn`), the reference engine (CPU).
  single        train_peer.py, one agent per update call; A agents are trained one after
                another, so its agent-updates/s do not depend on A. On CPU it is measured two ways
                and the faster is used for each A: 1 process x T threads (the figure as is), and
                T processes x 1 thread run at once (per-process rate r, taken as T x the slowest
                of the T, so a process that ran partly alone does not inflate it; for A agents
                spread over min(A, T) processes: A / ceil(A / T) x r). On GPU: one process.
  stacked       train_peer_stacked.py --mode bmm: all A agents in one batched update (baddbmm).
  stacked-vmap  train_peer_stacked.py --mode vmap (torch.func.vmap + functional_call).
  stacked-graph train_peer_stacked.py --mode bmm --cuda-graph (GPU only).
  jax           train_peer_jax.py: jax.jit(jax.vmap(update)) over the A agents.

Defaults: CPU pgser, pgser-burn, single, stacked, jax; GPU pgser, single, stacked, stacked-graph,
jax (--peers to choose, 'all' for every one that applies).

On CPU the machine's sgemm figure is measured in the same run, before and after the peers
(bench/sgemm_peak.py with the torch interpreter: the best square-matrix GFLOP/s at --threads), and
every cell is also given as a percentage of the larger of the two. Each peer reports agent-updates/s (A x updates/s) measured
in-process around the update loop only (imports, init, compilation and warm-up excluded), for a
run of about --seconds (the new peers calibrate the number of updates themselves; train_peer.py
gets it from a short probe run) or exactly --updates. GFLOP/s = agent-updates/s x the per-update
matmul FLOP count of train_flops.py (≈1.64 GFLOP for FetchPush, batch 512, H 256), the same
count for every peer.

A peer that fails, times out or whose interpreter lacks its framework is shown as such in the
table; the driver carries on. Children's stdout/stderr: <workdir>/grid-logs/.

JAX on GPU spends ~40 s per A compiling (XLA's Triton GEMM autotuning; untimed); with
XLA_FLAGS=--xla_gpu_enable_triton_gemm=false in the environment it compiles in ~2 s at about
the same speed (H100, A = 10: 13.2k vs 13.5k agent-updates/s), which shortens a grid run.

Threads (CPU): children get OMP_NUM_THREADS=MKL_NUM_THREADS=T and --threads T; the JAX peer
sets XLA_FLAGS for T threads, which XLA does not strictly obey (see train_peer_jax.py); --jax-pin
pins it to T CPUs.

Usage:
    bench_grid.py [--device cpu|cuda] [--agents 1,3,10,30] [--python PY] [--jax-python PY]
                  [--peers single,stacked,jax | all] [--threads 2] [--seconds 4 | --updates N]
                  [--warmup 4] [--task FetchPush] [--algo td3bc] [--batch-size 512] [--hidden 256]
                  [--repeat 1] [--rounds 1] [--timeout 300] [--workdir bench-out] [--json OUT.json]

On a GPU machine whose python3 has torch and jax:
    python3 bench/bench_grid.py --device cuda --python python3 --jax-python python3 --json bench-out/grid-gpu.json
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
from train_flops import flops_per_update  # noqa: E402
from peer_python import last_json  # noqa: E402

TASKS = {  # as bench_train.py
    "FetchReach": (10, 3, 4),
    "FetchPush": (25, 3, 4),
    "FetchSlide": (25, 3, 4),
    "FetchPickAndPlace": (25, 3, 4),
    "FetchPick": (25, 3, 4),
}
ALL_PEERS = ("pgser", "pgser-burn", "single", "stacked", "stacked-vmap", "stacked-graph", "jax")
LABELS = {"pgser": "pgser stack", "pgser-burn": "pgser burn", "single": "train_peer.py", "stacked": "stacked bmm", "stacked-vmap": "stacked vmap",
          "stacked-graph": "stacked bmm+graph", "jax": "jax jit(vmap)"}


def interpreter(arg: str | None, fallback: str) -> str:
    """Absolute path (not symlink-resolved: a venv's python must stay the venv's) or a name on PATH."""
    if not arg:
        return fallback
    if "/" in arg:
        return str(Path(arg).absolute())
    from shutil import which
    return which(arg) or arg


def has_module(python: str, module: str) -> str | None:
    """None if `python -c 'import module'` works, else why not (one line)."""
    try:
        p = subprocess.run([python, "-c", f"import {module}"], capture_output=True, text=True, timeout=180,
                           env=dict(os.environ, JAX_PLATFORMS=os.environ.get("JAX_PLATFORMS", "cpu")))
    except (OSError, subprocess.TimeoutExpired) as e:
        return f"{python}: {e}"
    if p.returncode != 0:
        last = (p.stderr.strip().splitlines() or ["?"])[-1]
        return f"no {module} in {python}: {last[:120]}"
    return None


class Runner:
    def __init__(self, logdir: Path, env: dict, timeout: float):
        self.logdir, self.env, self.timeout = logdir, env, timeout
        self.n = 0

    def start(self, name: str, cmd: list[str]):
        self.n += 1
        stem = self.logdir / f"{self.n:03d}_{name}"
        out, err = open(f"{stem}.out", "wb"), open(f"{stem}.err", "wb")
        try:
            proc = subprocess.Popen(cmd, stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=self.env)
        except OSError as e:
            out.close(), err.close()
            return {"cmd": cmd, "error": str(e), "stem": stem}
        return {"cmd": cmd, "proc": proc, "files": (out, err), "stem": stem, "t0": time.perf_counter()}

    def finish(self, h) -> dict:
        """{'ok': True, 'report': {...}} or {'ok': False, 'why': ...}."""
        if "error" in h:
            return {"ok": False, "why": f"could not start: {h['error']}", "cmd": shlex.join(h["cmd"])}
        proc = h["proc"]
        left = max(1.0, self.timeout - (time.perf_counter() - h["t0"]))
        try:
            rc = proc.wait(timeout=left)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            rc = None
        for f in h["files"]:
            f.close()
        out = Path(f"{h['stem']}.out").read_text(errors="replace")
        err = Path(f"{h['stem']}.err").read_text(errors="replace")
        rep = last_json(out)
        res = {"cmd": shlex.join(h["cmd"]), "log": str(h["stem"]) + ".{out,err}",
               "wall_s": time.perf_counter() - h["t0"]}
        if rc is None:
            return {**res, "ok": False, "why": f"timed out after {self.timeout:.0f} s"}
        if rc != 0 or rep is None:
            lines = [ln for ln in err.strip().splitlines() if ln.strip()]
            why = f"exit {rc}" if rc != 0 else "no JSON line"
            if lines:
                why += ": " + lines[-1].strip()[:160]
            return {**res, "ok": False, "why": why}
        return {**res, "ok": True, "report": rep}

    def run(self, name, cmd):
        return self.finish(self.start(name, cmd))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    ap.add_argument("--agents", help="comma-separated A values (default 1,3,10,30 on cpu, 1,10,30,60 on cuda)")
    ap.add_argument("--python", help="interpreter with torch (default bench-out/torch-venv/bin/python if it "
                                     "exists, else this one)")
    ap.add_argument("--jax-python", help="interpreter with jax (default bench-out/jax-venv/bin/python if it "
                                         "exists, else --python's)")
    ap.add_argument("--peers", help=f"comma-separated from {','.join(ALL_PEERS)}, or 'all'")
    ap.add_argument("--threads", type=int, default=2, help="CPU threads per measurement (default 2)")
    ap.add_argument("--seconds", type=float, default=4.0, help="timed seconds per measurement (default 4)")
    ap.add_argument("--updates", type=int, help="exact timed updates per measurement instead of --seconds")
    ap.add_argument("--warmup", type=int, default=4, help="untimed updates first (default 4)")
    ap.add_argument("--task", choices=sorted(TASKS), default="FetchPush")
    ap.add_argument("--algo", choices=("td3bc", "td3"), default="td3bc")
    ap.add_argument("--batch-size", type=int, default=512)
    ap.add_argument("--hidden", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=1, help="runs per cell in a row; the median is used (default 1)")
    ap.add_argument("--rounds", type=int, default=1,
                    help="passes over every peer and A, peers in a rotated order each pass; each cell shows the "
                         "median over the passes and the table lists every pass's figure (default 1)")
    ap.add_argument("--timeout", type=float, default=300, help="seconds before a child is killed (default 300)")
    ap.add_argument("--jax-pin", action="store_true", help="CPU: pin the JAX peer to --threads CPUs")
    ap.add_argument("--tf32", action="store_true", help="GPU: let stacked and JAX peers use TF32 matmuls")
    ap.add_argument("--pgser", default=str(REPO / "target" / "release" / "pgser-train"),
                    help="pgser-train binary (default target/release/pgser-train)")
    ap.add_argument("--pgser-device", default=None, help="pgser's --device (default cpu; on cuda: cuda, its CUDA engine)")
    ap.add_argument("--workdir", default=str(REPO / "bench-out"))
    ap.add_argument("--json", help="write all figures to this file")
    a = ap.parse_args(argv)
    if a.threads < 1 or a.repeat < 1 or a.rounds < 1 or a.seconds <= 0 or (a.updates is not None and a.updates < 2):
        ap.error("--threads/--repeat/--rounds >= 1, --seconds > 0, --updates >= 2")
    gpu = a.device == "cuda"
    agents = [int(x) for x in (a.agents or ("1,10,30,60" if gpu else "1,3,10,30")).split(",")]
    if a.peers in (None, ""):
        peers = ["pgser"] + ([] if gpu else ["pgser-burn"]) + ["single", "stacked"] + (["stacked-graph"] if gpu else []) + ["jax"]
    elif a.peers == "all":
        peers = [p for p in ALL_PEERS if (p != "stacked-graph" or gpu) and (p != "pgser-burn" or not gpu)]
    else:
        peers = [p.strip() for p in a.peers.split(",") if p.strip()]
        bad = [p for p in peers if p not in ALL_PEERS]
        if bad:
            ap.error(f"unknown peers {bad}; choose from {ALL_PEERS}")
        if "stacked-graph" in peers and not gpu:
            ap.error("stacked-graph needs --device cuda")

    default_torch = REPO / "bench-out" / "torch-venv" / "bin" / "python"
    default_jax = REPO / "bench-out" / "jax-venv" / "bin" / "python"
    py = interpreter(a.python, str(default_torch) if default_torch.exists() else sys.executable)
    jpy = interpreter(a.jax_python, str(default_jax) if default_jax.exists() and not a.python else py)
    obs, goal, act = TASKS[a.task]
    flops = flops_per_update(obs, goal, act, a.hidden, a.batch_size)
    T = a.threads

    logdir = Path(a.workdir).absolute() / "grid-logs"
    logdir.mkdir(parents=True, exist_ok=True)
    t = str(T)
    env = dict(os.environ, OMP_NUM_THREADS=t, MKL_NUM_THREADS=t, PYTHONUNBUFFERED="1")
    runner = Runner(logdir, env, a.timeout)
    dims = ["--obs", str(obs), "--goal", str(goal), "--act", str(act), "--batch-size", str(a.batch_size),
            "--algo", a.algo]
    length = ["--updates", str(a.updates)] if a.updates else ["--seconds", str(a.seconds)]

    # Which interpreters can run which peers (checked once, so a missing framework is one line).
    missing = {}
    if any(p not in ("jax", "pgser", "pgser-burn") for p in peers) or not gpu:
        missing["torch"] = has_module(py, "torch")
    if "jax" in peers:
        missing["jax"] = has_module(jpy, "jax")
    for k, why in missing.items():
        if why:
            print(f"note: {why}", file=sys.stderr)

    load_before = os.getloadavg()

    def sgemm_figure():
        """The best GFLOP/s of sgemm_peak.py at T threads, or None (no torch, or it failed)."""
        if gpu or missing.get("torch"):
            return None
        r = subprocess.run([py, str(HERE / "sgemm_peak.py"), "--threads", str(T)], capture_output=True, text=True,
                           env=env, timeout=a.timeout)
        figs = [float(line.split(":")[1].split()[0]) for line in r.stdout.splitlines() if line.startswith("threads")]
        return max(figs) if r.returncode == 0 and figs else None

    sgemm_before = sgemm_figure()

    def med(runs):
        ok = [r for r in runs if r["ok"]]
        if not ok:
            return runs[-1]
        ok.sort(key=lambda r: r["report"]["agent_updates_per_sec"])
        best = dict(ok[len(ok) // 2])
        best["all"] = [r["report"]["agent_updates_per_sec"] for r in ok]
        return best

    # ---- single-agent peer ------------------------------------------------------------------------
    def single_cmd(threads, updates):
        args = [*dims, "--updates", str(updates), "--warmup", str(a.warmup), "--threads", str(threads),
                "--device", a.device, "--json"]
        if a.hidden == 256:
            return [py, str(HERE / "train_peer.py"), *args]
        code = (f"import sys; sys.path.insert(0, {str(HERE)!r}); import train_peer; "
                f"train_peer.HIDDEN = {a.hidden}; train_peer.main()")
        return [py, "-c", code, *args]

    def run_single(cells):
        single_info = {}
        if missing.get("torch"):
            single_info = {"ok": False, "why": missing["torch"], "missing": True}
        else:
            n1 = a.updates
            if not n1:  # probe the rate for --seconds
                pr = runner.run("single_probe", single_cmd(T, 10))
                if pr["ok"]:
                    n1 = max(10, int(pr["report"]["updates_per_sec"] * a.seconds))
                else:
                    single_info = {"ok": False, "why": "probe " + pr["why"]}
            if n1:
                runs = []
                for r in range(a.repeat):
                    x = runner.run(f"single_1x{T}", single_cmd(T, n1))
                    if x["ok"]:
                        x["report"]["agent_updates_per_sec"] = x["report"]["updates_per_sec"]
                    runs.append(x)
                one = med(runs)
                single_info = {"1xT": one}
                if not gpu and T > 1:
                    runs = []
                    nT = n1 if a.updates else max(10, n1 // T)
                    env1 = dict(env, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
                    for r in range(a.repeat):
                        saved, runner.env = runner.env, env1
                        hs = [runner.start(f"single_{T}x1_p{i}", single_cmd(1, nT)) for i in range(T)]
                        runner.env = saved
                        res = [runner.finish(h) for h in hs]
                        if all(x["ok"] for x in res):
                            rates = [x["report"]["updates_per_sec"] for x in res]
                            runs.append({"ok": True, "cmd": res[0]["cmd"] + f"  (x{T} at once)",
                                         "report": {"agent_updates_per_sec": T * min(rates),
                                                    "per_process": rates, "updates_per_sec": min(rates),
                                                    "torch": res[0]["report"].get("torch")}})
                        else:
                            runs.append(next(x for x in res if not x["ok"]))
                    single_info["Tx1"] = med(runs)
        for A in agents:
            if not single_info.get("1xT"):
                cells["single"][A] = {"ok": False, "why": single_info.get("why", "?"),
                                      "missing": single_info.get("missing", False)}
                continue
            cands = []
            one = single_info["1xT"]
            if one["ok"]:
                cands.append((one["report"]["agent_updates_per_sec"], f"1x{T}" if not gpu else "1 proc", one))
            many = single_info.get("Tx1")
            if many and many["ok"]:
                r = many["report"]["updates_per_sec"]
                procs = min(A, T)
                eff = A / math.ceil(A / T) * r
                cands.append((eff, f"{procs}x1", many))
            if not cands:
                cells["single"][A] = {"ok": False, "why": one.get("why", "?")}
                continue
            v, how, src = max(cands, key=lambda c: c[0])
            cells["single"][A] = {"ok": True, "agent_updates_per_sec": v, "how": how, "cmd": src["cmd"],
                                  "report": src["report"]}
        for k, v in single_info.items():
            if isinstance(v, dict):
                print(f"single {k:10s} " + (f"{v['report']['agent_updates_per_sec']:10.1f} agent-updates/s"
                                            if v.get("ok") else f"FAILED ({v.get('why')})"), flush=True)
        return single_info

    # ---- pgser: the stacked agent of pgser-train ----------------------------------------------------
    def run_pgser(cells, peer="pgser"):
        dev = "cpu-burn" if peer == "pgser-burn" else a.pgser_device or ("cuda" if gpu else "cpu")
        for A in agents:
            if not Path(a.pgser).exists():
                cells[peer][A] = {"ok": False, "why": f"{a.pgser} not built", "missing": True}
                continue
            base = [a.pgser, "bench", "--task", a.task, "--algo", a.algo, "--agents", str(A), "--batch-size",
                    str(a.batch_size), "--hidden", str(a.hidden), "--threads", t, "--device", dev, "--json"]
            n = a.updates
            if not n:  # probe the rate for --seconds
                pr = runner.run(f"{peer}_probe_A{A}", [*base, "--updates", "3", "--warmup", "1"])
                n = max(3, int(pr["report"]["updates_per_sec"] * a.seconds)) if pr["ok"] else None
                if not pr["ok"]:
                    cells[peer][A] = pr
                    continue
            runs = [runner.run(f"{peer}_A{A}", [*base, "--updates", str(n), "--warmup", str(a.warmup)])
                    for _ in range(a.repeat)]
            x = med(runs)
            if x["ok"]:
                x["agent_updates_per_sec"] = x["report"]["agent_updates_per_sec"]
            cells[peer][A] = x
            print(f"{peer:14s} A={A:<4d} " + (f"{x['agent_updates_per_sec']:10.1f} agent-updates/s"
                                                if x["ok"] else f"FAILED ({x['why']})"), flush=True)

    # ---- many-agent peers -------------------------------------------------------------------------
    def run_many(cells, p):
        fw = "jax" if p == "jax" else "torch"
        for A in agents:
            if missing.get(fw):
                cells[p][A] = {"ok": False, "why": missing[fw], "missing": True}
                continue
            common = [*dims, "--hidden", str(a.hidden), "--agents", str(A), *length, "--warmup", str(a.warmup),
                      "--threads", t, "--json"]
            if p == "jax":
                cmd = [jpy, str(HERE / "train_peer_jax.py"), *common, "--device", "gpu" if gpu else "cpu"]
                if a.jax_pin:
                    cmd.append("--pin")
            else:
                cmd = [py, str(HERE / "train_peer_stacked.py"), *common, "--device", a.device,
                       "--mode", "vmap" if p == "stacked-vmap" else "bmm"]
                if p == "stacked-graph":
                    cmd.append("--cuda-graph")
            if a.tf32 and gpu and p != "single":
                cmd.append("--tf32")
            runs = [runner.run(f"{p}_A{A}", cmd) for _ in range(a.repeat)]
            x = med(runs)
            if x["ok"]:
                x["agent_updates_per_sec"] = x["report"]["agent_updates_per_sec"]
            cells[p][A] = x
            print(f"{p:14s} A={A:<4d} " + (f"{x['agent_updates_per_sec']:10.1f} agent-updates/s"
                                          if x["ok"] else f"FAILED ({x['why']})"), flush=True)

    # ---- rounds -------------------------------------------------------------------------------
    # Each round measures every peer and A once, the peers in a rotated order, so that a machine
    # whose speed drifts from minute to minute (shared hosts do) does not favour whichever peer
    # runs first; each cell shows the median over the rounds.
    passes = []
    for r in range(a.rounds):
        order = peers[r % len(peers):] + peers[:r % len(peers)]
        if a.rounds > 1:
            print(f"round {r + 1}/{a.rounds}: {', '.join(order)}", flush=True)
        got: dict[str, dict[int, dict]] = {p: {} for p in peers}
        info = {}
        for p in order:
            if p == "single":
                info = run_single(got)
            elif p in ("pgser", "pgser-burn"):
                run_pgser(got, p)
            else:
                run_many(got, p)
        passes.append((got, info))
    cells: dict[str, dict[int, dict]] = {p: {} for p in peers}
    for p in peers:
        for A in agents:
            runs = [got[p][A] for got, _ in passes if A in got[p]]
            ok = sorted((x for x in runs if x.get("ok")), key=lambda x: x["agent_updates_per_sec"])
            if not ok:
                cells[p][A] = runs[-1]
                continue
            cells[p][A] = dict(ok[len(ok) // 2])
            cells[p][A]["rounds"] = [x["agent_updates_per_sec"] for x in runs if x.get("ok")]
    single_info = passes[0][1] if a.rounds == 1 else {"rounds": [info for _, info in passes]}
    load_after = os.getloadavg()
    sgemm_after = sgemm_figure()
    sgemm = max([x for x in (sgemm_before, sgemm_after) if x is not None], default=None)

    # ---- table --------------------------------------------------------------------------------
    gpu_name = None
    for p in peers:
        for c in cells[p].values():
            if c.get("ok") and c.get("report", {}).get("gpu"):
                gpu_name = c["report"]["gpu"]
    print()
    print(f"agent-updates/s (GFLOP/s) — {a.task} {a.algo}, batch {a.batch_size}/agent, hidden {a.hidden}, "
          f"{flops / 1e9:.3f} GFLOP per agent-update (train_flops.py), device {a.device}"
          + (f" ({gpu_name})" if gpu_name else f", {T} threads")
          + (f", {a.updates} updates" if a.updates else f", ~{a.seconds:g} s per run")
          + (f", median of {a.rounds} rounds" if a.rounds > 1 else ""))
    print(f"machine: {os.cpu_count()} cores, load {load_before[0]:.2f} before / {load_after[0]:.2f} after; "
          f"torch python {py}; jax python {jpy}")
    if sgemm:
        print(f"sgemm figure at {T} threads (sgemm_peak.py): {sgemm_before or 0:.0f} before / {sgemm_after or 0:.0f} "
              f"after; cells give % of {sgemm:.0f} GFLOP/s")
    w = 22
    hdr = f"{'A':>4s}  " + "".join(f"{LABELS[p]:>{w}s}" for p in peers)
    print(hdr)
    print("-" * len(hdr))

    def cell(c):
        if not c:
            return "-"
        if not c.get("ok"):
            why = c.get("why", "")
            short = "missing" if c.get("missing") else ("timeout" if "timed out" in why else "FAILED")
            return short
        v = c["agent_updates_per_sec"]
        s = f"{v:,.0f} ({v * flops / 1e9:,.0f})" if v >= 100 else f"{v:,.1f} ({v * flops / 1e9:,.1f})"
        if sgemm:
            s += f" {100 * v * flops / 1e9 / sgemm:.0f}%"
        if c.get("how"):
            s = f"{c['how']} {s}"
        return s

    for A in agents:
        print(f"{A:>4d}  " + "".join(f"{cell(cells[p].get(A)):>{w}s}" for p in peers))
    if a.rounds > 1:
        print(f"medians of {a.rounds} rounds; each round's figure, in round order:")
        for A in agents:
            figs = lambda c: "/".join(f"{v:.0f}" if v >= 100 else f"{v:.1f}" for v in (c or {}).get("rounds", []))
            print(f"{A:>4d}  " + "".join(f"{figs(cells[p].get(A)) or '-':>{w}s}" for p in peers))
    fails = {(p, A): c["why"] for p in peers for A, c in cells[p].items() if not c.get("ok")}
    seen = set()
    for (p, A), why in fails.items():
        if (p, why) in seen:
            continue
        seen.add((p, why))
        print(f"note: {LABELS[p]} A={A}: {why}")
    if "single" in peers and not gpu:
        print(f"note: single = the faster of 1 process x {T} threads and min(A, {T}) processes x 1 thread "
              f"(label in the cell); independent of A but for the process split")

    if a.json:
        doc = {"device": a.device, "task": a.task, "algo": a.algo, "batch_size": a.batch_size, "hidden": a.hidden,
               "threads": T, "seconds": a.seconds, "updates": a.updates, "warmup": a.warmup, "agents": agents,
               "rounds": a.rounds,
               "peers": peers, "flops_per_update": flops, "python": py, "jax_python": jpy,
               "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform(), "gpu": gpu_name,
                           "loadavg_before": load_before, "loadavg_after": load_after},
               "single_measurements": single_info,
               "sgemm_gflops": {"before": sgemm_before, "after": sgemm_after},
               "cells": {p: {str(A): c for A, c in cells[p].items()} for p in peers}}
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps(doc, indent=2, default=str) + "\n")
        print(f"wrote {a.json}")


if __name__ == "__main__":
    main()
