#!/usr/bin/env python3
"""Python peer of `pgser-train bench-sampler --in-memory`: cpprb's PrioritizedReplayBuffer.

The in-memory comparison for bench_sampler.py. It loads the SAME scored table (the output of
`pgser-etl score`) with pyarrow, columns obs, goal, action, reward, next_obs (what a training
row needs, as pgser's sampler reads) and q, computes the same priorities from q as
src/sampler/priority.rs does:

    q       p = (clip(q, -1/(1-gamma), 0) + 1/(1-gamma) + eps)^alpha   (default; eps 0.01, alpha 1)
    rank    p = 1 / rank^alpha, rank 1 for the highest q (ties in row order)
    uniform p = 1

with gamma read from the table's `pgser` footer (as pgser does), adds every row to a
cpprb.PrioritizedReplayBuffer with those priorities, and times `sample(batch_size, beta)`.

cpprb stores (priority + eps_cpprb)^alpha_cpprb for priorities passed to add(); the buffer is
made with alpha=1.0 and eps=0.0, and our final p (alpha already applied) is passed, so the
buffer's sampling weights are exactly ours. (cpprb's default eps=1e-4 would shift them by
1e-4, negligible next to p >= 0.01, but there is no reason to.) cpprb always computes the
importance weights (N P(i))^-beta / max; pgser only with --is-beta, so bench_sampler.py passes
--is-beta 0.4 to pgser by default to make both do that work.

A check that the buffer samples by our p: over the untimed warm-up batches, the mean p of the
drawn rows is compared with its expectation under p-proportional draws, sum(p^2)/sum(p)
("check" in the JSON; uniform draws would give mean(p) instead).

--impl numpy is the documented fallback for machines where cpprb does not install: a sum tree
held in numpy arrays (one array per level, leaves padded to a power of two, float64), the
same stratified draw as pgser's SumTree::sample (stratum j of total/k, one uniform draw in
each), descended level by level with vectorized numpy ops, rows gathered with fancy indexing,
IS weights as pgser's is_weights.

Timings: setup_seconds is load (pyarrow read + to numpy) + priorities + buffer fill, each also
given apart; seconds is the timed sample() calls only, after --warmup untimed ones.

Prints one line; with --json:
    {"peer": "cpprb", "version": ..., "numpy": ..., "pyarrow": ..., "rows": ..., "batch_size": ...,
     "batches": ..., "seconds": ..., "samples_per_sec": ..., "batches_per_sec": ...,
     "setup_seconds": ..., "load_seconds": ..., "priority_seconds": ..., "fill_seconds": ...,
     "buffer_bytes": ..., "check": {...}}

Usage:
    sampler_peer.py --data scored.parquet [--batch-size 256] [--batches 3000] [--warmup 50]
                    [--beta 0.4] [--priority q|rank|uniform] [--priority-alpha 1]
                    [--priority-eps 0.01] [--impl cpprb|numpy] [--seed 0] [--json]
"""
from __future__ import annotations

import argparse
import importlib.metadata
import json
import sys
import time

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

COLUMNS = ("obs", "goal", "action", "reward", "next_obs")


def version(pkg: str) -> str | None:
    try:
        return importlib.metadata.version(pkg)
    except importlib.metadata.PackageNotFoundError:
        return None


def footer(path: str) -> dict:
    kv = pq.ParquetFile(path).metadata.metadata or {}
    raw = kv.get(b"pgser")
    if raw is None:
        sys.exit(f"{path}: no pgser footer; a scored table from `pgser-etl score` is expected")
    doc = json.loads(raw)
    if doc.get("kind") != "transition":
        sys.exit(f"{path}: footer kind is {doc.get('kind')}, a scored table from `pgser-etl score` is expected")
    return doc


def load(path: str) -> tuple[dict, np.ndarray]:
    """The training columns as [rows, dim] float32 arrays (reward [rows, 1]) and q [rows]."""
    table = pq.read_table(path, columns=[*COLUMNS, "q"])
    cols = {}
    for name in COLUMNS:
        col = table.column(name).combine_chunks()
        if pa.types.is_fixed_size_list(col.type):
            width = col.type.list_size
            cols[name] = col.flatten().to_numpy(zero_copy_only=False).astype(np.float32, copy=False).reshape(-1, width)
        else:
            cols[name] = col.to_numpy(zero_copy_only=False).astype(np.float32, copy=False).reshape(-1, 1)
    q = table.column("q").combine_chunks().to_numpy(zero_copy_only=False).astype(np.float32, copy=False)
    if not np.isfinite(q).all():
        sys.exit(f"{path}: q has non-finite values")
    return cols, q


def priorities(q: np.ndarray, kind: str, alpha: float, eps: float, gamma: float) -> np.ndarray:
    """As PriorityConfig::priorities in src/sampler/priority.rs (float64)."""
    if kind == "q":
        lo = -1.0 / (1.0 - gamma)
        return (np.clip(q.astype(np.float64), lo, 0.0) - lo + eps) ** alpha
    if kind == "rank":
        # highest q first, ties in row order: a stable sort of -q
        order = np.argsort(-q.astype(np.float64), kind="stable")
        p = np.empty(len(q), dtype=np.float64)
        p[order] = np.arange(1, len(q) + 1, dtype=np.float64) ** (-alpha)
        return p
    return np.ones(len(q), dtype=np.float64)


