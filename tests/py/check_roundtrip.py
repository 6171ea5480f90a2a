#!/usr/bin/env python3
"""Check a pgser trajectory Parquet file against the pickles it came from.

Usage:
  check_roundtrip.py --parquet OUT.parquet [--episodes k1,k2,...] [--float32]
                     [--task NAME] IN.pkl [IN2.pkl ...]

Loads each (trusted!) pickle as stored (stored_pickle.py: each dtype keeps
its byte order; values checked against numpy's pickle.load), takes the
first k_i episodes of input i (all when --episodes is absent), concatenates
them, and checks that the Parquet file has

  * columns exactly: episode int64, step int32, obs, achieved_goal,
    desired_goal, action -- the last four FixedSizeList<float64> (or
    float32 with --float32, or when the sources are float32) of the right
    width -- then one passthrough column per other array of the first input
    (its key, in the pickle's order), listed in the footer's `passthrough`
    with its dtype (the source's, byte order included: `>f4`), shape and
    layout, and holding the source's values on exactly the rows that layout
    gives (per step: every row; per transition: all but step T-1; per
    episode: step 0), equal bit for bit;
  * one row per (episode, step), episode-major: episodes 0..E-1 dense and
    contiguous, steps 0..T-1 in order;
  * obs <- o, achieved_goal <- ag, desired_goal <- g, action <- u, equal
    BIT FOR BIT after converting the source to native little-endian C order
    (with --float32: to source.astype(float32));
  * desired_goal and action null exactly on step T-1, non-null elsewhere;
    obs and achieved_goal never null (no null floats inside valid lists);
  * footer key-value metadata "pgser" = JSON with schema_version,
    kind == "trajectory", task (== --task when given), T, episodes,
    obs_dim, goal_dim, act_dim matching the data.

Prints "OK <rows> rows" and exits 0, or prints every kind of difference
found (the first mismatching episode/step/column for values) and exits 1.
Exit 2 means the inputs or arguments themselves are unusable.
Needs numpy and pyarrow.
"""
import argparse
import json
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

import stored_pickle

COLUMNS = ["episode", "step", "obs", "achieved_goal", "desired_goal", "action"]
SOURCE_KEY = {"obs": "o", "achieved_goal": "ag", "desired_goal": "g", "action": "u"}
DIM_KEY = {"obs": "obs_dim", "achieved_goal": "goal_dim",
           "desired_goal": "goal_dim", "action": "act_dim"}


def die(msg):
    print(f"error: {msg}")
    sys.exit(2)


def native(a):
    """Native little-endian, C-order copy (pgser's Parquet layout)."""
    a = np.asarray(a)
    return np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<")))


def load_inputs(paths, counts):
    parts = []
    for i, path in enumerate(paths):
        # As stored, byte order included (numpy's pickle.load gives a big-endian array back as
        # a native one); stored_pickle checks the values against numpy's own reading too.
        d = stored_pickle.load(path)  # trusted test inputs only
        if not isinstance(d, dict):
            die(f"{path}: top level is {type(d).__name__}, not a dict")
        arrs, extras = {}, {}
        for k, v in d.items():
            if k not in ("o", "ag", "u", "g"):
                extras[k] = np.asarray(v)
        for k in ("o", "ag", "u", "g"):
            if k not in d:
                die(f"{path}: missing key {k!r}")
            a = d[k]
            if not isinstance(a, np.ndarray) or a.dtype.kind != "f" or a.ndim != 3:
                die(f"{path}: {k} is not a 3-d float ndarray")
            arrs[k] = a
        n, t = arrs["o"].shape[:2]
        if (arrs["ag"].shape[:2] != (n, t) or arrs["u"].shape[:2] != (n, t - 1)
                or arrs["g"].shape[:2] != (n, t - 1)):
            die(f"{path}: inconsistent shapes "
                + ", ".join(f"{k}{arrs[k].shape}" for k in arrs))
        k_i = n if counts is None else counts[i]
        if k_i > n:
            die(f"{path}: asked for {k_i} episodes, file has {n}")
        parts.append((path, k_i, {k: native(v[:k_i]) for k, v in arrs.items()},
                      {k: v[:k_i] for k, v in extras.items()}))
    return parts


def layout(a, t):
    """pgser's layout of a passthrough array [N, ...]: per step, transition or episode."""
    if a.ndim >= 2 and a.shape[1] == t:
        return "step", list(a.shape[2:])
    if a.ndim >= 2 and a.shape[1] == t - 1:
        return "transition", list(a.shape[2:])
    return "episode", list(a.shape[1:])


def bits(a):
    return a.view(np.uint64 if a.dtype.itemsize == 8 else np.uint32)


