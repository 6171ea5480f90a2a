#!/usr/bin/env python3
"""Benchmark `pgser-etl score` (goal-swap + twin-critic scoring, PGSER Alg. 2 step 2) against a
numpy/PyTorch/pyarrow peer (score_peer.py) doing the same job on the same inputs.

Inputs (built once, then reused from --workdir; delete them to rebuild):
  traj.parquet   pgser-etl collect --task FetchPush --policy random --episodes 2500 --seed 0
  q.ckpt         pgser-train --data traj.parquet --updates 20 --eval-episodes 0      (hidden 256 x 3,
                 the real size: the weights are barely trained, which does not change the cost)
  q_h32.ckpt     the same with --hidden 32: a critic ~45x cheaper, for the critic-only figure
Each timed command runs under `/usr/bin/time -v` (max RSS, CPU, elapsed from there), R times per
side in alternating order so drift in machine load hits both sides alike; the inputs are read once
untimed first (warm page cache for everyone; the cache cannot be dropped here) and each run's
output is deleted + sync'd, untimed, before the next run.

Figures:
  rows/s (in-process): rows / the seconds each side reports itself (pgser's --json `seconds`,
      from the start of `score` to the closed output; the peer's, from before the checkpoint and
      table are read to the closed output). Interpreter/process start is outside it.
  rows/s (wall): rows / wall time of the whole child, start-up and imports included.
  the ratio pgser/peer on both.
  critic GFLOP/s. FLOPs per row = 2 critics x sum over layers of 2·in·out (a multiply-add is 2
      FLOPs; biases, ReLU, min are not counted), read from the checkpoint's shapes; for FetchPush
      with hidden 256 that is 2·2·(32·256 + 256·256 + 256·256 + 256·1) = 558,080.
      - pgser end to end: rows/s (in-process) x FLOPs/row: a lower bound for the critic alone;
      - pgser critic-only: there is no subcommand that times pgser's critic alone (pgser-train
        has `bench`: a training update, and `bench-sampler`), so it is estimated by subtraction:
        Δ = median seconds(q.ckpt) - median seconds(q_h32.ckpt), same table, K, seed, threads, so
        the swap, reading, writing and the bookkeeping cancel, and critic rows/s = rows / Δ. The
        h32 critic's own time is subtracted too (its FLOPs are ~2% of the big one's), so this
        slightly overstates the big critic's speed;
      - the peer's critic: rows / its timed torch loop (critic_seconds), for comparison.
  peak: from lscpu: cores x FMA units per core x f32 lanes x 2 FLOPs x GHz. Lanes: 16 with
      avx512f, 8 with avx2+fma. FMA units: an ASSUMPTION, 2 per core for an AVX-512 Xeon (true of
      Xeon Gold/Platinum Skylake-SP and later; some Silver/Bronze parts have 1), 2 for AVX2 cores.
      GHz: lscpu's "CPU max MHz" when it is there; in a VM it often is not, and then the nominal
      clock (/proc/cpuinfo "cpu MHz", i.e. the TSC) is used: the real all-core (turbo) clock may be
      higher, and heavy AVX-512 code may run slower, so the fraction of peak is approximate.
      --measure-peak checks both: a small C program (gcc, AVX-512 only) times a dependent imul chain
      (3 cycles per imul -> the real clock) and 16 independent zmm FMA chains (-> FMAs/cycle) on T
      cores at once, and the fractions of that measured peak are printed too.

Machine load: another job on a 2-core machine ruins the figures (torch's OpenMP threads spin at
barriers and lose whole time slices). Before each run the driver samples /proc/stat for 1 s and
waits (up to --quiet-wait s) until the machine is quieter than --quiet-below busy cores; during
each run it measures the CPU time others used (machine busy CPU-s minus the child's) and re-runs
a run where that exceeds --max-foreign cores (up to --retries times). The 1/5/15-minute load
averages are printed with every run. OMP_WAIT_POLICY from the caller's environment is passed to
both children (PASSIVE makes torch sleep instead of spin; leave it unset on an idle machine).

Threads: --threads T on both command lines (pgser's rayon pool; the peer's torch.set_num_threads
and pyarrow's CPU pool) and RAYON_NUM_THREADS=OMP_NUM_THREADS=MKL_NUM_THREADS=T in the env.

Usage:
    bench_score.py [--pgser-etl target/release/pgser-etl] [--pgser-train target/release/pgser-train]
                   [--python bench-out/torch-venv/bin/python] [--workdir bench-out/score]
                   [--episodes 2500] [--swaps 4] [--threads 2] [--repeat 3] [--seed 0]
                   [--no-tiny] [--measure-peak] [--peer-arg ARG ...] [--pgser-arg ARG ...]
                   [--json OUT.json]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import statistics
import struct
import subprocess
import sys
import time
from pathlib import Path

import peer_python

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
MiB = 1 << 20
CLK_TCK = os.sysconf("SC_CLK_TCK")


# ---- machine -------------------------------------------------------------------------------

def cpu_jiffies():
    """(busy, total) jiffies over all CPUs from /proc/stat (guest time is inside user)."""
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:]]
    idle = v[3] + (v[4] if len(v) > 4 else 0)  # idle + iowait
    total = sum(v[:8])  # user nice system idle iowait irq softirq steal
    return total - idle, total


def busy_cores(seconds=1.0):
    b0, _ = cpu_jiffies()
    time.sleep(seconds)
    b1, _ = cpu_jiffies()
    return (b1 - b0) / CLK_TCK / seconds


def wait_quiet(below, max_wait):
    """Wait until the machine uses fewer than `below` cores; return (busy, waited s)."""
    t0 = time.perf_counter()
    while True:
        b = busy_cores(1.0)
        if b < below or time.perf_counter() - t0 >= max_wait:
            return b, time.perf_counter() - t0


def lscpu():
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return {}
    d = {}
    for line in out.splitlines():
        k, _, v = line.partition(":")
        d[k.strip()] = v.strip()
    return d


def peak(threads):
    info = lscpu()
    flags = set(info.get("Flags", "").split())
    model = info.get("Model name", platform.processor())
    sockets = int(info.get("Socket(s)", "1") or 1)
    cores = int(info.get("Core(s) per socket", "0") or 0) * sockets or os.cpu_count()
    if info.get("CPU max MHz"):
        mhz, mhz_from = float(info["CPU max MHz"]), "lscpu CPU max MHz"
    else:
        mhz, mhz_from = None, None
        try:
            for line in open("/proc/cpuinfo"):
                if line.startswith("cpu MHz"):
                    mhz, mhz_from = float(line.split(":")[1]), "/proc/cpuinfo cpu MHz (nominal/TSC; lscpu gives no max MHz here)"
                    break
        except OSError:
            pass
    if "avx512f" in flags:
        isa, lanes, fma_units = "AVX-512", 16, 2
        fma_note = "2 AVX-512 FMA units per core ASSUMED (Xeon Gold/Platinum class; some Silver/Bronze have 1)"
    elif "avx2" in flags and "fma" in flags:
        isa, lanes, fma_units = "AVX2+FMA", 8, 2
        fma_note = "2 FMA units per core ASSUMED (Haswell and later)"
    else:
        isa, lanes, fma_units, fma_note = "SSE", 4, 1, "no FMA: 1 add + 1 mul pipe counted as 1 FMA unit"
    ghz = (mhz or 0) / 1000
    per_core = fma_units * lanes * 2 * ghz
    return {"model": model, "family": info.get("CPU family"), "model_number": info.get("Model"),
            "hypervisor": info.get("Hypervisor vendor"), "cores": cores, "ghz": ghz, "ghz_from": mhz_from,
            "isa": isa, "lanes_f32": lanes, "fma_units_per_core": fma_units, "fma_note": fma_note,
            "flags": sorted(flags & {"avx512f", "avx2", "fma", "avx512_bf16", "avx512_fp16", "amx_tile"}),
            "gflops_per_core": per_core, "gflops_machine": per_core * cores,
            "gflops_threads": per_core * min(threads, cores)}


CLOCK_C = r"""
// Effective core clock from a dependent imul chain (3-cycle latency on Intel cores since
// Nehalem), and AVX-512 FMA throughput on one core (16 independent zmm accumulators, asm).
#include <stdio.h>
#include <time.h>
static double now(){struct timespec t;clock_gettime(CLOCK_MONOTONIC,&t);return t.tv_sec+t.tv_nsec*1e-9;}
int main(){
  long n=600000000L; long x=3, y=1;
  double t0=now();
  for(long i=0;i<n;i+=4){ __asm__ volatile("imul %1,%0\n\timul %1,%0\n\timul %1,%0\n\timul %1,%0":"+r"(x):"r"(y)); }
  double ghz = n*3.0/(now()-t0)/1e9;
  long m=100000000L; t0=now();
  for(long i=0;i<m;i++){
    __asm__ volatile(
#define F(k) "vfmadd231ps %%zmm30,%%zmm31,%%zmm" #k "\n\t"
      F(0) F(1) F(2) F(3) F(4) F(5) F(6) F(7) F(8) F(9) F(10) F(11) F(12) F(13) F(14) F(15)
      ::: "xmm0","xmm1","xmm2","xmm3","xmm4","xmm5","xmm6","xmm7","xmm8","xmm9","xmm10","xmm11",
          "xmm12","xmm13","xmm14","xmm15");
  }
  double gf=m*16.0*16*2/(now()-t0)/1e9;
  printf("{\"ghz\": %.4f, \"fma_gflops\": %.2f, \"fma_per_cycle\": %.3f}\n", ghz, gf, gf/32/ghz);
  return 0;
}
"""


def measure_peak(work: Path, threads: int):
    """Run the clock/FMA microbenchmark on `threads` cores at once (gcc needed; AVX-512 only)."""
    src, exe = work / "peak_fma.c", work / "peak_fma"
    src.write_text(CLOCK_C)
    try:
        subprocess.run(["gcc", "-O2", "-mavx512f", "-o", str(exe), str(src)], check=True, capture_output=True)
        procs = [subprocess.Popen([str(exe)], stdout=subprocess.PIPE, text=True) for _ in range(threads)]
        res = [json.loads(p.communicate()[0]) for p in procs]
    except (OSError, subprocess.CalledProcessError, json.JSONDecodeError) as e:
        return {"error": str(e)}
    return {"per_core": res, "ghz_mean": statistics.mean(r["ghz"] for r in res),
            "fma_per_cycle_mean": statistics.mean(r["fma_per_cycle"] for r in res),
            "gflops_total": sum(r["fma_gflops"] for r in res)}


# ---- checkpoint ----------------------------------------------------------------------------

def critic_flops(ckpt: Path):
    """FLOPs per row of min(Q1, Q2): 2 critics x sum of 2·in·out over their Linear layers."""
    raw = open(ckpt, "rb").read(1 << 20)
    (n,) = struct.unpack("<Q", raw[:8])
    if n + 8 > len(raw):
        raw = open(ckpt, "rb").read(8 + n)
    header = json.loads(raw[8:8 + n])
    header.pop("__metadata__", None)
    total, shapes = 0, {}
    for c in ("critic1", "critic2"):
        k = 0
        while f"{c}.{k}.weight" in header:
            out, inp = header[f"{c}.{k}.weight"]["shape"]
            total += 2 * inp * out
            shapes.setdefault(c, []).append([inp, out])
            k += 2
    return total, shapes["critic1"]


# ---- runs ----------------------------------------------------------------------------------

def parse_time_v(text: str) -> dict:
    """The figures GNU time -v prints on stderr (the last block of them)."""
    keys = {"Maximum resident set size (kbytes)": "max_rss_kib", "User time (seconds)": "user_s",
            "System time (seconds)": "sys_s", "Percent of CPU this job got": "cpu_percent",
            "Elapsed (wall clock) time (h:mm:ss or m:ss)": "elapsed", "Exit status": "exit_status"}
    res = {}
    for line in text.splitlines():
        k, _, v = line.strip().rpartition(": ")
        if k in keys:
            res[keys[k]] = v
    out = {}
    if "max_rss_kib" in res:
        out["max_rss_mib"] = int(res["max_rss_kib"]) / 1024
    for k in ("user_s", "sys_s"):
        if k in res:
            out[k] = float(res[k])
    if "cpu_percent" in res:
        out["cpu_percent"] = float(res["cpu_percent"].rstrip("%") or "nan")
    if "elapsed" in res:
        parts = [float(p) for p in res["elapsed"].split(":")]
        s = 0.0
        for p in parts:
            s = s * 60 + p
        out["time_elapsed_s"] = s
    return out


def tail(path: Path, n=30):
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""


def run_timed(cmd, env, out_path: Path, err_path: Path) -> dict:
    full = ["/usr/bin/time", "-v", *cmd]
    b0, _ = cpu_jiffies()
    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(full, stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env)
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    b1, _ = cpu_jiffies()
    res = {"rc": os.waitstatus_to_exitcode(status), "wall_s": wall}
    res.update(parse_time_v(err_path.read_text(errors="replace")))
    cpu = res.get("user_s", ru.ru_utime) + res.get("sys_s", ru.ru_stime)
    res["cpu_s"] = cpu
    res["cores_busy"] = cpu / wall if wall > 0 else float("nan")
    # CPU others used while the child ran, in cores (jiffy granularity: +-0.01 s per CPU).
    res["foreign_cores"] = max(0.0, ((b1 - b0) / CLK_TCK - cpu) / wall) if wall > 0 else float("nan")
    res["loadavg"] = os.getloadavg()
    return res


def median(xs):
    xs = [x for x in xs if x is not None]
    return statistics.median(xs) if xs else float("nan")


def ensure_inputs(args, work: Path, env):
    traj, q, tiny = work / "traj.parquet", work / "q.ckpt", work / "q_h32.ckpt"
    built = {}
    steps = [
        (traj, [args.pgser_etl, "collect", "--task", "FetchPush", "--policy", "random",
                "--episodes", str(args.episodes), "--seed", "0", "-o", str(traj)]),
        (q, [args.pgser_train, "--data", str(traj), "-o", str(q), "--updates", "20", "--eval-episodes", "0",
             "--threads", str(args.threads)]),
    ]
    if not args.no_tiny:
        steps.append((tiny, [args.pgser_train, "--data", str(traj), "-o", str(tiny), "--updates", "20",
                             "--eval-episodes", "0", "--hidden", "32", "--threads", str(args.threads)]))
    for path, cmd in steps:
        if path.is_file():
            print(f"using cached {path}")
        else:
            print(f"building {path}: {shlex.join(cmd)}", flush=True)
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, env=env, stdout=subprocess.DEVNULL)
            print(f"  done in {time.perf_counter() - t0:.1f} s", flush=True)
        built[path.name] = shlex.join(cmd)
    return traj, q, tiny, built


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pgser-etl", default=str(REPO / "target" / "release" / "pgser-etl"))
    ap.add_argument("--pgser-train", default=str(REPO / "target" / "release" / "pgser-train"))
    ap.add_argument("--python", help="the peer's interpreter (torch, numpy, pyarrow; default bench-out/torch-venv)")
    ap.add_argument("--workdir", default=str(REPO / "bench-out" / "score"),
                    help="inputs, outputs and logs (bench-logs/) (default <repo>/bench-out/score)")
    ap.add_argument("--episodes", type=int, default=2500)
    ap.add_argument("--swaps", type=int, default=4, help="K, both sides")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-tiny", action="store_true", help="skip the --hidden 32 runs (no critic-only figure)")
    ap.add_argument("--quiet-below", type=float, default=0.3,
                    help="before a run, wait until the machine uses fewer cores than this (default 0.3)")
    ap.add_argument("--quiet-wait", type=float, default=300, help="longest wait for that, s (default 300)")
    ap.add_argument("--max-foreign", type=float, default=0.25,
                    help="re-run a run during which others used more cores than this (default 0.25)")
    ap.add_argument("--retries", type=int, default=3, help="re-runs per run at most (default 3)")
    ap.add_argument("--peer-arg", action="append", default=[], help="extra argument for score_peer.py")
    ap.add_argument("--pgser-arg", action="append", default=[], help="extra argument for pgser-etl score")
    ap.add_argument("--keep-outputs", action="store_true")
    ap.add_argument("--measure-peak", action="store_true",
                    help="also measure the clock (dependent imul chain) and the AVX-512 FMA rate on T cores at "
                         "once with a small C program (gcc), and give fractions of that measured peak too")
    ap.add_argument("--json", help="also write everything to this JSON file")
    args = ap.parse_args(argv)

    args.pgser_etl, args.pgser_train = (str(Path(b).resolve()) for b in (args.pgser_etl, args.pgser_train))
    for b in (args.pgser_etl, args.pgser_train):
        if not os.access(b, os.X_OK):
            sys.exit(f"{b} is not executable (cargo build --release)")
    args.python = peer_python.resolve(args.python, "torch numpy pyarrow")
    work = Path(args.workdir).resolve()
    logs = work / "bench-logs"
    logs.mkdir(parents=True, exist_ok=True)
    t = str(args.threads)
    env = dict(os.environ, RAYON_NUM_THREADS=t, OMP_NUM_THREADS=t, MKL_NUM_THREADS=t)

    traj, q, tiny, built = ensure_inputs(args, work, env)
    for p in (traj, q, tiny):
        if p.is_file():
            subprocess.run(["cat", str(p)], stdout=subprocess.DEVNULL, check=True)  # warm the cache

    outs = {"pgser": work / "out_pgser.parquet", "peer": work / "out_peer.parquet",
            "pgser_h32": work / "out_pgser_h32.parquet"}
    common = ["--swaps", str(args.swaps), "--seed", str(args.seed), "--threads", t]
    cmds = {
        "pgser": [args.pgser_etl, "score", "--q", str(q), "--data", str(traj), "-o", str(outs["pgser"]),
                  *common, "--json", *args.pgser_arg],
        "peer": [args.python, str(HERE / "score_peer.py"), "--q", str(q), "--data", str(traj),
                 "-o", str(outs["peer"]), *common, *args.peer_arg],
        "pgser_h32": [args.pgser_etl, "score", "--q", str(tiny), "--data", str(traj), "-o", str(outs["pgser_h32"]),
                      *common, "--json", *args.pgser_arg],
    }
    sides = ["pgser", "peer"] + ([] if args.no_tiny else ["pgser_h32"])

    load_before = os.getloadavg()
    runs = {s: [] for s in sides}
    rejected = []
    for r in range(args.repeat):
        order = sides if r % 2 == 0 else sides[::-1]
        for side in order:
            for attempt in range(args.retries + 1):
                outs[side].unlink(missing_ok=True)
                os.sync()
                busy_before, waited = wait_quiet(args.quiet_below, args.quiet_wait)
                out, err = logs / f"{side}_{r}.out", logs / f"{side}_{r}.err"
                m = run_timed(cmds[side], env, out, err)
                rep = peer_python.last_json(out.read_text(errors="replace"), "rows_per_sec")
                if m["rc"] != 0 or rep is None:
                    print(f"\n{side} failed (exit {m['rc']}): {shlex.join(cmds[side])}\n--- stdout\n{tail(out)}\n"
                          f"--- stderr\n{tail(err)}", file=sys.stderr)
                    sys.exit(1)
                m.update(run=r, attempt=attempt, busy_before=busy_before, waited_s=waited, report=rep,
                         output_bytes=outs[side].stat().st_size)
                la = m["loadavg"]
                print(f"  run {r + 1}/{args.repeat} {side:10s}: {rep['rows_per_sec']:9.0f} rows/s in-process "
                      f"({rep['seconds']:6.2f} s), wall {m['wall_s']:6.2f} s, max RSS {m.get('max_rss_mib', 0):6.0f} MiB, "
                      f"cores busy {m['cores_busy']:4.2f}, others {m['foreign_cores']:4.2f} cores "
                      f"(before: {busy_before:4.2f}{f', waited {waited:.0f} s' if waited > 1.5 else ''}), "
                      f"load {la[0]:.2f} {la[1]:.2f} {la[2]:.2f}", flush=True)
                if m["foreign_cores"] <= args.max_foreign or attempt == args.retries:
                    if m["foreign_cores"] > args.max_foreign:
                        print(f"    (kept although others used {m['foreign_cores']:.2f} cores: out of retries)")
                    runs[side].append(m)
                    break
                print(f"    others used {m['foreign_cores']:.2f} cores during it > {args.max_foreign}: re-running")
                rejected.append(m)
    load_after = os.getloadavg()

    # Same job? Check pgser's q and reward with the peer's code, compare schemas and summaries.
    vout = logs / "verify.out"
    with open(vout, "wb") as f:
        subprocess.run([args.python, str(HERE / "score_peer.py"), "--q", str(q), "--verify", str(outs["pgser"]),
                        "--against", str(outs["peer"]), "--threads", t], stdout=f, stderr=subprocess.STDOUT, env=env)
    check = peer_python.last_json(vout.read_text(errors="replace"), "q_max_abs_diff")
    if not args.keep_outputs:
        for p in outs.values():
            p.unlink(missing_ok=True)

    def summary(side):
        rs = runs[side]
        return {
            "rows": rs[-1]["report"]["rows"],
            "rows_per_sec_median": median([x["report"]["rows_per_sec"] for x in rs]),
            "rows_per_sec_all": [x["report"]["rows_per_sec"] for x in rs],
            "seconds_median": median([x["report"]["seconds"] for x in rs]),
            "wall_s_median": median([x["wall_s"] for x in rs]),
            "wall_s_all": [x["wall_s"] for x in rs],
            "wall_rows_per_sec_median": median([x["report"]["rows"] / x["wall_s"] for x in rs]),
            "max_rss_mib_median": median([x.get("max_rss_mib") for x in rs]),
            "cpu_s_median": median([x["cpu_s"] for x in rs]),
            "cores_busy_median": median([x["cores_busy"] for x in rs]),
            "foreign_cores_max": max(x["foreign_cores"] for x in rs),
            "output_mb": rs[-1]["output_bytes"] / 1e6,
            "critic_seconds_median": median([x["report"].get("critic_seconds") for x in rs]),
        }

    s = {side: summary(side) for side in sides}
    rows = s["pgser"]["rows"]
    ratio = s["pgser"]["rows_per_sec_median"] / s["peer"]["rows_per_sec_median"]
    ratio_wall = s["peer"]["wall_s_median"] / s["pgser"]["wall_s_median"]
    flops, shapes = critic_flops(q)
    pk = peak(args.threads)
    if args.measure_peak:
        busy_before, _ = wait_quiet(args.quiet_below, args.quiet_wait)
        pk["measured"] = mp = measure_peak(work, args.threads)
        mp["busy_before"] = busy_before
    g = {"flops_per_row": flops, "critic_layers_in_out": shapes}
    g["pgser_end_to_end_gflops"] = s["pgser"]["rows_per_sec_median"] * flops / 1e9
    peer_rep = [x["report"] for x in runs["peer"]]
    g["peer_critic_rows_per_sec"] = median([x["rows"] / x["critic_seconds"] for x in peer_rep])
    g["peer_critic_gflops"] = g["peer_critic_rows_per_sec"] * flops / 1e9
    if not args.no_tiny:
        tflops, _ = critic_flops(tiny)
        delta = s["pgser"]["seconds_median"] - s["pgser_h32"]["seconds_median"]
        g.update(tiny_flops_per_row=tflops, critic_delta_s=delta)
        if delta > 0:
            g["pgser_critic_rows_per_sec"] = rows / delta
            g["pgser_critic_gflops"] = rows / delta * flops / 1e9
    for k in ("pgser_end_to_end_gflops", "pgser_critic_gflops", "peer_critic_gflops"):
        if k in g and pk["gflops_threads"] > 0:
            g[k.replace("gflops", "fraction_of_peak")] = g[k] / pk["gflops_threads"]
        if k in g and pk.get("measured", {}).get("gflops_total"):
            g[k.replace("gflops", "fraction_of_measured_peak")] = g[k] / pk["measured"]["gflops_total"]

    def versions():
        v = {"python_driver": platform.python_version(), "platform": platform.platform()}
        for name, b in (("pgser-etl", args.pgser_etl),):
            try:
                v[name] = subprocess.run([b, "--version"], capture_output=True, text=True).stdout.strip()
            except OSError:
                pass
        try:
            import hashlib
            h = hashlib.sha256()
            with open(args.pgser_etl, "rb") as f:
                for block in iter(lambda: f.read(1 << 20), b""):
                    h.update(block)
            v["pgser-etl binary"] = (f"sha256 {h.hexdigest()[:16]}, built "
                                     f"{time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(os.path.getmtime(args.pgser_etl)))}")
        except OSError:
            pass
        try:
            v["git"] = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"],
                                      capture_output=True, text=True).stdout.strip()
        except OSError:
            pass
        pr = runs["peer"][-1]["report"]
        v.update({k: pr.get(k) for k in ("torch", "numpy", "pyarrow")})
        return v

    ver = versions()
    print()
    print(f"pgser-etl score vs numpy/torch/pyarrow peer — FetchPush, {args.episodes} episodes, K={args.swaps} swaps, "
          f"{rows:,} rows, {args.threads} threads, {args.repeat} runs per side (alternating order)")
    print(f"machine: {pk['model']} (family {pk['family']} model {pk['model_number']}, {pk['hypervisor'] or 'bare'}), "
          f"{pk['cores']} cores; load avg {load_before[0]:.2f}/{load_before[1]:.2f}/{load_before[2]:.2f} before, "
          f"{load_after[0]:.2f}/{load_after[1]:.2f}/{load_after[2]:.2f} after; OMP_WAIT_POLICY="
          f"{env.get('OMP_WAIT_POLICY', '(unset)')}; {len(rejected)} run(s) re-run for foreign load")
    hdr = (f"{'':16s}{'rows/s':>10s}{'(min..max)':>20s}{'in-proc s':>10s}{'wall s':>8s}{'rows/s wall':>12s}"
           f"{'max RSS MiB':>12s}{'CPU s':>7s}{'busy':>6s}{'others':>7s}{'out MB':>8s}")
    print(hdr)
    print("-" * len(hdr))
    labels = {"pgser": "pgser-etl", "peer": "python peer", "pgser_h32": "pgser (h32)"}
    for side in sides:
        x = s[side]
        a = x["rows_per_sec_all"]
        print(f"{labels[side]:16s}{x['rows_per_sec_median']:10.0f}{f'({min(a):.0f}..{max(a):.0f})':>20s}"
              f"{x['seconds_median']:10.2f}{x['wall_s_median']:8.2f}{x['wall_rows_per_sec_median']:12.0f}"
              f"{x['max_rss_mib_median']:12.0f}{x['cpu_s_median']:7.2f}{x['cores_busy_median']:6.2f}"
              f"{x['foreign_cores_max']:7.2f}{x['output_mb']:8.1f}")
    print(f"ratio pgser/peer: {ratio:.2f}x rows/s in-process, {ratio_wall:.2f}x by wall time (>1: pgser faster)")
    pp = median([x["read_seconds"] for x in peer_rep]), median([x["swap_seconds"] for x in peer_rep]), \
        median([x["normalize_seconds"] for x in peer_rep]), median([x["critic_seconds"] for x in peer_rep]), \
        median([x["write_seconds"] for x in peer_rep])
    print(f"peer phases (median s): read {pp[0]:.2f}, swap {pp[1]:.2f}, normalize {pp[2]:.2f}, "
          f"critic {pp[3]:.2f}, write {pp[4]:.2f}")
    print()
    print(f"critic FLOPs/row: {flops:,} = 2 critics x sum 2·in·out over layers {shapes}")
    print(f"peak: {pk['cores']} cores x {pk['fma_units_per_core']} FMA units x {pk['lanes_f32']} f32 lanes ({pk['isa']}) "
          f"x 2 x {pk['ghz']:.2f} GHz = {pk['gflops_machine']:.1f} GFLOP/s machine, "
          f"{pk['gflops_threads']:.1f} for {min(args.threads, pk['cores'])} thread(s)")
    print(f"  clock from {pk['ghz_from']}; {pk['fma_note']}")
    mp = pk.get("measured")
    if mp and "gflops_total" in mp:
        print(f"  measured (--measure-peak, {args.threads} copies at once): clock {mp['ghz_mean']:.2f} GHz from a dependent "
              f"imul chain, {mp['fma_per_cycle_mean']:.2f} zmm FMAs/cycle/core -> {mp['gflops_total']:.1f} GFLOP/s "
              f"on {args.threads} core(s); 'meas.' below is the fraction of that")
    elif mp:
        print(f"  --measure-peak failed: {mp.get('error')}")
    fm = lambda k: (f", {100 * g[k]:.1f}% of meas." if k in g else "")
    print(f"pgser end to end:   {g['pgser_end_to_end_gflops']:7.1f} GFLOP/s "
          f"({100 * g.get('pgser_end_to_end_fraction_of_peak', float('nan')):.1f}% of peak"
          f"{fm('pgser_end_to_end_fraction_of_measured_peak')}; lower bound for the critic)")
    if "pgser_critic_gflops" in g:
        print(f"pgser critic only:  {g['pgser_critic_gflops']:7.1f} GFLOP/s "
              f"({100 * g['pgser_critic_fraction_of_peak']:.1f}% of peak{fm('pgser_critic_fraction_of_measured_peak')}; "
              f"{g['pgser_critic_rows_per_sec']:.0f} rows/s; "
              f"by subtraction: {s['pgser']['seconds_median']:.2f} s - {s['pgser_h32']['seconds_median']:.2f} s (h32 critic, "
              f"{g['tiny_flops_per_row']:,} FLOPs/row) = {g['critic_delta_s']:.2f} s for {rows:,} rows)")
    elif not args.no_tiny:
        print(f"pgser critic only: subtraction gave {g['critic_delta_s']:.2f} s (not positive): no figure")
    print(f"peer critic (torch {ver.get('torch')}): {g['peer_critic_gflops']:7.1f} GFLOP/s "
          f"({100 * g['peer_critic_fraction_of_peak']:.1f}% of peak{fm('peer_critic_fraction_of_measured_peak')}; "
          f"{g['peer_critic_rows_per_sec']:.0f} rows/s, timed loop)")
    if check:
        o = check.get("outputs", {})
        print(f"check: pgser's q recomputed by the peer's torch critic on {check['rows_checked']:,} rows: max |Δq| "
              f"{check['q_max_abs_diff']:.2e}; reward mismatches {check['reward_mismatches']}; schemas "
              f"{'equal' if check.get('schema_equal') else 'DIFFER'}; q mean pgser {o.get('pgser', {}).get('q_mean', float('nan')):.4f} "
              f"peer {o.get('peer', {}).get('q_mean', float('nan')):.4f}; reward=0 fraction pgser "
              f"{o.get('pgser', {}).get('reward_zero_fraction', float('nan')):.4f} peer "
              f"{o.get('peer', {}).get('reward_zero_fraction', float('nan')):.4f}")
    else:
        print(f"check failed to run:\n{tail(vout)}")
    print("versions: " + ", ".join(f"{k} {v}" for k, v in ver.items()))
    print("commands:")
    for side in sides:
        print(f"  /usr/bin/time -v {shlex.join(cmds[side])}")

    if args.json:
        doc = {"episodes": args.episodes, "swaps": args.swaps, "threads": args.threads, "repeat": args.repeat,
               "rows": rows, "inputs": built, "commands": {k: shlex.join(v) for k, v in cmds.items()},
               "env": {k: env[k] for k in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                                           "OMP_WAIT_POLICY") if k in env},
               "loadavg_before": load_before, "loadavg_after": load_after, "summary": s,
               "ratio_pgser_over_peer_rows_per_sec": ratio, "ratio_peer_wall_over_pgser_wall": ratio_wall,
               "gflops": g, "peak": pk, "versions": ver, "check": check, "runs": runs, "rejected_runs": rejected}
        Path(args.json).write_text(json.dumps(doc, indent=2) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