class NumpySumTree:
    """Fallback peer: levels[0] is the root (1 node), levels[-1] the padded leaves."""

    def __init__(self, cols: dict, p: np.ndarray, seed: int):
        n = len(p)
        leaves = 1 << max(0, (n - 1).bit_length())
        leaf = np.zeros(leaves, dtype=np.float64)
        leaf[:n] = p
        levels = [leaf]
        while len(levels[-1]) > 1:
            x = levels[-1]
            levels.append(x[0::2] + x[1::2])
        self.levels = levels[::-1]
        self.n = n
        self.cols = cols
        self.min = float(p.min())
        self.rng = np.random.default_rng(seed)

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in self.levels) + sum(a.nbytes for a in self.cols.values())

    def sample(self, k: int, beta: float) -> dict:
        total = self.levels[0][0]
        mass = (np.arange(k) + self.rng.random(k)) * (total / k)
        idx = np.zeros(k, dtype=np.int64)
        for level in self.levels[1:]:
            idx *= 2
            left = level[idx]
            right = mass >= left
            mass -= np.where(right, left, 0.0)
            idx += right
        idx = np.minimum(idx, self.n - 1)
        # (pgser also walks back over zero-priority rows; our priorities are all > 0)
        out = {name: a[idx] for name, a in self.cols.items()}
        prob = self.levels[-1][idx] / total
        w = (self.n * prob) ** (-beta)
        out["weights"] = (w / (self.n * self.min / total) ** (-beta)).astype(np.float32)
        out["indexes"] = idx
        return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="scored table (pgser-etl score)")
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--batches", type=int, default=3000, help="timed sample() calls (default 3000)")
    ap.add_argument("--warmup", type=int, default=50, help="untimed sample() calls first (default 50)")
    ap.add_argument("--beta", type=float, default=0.4, help="IS exponent passed to sample() (default 0.4)")
    ap.add_argument("--priority", default="q", choices=("q", "rank", "uniform"))
    ap.add_argument("--priority-alpha", type=float, default=1.0)
    ap.add_argument("--priority-eps", type=float, default=1e-2)
    ap.add_argument("--impl", default="cpprb", choices=("cpprb", "numpy"),
                    help="cpprb's PrioritizedReplayBuffer (default) or the numpy sum-tree fallback")
    ap.add_argument("--seed", type=int, default=0, help="numpy fallback's seed (cpprb seeds itself)")
    ap.add_argument("--json", action="store_true", help="print one JSON line")
    a = ap.parse_args(argv)
    if a.batches < 1 or a.batch_size < 1 or a.warmup < 0:
        ap.error("--batches and --batch-size must be >= 1, --warmup >= 0")

    gamma = float(footer(a.data)["gamma"])
    t0 = time.perf_counter()
    cols, q = load(a.data)
    t1 = time.perf_counter()
    p = priorities(q, a.priority, a.priority_alpha, a.priority_eps, gamma)
    t2 = time.perf_counter()
    rows = len(q)
    del q

    if a.impl == "cpprb":
        try:
            import cpprb
        except ImportError as e:
            sys.exit(f"cannot import cpprb ({e}); install it (pip install cpprb) or use --impl numpy")
        env_dict = {name: {"shape": arr.shape[1], "dtype": np.float32} for name, arr in cols.items()}
        rb = cpprb.PrioritizedReplayBuffer(rows, env_dict, alpha=1.0, eps=0.0)
        rb.add(priorities=p, **cols)
        if rb.get_stored_size() != rows:
            sys.exit(f"cpprb stored {rb.get_stored_size()} rows of {rows}")
        buffer_bytes = sum(arr.nbytes for arr in cols.values())  # cpprb copies them into its own arrays
        del cols
        sample = lambda: rb.sample(a.batch_size, beta=a.beta)  # noqa: E731
        peer, ver = "cpprb", version("cpprb")
    else:
        tree = NumpySumTree(cols, p, a.seed)
        buffer_bytes = tree.nbytes
        sample = lambda: tree.sample(a.batch_size, a.beta)  # noqa: E731
        peer, ver = "numpy-sumtree", np.__version__
    t3 = time.perf_counter()

    # warm-up, with the check that draws follow p
    drawn_p = []
    for _ in range(a.warmup):
        b = sample()
        drawn_p.append(p[np.asarray(b["indexes"]).reshape(-1)])
    if a.warmup:
        got = float(np.concatenate(drawn_p).mean())
        want = float((p * p).sum() / p.sum())
        n_drawn = a.warmup * a.batch_size
        # standard error of the mean of n iid draws from the p-weighted distribution
        var = float((p ** 3).sum() / p.sum()) - want ** 2
        se = (max(var, 0.0) / n_drawn) ** 0.5
        check = {"drawn": n_drawn, "mean_p_drawn": got, "mean_p_expected": want,
                 "mean_p_uniform": float(p.mean()), "z": (got - want) / se if se > 0 else 0.0}
    else:
        check = None

    t4 = time.perf_counter()
    for _ in range(a.batches):
        sample()
    seconds = time.perf_counter() - t4

    res = {
        "peer": peer, "version": ver, "numpy": np.__version__, "pyarrow": version("pyarrow"),
        "python": sys.version.split()[0],
        "rows": rows, "batch_size": a.batch_size, "batches": a.batches, "warmup": a.warmup, "beta": a.beta,
        "priority": a.priority, "priority_alpha": a.priority_alpha, "priority_eps": a.priority_eps, "gamma": gamma,
        "seconds": seconds, "samples_per_sec": a.batches * a.batch_size / seconds,
        "batches_per_sec": a.batches / seconds,
        "setup_seconds": t3 - t0, "load_seconds": t1 - t0, "priority_seconds": t2 - t1, "fill_seconds": t3 - t2,
        "buffer_bytes": buffer_bytes, "check": check,
    }
    if a.json:
        print(json.dumps(res), flush=True)
    else:
        print(f"{peer} {ver}: {rows} rows, batch {a.batch_size}: {res['samples_per_sec']:.0f} samples/s "
              f"({res['batches_per_sec']:.1f} batches/s), setup {res['setup_seconds']:.2f} s")


if __name__ == "__main__":
    main()
