#!/usr/bin/env python3
"""Benchmark `pgser-etl convert` against the Python/pyarrow peer (convert_peer.py).

Both converters run as child processes on the same WGCSL-style pickle, R times
each in alternating order.  Wall time is measured around the child; peak RSS,
user and system CPU come from the child's rusage (os.wait4, the same numbers
GNU time prints as %M, %U, %S).  The page cache cannot be dropped here, so the
input is read once, untimed (cat IN > /dev/null), before any timed run so that
both sides start from a warm cache; each run's output is deleted and `sync` is
called, untimed, before the next run.

Usage:
    bench_convert.py --pgser PATH_TO_pgser-etl [--episodes N] [--workdir DIR]
                     [--repeat R] [--json OUT.json] [--task FetchPush]
                     [--protocol {3,4}] [--seed S] [--input IN.pkl]
                     [--python PY] [--peer-sha256] [--pgser-arg ARG ...]
                     [--verify-data] [--keep-outputs]
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

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
from make_wgcsl_pickle import DEFAULT_EPISODES, HORIZON, TASKS  # noqa: E402
import peer_python  # noqa: E402

MB = 1e6
MiB = 1 << 20


def run_measured(cmd: list[str], log_path: Path) -> dict:
    """Run cmd as a child, return wall seconds and the child's rusage."""
    with open(log_path, "wb") as log:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    return {
        "rc": proc.returncode,
        "wall_s": wall,
        "peak_rss_bytes": ru.ru_maxrss * 1024,  # Linux reports KiB
        "user_s": ru.ru_utime,
        "sys_s": ru.ru_stime,
        "major_faults": ru.ru_majflt,
    }



def peer_timings(log_path: Path) -> dict | None:
    for line in log_path.read_text(errors="replace").splitlines():
        if line.startswith("PEER_TIMINGS "):
            return json.loads(line[len("PEER_TIMINGS "):])
    return None


def ensure_input(args, workdir: Path) -> Path:
    if args.input:
        p = Path(args.input)
        if not p.is_file():
            sys.exit(f"--input {p} does not exist")
        return p
    name = f"wgcsl_{args.task}_{args.episodes}ep_p{args.protocol}_s{args.seed}.pkl"
    p = workdir / name
    if p.is_file():
        print(f"using cached input {p}")
        return p
    print(f"generating {p} ...", flush=True)
    cmd = [args.python, str(HERE / "make_wgcsl_pickle.py"), "--episodes", str(args.episodes),
           "--task", args.task, "--protocol", str(args.protocol), "--seed", str(args.seed),
           "--out", str(p)]
    subprocess.run(cmd, check=True)
    return p


def warm_cache(path: Path) -> float:
    t0 = time.perf_counter()
    with open(os.devnull, "wb") as null:
        subprocess.run(["cat", str(path)], stdout=null, check=True)
    return time.perf_counter() - t0


def verify(pgser_out: Path, peer_out: Path, expected_rows: int | None, full: bool) -> dict:
    import pyarrow.parquet as pq

    a, b = pq.ParquetFile(pgser_out), pq.ParquetFile(peer_out)
    res = {"rows_pgser": a.metadata.num_rows, "rows_python": b.metadata.num_rows,
           "row_groups_pgser": a.metadata.num_row_groups, "row_groups_python": b.metadata.num_row_groups,
           "footer_pgser_key": b"pgser" in (a.metadata.metadata or {}),
           "footer_python_key": b"pgser" in (b.metadata.metadata or {})}
    res["rows_equal"] = res["rows_pgser"] == res["rows_python"]
    if expected_rows is not None:
        res["rows_expected"] = expected_rows
        res["rows_equal"] = res["rows_equal"] and res["rows_pgser"] == expected_rows
    sa, sb = a.schema_arrow.remove_metadata(), b.schema_arrow.remove_metadata()
    res["schema_equal"] = sa.equals(sb)
    if not res["schema_equal"]:
        res["schema_pgser"] = str(sa)
        res["schema_python"] = str(sb)
    if full:
        ta, tb = a.read(), b.read()
        diffs = []
        for name in sb.names:
            if name not in sa.names:
                diffs.append(f"{name}: missing in pgser output")
                continue
            ca, cb = ta.column(name), tb.column(name)
            if ca.type != cb.type:
                try:
                    ca = ca.cast(cb.type)
                except Exception as e:  # noqa: BLE001
                    diffs.append(f"{name}: types differ ({ca.type} vs {cb.type}): {e}")
                    continue
            if not ca.equals(cb):
                diffs.append(f"{name}: values differ")
        res["data_equal"] = not diffs
        res["data_diffs"] = diffs
    return res


