#!/usr/bin/env python3
"""A small folder of OGBench shards in Horizon Reduction's layout, cut from a dataset file that
OGBench's own generator wrote (tests/fixtures/ogbench): episodes [k*E, (k+1)*E) of the file
become `NAME-k.npz`, each array cut alike, saved with np.savez_compressed as OGBench saves its
files; the `-val.npz` file beside it is copied as `NAME-val.npz`.

Usage: make_ogbench_shards.py DATASET.npz OUT_DIR EPISODES_PER_SHARD [--float64 K] [--val-float64]
  --float64 K: shard K's observations stored as float64 (shards that disagree).
  --val-float64: the -val.npz file's observations stored as float64 (a validation shard that
  disagrees with the training shards).
"""
import argparse
import os
import shutil

import numpy as np

p = argparse.ArgumentParser()
p.add_argument("dataset")
p.add_argument("out")
p.add_argument("per_shard", type=int)
p.add_argument("--float64", type=int, default=None)
p.add_argument("--val-float64", action="store_true")
a = p.parse_args()

name = os.path.basename(a.dataset)[: -len(".npz")]
with np.load(a.dataset) as f:
    arrays = {k: f[k] for k in f.files}
ends = np.nonzero(arrays["terminals"])[0]
starts = np.concatenate([[0], ends[:-1] + 1])
os.makedirs(a.out, exist_ok=True)
for k, first in enumerate(range(0, len(ends), a.per_shard)):
    last = min(first + a.per_shard, len(ends)) - 1
    rows = slice(starts[first], ends[last] + 1)
    shard = {key: v[rows] for key, v in arrays.items()}
    if a.float64 == k:
        shard["observations"] = shard["observations"].astype(np.float64)
    np.savez_compressed(os.path.join(a.out, f"{name}-{k}.npz"), **shard)
val = a.dataset[: -len(".npz")] + "-val.npz"
if os.path.exists(val) and a.val_float64:
    with np.load(val) as f:
        v = {k: f[k] for k in f.files}
    v["observations"] = v["observations"].astype(np.float64)
    np.savez_compressed(os.path.join(a.out, f"{name}-val.npz"), **v)
elif os.path.exists(val):
    shutil.copyfile(val, os.path.join(a.out, f"{name}-val.npz"))
