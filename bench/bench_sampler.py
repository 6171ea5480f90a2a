#!/usr/bin/env python3
"""Prioritized-sampler throughput: `pgser-train bench-sampler` (disk and --in-memory) vs cpprb.

(a) On one scored table (`pgser-etl score` output), in the same run:

    pgser disk     pgser-train bench-sampler --data T --batch-size 256 --batches N --json
                   rows read from the Parquet row groups by pgser's background thread, in
                   blocks of 256-4096 batches, as keys rebuilt from the original data;
                   only the sum tree and that data are in memory
    pgser memory   the same with --in-memory (rows loaded into arrays first)
    cpprb          sampler_peer.py: cpprb.PrioritizedReplayBuffer holding every row, the same
                   priorities from q, sample(256, beta) timed (the in-memory peer)
    numpy          sampler_peer.py --impl numpy: a numpy sum tree, the documented fallback
                   peer (and a second reference point); skip with --peers cpprb

Priorities are the same on every side (--priority, --priority-alpha; gamma from the table's
footer). cpprb always computes importance weights with beta, so pgser gets --is-beta with the
same beta (default 0.4; --is-beta none drops it from pgser's command, which is the trainer's
default, and leaves the peer at 0.4). pgser's sampler uses rayon for row-group reads (disk) and a
producer thread besides the consumer; cpprb is single-threaded. Every figure is the child's own
in-process timing of the sampling loop only (setup excluded; setup is given apart); peak RSS
is the child's rusage. Each side runs --repeat times, rotating the order so that slow drift in
machine load hits all of them; the table gives medians. The table file is read once (cat >
/dev/null) before the runs, so "disk" means the page cache on a warm machine, as in training.

(b) The trainer's needs: `pgser-train bench --task <the table's task> --batch-size 512
--updates 100 --json` gives updates/s; with --aug-ratio 0.5 each update takes
round(512 * 0.5) = 256 prioritized rows, so the trainer consumes updates/s * 256 rows/s from
the sampler. The disk sampler's samples/s over that is "x the trainer's needs" (> 1: the
sampler is not what limits training; the sampler's thread shares the cores with the update
in a real run, so it is an upper bound on the headroom).

Without --data, a default table is built (or reused) in bench-out/sampler-default/:
    pgser-etl collect --task FetchPush --policy random --episodes 500 --seed 0 -o traj.parquet
    pgser-train --data traj.parquet -o q.ckpt --updates 200 --eval-episodes 0
    pgser-etl score --q q.ckpt --data traj.parquet -o scored.parquet --swaps 8 --seed 0

Usage:
    bench_sampler.py [--data scored.parquet] [--batches 3000] [--batch-size 256] [--repeat 3]
                     [--python bench-out/torch-venv/bin/python] [--pgser-train PATH]
                     [--pgser-etl PATH] [--is-beta 0.4|none] [--priority q|rank|uniform]
                     [--priority-alpha 1] [--peers cpprb,numpy] [--threads T]
                     [--trainer-updates 100] [--json OUT.json]

The peer's interpreter needs cpprb, pyarrow and numpy:
    bench-out/torch-venv/bin/pip install cpprb pyarrow
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
TRAIN_BATCH = 512
AUG_RATIO = 0.5
MiB = 1 << 20


def run_measured(cmd: list[str], env: dict, out_path: Path, err_path: Path, key: str) -> dict:
    """Run cmd as a child (stdout, stderr to files), return wall seconds, rusage and the last
    stdout line that is a JSON object holding `key`."""
    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env)
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    res = {"rc": os.waitstatus_to_exitcode(status), "wall_s": wall,
           "cpu_s": ru.ru_utime + ru.ru_stime, "peak_rss_bytes": ru.ru_maxrss * 1024}
    res["report"] = peer_python.last_json(out_path.read_text(errors="replace"), key)
    return res



def median(xs):
    return statistics.median(xs) if xs else float("nan")


def read_footer(path: Path, python: str) -> dict:
    """The table's pgser footer (task, gamma, rows), read by the peer's interpreter (pyarrow)."""
    code = ("import json, sys, pyarrow.parquet as pq; f = pq.ParquetFile(sys.argv[1]); "
            "d = json.loads(f.metadata.metadata[b'pgser']); "
            "print(json.dumps({'task': d.get('task'), 'gamma': d.get('gamma'), 'kind': d.get('kind'), "
            "'swaps': d.get('swaps'), 'episodes': d.get('episodes'), 'rows': f.metadata.num_rows, "
            "'row_groups': f.metadata.num_row_groups}))")
    out = subprocess.run([python, "-c", code, str(path)], capture_output=True, text=True, cwd="/")
    if out.returncode != 0:
        sys.exit(f"cannot read the footer of {path}:\n{out.stderr}")
    return json.loads(out.stdout)


def build_default(etl: Path, train: Path, workdir: Path) -> Path:
    """bench-out/sampler-default/scored.parquet, built once (each step skipped if its output exists)."""
    workdir.mkdir(parents=True, exist_ok=True)
    traj, ckpt, scored = workdir / "traj.parquet", workdir / "q.ckpt", workdir / "scored.parquet"
    steps = [
        (traj, [str(etl), "collect", "--task", "FetchPush", "--policy", "random", "--episodes", "500",
                "--seed", "0", "-o", str(traj)]),
        (ckpt, [str(train), "--data", str(traj), "-o", str(ckpt), "--updates", "200", "--eval-episodes", "0"]),
        (scored, [str(etl), "score", "--q", str(ckpt), "--data", str(traj), "-o", str(scored),
                  "--swaps", "8", "--seed", "0"]),
    ]
    for path, cmd in steps:
        if path.exists():
            continue
        print(f"building the default table: {shlex.join(cmd)}", flush=True)
        r = subprocess.run(cmd, cwd=workdir)
        if r.returncode != 0:
            sys.exit(f"failed (exit {r.returncode}): {shlex.join(cmd)}")
    return scored


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", help="scored table (pgser-etl score); default: build bench-out/sampler-default/scored.parquet")
    ap.add_argument("--batches", type=int, default=3000, help="batches per run (default 3000)")
    ap.add_argument("--batch-size", type=int, default=256, help="rows per batch (default 256)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per side (default 3)")
    ap.add_argument("--python", default=None,
                    help=f"interpreter for the peer, with cpprb, pyarrow and numpy (default {peer_python.DEFAULT.relative_to(REPO)})")
    ap.add_argument("--pgser-train", default=str(REPO / "target" / "release" / "pgser-train"))
    ap.add_argument("--pgser-etl", default=str(REPO / "target" / "release" / "pgser-etl"),
                    help="only used to build the default table")
    ap.add_argument("--is-beta", default="0.4",
                    help="IS exponent: passed to the peer's sample() and to pgser as --is-beta; "
                         "'none': pgser computes no weights (the peer still uses 0.4) (default 0.4)")
    ap.add_argument("--priority", default="q", choices=("q", "rank", "uniform"))
    ap.add_argument("--priority-alpha", type=float, default=1.0)
    ap.add_argument("--peers", default="cpprb,numpy", help="comma list of cpprb, numpy (default both)")
    ap.add_argument("--peer-warmup", type=int, default=50, help="peer's untimed sample() calls (default 50)")
    ap.add_argument("--threads", type=int, default=None,
                    help="RAYON_NUM_THREADS and --threads for pgser (default: pgser's own, all cores)")
    ap.add_argument("--trainer-updates", type=int, default=100, help="updates of `pgser-train bench` (default 100)")
    ap.add_argument("--no-trainer", action="store_true", help="skip part (b)")
    ap.add_argument("--workdir", default=str(REPO / "bench-out"), help="logs go to WORKDIR/sampler-logs")
    ap.add_argument("--json", help="also write the figures to this JSON file "
                                    "(default WORKDIR/sampler.json)")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.batches < 2 or args.batch_size < 1:
        ap.error("--repeat >= 1, --batches >= 2, --batch-size >= 1")

    train = Path(args.pgser_train).resolve()
    if not os.access(train, os.X_OK):
        sys.exit(f"--pgser-train {train} is not an executable file (cargo build --release)")
    python = peer_python.resolve(args.python, "cpprb pyarrow numpy")
    peers = [p.strip() for p in args.peers.split(",") if p.strip()]
    if any(p not in ("cpprb", "numpy") for p in peers):
        ap.error("--peers: cpprb and/or numpy")
    workdir = Path(args.workdir).resolve()
    if args.data:
        data = Path(args.data).resolve()
    else:
        etl = Path(args.pgser_etl).resolve()
        if not os.access(etl, os.X_OK):
            sys.exit(f"--pgser-etl {etl} is not an executable file (needed to build the default table)")
        data = build_default(etl, train, workdir / "sampler-default")
    if not data.is_file():
        sys.exit(f"--data {data}: no such file")
    footer = read_footer(data, python)
    if footer["kind"] != "transition":
        sys.exit(f"{data}: footer kind {footer['kind']}: a scored table from `pgser-etl score` is expected")
    size = data.stat().st_size
    logdir = workdir / "sampler-logs"
    logdir.mkdir(parents=True, exist_ok=True)

    beta = None if args.is_beta.lower() == "none" else float(args.is_beta)
    env = dict(os.environ)
    thr = []
    if args.threads:
        env["RAYON_NUM_THREADS"] = str(args.threads)
        thr = ["--threads", str(args.threads)]
    pri = ["--priority", args.priority, "--priority-alpha", repr(args.priority_alpha)]
    base = [str(train), "bench-sampler", "--data", str(data), "--batch-size", str(args.batch_size),
            "--batches", str(args.batches), *pri, *thr, "--json"]
    if beta is not None:
        base += ["--is-beta", repr(beta)]
    peer = [python, str(HERE / "sampler_peer.py"), "--data", str(data), "--batch-size", str(args.batch_size),
            "--batches", str(args.batches), "--warmup", str(args.peer_warmup),
            "--beta", repr(0.4 if beta is None else beta), *pri, "--json"]
    cmds = {"pgser-disk": base, "pgser-memory": base + ["--in-memory"]}
    for p in peers:
        cmds[p] = peer + ["--impl", p]
    labels = {"pgser-disk": "pgser disk", "pgser-memory": "pgser --in-memory",
              "cpprb": "cpprb (memory)", "numpy": "numpy sum tree (memory)"}

    # warm the page cache: every side reads the file, only the disk side during its timing
    t0 = time.perf_counter()
    with open(data, "rb") as f:
        while f.read(16 * MiB):
            pass
    cache_s = time.perf_counter() - t0

    load_before = os.getloadavg()
    sides = list(cmds)
    runs = {s: [] for s in sides}
    failed = {}
    for r in range(args.repeat):
        order = sides[r % len(sides):] + sides[:r % len(sides)]
        for side in order:
            if side in failed:
                continue
            out, err = logdir / f"{side}_{r}.out", logdir / f"{side}_{r}.err"
            m = run_measured(cmds[side], env, out, err, "samples_per_sec")
            if m["rc"] != 0 or m["report"] is None:
                why = f"exit {m['rc']}" if m["rc"] != 0 else "no JSON line with samples_per_sec on stdout"
                print(f"\n{side} failed ({why}): {shlex.join(cmds[side])}\n--- stdout\n{peer_python.tail(out)}\n"
                      f"--- stderr\n{peer_python.tail(err)}", file=sys.stderr)
                failed[side] = why
                continue
            m["run"] = r
            m["loadavg"] = os.getloadavg()
            runs[side].append(m)
            rep = m["report"]
            print(f"  run {r + 1}/{args.repeat} {side:13s}: {rep['samples_per_sec']:11.0f} samples/s  "
                  f"setup {rep['setup_seconds']:6.2f} s  peak RSS {m['peak_rss_bytes'] / MiB:7.0f} MiB  "
                  f"(load {m['loadavg'][0]:.2f})", flush=True)

    trainer = None
    if not args.no_trainer:
        tcmd = [str(train), "bench", "--task", footer["task"], "--batch-size", str(TRAIN_BATCH),
                "--updates", str(args.trainer_updates), *thr, "--json"]
        m = run_measured(tcmd, env, logdir / "trainer.out", logdir / "trainer.err", "updates_per_sec")
        if m["rc"] != 0 or m["report"] is None:
            print(f"\ntrainer bench failed (exit {m['rc']}): {shlex.join(tcmd)}\n{peer_python.tail(logdir / 'trainer.err')}",
                  file=sys.stderr)
            failed["trainer"] = f"exit {m['rc']}"
        else:
            ups = m["report"]["updates_per_sec"]
            per_update = round(TRAIN_BATCH * AUG_RATIO)
            trainer = {"command": shlex.join(tcmd), "updates_per_sec": ups, "rows_per_update": per_update,
                       "rows_per_sec_needed": ups * per_update, "report": m["report"],
                       "loadavg": os.getloadavg()}
    load_after = os.getloadavg()

    def summary(side):
        xs = runs[side]
        sps = [x["report"]["samples_per_sec"] for x in xs]
        last = xs[-1]["report"]
        return {"samples_per_sec_median": median(sps), "samples_per_sec_min": min(sps),
                "samples_per_sec_max": max(sps), "samples_per_sec_all": sps,
                "batches_per_sec_median": median([x["report"]["batches_per_sec"] for x in xs]),
                "setup_seconds_median": median([x["report"]["setup_seconds"] for x in xs]),
                "peak_rss_mib_median": median([x["peak_rss_bytes"] / MiB for x in xs]),
                "version": last.get("version"), "rows": last.get("rows"), "check": last.get("check")}

    s = {side: summary(side) for side in sides if runs[side]}

    def ratio(a, b):
        return s[a]["samples_per_sec_median"] / s[b]["samples_per_sec_median"] if a in s and b in s else None

    ratios = {"pgser_memory_over_cpprb": ratio("pgser-memory", "cpprb"),
              "pgser_disk_over_cpprb": ratio("pgser-disk", "cpprb"),
              "pgser_memory_over_numpy": ratio("pgser-memory", "numpy"),
              "pgser_disk_over_numpy": ratio("pgser-disk", "numpy")}
    if trainer:
        for side in ("pgser-disk", "pgser-memory"):
            if side in s:
                trainer[f"{side.replace('-', '_')}_times_needs"] = (s[side]["samples_per_sec_median"]
                                                                  / trainer["rows_per_sec_needed"])
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    machine = {"cpu_count": os.cpu_count(), "usable_cores": usable, "platform": platform.platform(),
               "processor": platform.processor() or platform.machine(), "python": platform.python_version(),
               "loadavg_before": load_before, "loadavg_after": load_after}

    # ---- report --------------------------------------------------------
    print()
    print(f"prioritized sampler: {data.name} ({footer['rows']} rows, {footer['row_groups']} row groups, "
          f"{size / 1e6:.1f} MB, {footer['task']}, swaps {footer['swaps']}); batch {args.batch_size}, "
          f"{args.batches} batches per run, {args.repeat} runs per side in rotating order")
    print(f"priorities {args.priority} alpha {args.priority_alpha:g} (gamma {footer['gamma']}); IS beta: "
          + (f"{beta:g} on every side" if beta is not None else "none for pgser, 0.4 for the peers")
          + (f"; pgser threads {args.threads}" if args.threads else "; pgser threads: default (all cores)"))
    print(f"machine: {machine['cpu_count']} cores ({usable} usable); 1-min load average "
          f"{load_before[0]:.2f} before, {load_after[0]:.2f} after; page cache warmed ({cache_s:.2f} s)")
    hdr = (f"{'':26s}{'samples/s':>12s}{'min':>11s}{'max':>11s}{'batches/s':>11s}{'setup s':>9s}"
           f"{'peak RSS MiB':>14s}")
    print(hdr)
    print("-" * len(hdr))
    for side in sides:
        if side not in s:
            print(f"{labels[side]:26s}  FAILED: {failed.get(side)}")
            continue
        x = s[side]
        lab = labels[side] + (f" {x['version']}" if side == "cpprb" and x["version"] else "")
        print(f"{lab:26s}{x['samples_per_sec_median']:12.0f}{x['samples_per_sec_min']:11.0f}"
              f"{x['samples_per_sec_max']:11.0f}{x['batches_per_sec_median']:11.1f}"
              f"{x['setup_seconds_median']:9.2f}{x['peak_rss_mib_median']:14.0f}")
    for key, lab in (("pgser_memory_over_cpprb", "pgser-memory/cpprb"), ("pgser_disk_over_cpprb", "pgser-disk/cpprb"),
                     ("pgser_memory_over_numpy", "pgser-memory/numpy"), ("pgser_disk_over_numpy", "pgser-disk/numpy")):
        if ratios[key] is not None:
            print(f"ratio {lab:20s}: {ratios[key]:6.2f}x  (samples/s, medians; >1: pgser faster)")
    for side in peers:
        c = s.get(side, {}).get("check")
        if c:
            print(f"check {side}: mean p of {c['drawn']} drawn rows {c['mean_p_drawn']:.5g}, expected "
                  f"{c['mean_p_expected']:.5g} (z {c['z']:+.2f}; uniform draws would give {c['mean_p_uniform']:.5g})")
    if trainer:
        print(f"trainer: {trainer['command']}")
        print(f"  {trainer['updates_per_sec']:.1f} updates/s x {trainer['rows_per_update']} prioritized rows/update "
              f"(batch {TRAIN_BATCH}, --aug-ratio {AUG_RATIO}) = {trainer['rows_per_sec_needed']:.0f} rows/s needed")
        if "pgser_disk_times_needs" in trainer:
            fmt = lambda x: f"{x:.0f}" if x >= 10 else f"{x:.2f}"  # noqa: E731
            print(f"  disk sampler: {fmt(trainer['pgser_disk_times_needs'])}x the trainer's needs"
                  + (f"; in memory: {fmt(trainer['pgser_memory_times_needs'])}x"
                     if "pgser_memory_times_needs" in trainer else ""))
    if failed:
        print(f"failed: {failed}")

    out_json = Path(args.json) if args.json else workdir / "sampler.json"
    doc = {"data": str(data), "file_bytes": size, "footer": footer, "batch_size": args.batch_size,
           "batches": args.batches, "repeat": args.repeat, "is_beta": beta, "priority": args.priority,
           "priority_alpha": args.priority_alpha, "threads": args.threads,
           "commands": {k: shlex.join(v) for k, v in cmds.items()}, "machine": machine, "summary": s,
           "ratios": ratios, "trainer": trainer, "failed": failed, "runs": runs}
    out_json.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {out_json}")
    if failed:
        sys.exit(1)


if __name__ == "__main__":
    main()
