#!/usr/bin/env python3
"""The Python peer of `pgser-etl score`: goal-swap every transition of a trajectory table and
score each row with a checkpoint's twin critics, the way a researcher would write it.

  - pyarrow reads the trajectory table (obs, achieved_goal, action; float64 tables are cast to
    float32, as pgser reads them);
  - numpy does the swap, vectorized: for every transition (e, t), t < T-1, in table order, K goal
    sources k ~ U{0 .. n·T-1} from one rng.integers call (goal_episode = k // T,
    goal_step = k % T), gathers, and the reward R = 0 if ||ag' - g|| <= threshold else -1
    (the distance in float64, as pgser's Task::reward);
  - PyTorch on the CPU runs both critics, q = min(Q1, Q2)([clip((o-μ)/σ), clip((g-μ)/σ), a]),
    under torch.no_grad, in batches of --batch rows (0: all rows in one call; 2048 was the
    fastest tried on the 2-core benchmark machine: ~230 GFLOP/s, vs ~145 at 8192 and ~107 for all
    490k rows at once, whose activations fall out of cache); the weights come
    from the safetensors file through numpy (no safetensors package, as tests/py/check_checkpoint.py);
  - pyarrow writes the transition table (docs/tables.md columns, same names and types as pgser's)
    with zstd (pyarrow's default level, 1; other writer settings at pyarrow's defaults, which
    means dictionary encoding is tried on every column: --no-dictionary turns it off as pgser's
    writer does: on the 490k-row FetchPush benchmark 32.3 -> 26.1 MB and 0.62 -> 0.49 s).

It holds the whole table in memory (no streaming): the obvious way for data of this size.

The last stdout line is one JSON object:
  {peer, torch, threads, rows, seconds, rows_per_sec, critic_seconds, ...phases}
`seconds` is in-process, from before the checkpoint and table are read to after the output is
closed (interpreter start and imports are outside it; the driver's wall time has them).

Usage:
  score_peer.py --q CKPT --data TRAJ.parquet -o OUT.parquet [--swaps 4] [--seed 0] [--threads 2]
                [--batch 2048]
  score_peer.py --q CKPT --verify PGSER_OUT.parquet [--verify-rows 50000]
      recompute reward and q of rows of a pgser-etl score output with this peer's numpy/torch
      code and report the largest differences (a check that both sides do the same job).
"""
from __future__ import annotations

import argparse
import json
import os
import struct
import sys
import time

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import torch
from torch import nn


def read_safetensors(path):
    raw = open(path, "rb").read()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + n])
    meta = header.pop("__metadata__", {})
    data = raw[8 + n :]
    tensors = {}
    for name, info in header.items():
        assert info["dtype"] == "F32", (name, info["dtype"])
        a, b = info["data_offsets"]
        tensors[name] = np.frombuffer(data[a:b], dtype="<f4").reshape(info["shape"])
    return tensors, meta


def critic(t, prefix):
    """nn.Sequential(Linear, ReLU, ..., Linear) from weights `prefix.{0,2,4,...}.weight` [out, in]."""
    layers, k = [], 0
    while f"{prefix}.{k}.weight" in t:
        w, b = t[f"{prefix}.{k}.weight"], t[f"{prefix}.{k}.bias"]
        lin = nn.Linear(w.shape[1], w.shape[0])
        lin.weight.data = torch.from_numpy(w.copy())
        lin.bias.data = torch.from_numpy(b.copy())
        layers.append(lin)
        if f"{prefix}.{k + 2}.weight" in t:
            layers.append(nn.ReLU())
        k += 2
    return nn.Sequential(*layers).eval()


class Scorer:
    def __init__(self, ckpt):
        t, meta = read_safetensors(ckpt)
        self.task = json.loads(meta["task"])
        self.config = json.loads(meta["config"])
        self.clip = np.float32(float(meta["normalizer_clip"]))
        self.norm = {k: t[f"normalizer.{k}"] for k in ("obs_mean", "obs_std", "goal_mean", "goal_std")}
        self.q1, self.q2 = critic(t, "critic1"), critic(t, "critic2")
        self.shapes = [tuple(t[f"critic1.{k}.weight"].shape) for k in range(0, 100, 2) if f"critic1.{k}.weight" in t]

    def inputs(self, obs, goal, action):
        c, n = self.clip, self.norm
        o = np.clip((obs - n["obs_mean"]) / n["obs_std"], -c, c)
        g = np.clip((goal - n["goal_mean"]) / n["goal_std"], -c, c)
        return np.concatenate([o, g, action], axis=1).astype(np.float32, copy=False)

    def q(self, x, batch):
        out = np.empty(len(x), np.float32)
        xt = torch.from_numpy(x)
        step = batch if batch > 0 else max(len(x), 1)
        with torch.no_grad():
            for s in range(0, len(x), step):
                xb = xt[s : s + step]
                out[s : s + step] = torch.minimum(self.q1(xb), self.q2(xb))[:, 0].numpy()
        return out