def median(xs):
    return statistics.median(xs) if xs else float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description="pgser-etl convert vs Python/pyarrow peer")
    ap.add_argument("--pgser", required=True, help="path to the pgser-etl binary")
    ap.add_argument("--episodes", type=int, default=DEFAULT_EPISODES,
                    help=f"episodes in the generated pickle (default {DEFAULT_EPISODES}, ~315 MB for FetchPush)")
    ap.add_argument("--workdir", default=str(REPO / "bench-out"),
                    help="where the input is cached and outputs/logs go (default <repo>/bench-out)")
    ap.add_argument("--repeat", type=int, default=3, help="timed runs per side (default 3)")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    ap.add_argument("--task", default="FetchPush", choices=sorted(TASKS))
    ap.add_argument("--protocol", type=int, default=4, choices=(3, 4))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--input", help="use this pickle instead of generating one")
    ap.add_argument("--python", default=sys.executable,
                    help="interpreter for the peer and the generator (needs numpy, pyarrow)")
    ap.add_argument("--peer-sha256", action="store_true",
                    help="make the peer hash its input into the footer too (use if pgser-etl does)")
    ap.add_argument("--pgser-arg", action="append", default=[],
                    help="extra argument for `pgser-etl convert` (repeatable)")
    ap.add_argument("--verify-data", action="store_true",
                    help="also read both outputs back and compare every column")
    ap.add_argument("--keep-outputs", action="store_true", help="keep the last outputs")
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")

    pgser = Path(args.pgser).resolve()
    if not os.access(pgser, os.X_OK):
        sys.exit(f"--pgser {pgser} is not an executable file")
    workdir = Path(args.workdir).resolve()
    workdir.mkdir(parents=True, exist_ok=True)

    inp = ensure_input(args, workdir)
    in_bytes = inp.stat().st_size
    expected_rows = None if args.input else args.episodes * HORIZON

    out_pgser = workdir / "out_pgser.parquet"
    out_peer = workdir / "out_python.parquet"
    cmds = {
        "pgser": [str(pgser), "convert", str(inp), "-o", str(out_pgser), "--task", args.task,
                  *args.pgser_arg],
        "python": [args.python, str(HERE / "convert_peer.py"), str(inp), str(out_peer),
                   "--task", args.task, *(["--sha256"] if args.peer_sha256 else [])],
    }
    outs = {"pgser": out_pgser, "python": out_peer}

    warm_s = warm_cache(inp)
    print(f"warm-up: read {inp.name} once untimed ({in_bytes / MB:.1f} MB in {warm_s:.2f} s) "
          f"so both sides start from a warm page cache (dropping caches is not possible here)",
          flush=True)

    runs = {"pgser": [], "python": []}
    for r in range(args.repeat):
        order = ("pgser", "python") if r % 2 == 0 else ("python", "pgser")
        for side in order:
            outs[side].unlink(missing_ok=True)
            os.sync()  # untimed: flush the previous run's dirty pages
            log = workdir / f"log_{side}_{r}.txt"
            m = run_measured(cmds[side], log)
            if m["rc"] != 0:
                print(f"\n{side} failed (exit {m['rc']}): {shlex.join(cmds[side])}\n{peer_python.tail(log)}",
                      file=sys.stderr)
                sys.exit(1)
            m["output_bytes"] = outs[side].stat().st_size
            if side == "python":
                m["phases"] = peer_timings(log)
            m["run"] = r
            runs[side].append(m)
            print(f"  run {r + 1}/{args.repeat} {side:6s}: {m['wall_s']:7.2f} s  "
                  f"peak RSS {m['peak_rss_bytes'] / MiB:7.1f} MiB  "
                  f"cpu {m['user_s'] + m['sys_s']:6.2f} s", flush=True)

    check = verify(out_pgser, out_peer, expected_rows, args.verify_data)
    if not args.keep_outputs:
        for p in outs.values():
            p.unlink(missing_ok=True)

    def summary(side):
        rs = runs[side]
        wall = median([x["wall_s"] for x in rs])
        return {
            "wall_s_median": wall,
            "wall_s_min": min(x["wall_s"] for x in rs),
            "wall_s_all": [x["wall_s"] for x in rs],
            "mb_per_s": in_bytes / MB / wall,
            "peak_rss_bytes_max": max(x["peak_rss_bytes"] for x in rs),
            "peak_rss_mib_median": median([x["peak_rss_bytes"] / MiB for x in rs]),
            "cpu_s_median": median([x["user_s"] + x["sys_s"] for x in rs]),
            "output_bytes": rs[-1]["output_bytes"],
        }

    s = {side: summary(side) for side in runs}
    phases = [x["phases"] for x in runs["python"] if x.get("phases")]
    py_phases = {k: median([p[k] for p in phases]) for k in ("load_s", "sha256_s", "build_s", "write_s", "total_s")} if phases else None
    ratios = {
        "python_time_over_pgser_time": s["python"]["wall_s_median"] / s["pgser"]["wall_s_median"],
        "pgser_peak_over_python_peak": s["pgser"]["peak_rss_mib_median"] / s["python"]["peak_rss_mib_median"],
    }
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = os.cpu_count()
    machine = {"cpu_count": os.cpu_count(), "usable_cores": affinity, "platform": platform.platform(),
               "processor": platform.processor() or platform.machine(), "python": platform.python_version()}
    try:
        import pyarrow
        machine["pyarrow"] = pyarrow.__version__
    except ImportError:
        pass

    # ---- report --------------------------------------------------------
    print()
    print(f"pgser-etl convert vs Python peer — {args.task}, input {inp.name}")
    print(f"input: {in_bytes / MB:.1f} MB ({in_bytes / MiB:.1f} MiB); rows {check['rows_pgser']:,}; "
          f"{args.repeat} runs per side, alternating order; machine: {machine['cpu_count']} cores "
          f"({machine['usable_cores']} usable)")
    print("cache: input read once untimed before timing (warm page cache for both; caches not dropped); "
          "a run's old output deleted + sync before it")
    hdr = f"{'':18s}{'median wall s':>14s}{'MB/s':>9s}{'peak RSS MiB':>14s}{'CPU s':>8s}{'output MB':>11s}"
    print(hdr)
    print("-" * len(hdr))
    for side, label in (("pgser", "pgser-etl"), ("python", "python/pyarrow")):
        x = s[side]
        print(f"{label:18s}{x['wall_s_median']:14.2f}{x['mb_per_s']:9.1f}{x['peak_rss_mib_median']:14.1f}"
              f"{x['cpu_s_median']:8.2f}{x['output_bytes'] / MB:11.1f}")
    print(f"time ratio python/pgser: {ratios['python_time_over_pgser_time']:.2f}x   "
          f"peak-RSS ratio pgser/python: {ratios['pgser_peak_over_python_peak']:.2f}")
    if py_phases:
        print(f"python phases (median s): pickle.load {py_phases['load_s']:.2f}, "
              + (f"sha256 {py_phases['sha256_s']:.2f}, " if args.peer_sha256 else "")
              + f"table build {py_phases['build_s']:.2f}, write_table {py_phases['write_s']:.2f} "
              f"(in-process total {py_phases['total_s']:.2f}; the rest is interpreter start + imports)")
    ok = check["rows_equal"] and check.get("data_equal", True)
    print(f"check: rows pgser={check['rows_pgser']:,} python={check['rows_python']:,}"
          + (f" expected={expected_rows:,}" if expected_rows is not None else "")
          + f" -> {'OK' if check['rows_equal'] else 'MISMATCH'}; "
          f"schemas {'equal' if check['schema_equal'] else 'DIFFER'}; "
          f"pgser footer key: pgser={check['footer_pgser_key']} python={check['footer_python_key']}"
          + (f"; data {'equal' if check['data_equal'] else 'DIFFER: ' + ', '.join(check['data_diffs'])}"
             if args.verify_data else ""))
    if not check["schema_equal"]:
        print(f"  pgser schema:\n{check['schema_pgser']}\n  python schema:\n{check['schema_python']}")

    if args.json:
        doc = {
            "task": args.task, "input": str(inp), "input_bytes": in_bytes, "input_mb": in_bytes / MB,
            "episodes": args.episodes if not args.input else None, "repeat": args.repeat,
            "cache": "input warmed by one untimed full read; page cache not dropped",
            "commands": {k: shlex.join(v) for k, v in cmds.items()},
            "machine": machine, "summary": s, "ratios": ratios, "python_phases_median": py_phases,
            "runs": runs, "check": check,
        }
        Path(args.json).write_text(json.dumps(doc, indent=2) + "\n")
        print(f"wrote {args.json}")
    sys.exit(0 if ok else 2)


if __name__ == "__main__":
    main()
