#!/usr/bin/env python3
"""Training updates/s: `pgser-train bench` (Rust, burn) vs the PyTorch peer (train_peer.py), same run.

Both sides do the same goal-conditioned TD3+BC (or TD3) update on random batches generated
before timing (see train_peer.py for the update), with the same batch size, number of timed
updates and thread count, and each reports updates/s measured in-process around the update
loop only: interpreter start, `import torch`, weight init and warm-up are not in the figure.
Each side runs as a child process, R times, in alternating order (as bench_convert.py does),
so slow drift in machine load hits both; the table gives the median over the runs.

Threads: both children get RAYON_NUM_THREADS=T (burn's CPU backend and our own code use rayon)
and OMP_NUM_THREADS=MKL_NUM_THREADS=T (torch's intra-op pool), plus `--threads T` on both
command lines (torch.set_num_threads on the peer). --cpu-set pins both children to the same
cores, which keeps them from spreading over more cores than T threads could use anyway and,
on a shared machine, makes the runs more comparable.

On a machine with other work running, torch's OpenMP threads (libgomp, which spins at its
barriers) lose badly when a core is taken away; OMP_WAIT_POLICY=PASSIVE in the caller's
environment (passed through to both children) makes them sleep instead. Leave it unset for
figures on an idle machine, where spinning is what a default PyTorch install does.

The child's user+system CPU time (rusage) over its wall time is printed as "cores busy": a
check that each side really used about T cores. It includes start-up, so it reads a bit low.

Usage:
    bench_train.py [--pgser target/release/pgser-train] [--python bench-out/torch-venv/bin/python]
                   [--task FetchPush] [--algo td3bc|td3|ddpg] [--batch-size 512] [--updates 300]
                   [--threads 2] [--repeat 3] [--cpu-set 0,1] [--json OUT.json]
                   [--peer-device cpu|cuda] [--pgser-arg ARG ...]

The peer's interpreter needs torch and numpy:
    python3 -m venv bench-out/torch-venv && bench-out/torch-venv/bin/pip install torch numpy
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

import peer_python

HERE = Path(__file__).resolve().parent
REPO = HERE.parent

# task -> (obs_dim, goal_dim, act_dim), as in make_wgcsl_pickle.TASKS; copied rather than imported
# because that module needs numpy and this driver should run on a bare python3.
TASKS = {
    "FetchReach": (10, 3, 4),
    "FetchPush": (25, 3, 4),
    "FetchSlide": (25, 3, 4),
    "FetchPickAndPlace": (25, 3, 4),
    "FetchPick": (25, 3, 4),
    "HandManipulateBlockRotateZ": (61, 7, 20),
    "HandManipulateEggRotate": (61, 7, 20),
}



def parse_cpu_set(spec: str) -> set[int]:
    """'0,2-3' -> {0, 2, 3} (taskset -c syntax, without needing taskset installed)."""
    cpus = set()
    for part in spec.split(","):
        lo, _, hi = part.partition("-")
        cpus.update(range(int(lo), int(hi or lo) + 1))
    return cpus


def run_measured(cmd: list[str], env: dict, cpus: set[int] | None, out_path: Path, err_path: Path) -> dict:
    """Run cmd as a child (stdout and stderr to files, so a chatty child cannot block on a pipe
    while we wait4), return wall seconds, the child's rusage and its stdout's JSON line."""
    preexec = (lambda: os.sched_setaffinity(0, cpus)) if cpus else None
    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env,
                                preexec_fn=preexec)
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    res = {"rc": os.waitstatus_to_exitcode(status), "wall_s": wall,
           "cpu_s": ru.ru_utime + ru.ru_stime, "peak_rss_bytes": ru.ru_maxrss * 1024}
    res["cores_busy"] = res["cpu_s"] / wall if wall > 0 else float("nan")
    res["report"] = peer_python.last_json(out_path.read_text(errors="replace"))
    return res


def tail(path: Path, n: int = 30) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-n:])
    except OSError:
        return ""


def median(xs):
    return statistics.median(xs) if xs else float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pgser", default=str(REPO / "target" / "release" / "pgser-train"),
                    help="path to the pgser-train binary (default <repo>/target/release/pgser-train)")
    ap.add_argument("--python", default=None,
                    help=f"interpreter for the peer, with torch and numpy (default {peer_python.DEFAULT.relative_to(REPO)})")
    ap.add_argument("--task", default="FetchPush", choices=sorted(TASKS), help="sets the peer's dims")
    ap.add_argument("--algo", default="td3bc", choices=("td3bc", "td3", "ddpg"),
                    help="ddpg: MRN's update, as `pgser-train online` makes it (targets every 40 updates)")
    ap.add_argument("--batch-size", type=int, default=512)
    ap.add_argument("--updates", type=int, default=300, help="timed updates per run (default 300)")
    ap.add_argument("--warmup", type=int, default=20, help="untimed warm-up updates, both sides (default 20)")
    ap.add_argument("--threads", type=int, default=2, help="threads for both sides (default 2)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per side (default 3)")
    ap.add_argument("--cpu-set", help="pin both children to these CPUs, taskset -c syntax (e.g. 0,1 or 0-3)")
    ap.add_argument("--seed", type=int, default=0, help="peer's seed")
    ap.add_argument("--peer-device", default="cpu", choices=("cpu", "cuda"),
                    help="device for the peer (pgser's flex backend is CPU; cuda is for reference)")
    ap.add_argument("--pgser-arg", action="append", default=[],
                    help="extra argument for `pgser-train bench` (repeatable)")
    ap.add_argument("--workdir", default=str(REPO / "bench-out"),
                    help="where the children's logs go (default <repo>/bench-out)")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.threads < 1 or args.updates < 1:
        ap.error("--repeat, --threads and --updates must be >= 1")

    pgser = Path(args.pgser).resolve()
    if not os.access(pgser, os.X_OK):
        sys.exit(f"--pgser {pgser} is not an executable file (cargo build --release --bin pgser-train)")
    python = peer_python.resolve(args.python, "torch numpy")
    cpus = parse_cpu_set(args.cpu_set) if args.cpu_set else None
    if cpus and len(cpus) < args.threads:
        print(f"warning: --cpu-set has {len(cpus)} CPUs for {args.threads} threads: threads will share cores",
              file=sys.stderr)
    logdir = Path(args.workdir).resolve() / "train-logs"
    logdir.mkdir(parents=True, exist_ok=True)

    t = str(args.threads)
    env = dict(os.environ, RAYON_NUM_THREADS=t, OMP_NUM_THREADS=t, MKL_NUM_THREADS=t)
    obs, goal, act = TASKS[args.task]
    cmds = {
        "pgser": [str(pgser), "bench", "--task", args.task, "--batch-size", str(args.batch_size),
                  "--updates", str(args.updates), "--warmup", str(args.warmup), "--threads", t,
                  "--algo", args.algo, "--json",
                  # MRN moves the targets once per cycle of 40 updates, as `pgser-train online` does.
                  *(["--policy-delay", "40", "--tau", "0.1"] if args.algo == "ddpg" else []),
                  *args.pgser_arg],
        "pytorch": [python, str(HERE / "train_peer.py"), "--obs", str(obs), "--goal", str(goal),
                    "--act", str(act), "--batch-size", str(args.batch_size), "--updates", str(args.updates),
                    "--warmup", str(args.warmup), "--threads", t, "--seed", str(args.seed),
                    "--algo", args.algo, "--device", args.peer_device, "--json"],
    }

    # The figures depend heavily on what else the machine is doing; record it next to them.
    load_before = os.getloadavg()
    runs = {"pgser": [], "pytorch": []}
    for r in range(args.repeat):
        order = ("pgser", "pytorch") if r % 2 == 0 else ("pytorch", "pgser")
        for side in order:
            out, err = logdir / f"{side}_{r}.out", logdir / f"{side}_{r}.err"
            m = run_measured(cmds[side], env, cpus, out, err)
            if m["rc"] != 0 or m["report"] is None:
                why = f"exit {m['rc']}" if m["rc"] != 0 else "no JSON line with updates_per_sec on stdout"
                print(f"\n{side} failed ({why}): {shlex.join(cmds[side])}\n--- stdout\n{tail(out)}\n"
                      f"--- stderr\n{tail(err)}", file=sys.stderr)
                sys.exit(1)
            m["run"] = r
            runs[side].append(m)
            rep = m["report"]
            print(f"  run {r + 1}/{args.repeat} {side:8s}: {rep['updates_per_sec']:8.1f} updates/s  "
                  f"(wall {m['wall_s']:6.2f} s incl. start-up, cores busy {m['cores_busy']:4.2f}, "
                  f"reported threads {rep.get('threads', '?')})", flush=True)
    load_after = os.getloadavg()

    def summary(side):
        ups = [x["report"]["updates_per_sec"] for x in runs[side]]
        last = runs[side][-1]["report"]
        return {
            "updates_per_sec_median": median(ups), "updates_per_sec_min": min(ups),
            "updates_per_sec_max": max(ups), "updates_per_sec_all": ups,
            "ms_per_update_median": 1e3 / median(ups),
            "cores_busy_median": median([x["cores_busy"] for x in runs[side]]),
            "peak_rss_mib_median": median([x["peak_rss_bytes"] / (1 << 20) for x in runs[side]]),
            "threads_reported": last.get("threads"),
            "backend": last.get("backend") or (f"torch {last.get('torch')} {last.get('device', 'cpu')}"
                                               if side == "pytorch" else "?"),
        }

    s = {side: summary(side) for side in runs}
    ratio = s["pgser"]["updates_per_sec_median"] / s["pytorch"]["updates_per_sec_median"]
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    machine = {"cpu_count": os.cpu_count(), "usable_cores": usable, "platform": platform.platform(),
               "processor": platform.processor() or platform.machine(), "python": platform.python_version(),
               "torch": runs["pytorch"][-1]["report"].get("torch"),
               "loadavg_before": load_before, "loadavg_after": load_after}

    # ---- report --------------------------------------------------------
    print()
    print(f"training updates/s: pgser-train bench vs PyTorch peer — {args.task} {args.algo}, batch {args.batch_size}, "
          f"{args.updates} timed updates, {args.threads} threads"
          + (f", pinned to CPUs {args.cpu_set}" if cpus else ""))
    print(f"machine: {machine['cpu_count']} cores ({usable} usable); 1-min load average "
          f"{load_before[0]:.2f} before, {load_after[0]:.2f} after; {args.repeat} runs per side, alternating order")
    hdr = (f"{'':22s}{'updates/s':>10s}{'min':>9s}{'max':>9s}{'ms/update':>11s}{'cores busy':>12s}"
           f"{'RSS MiB':>9s}  backend")
    print(hdr)
    print("-" * len(hdr))
    for side, label in (("pgser", "pgser-train"), ("pytorch", "pytorch peer")):
        x = s[side]
        print(f"{label:22s}{x['updates_per_sec_median']:10.1f}{x['updates_per_sec_min']:9.1f}"
              f"{x['updates_per_sec_max']:9.1f}{x['ms_per_update_median']:11.2f}{x['cores_busy_median']:12.2f}"
              f"{x['peak_rss_mib_median']:9.0f}  {x['backend']}")
    print(f"ratio pgser/pytorch (updates/s, medians): {ratio:.2f}x  (>1: pgser faster)")
    for side in runs:
        if s[side]["threads_reported"] not in (None, args.threads):
            print(f"note: {side} reported {s[side]['threads_reported']} threads, asked for {args.threads}")

    if args.json:
        doc = {"task": args.task, "algo": args.algo, "batch_size": args.batch_size, "updates": args.updates,
               "threads": args.threads, "cpu_set": args.cpu_set, "repeat": args.repeat,
               "commands": {k: shlex.join(v) for k, v in cmds.items()},
               "env": {k: env[k] for k in ("RAYON_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                                           "OMP_WAIT_POLICY") if k in env},
               "machine": machine, "summary": s, "ratio_pgser_over_pytorch": ratio,
               "runs": runs}
        Path(args.json).write_text(json.dumps(doc, indent=2) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