def rewards(next_ag, goal, threshold):
    d = np.linalg.norm(next_ag.astype(np.float64) - goal.astype(np.float64), axis=1)
    return np.where(d > threshold, np.float32(-1.0), np.float32(0.0)).astype(np.float32)


def vectors(table, name, dim):
    """A fixed-size-list column as a float32 [rows, dim] array (null entries read as their slot)."""
    col = table.column(name).combine_chunks()
    assert col.offset == 0
    values = col.values.to_numpy(zero_copy_only=False)
    return values.reshape(len(col), dim).astype(np.float32, copy=False)


def fixed_list(a):
    return pa.FixedSizeListArray.from_arrays(pa.array(a.reshape(-1)), a.shape[1])


def score(args):
    t0 = time.perf_counter()
    sc = Scorer(args.q)
    task = sc.task
    T, od, gd, ad = task["T"], task["obs_dim"], task["goal_dim"], task["act_dim"]

    table = pq.read_table(args.data, columns=["episode", "step", "obs", "achieved_goal", "action"])
    rows = table.num_rows
    n = rows // T
    ep = table.column("episode").to_numpy()
    st = table.column("step").to_numpy()
    if rows != n * T or not (np.array_equal(ep, np.repeat(np.arange(n), T)) and np.array_equal(st, np.tile(np.arange(T), n))):
        sys.exit(f"{args.data}: expected {n} episodes of T = {T} rows, in order")
    obs, ag, act = vectors(table, "obs", od), vectors(table, "achieved_goal", gd), vectors(table, "action", ad)
    del table
    t_read = time.perf_counter()

    K = args.swaps
    rng = np.random.default_rng(args.seed)
    src = (np.arange(n)[:, None] * T + np.arange(T - 1)[None, :]).reshape(-1)  # row of (e, t), t < T-1
    idx = np.repeat(src, K)
    k = rng.integers(0, n * T, size=len(idx))
    goal = ag[k]
    next_ag = ag[idx + 1]
    out = {
        "episode": idx // T,
        "step": (idx % T).astype(np.int32),
        "goal_episode": k // T,
        "goal_step": (k % T).astype(np.int32),
        "obs": obs[idx],
        "action": act[idx],
        "next_obs": obs[idx + 1],
        "next_achieved_goal": next_ag,
        "goal": goal,
        "reward": rewards(next_ag, goal, task["threshold"]),
    }
    t_swap = time.perf_counter()

    x = sc.inputs(out["obs"], goal, out["action"])
    t_norm = time.perf_counter()
    out["q"] = sc.q(x, args.batch)
    del x
    t_critic = time.perf_counter()
    if not np.isfinite(out["q"]).all():
        sys.exit(f"{args.q}: the critic gives non-finite Q")

    f32 = pa.float32()
    vec = lambda name, d: pa.field(name, pa.list_(pa.field("item", f32, nullable=False), d), nullable=False)
    schema = pa.schema([
        pa.field("episode", pa.int64(), nullable=False), pa.field("step", pa.int32(), nullable=False),
        pa.field("goal_episode", pa.int64(), nullable=False), pa.field("goal_step", pa.int32(), nullable=False),
        vec("obs", od), vec("action", ad), vec("next_obs", od), vec("next_achieved_goal", gd), vec("goal", gd),
        pa.field("reward", f32, nullable=False), pa.field("q", f32, nullable=False),
    ])
    arrays = [pa.array(out[f.name]) if out[f.name].ndim == 1 else fixed_list(out[f.name]) for f in schema]
    result = pa.Table.from_arrays(arrays, schema=schema)
    pq.write_table(result, args.output, compression="zstd", use_dictionary=not args.no_dictionary)
    t_end = time.perf_counter()

    total = t_end - t0
    m = len(idx)
    q = out["q"]
    print(json.dumps({
        "peer": "numpy+torch+pyarrow", "torch": torch.__version__, "numpy": np.__version__, "pyarrow": pa.__version__,
        "threads": torch.get_num_threads(), "batch": args.batch, "rows": m, "episodes": n, "swaps": K,
        "seconds": total, "rows_per_sec": m / total, "critic_seconds": t_critic - t_norm,
        "read_seconds": t_read - t0, "swap_seconds": t_swap - t_read, "normalize_seconds": t_norm - t_swap,
        "write_seconds": t_end - t_critic, "critic_shapes": sc.shapes,
        "q_min": float(q.min()), "q_mean": float(q.mean(dtype=np.float64)), "q_max": float(q.max()),
        "output_bytes": os.path.getsize(args.output), "dictionary": not args.no_dictionary,
    }))


