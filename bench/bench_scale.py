#!/usr/bin/env python3
"""Datasets larger than memory (issue 65): pgser's out-of-core pool against OGBench's and Horizon
Reduction's samplers, side by side, in one run, on one folder of `.npz` shards.

Given a folder of shards in Horizon Reduction's layout (`NAME-0.npz` .. `NAME-(K-1).npz`, a
`NAME-val.npz` beside them is left out) and a memory budget, it measures:

1. convert    `pgser-etl convert DIR -o TABLE`: rows/s and peak RSS (GNU time's %M; see
              run_measured for why not this process's wait4). `--converted TABLE` reuses a
              table folder instead (nothing timed).
2. batches of 1024 in OGBench's layout (GCIQL's goal fractions on every side), three ways:
   pgser      `pgser.Sampler(TABLE, layout="ogbench", memory_budget=BUDGET, batch_size=1024)`,
              whole table, in a child process so that its peak RSS is its own;
   ram        `ogbench_peer.py --scheme ram`: one shard in memory (OGBench's trainer on one file);
   reload     `ogbench_peer.py --scheme reload --replace-interval N`: Horizon Reduction's one
              shard at a time, the next loaded synchronously every N batches (1000; 4000 for
              humanoidmaze, as their trainer uses).
   Each batch is timed on its own (perf_counter around `.sample(1024)` / one iteration) after a
   warm-up: batches/s, median, p99.9 and the longest batch (the pause a learner sees), and the
   child's peak RSS. pgser's Sampler does not report its pool's waits to Python, so pauses are
   read from the batch times, which is what a learner sees anyway.
3. the table's size as float32, as the pool plans it (src/sampler/pool.rs `Layout::bytes`:
   episodes x 4 x (T (obs + goal) + (T - 1)(goal + act)), dims from the manifest's footer), the
   budget and their ratio (3x or more is the aim), and the pool's plan (`Plan::of`'s split,
   mirrored here: resident row groups, reservoir), read from the shards' Parquet metadata.
4. the machine: CPU model, cores, memory, load average at start and end (and after each run).
5. RSS against size: (a) again, same budget, on a table of the first k shards (converted from a
   folder of symlinks to the first k .npz files). The default k is the fewest shards whose
   float32 size is 1.5x the budget or more, so that both tables stream: peak RSS should then be
   the same for both (flat), set by the budget and not by the table.

Fairness notes (also in the JSON): pgser's Sampler draws on a background thread that keeps
`--prefetch` batches ready, so on an idle machine it uses a second core while the learner's
thread waits in `.sample`; the numpy peers draw on the calling thread. The page cache is not
dropped (it cannot be, here): a table that fits in memory is likely cached after its convert, so
"from disk" then means the page cache; the JSON records the table's bytes and the machine's
memory so a reader can tell. Every side runs alone, one after another (`--repeat` rotates the
order; the summary gives medians, and the longest batch and peak RSS of all runs).

Prints progress, then a markdown table ready for BENCHMARKS.md; writes the figures to --json
(default WORKDIR/scale.json) and the table to WORKDIR/scale.md.

Usage (run in a Python that has `pgser` (make python) and numpy; pyarrow for the plan):
    .venv/bin/python bench/bench_scale.py SHARDS_DIR --budget 1GB [--converted TABLE]
        [--workdir bench-out/scale-NAME] [--batches N] [--warmup 20] [--batch-size 1024]
        [--replace-interval N] [--prefix K | --no-prefix] [--repeat 1] [--seed 0]
        [--prefetch 4] [--draws-per-row 1] [--convert-arg ARG ...] [--peer-python PY] [--pgser-etl PATH]
        [--json OUT.json]
bench/make_scale_data.sh gives the commands for the benchmark's data sets.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import shlex
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(HERE))
import peer_python  # noqa: E402

MiB = 1 << 20
# The pool's split of a budget (src/sampler/pool.rs): the reservoir's share, blocks in flight.
RESERVOIR_SHARE = 0.125
IN_FLIGHT = 3
SIDES = ("pgser", "pgser-prefix", "ram", "reload")


# ---------------------------------------------------------------- sizes and the plan


def parse_size(s: str) -> int:
    """A size as pgser's `--memory-budget` reads it (src/sampler/view.rs `parse_bytes`)."""
    m = re.fullmatch(r"\s*([0-9.]+)\s*([A-Za-z]*)\s*", s)
    units = {"": 1, "b": 1, "k": 1e3, "kb": 1e3, "m": 1e6, "mb": 1e6, "g": 1e9, "gb": 1e9, "t": 1e12,
             "tb": 1e12, "kib": 1 << 10, "mib": 1 << 20, "gib": 1 << 30, "tib": 1 << 40}
    if not m or m.group(2).lower() not in units:
        raise argparse.ArgumentTypeError(f"{s!r}: not a size (e.g. 2GB, 512MiB, 1000000000)")
    try:
        b = float(m.group(1)) * units[m.group(2).lower()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{s!r}: not a size (e.g. 2GB, 512MiB, 1000000000)") from None
    if b < 1:
        raise argparse.ArgumentTypeError(f"{s!r}: not a size of at least one byte")
    return int(b)


def human(n: float) -> str:
    """Bytes as pgser prints them (decimal units)."""
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= scale:
            return f"{n / scale:.2f} {unit}" if unit == "GB" else f"{n / scale:.1f} {unit}"
    return f"{n:.0f} B"


def episode_bytes(f: dict) -> int:
    """Float32 bytes of one episode as the pool holds it (src/sampler/pool.rs `episode_bytes`)."""
    t, goal = f["T"], f["goal_dim"]
    return 4 * (t * (f["obs_dim"] + goal) + (t - 1) * (goal + f["act_dim"]))


def table_info(table: Path, budget: int) -> dict:
    """The table's size as float32 (the pool's `Layout::bytes`) and, when pyarrow is at hand, the
    pool's plan for `budget` (`Plan::of`, mirrored: refusal, whole, or slots + reservoir)."""
    man = json.loads((table / "manifest.json").read_text())
    f = man["footer"]
    per_ep = episode_bytes(f)
    info = {"path": str(table), "shards": len(man["shards"]), "episodes": man["episodes"], "rows": man["rows"],
            "T": f["T"], "obs_dim": f["obs_dim"], "goal_dim": f["goal_dim"], "act_dim": f["act_dim"],
            "task": f.get("task"), "disk_bytes": sum(s["bytes"] for s in man["shards"]),
            "episode_f32_bytes": per_ep, "f32_bytes": man["episodes"] * per_ep,
            "transitions": man["episodes"] * (f["T"] - 1)}
    try:
        import pyarrow.parquet as pq
    except ImportError:
        info["plan"] = {"kind": "unknown (no pyarrow to read the row groups)"}
        return info
    blocks = []
    for s in man["shards"]:
        md = pq.ParquetFile(table / s["file"]).metadata
        blocks += [md.row_group(g).num_rows // f["T"] for g in range(md.num_row_groups)]
    info["row_groups"] = len(blocks)
    block = max(blocks) * per_ep
    info["largest_row_group_f32_bytes"] = block
    entry = 4 * (f["obs_dim"] + f["goal_dim"]) + 16
    if info["f32_bytes"] <= budget:
        info["plan"] = {"kind": "whole"}
        return info
    reservoir = max(min(int(budget * RESERVOIR_SHARE) // entry, man["episodes"] * f["T"]), 1)
    fixed = reservoir * entry + IN_FLIGHT * block
    slots = max(budget - fixed, 0) // block
    if slots < 2:
        info["plan"] = {"kind": "refused", "need_bytes": fixed + 2 * block}
    elif slots >= len(blocks):
        info["plan"] = {"kind": "whole"}
    else:
        eps = sorted(blocks, reverse=True)
        info["plan"] = {"kind": "pool", "resident_row_groups": slots, "row_groups": len(blocks),
                        "reservoir_goals": reservoir, "resident_episodes_at_most": sum(eps[:slots])}
    return info


def plan_text(info: dict, budget: int) -> str:
    p = info.get("plan", {})
    if p.get("kind") == "pool":
        return (f"pool: {p['resident_row_groups']} of {p['row_groups']} row groups resident, "
                f"{p['reservoir_goals']:,} reservoir goals (budget {human(budget)})")
    if p.get("kind") == "whole":
        return f"whole table in memory (it fits the budget {human(budget)})"
    if p.get("kind") == "refused":
        return f"refused: the budget holds fewer than two row groups (needs {human(p['need_bytes'])})"
    return p.get("kind", "?")


# ---------------------------------------------------------------- children


TIME = Path("/usr/bin/time")


def run_measured(cmd: list[str], out_path: Path, err_path: Path, env: dict | None = None) -> dict:
    """Run cmd as a child (stdout, stderr to files): wall seconds, CPU seconds and peak RSS.

    Peak RSS comes from GNU time (`/usr/bin/time -f %M`, the maxrss of what it waits for) when
    it is installed: a child's ru_maxrss starts at its parent's RSS when it forks (Linux carries
    the forking process's high-water mark across exec), so os.wait4 from this Python process,
    which holds pyarrow and numpy, would report at least this process's size. time is a small C
    program, so the command it forks starts from next to nothing.
    """
    rss_file = out_path.with_suffix(".maxrss")
    full = [str(TIME), "-o", str(rss_file), "-f", "%M", *cmd] if TIME.exists() else cmd
    with open(out_path, "wb") as out, open(err_path, "wb") as err:
        t0 = time.perf_counter()
        proc = subprocess.Popen(full, stdout=out, stderr=err, stdin=subprocess.DEVNULL, env=env)
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
    res = {"rc": os.waitstatus_to_exitcode(status), "wall_s": wall, "cpu_s": ru.ru_utime + ru.ru_stime,
           "major_faults": ru.ru_majflt}
    kib = None
    if TIME.exists():
        try:
            kib = int(rss_file.read_text().split()[-1])
        except (OSError, ValueError, IndexError):
            pass
    if kib is not None:
        res.update({"peak_rss_bytes": kib * 1024, "peak_rss_from": "/usr/bin/time %M"})
    else:
        res.update({"peak_rss_bytes": ru.ru_maxrss * 1024,
                    "peak_rss_from": "os.wait4 ru_maxrss (at least this script's own RSS at the fork)"})
    return res



def vm(key: str) -> int | None:
    """This process's /proc/self/status figure `key` (VmRSS, VmHWM) in bytes."""
    try:
        for line in open("/proc/self/status"):
            if line.startswith(key + ":"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def pgser_child(argv: list[str]) -> None:
    """(a) in its own process: open the Sampler, warm up, time each `.sample(n)`; print one JSON."""
    ap = argparse.ArgumentParser(prog="bench_scale.py _pgser")
    ap.add_argument("table")
    ap.add_argument("--budget-bytes", type=int, required=True)
    ap.add_argument("--batches", type=int, required=True)
    ap.add_argument("--warmup", type=int, required=True)
    ap.add_argument("--batch-size", type=int, required=True)
    ap.add_argument("--seed", type=int, required=True)
    ap.add_argument("--prefetch", type=int, required=True)
    ap.add_argument("--draws-per-row", type=int, default=1)
    a = ap.parse_args(argv)
    import numpy as np
    import pgser

    rss_start = vm("VmRSS")
    t0 = time.perf_counter()
    s = pgser.Sampler(a.table, layout="ogbench", memory_budget=a.budget_bytes, batch_size=a.batch_size,
                      seed=a.seed, prefetch=a.prefetch, draws_per_row=a.draws_per_row)
    open_s = time.perf_counter() - t0
    rss_open = vm("VmRSS")
    for _ in range(a.warmup):
        b = s.sample(a.batch_size)
    rss_warm = vm("VmRSS")
    times = np.empty(a.batches)
    start = time.perf_counter()
    for i in range(a.batches):
        t = time.perf_counter()
        b = s.sample(a.batch_size)
        times[i] = time.perf_counter() - t
    seconds = time.perf_counter() - start
    shapes = {k: list(v.shape) for k, v in b.items()}
    pool = s.pool_stats()  # the pool's own waits for blocks: tells disk waits from scheduling
    s.close()
    ms = times * 1e3
    med = float(np.median(ms))
    slow = ms > 10 * med
    top = np.argsort(ms)[::-1][:10]
    print(json.dumps({
        "side": "pgser", "pgser": getattr(pgser, "long_version", "?"), "numpy": np.__version__,
        "batches": a.batches, "batch_size": a.batch_size, "seconds": seconds,
        "batches_per_sec": a.batches / seconds, "median_ms": med,
        "p99_ms": float(np.quantile(ms, 0.99)), "p999_ms": float(np.quantile(ms, 0.999)),
        "max_ms": float(ms.max()), "mean_ms": float(ms.mean()),
        "slow_batches": int(slow.sum()), "slow_ms_total": float(ms[slow].sum()),
        "longest": [[int(i), float(ms[i])] for i in top],
        "pool": pool, "open_seconds": open_s, "rss_start_bytes": rss_start, "rss_after_open_bytes": rss_open,
        "rss_after_warmup_bytes": rss_warm, "rss_end_bytes": vm("VmRSS"), "hwm_bytes": vm("VmHWM"),
        "peak_rss_self_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024,
        "batch_shapes": shapes,
    }), flush=True)


# ---------------------------------------------------------------- data


def shard_number(p: Path) -> int | None:
    m = re.search(r"-(\d+)\.npz$", p.name)
    return int(m.group(1)) if m else None


def npz_shards(folder: Path) -> list[Path]:
    """The training shards, ordered by number as `convert` orders them (-2 before -10)."""
    files = [p for p in folder.glob("*.npz") if shard_number(p) is not None]
    if not files:
        sys.exit(f"{folder}: no NAME-i.npz shards")
    return sorted(files, key=shard_number)


def remove_table(path: Path) -> None:
    """Remove an earlier output of this script: a table folder (manifest.json, .parquet, val/)
    or a convert that was killed; anything else there is refused, never deleted."""
    if not path.exists():
        return
    allowed = {"manifest.json", "val"}
    odd = [p.name for p in path.iterdir() if p.name not in allowed and not p.name.endswith(".parquet")
           and not p.name.startswith(".")]
    if odd:
        sys.exit(f"{path}: holds files other than a table folder's ({', '.join(sorted(odd)[:5])}); "
                 f"not removing it, pass another --workdir")
    shutil.rmtree(path)


def convert(etl: Path, src: Path, out: Path, extra: list[str], logdir: Path, label: str) -> dict:
    remove_table(out)
    os.sync()  # untimed: earlier runs' dirty pages
    cmd = [str(etl), "convert", str(src), "-o", str(out), *extra]
    print(f"convert ({label}): {shlex.join(cmd)}", flush=True)
    load = os.getloadavg()
    m = run_measured(cmd, logdir / f"convert-{label}.out", logdir / f"convert-{label}.err")
    if m["rc"] != 0:
        sys.exit(f"convert failed (exit {m['rc']}): {shlex.join(cmd)}\n{peer_python.tail(logdir / f'convert-{label}.err')}")
    man = json.loads((out / "manifest.json").read_text())
    m.update({"command": shlex.join(cmd), "rows": man["rows"], "episodes": man["episodes"],
              "shards": len(man["shards"]), "rows_per_sec": man["rows"] / m["wall_s"],
              "output_bytes": sum(s["bytes"] for s in man["shards"]),
              "input_bytes": sum(p.stat().st_size for p in npz_shards(src)),
              "loadavg_before": load, "loadavg_after": os.getloadavg()})
    print(f"  {m['rows']:,} rows in {m['wall_s']:.1f} s: {m['rows_per_sec']:,.0f} rows/s, "
          f"peak RSS {m['peak_rss_bytes'] / MiB:,.0f} MiB", flush=True)
    return m


def prefix_count(info: dict, budget: int, n: int) -> int:
    """The fewest shards whose float32 size is 1.5x the budget or more (so the prefix streams too)."""
    man = json.loads((Path(info["path"]) / "manifest.json").read_text())
    total = 0
    for k, s in enumerate(man["shards"], 1):
        total += s["episodes"] * info["episode_f32_bytes"]
        if total >= 1.5 * budget:
            return k
    return n


def same_prefix(ptable: Path, table: Path, k: int) -> bool:
    """Whether `ptable` was converted from the first k sources of `table`, with its settings
    (the sources' SHA-256 in the footers, and the manifests' convert settings)."""
    try:
        p, t = (json.loads((x / "manifest.json").read_text()) for x in (ptable, table))
    except (OSError, ValueError):
        return False
    sha = lambda m: [src.get("sha256") for src in m["footer"].get("sources", [])]  # noqa: E731
    return (len(p["shards"]) == k and sha(p) == sha(t)[:k] and None not in sha(p)
            and p.get("settings") == t.get("settings"))


def machine() -> dict:
    model = None
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = None
    try:
        for line in open("/proc/meminfo"):
            if line.startswith("MemTotal:"):
                mem = int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count()
    out = {"cpu_model": model or platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
           "usable_cores": usable, "mem_total_bytes": mem, "platform": platform.platform(),
           "python": platform.python_version()}
    try:
        import numpy
        out["numpy"] = numpy.__version__
    except ImportError:
        pass
    return out


# ---------------------------------------------------------------- the run


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["_pgser"]:
        return pgser_child(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("shards", help="folder of NAME-i.npz shards (Horizon Reduction's layout)")
    ap.add_argument("--budget", required=True, type=parse_size,
                    help="pgser's memory_budget: bytes or a size (2GB, 512MiB), as --memory-budget reads it")
    ap.add_argument("--converted", help="reuse this table folder (convert of SHARDS) instead of converting")
    ap.add_argument("--workdir", help="tables, logs and outputs (default bench-out/scale-<shards folder name>)")
    ap.add_argument("--batches", type=int, help="timed batches per side (default max(3000, 3 x the reload interval))")
    ap.add_argument("--warmup", type=int, default=20, help="untimed batches first (default 20)")
    ap.add_argument("--batch-size", type=int, default=1024)
    ap.add_argument("--replace-interval", type=int,
                    help="the reload peer's batches per shard (default 4000 for humanoidmaze data, else 1000)")
    ap.add_argument("--prefix", type=int, help="shards in the RSS-vs-size table (default: the fewest whose "
                                                 "float32 size is 1.5x the budget)")
    ap.add_argument("--no-prefix", action="store_true", help="skip the RSS-vs-size run")
    ap.add_argument("--repeat", type=int, default=1, help="runs per side, order rotated (default 1)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--prefetch", type=int, default=4, help="pgser.Sampler's prefetch (default 4, its own)")
    ap.add_argument("--draws-per-row", type=int, default=1,
                    help="pgser.Sampler's draws_per_row: draws per transition a row group stays for (default 1)")
    ap.add_argument("--convert-arg", action="append", default=[],
                    help="extra argument for `pgser-etl convert` (repeatable; e.g. --convert-arg=--row-group-rows=4001)")
    ap.add_argument("--python", default=sys.executable, help="interpreter with pgser for (a) (default: this one)")
    ap.add_argument("--peer-python", default=None, help="interpreter with numpy for the peers (default: --python)")
    ap.add_argument("--pgser-etl", default=str(REPO / "target" / "release" / "pgser-etl"))
    ap.add_argument("--json", help="write the figures here (default WORKDIR/scale.json)")
    args = ap.parse_args(argv)
    if args.repeat < 1 or args.batch_size < 1 or args.warmup < 0:
        ap.error("--repeat >= 1, --batch-size >= 1, --warmup >= 0")

    src = Path(args.shards).resolve()
    shards = npz_shards(src)
    name = re.sub(r"-\d+\.npz$", "", shards[0].name)
    workdir = Path(args.workdir or REPO / "bench-out" / f"scale-{src.name}").resolve()
    logdir = workdir / "logs"
    logdir.mkdir(parents=True, exist_ok=True)
    etl = Path(args.pgser_etl).resolve()
    python = peer_python.resolve(args.python, "pgser numpy (make python)")
    peer_py = peer_python.resolve(args.peer_python, "numpy") if args.peer_python else python
    interval = args.replace_interval or (4000 if "humanoidmaze" in name else 1000)
    batches = args.batches or max(3000, 3 * interval)
    budget = args.budget
    if batches < 2 * interval:
        print(f"note: {batches} batches with a reload every {interval}: the reload peer reloads "
              f"{(batches - 1) // interval} time(s) (2 or more wants --batches {3 * interval})", flush=True)
    load_start = os.getloadavg()
    mach = machine()
    print(f"{name}: {len(shards)} shards in {src}; budget {human(budget)}; {batches} batches of "
          f"{args.batch_size} per side after {args.warmup} warm-up; machine {mach['cpu_model']}, "
          f"{mach['usable_cores']} cores, load {load_start[0]:.2f}", flush=True)

    # 1. convert
    conv = {}
    if args.converted:
        table = Path(args.converted).resolve()
        if not (table / "manifest.json").is_file():
            sys.exit(f"--converted {table}: no manifest.json (not a table folder)")
        # The peers read the shards, pgser the table: they must be the same data.
        footer = json.loads((table / "manifest.json").read_text())["footer"]
        names = [Path(x["path"]).name for x in footer.get("sources", [])]
        if names != [p.name for p in shards]:
            sys.exit(f"--converted {table}: converted from {len(names)} sources ({', '.join(names[:3])} ...), "
                     f"not from the {len(shards)} shards of {src} ({', '.join(p.name for p in shards[:3])} ...)")
    else:
        if not os.access(etl, os.X_OK):
            sys.exit(f"--pgser-etl {etl}: not an executable file (cargo build --release)")
        table = workdir / "table"
        conv["whole"] = convert(etl, src, table, args.convert_arg, logdir, "whole")

    # 3. the table against the budget
    info = table_info(table, budget)
    info["ratio_to_budget"] = info["f32_bytes"] / budget
    print(f"table: {info['rows']:,} rows, {info['episodes']:,} episodes of T = {info['T']}, "
          f"obs {info['obs_dim']} goal {info['goal_dim']} act {info['act_dim']}: {human(info['f32_bytes'])} as "
          f"float32, {info['ratio_to_budget']:.2f}x the budget; {human(info['disk_bytes'])} on disk; "
          f"{plan_text(info, budget)}", flush=True)
    if info["plan"].get("kind") == "refused":
        sys.exit(f"{table}: pgser would refuse a budget of {human(budget)}: it holds fewer than two row groups; "
                 f"give at least {human(info['plan']['need_bytes'])} or convert with a smaller --row-group-rows")
    if info["ratio_to_budget"] < 3:
        print(f"note: the table is {info['ratio_to_budget']:.2f}x the budget (3x or more is the aim)", flush=True)

    # 5. the prefix table
    prefix = None
    if not args.no_prefix:
        k = args.prefix or prefix_count(info, budget, len(shards))
        if k >= len(shards) or k < 1:
            print(f"RSS-vs-size: skipped (a prefix of {k} shards is not part of the {len(shards)}; the fewest "
                  f"that are 1.5x the budget are all of them: a smaller --budget or --prefix K)", flush=True)
        else:
            psrc = workdir / f"prefix-{k}-npz"
            if psrc.exists():
                shutil.rmtree(psrc)
            psrc.mkdir(parents=True)
            for p in shards[:k]:
                (psrc / p.name).symlink_to(p)
            ptable = workdir / f"prefix-{k}"
            if args.converted and same_prefix(ptable, table, k):
                print(f"prefix: reusing {ptable} (its sources are the table's first {k})", flush=True)
            else:
                if not os.access(etl, os.X_OK):
                    sys.exit(f"--pgser-etl {etl}: not an executable file (needed for the prefix table)")
                conv["prefix"] = convert(etl, psrc, ptable, args.convert_arg, logdir, f"prefix-{k}")
                ps, ts = (json.loads((x / "manifest.json").read_text()).get("settings", {}) for x in (ptable, table))
                diff = {key: (ts.get(key), ps.get(key)) for key in set(ps) | set(ts) if ps.get(key) != ts.get(key)}
                if diff:
                    sys.exit(f"{ptable}: converted with other settings than {table} (table, prefix: {diff}); "
                             f"pass the --convert-arg that made the table")
            pinfo = table_info(ptable, budget)
            pinfo["ratio_to_budget"] = pinfo["f32_bytes"] / budget
            if pinfo["plan"].get("kind") == "refused":
                sys.exit(f"{ptable}: pgser would refuse a budget of {human(budget)}: give at least "
                         f"{human(pinfo['plan']['need_bytes'])} or convert with a smaller --row-group-rows")
            prefix = {"shards": k, "table": pinfo}
            print(f"prefix: first {k} shards, {human(pinfo['f32_bytes'])} as float32 "
                  f"({pinfo['ratio_to_budget']:.2f}x the budget); {plan_text(pinfo, budget)}", flush=True)

    # 2. the samplers
    def pgser_cmd(t: Path) -> list[str]:
        return [python, str(Path(__file__).resolve()), "_pgser", str(t), "--budget-bytes", str(budget),
                "--batches", str(batches), "--warmup", str(args.warmup), "--batch-size", str(args.batch_size),
                "--seed", str(args.seed), "--prefetch", str(args.prefetch),
                "--draws-per-row", str(args.draws_per_row)]

    peer = [peer_py, str(HERE / "ogbench_peer.py"), str(src), "--batches", str(batches), "--warmup",
            str(args.warmup), "--batch-size", str(args.batch_size), "--seed", str(args.seed)]
    cmds = {"pgser": pgser_cmd(table), "ram": peer + ["--scheme", "ram"],
            "reload": peer + ["--scheme", "reload", "--replace-interval", str(interval)]}
    if prefix:
        cmds["pgser-prefix"] = pgser_cmd(workdir / f"prefix-{prefix['shards']}")
    sides = [s for s in SIDES if s in cmds]
    runs = {s: [] for s in sides}
    failed = {}
    for r in range(args.repeat):
        order = sides[r % len(sides):] + sides[:r % len(sides)]
        for side in order:
            if side in failed:
                continue
            out, err = logdir / f"{side}_{r}.out", logdir / f"{side}_{r}.err"
            load = os.getloadavg()
            m = run_measured(cmds[side], out, err)
            rep = peer_python.last_json(out.read_text(errors="replace"), "batches_per_sec")
            if m["rc"] != 0 or rep is None:
                why = f"exit {m['rc']}" if m["rc"] != 0 else "no JSON line with batches_per_sec"
                print(f"\n{side} failed ({why}): {shlex.join(cmds[side])}\n{peer_python.tail(err)}", file=sys.stderr)
                last = [x for x in peer_python.tail(err).splitlines() if x.strip()]
                failed[side] = f"{why}: {last[-1].strip() if last else ''}"
                continue
            m.update({"run": r, "report": rep, "loadavg_before": load, "loadavg_after": os.getloadavg()})
            runs[side].append(m)
            print(f"  run {r + 1}/{args.repeat} {side:12s}: {rep['batches_per_sec']:8.0f} batches/s  median "
                  f"{rep['median_ms']:6.2f} ms  p99.9 {rep['p999_ms']:7.2f} ms  longest {rep['max_ms']:8.1f} ms  "
                  f"peak RSS {m['peak_rss_bytes'] / MiB:7.0f} MiB  (load {m['loadavg_after'][0]:.2f})", flush=True)
    load_end = os.getloadavg()

    def summary(side: str) -> dict:
        xs = runs[side]
        rep = [x["report"] for x in xs]
        med = lambda k: statistics.median([r[k] for r in rep])  # noqa: E731
        s = {"command": shlex.join(cmds[side]), "runs": len(xs), "batches_per_sec": med("batches_per_sec"),
             "batches_per_sec_all": [r["batches_per_sec"] for r in rep], "median_ms": med("median_ms"),
             "p999_ms": med("p999_ms"), "max_ms": max(r["max_ms"] for r in rep),
             "peak_rss_bytes": max(x["peak_rss_bytes"] for x in xs)}
        if side.startswith("pgser"):
            s.update({"open_seconds": med("open_seconds"), "slow_batches": med("slow_batches"),
                      "slow_ms_total": med("slow_ms_total"), "p99_ms": med("p99_ms")})
        else:
            s.update({"reloads": rep[-1]["reloads"], "rows_loaded": rep[-1]["rows_loaded"],
                      "load_seconds": med("load_seconds")})
        return s

    summ = {s: summary(s) for s in sides if runs[s]}
    rss = None
    if "pgser" in summ and "pgser-prefix" in summ:
        rss = {"prefix_shards": prefix["shards"], "prefix_f32_bytes": prefix["table"]["f32_bytes"],
               "whole_f32_bytes": info["f32_bytes"], "prefix_peak_rss_bytes": summ["pgser-prefix"]["peak_rss_bytes"],
               "whole_peak_rss_bytes": summ["pgser"]["peak_rss_bytes"],
               "size_ratio": info["f32_bytes"] / prefix["table"]["f32_bytes"],
               "rss_ratio": summ["pgser"]["peak_rss_bytes"] / summ["pgser-prefix"]["peak_rss_bytes"]}

    md = markdown(name, len(shards), info, budget, conv, summ, prefix, rss, interval, batches, args, mach,
                  load_start, load_end, failed)
    print()
    print(md)
    (workdir / "scale.md").write_text(md + "\n")
    doc = {"dataset": name, "shards_dir": str(src), "shards": len(shards), "table": info, "budget_bytes": budget,
           "ratio_table_f32_to_budget": info["ratio_to_budget"], "batch_size": args.batch_size,
           "batches": batches, "warmup": args.warmup, "replace_interval": interval, "seed": args.seed,
           "prefetch": args.prefetch, "draws_per_row": args.draws_per_row, "repeat": args.repeat, "convert": conv, "prefix": prefix,
           "rss_vs_size": rss, "summary": summ, "runs": runs, "failed": failed, "machine": mach,
           "loadavg_start": load_start, "loadavg_end": load_end,
           "notes": ["pgser.Sampler draws on a background thread (prefetch batches ready): on an idle machine "
                     "it uses a second core while .sample() waits; the numpy peers draw on the calling thread",
                     "page cache not dropped: a table smaller than the machine's memory is likely cached "
                     "after its convert (see table.disk_bytes and machine.mem_total_bytes)",
                     "pool waits are not exposed to Python: pauses are the batch-time outliers "
                     "(summary.*.max_ms, slow_batches = batches over 10x the median)"]}
    out_json = Path(args.json) if args.json else workdir / "scale.json"
    out_json.write_text(json.dumps(doc, indent=2) + "\n")
    print(f"wrote {out_json} and {workdir / 'scale.md'}")
    if failed:
        sys.exit(1)


def markdown(name, n, info, budget, conv, summ, prefix, rss, interval, batches, args, mach, l0, l1, failed) -> str:
    mib = lambda b: f"{b / MiB:,.0f} MiB"  # noqa: E731
    lines = [f"### {name}: {n} shards, {info['rows']:,} rows ({info['episodes']:,} episodes of {info['T']}), "
             f"{human(info['f32_bytes'])} as float32; budget {human(budget)} ({info['ratio_to_budget']:.2f}x)",
             "",
             f"{mach['cpu_model']}, {mach['usable_cores']} cores, "
             f"{human(mach['mem_total_bytes'] or 0)} memory; load average {l0[0]:.2f} at start, {l1[0]:.2f} at end; "
             f"table {human(info['disk_bytes'])} on disk; {plan_text(info, budget)}.",
             ""]
    if conv:
        lines += ["| `pgser-etl convert` | rows | wall | rows/s | peak RSS | input | output |", "|---|---|---|---|---|---|---|"]
        for k, c in conv.items():
            what = f"{c['shards']} shards" + (" (prefix)" if k == "prefix" else "")
            lines.append(f"| {what} | {c['rows']:,} | {c['wall_s']:.1f} s | {c['rows_per_sec']:,.0f} | "
                         f"{mib(c['peak_rss_bytes'])} | {human(c['input_bytes'])} | {human(c['output_bytes'])} |")
        lines.append("")
    lines += [f"| batches of {args.batch_size}, OGBench's layout ({batches:,} timed) | data drawn from | batches/s | "
              f"median | p99.9 | longest (pause) | peak RSS | start |", "|---|---|---|---|---|---|---|---|"]
    labels = {
        "pgser": ("pgser.Sampler, memory_budget", f"the whole table ({info['shards']} shards)"),
        "pgser-prefix": ("pgser.Sampler, same budget", f"the first {prefix['shards'] if prefix else '?'} shards"),
        "ram": ("numpy, one shard in RAM (OGBench)", "shard 0"),
        "reload": (f"numpy, reload every {interval} (Horizon Reduction)", "one shard at a time"),
    }
    for side in SIDES:
        if side not in summ:
            if side in failed:
                lines.append(f"| {labels[side][0]} | failed: {failed[side].splitlines()[0]} | | | | | | |")
            continue
        s = summ[side]
        where = labels[side][1]
        if side == "reload":
            where += f", {s['reloads']} reloads"
        lines.append(f"| {labels[side][0]} | {where} | {s['batches_per_sec']:,.0f} | {s['median_ms']:.2f} ms | "
                     f"{s['p999_ms']:.2f} ms | {s['max_ms']:.1f} ms | {mib(s['peak_rss_bytes'])} | "
                     f"{s.get('open_seconds', s.get('load_seconds', 0)):.2f} s |")
    lines += ["", "start: opening the Sampler (pgser: the goal reservoir's first fill from every row group and "
                  "the first resident row groups) or loading the first shard (numpy), before the warm-up; not "
                  "in batches/s. longest: the slowest single batch, a pool's wait or a shard's reload."]
    if rss:
        lines += ["", f"Peak RSS against size, same budget: {rss['prefix_shards']} shards "
                      f"({human(rss['prefix_f32_bytes'])} as float32) {mib(rss['prefix_peak_rss_bytes'])}; "
                      f"{n} shards ({human(rss['whole_f32_bytes'])}) {mib(rss['whole_peak_rss_bytes'])}: "
                      f"{rss['size_ratio']:.2f}x the data, {rss['rss_ratio']:.2f}x the memory."]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
