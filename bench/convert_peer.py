#!/usr/bin/env python3
"""Python peer of `pgser-etl convert`: WGCSL pickle -> per-step Parquet table.

This is the way the job is usually done in Python (pickle.load + numpy +
pyarrow), used by bench_convert.py as the baseline.  It produces the same table
as pgser-etl:

    episode        int64                          one row per (episode, step)
    step           int32
    obs            fixed_size_list<float64>[obs_dim]
    achieved_goal  fixed_size_list<float64>[goal_dim]
    desired_goal   fixed_size_list<float64>[goal_dim]  nullable: null on the last step
    action         fixed_size_list<float64>[act_dim]   nullable: null on the last step

written with pyarrow.parquet.write_table(..., compression="zstd") and otherwise
default options, plus a `pgser` JSON entry in the footer (schema) metadata.

Phase timings go to stderr as one line:  PEER_TIMINGS {"load_s": ..., ...}

Usage:
    convert_peer.py IN.pkl OUT.parquet [--task FetchPush] [--sha256]
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import sys
import time

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


def vec_type(width: int) -> pa.DataType:
    return pa.list_(pa.field("item", pa.float64(), nullable=False), width)


def fixed_size_list(values: np.ndarray, width: int, mask=None) -> pa.FixedSizeListArray:
    # values is [rows, width] C-contiguous float64: pa.array wraps it without a copy
    flat = pa.array(values.reshape(-1))
    return pa.FixedSizeListArray.from_arrays(flat, type=vec_type(width), mask=mask)


def pad_last_step(x: np.ndarray, T: int) -> np.ndarray:
    """[N, T-1, D] -> [N, T, D] with a zero row appended to every episode."""
    out = np.zeros((x.shape[0], T, x.shape[2]), dtype=np.float64)
    out[:, : T - 1] = x
    return out


def build_table(data: dict, meta: dict) -> pa.Table:
    o = np.ascontiguousarray(data["o"], dtype=np.float64)
    ag = np.ascontiguousarray(data["ag"], dtype=np.float64)
    u = np.asarray(data["u"], dtype=np.float64)
    g = np.asarray(data["g"], dtype=np.float64)

    N, T, obs_dim = o.shape
    goal_dim, act_dim = ag.shape[2], u.shape[2]
    if ag.shape[:2] != (N, T) or u.shape[:2] != (N, T - 1) or g.shape != (N, T - 1, goal_dim):
        raise ValueError(f"inconsistent shapes: o{o.shape} ag{ag.shape} u{u.shape} g{g.shape}")
    rows = N * T

    episode = np.repeat(np.arange(N, dtype=np.int64), T)
    step = np.tile(np.arange(T, dtype=np.int32), N)
    last = np.zeros(rows, dtype=bool)
    last[T - 1 :: T] = True  # u and g have no entry for the final observation
    null_last = pa.array(last)

    schema = pa.schema(
        [
            pa.field("episode", pa.int64(), nullable=False),
            pa.field("step", pa.int32(), nullable=False),
            pa.field("obs", vec_type(obs_dim), nullable=False),
            pa.field("achieved_goal", vec_type(goal_dim), nullable=False),
            pa.field("desired_goal", vec_type(goal_dim), nullable=True),
            pa.field("action", vec_type(act_dim), nullable=True),
        ]
    )
    meta.update(episodes=N, horizon=T, rows=rows,
                dims={"obs": obs_dim, "goal": goal_dim, "action": act_dim})
    schema = schema.with_metadata({"pgser": json.dumps(meta, sort_keys=True)})

    return pa.Table.from_arrays(
        [
            pa.array(episode),
            pa.array(step),
            fixed_size_list(o.reshape(rows, obs_dim), obs_dim),
            fixed_size_list(ag.reshape(rows, goal_dim), goal_dim),
            fixed_size_list(pad_last_step(g, T).reshape(rows, goal_dim), goal_dim, mask=null_last),
            fixed_size_list(pad_last_step(u, T).reshape(rows, act_dim), act_dim, mask=null_last),
        ],
        schema=schema,
    )


def sha256_file(path: str) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(1 << 20):
            h.update(chunk)
    return h.hexdigest()


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description="Python/pyarrow peer of `pgser-etl convert`")
    ap.add_argument("input", help="WGCSL-style pickle (dict with o, ag, u, g)")
    ap.add_argument("output", help="Parquet file to write")
    ap.add_argument("--task", default="FetchPush", help="task name recorded in the footer")
    ap.add_argument("--sha256", action="store_true",
                    help="record the input's SHA-256 in the footer (an extra full read of the input)")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    with open(args.input, "rb") as f:
        data = pickle.load(f)
    t1 = time.perf_counter()

    meta = {
        "format": "pgser.trajectories",
        "version": 1,
        "task": args.task,
        "source": {"file": os.path.basename(args.input), "bytes": os.path.getsize(args.input),
                   "format": "wgcsl-pickle"},
        "writer": f"convert_peer.py (pyarrow {pa.__version__}, numpy {np.__version__})",
    }
    if args.sha256:
        meta["source"]["sha256"] = sha256_file(args.input)
    t2 = time.perf_counter()
    table = build_table(data, meta)
    t3 = time.perf_counter()
    pq.write_table(table, args.output, compression="zstd")
    t4 = time.perf_counter()

    timings = {"load_s": t1 - t0, "sha256_s": t2 - t1, "build_s": t3 - t2,
               "write_s": t4 - t3, "total_s": t4 - t0, "rows": table.num_rows}
    print("PEER_TIMINGS " + json.dumps(timings), file=sys.stderr, flush=True)


if __name__ == "__main__":
    main()