def verify(args):
    """Recompute reward and q for rows of a pgser-etl score output (spread over the file)."""
    sc = Scorer(args.q)
    task = sc.task
    od, gd, ad = task["obs_dim"], task["goal_dim"], task["act_dim"]
    table = pq.read_table(args.verify, columns=["obs", "action", "next_achieved_goal", "goal", "reward", "q",
                                                "goal_episode", "goal_step"])
    sel = np.linspace(0, table.num_rows - 1, min(args.verify_rows, table.num_rows)).astype(np.int64)
    table = table.take(pa.array(sel))
    obs, act, goal = vectors(table, "obs", od), vectors(table, "action", ad), vectors(table, "goal", gd)
    next_ag = vectors(table, "next_achieved_goal", gd)
    q = sc.q(sc.inputs(obs, goal, act), args.batch)
    q_file = table.column("q").to_numpy()
    r_file = table.column("reward").to_numpy()
    r = rewards(next_ag, goal, task["threshold"])
    d = np.abs(q - q_file)
    print(json.dumps({
        "verify": args.verify, "rows_checked": len(sel), "rows_in_file": int(pq.read_metadata(args.verify).num_rows),
        "q_max_abs_diff": float(d.max()), "q_max_rel_diff": float((d / np.maximum(np.abs(q_file), 1e-6)).max()),
        "reward_mismatches": int((r != r_file).sum()), "reward_zero_fraction": float((r_file == 0).mean()),
        "goal_step_range": [int(table.column("goal_step").to_numpy().min()), int(table.column("goal_step").to_numpy().max())],
        **(against(args.verify, args.against) if args.against else {}),
    }))


def against(pgser_out, peer_out):
    """Schema, row count and q/reward summaries of the two outputs side by side (different goal
    draws, so rows differ; the distributions should not)."""
    a, b = pq.ParquetFile(pgser_out), pq.ParquetFile(peer_out)
    sa, sb = a.schema_arrow.remove_metadata(), b.schema_arrow.remove_metadata()
    stats = {}
    for side, f in (("pgser", pgser_out), ("peer", peer_out)):
        t = pq.read_table(f, columns=["q", "reward"])
        q, r = t.column("q").to_numpy(), t.column("reward").to_numpy()
        stats[side] = {"rows": len(q), "q_mean": float(q.mean(dtype=np.float64)), "q_min": float(q.min()),
                       "q_max": float(q.max()), "reward_zero_fraction": float((r == 0).mean()),
                       "row_groups": f_meta.num_row_groups if (f_meta := pq.read_metadata(f)) else None,
                       "bytes": os.path.getsize(f)}
    return {"schema_equal": sa.equals(sb), "outputs": stats}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--q", required=True, help="checkpoint (safetensors) with critic1/critic2 and normalizer")
    ap.add_argument("--data", help="trajectory table")
    ap.add_argument("-o", "--output", help="transition table to write")
    ap.add_argument("--swaps", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=2, help="torch.set_num_threads and pyarrow's CPU pool")
    ap.add_argument("--batch", type=int, default=2048, help="rows per critic call (0: all rows at once)")
    ap.add_argument("--no-dictionary", action="store_true",
                    help="write without dictionary encoding, as pgser does (default: pyarrow's default, dictionaries on)")
    ap.add_argument("--verify", help="instead of scoring, check the reward and q of this pgser-etl score output")
    ap.add_argument("--verify-rows", type=int, default=50000)
    ap.add_argument("--against", help="with --verify: the peer's output, to compare schemas and q/reward summaries")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    pa.set_cpu_count(args.threads)
    if args.verify:
        verify(args)
    elif args.data and args.output:
        score(args)
    else:
        ap.error("--data and -o are required (or --verify)")


if __name__ == "__main__":
    main()