def fmt(x):
    x = np.asarray(x)
    b = int(bits(x.reshape(1))[0])
    return f"{np.format_float_scientific(x.dtype.type(x), unique=True)} (bits 0x{b:0{2 * x.dtype.itemsize}x})"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[1])
    ap.add_argument("--parquet", required=True)
    ap.add_argument("--episodes", help="k1,k2,...: first k_i episodes of input i")
    ap.add_argument("--float32", action="store_true")
    ap.add_argument("--task", help="expected footer task (optional)")
    ap.add_argument("inputs", nargs="+")
    args = ap.parse_args()

    counts = None
    if args.episodes is not None:
        try:
            counts = [int(x) for x in args.episodes.split(",")]
        except ValueError:
            die(f"bad --episodes {args.episodes!r}")
        if len(counts) != len(args.inputs):
            die(f"--episodes has {len(counts)} counts for {len(args.inputs)} inputs")

    parts = load_inputs(args.inputs, counts)
    parts, extras_of = [p[:3] for p in parts], [p[3] for p in parts]
    T = parts[0][2]["o"].shape[1]
    extra_keys = list(extras_of[0])
    columns = COLUMNS + extra_keys
    dims = {"obs_dim": parts[0][2]["o"].shape[2], "goal_dim": parts[0][2]["ag"].shape[2],
            "act_dim": parts[0][2]["u"].shape[2]}
    widths = set()
    for path, _, a in parts:
        if a["o"].shape[1] != T:
            die(f"{path}: T={a['o'].shape[1]}, first input has T={T}")
        got = {"obs_dim": a["o"].shape[2], "goal_dim": a["ag"].shape[2], "act_dim": a["u"].shape[2]}
        if got != dims or a["g"].shape[2] != dims["goal_dim"]:
            die(f"{path}: dims {got} differ from first input {dims}")
        widths.update(v.dtype.itemsize for v in a.values())
    if len(widths) != 1 and not args.float32:
        die(f"inputs mix float widths {sorted(widths)} (only meaningful with --float32)")
    out_dtype = np.dtype(np.float32) if args.float32 or widths == {4} else np.dtype(np.float64)
    pa_float = pa.float32() if out_dtype == np.float32 else pa.float64()

    # expected data, concatenated; which input each global episode came from
    expected = {}
    origin = []
    for path, k_i, _ in parts:
        origin += [(path, j) for j in range(k_i)]
    with np.errstate(over="ignore", under="ignore", invalid="ignore"):
        for col, key in SOURCE_KEY.items():
            cat = np.concatenate([a[key] for _, _, a in parts], axis=0)
            expected[col] = np.ascontiguousarray(cat.astype(out_dtype))
    E = len(origin)
    rows_expected = E * T

    problems = []

    pf = pq.ParquetFile(args.parquet)
    table = pf.read()
    schema = table.schema

    # ---- footer metadata -------------------------------------------------
    kv = pf.metadata.metadata or {}
    meta = None
    if b"pgser" not in kv:
        problems.append(f"footer: no 'pgser' key-value metadata (keys: {sorted(k.decode() for k in kv)})")
    else:
        try:
            meta = json.loads(kv[b"pgser"])
        except ValueError as e:
            meta = None
            problems.append(f"footer: 'pgser' is not JSON: {e}")
        if meta is not None:
            if not isinstance(meta, dict):
                problems.append(f"footer: 'pgser' JSON is {type(meta).__name__}, not an object")
            else:
                want = {"kind": "trajectory", "T": T, "episodes": E, **dims}
                if args.task is not None:
                    want["task"] = args.task
                if "schema_version" not in meta:
                    problems.append("footer: 'pgser' lacks schema_version")
                if not isinstance(meta.get("task"), str) or not meta.get("task"):
                    problems.append(f"footer: task is {meta.get('task')!r}, want a non-empty string")
                for k, v in want.items():
                    if k not in meta:
                        problems.append(f"footer: 'pgser' lacks {k} (want {v!r})")
                    elif meta[k] != v or type(meta[k]) is bool:
                        problems.append(f"footer: {k} = {meta[k]!r}, want {v!r}")

    # ---- schema ----------------------------------------------------------
    if schema.names != columns:
        problems.append(f"columns are {schema.names}, want exactly {columns}")
    want_types = {"episode": pa.int64(), "step": pa.int32()}
    for name in COLUMNS:
        if name not in schema.names:
            continue
        t = schema.field(name).type
        if name in want_types:
            if t != want_types[name]:
                problems.append(f"column {name}: type {t}, want {want_types[name]}")
            continue
        size = dims[DIM_KEY[name]]
        if not pa.types.is_fixed_size_list(t):
            problems.append(f"column {name}: type {t}, want fixed_size_list<{pa_float}>[{size}]")
        elif t.value_type != pa_float or t.list_size != size:
            problems.append(f"column {name}: type {t}, want fixed_size_list<{pa_float}>[{size}]")

    if table.num_rows != rows_expected:
        problems.append(f"rows: {table.num_rows}, want {rows_expected} ({E} episodes x T={T})")

    def report_and_exit():
        for p in problems:
            print(p)
        print(f"FAILED: {len(problems)} problem(s) in {args.parquet}")
        sys.exit(1)

    if problems and (table.num_rows != rows_expected or schema.names != columns
                     or any(p.startswith("column ") for p in problems)):
        report_and_exit()

    # ---- episode / step ---------------------------------------------------
    want_ep = np.repeat(np.arange(E, dtype=np.int64), T)
    want_st = np.tile(np.arange(T, dtype=np.int32), E)
    for name, want in (("episode", want_ep), ("step", want_st)):
        col = table.column(name)
        if col.null_count:
            problems.append(f"column {name}: {col.null_count} nulls")
            continue
        got = col.to_numpy()
        bad = np.flatnonzero(got != want)
        if bad.size:
            r = int(bad[0])
            problems.append(
                f"column {name}: row {r} is {got[r]}, want {want[r]} "
                f"(want episode-major rows, episodes 0..{E - 1} dense, steps 0..{T - 1}); "
                f"{bad.size} rows differ")

    # ---- float columns ------------------------------------------------------
    last = want_st == T - 1
    for name in COLUMNS[2:]:
        arr = table.column(name).combine_chunks()
        if isinstance(arr, pa.ChunkedArray):  # very old pyarrow
            arr = pa.concat_arrays(arr.chunks)
        size = arr.type.list_size
        is_null = arr.is_null().to_numpy(zero_copy_only=False)
        want_null = last if name in ("desired_goal", "action") else np.zeros_like(last)
        bad = np.flatnonzero(is_null != want_null)
        if bad.size:
            r = int(bad[0])
            e, s = divmod(r, T)
            problems.append(
                f"column {name}: episode {e} step {s} is {'null' if is_null[r] else 'non-null'}, "
                f"want {'null' if want_null[r] else 'non-null'} ({bad.size} rows wrong)")
        child = arr.values.slice(arr.offset * size, len(arr) * size)
        child_null = child.is_null().to_numpy(zero_copy_only=False).reshape(len(arr), size)
        inner = child_null & ~is_null[:, None]
        if inner.any():
            r, c = (int(x) for x in np.argwhere(inner)[0])
            e, s = divmod(r, T)
            problems.append(f"column {name}: episode {e} step {s} component {c} is a null float inside a valid list")
            continue
        vals = child.to_numpy(zero_copy_only=False)
        if vals.dtype != out_dtype:
            problems.append(f"column {name}: values are {vals.dtype}, want {out_dtype}")
            continue
        vals = vals.reshape(E, T, size)
        want = expected[name]
        got = vals[:, :want.shape[1], :]
        neq = bits(np.ascontiguousarray(got)) != bits(want)
        if neq.any():
            e, s, c = (int(x) for x in np.argwhere(neq)[0])
            src, local = origin[e]
            problems.append(
                f"column {name}: first mismatch at episode {e} step {s} component {c} "
                f"(input {src} episode {local}, key {SOURCE_KEY[name]!r}): "
                f"got {fmt(got[e, s, c])}, want {fmt(want[e, s, c])}; "
                f"{int(neq.sum())} values differ")

    # ---- passthrough columns ----------------------------------------------
    listed = {p["column"]: p for p in (meta or {}).get("passthrough", [])} if isinstance(meta, dict) else {}
    if sorted(listed) != sorted(extra_keys):
        problems.append(f"footer: passthrough lists {sorted(listed)}, want {sorted(extra_keys)}")
    for key in extra_keys:
        src = np.concatenate([e[key] for e in extras_of], axis=0)
        per, shape = layout(src, T)
        p = listed.get(key, {})
        # The dtype as the file stored it, byte order included (`>f4`, `|u1`): the one export
        # writes back.
        want_meta = {"per": per, "shape": shape, "dtype": extras_of[0][key].dtype.str}
        got_meta = {k: p.get(k) for k in want_meta}
        if got_meta != want_meta:
            problems.append(f"footer: passthrough {key} is {got_meta}, want {want_meta}")
        has = {"step": np.ones(T, bool), "transition": np.arange(T) < T - 1, "episode": np.arange(T) == 0}[per]
        want_null = ~np.tile(has, E)
        arr = table.column(key).combine_chunks()
        is_null = arr.is_null().to_numpy(zero_copy_only=False)
        if (is_null != want_null).any():
            r = int(np.flatnonzero(is_null != want_null)[0])
            problems.append(f"column {key}: row {r} (episode {r // T}, step {r % T}) is "
                            f"{'null' if is_null[r] else 'set'}, want the other ({per})")
            continue
        size = int(np.prod(shape)) if shape else 1
        kept = arr.filter(pa.array(~want_null))
        flat = (kept.flatten() if shape else kept).to_numpy(zero_copy_only=False)
        got = flat.reshape(-1, size)
        want = native(src).reshape(-1, size)
        if got.dtype != want.dtype or got.shape != want.shape or got.tobytes() != want.tobytes():
            problems.append(f"column {key}: {got.dtype}{got.shape} differs from the source's {want.dtype}{want.shape}")

    if problems:
        report_and_exit()
    print(f"OK {table.num_rows} rows")


if __name__ == "__main__":
    main()
