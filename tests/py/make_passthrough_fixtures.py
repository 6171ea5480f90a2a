#!/usr/bin/env python3
"""WGCSL-style buffers holding more than o, ag, u, g, written by real numpy: what `convert` must
keep as passthrough columns and `export --format wgcsl` must give back bit for bit.

  make_passthrough_fixtures.py OUT_DIR

Writes (FetchReach's dimensions, T = 50, 3 episodes):
  wgcsl_info.pkl      float64, protocol 3: WGCSL's own `info_is_success` [N, T-1, 1] (float64,
                      as its replay buffer stores it), and `phase` [N, T] int32, one per step
  wgcsl_mixed.pkl     float32, protocol 4: `info_is_success` [N, T-1, 1] bool, `contact`
                      [N, T, 2] big-endian float32 in Fortran order, `episode_id` [N] int64
                      (one per episode), `seed_bytes` [N, 4] uint8, `tilt` [N, T-1, 2, 2] int16
Values are seeded (numpy's default_rng), so the files are the same on every run.
"""
import pickle
import sys
from pathlib import Path

import numpy as np

T, OBS, GOAL, ACT, N = 50, 10, 3, 4, 3


def base(rng, dtype):
    return {
        "o": rng.normal(size=(N, T, OBS)).astype(dtype),
        "ag": rng.normal(size=(N, T, GOAL)).astype(dtype),
        "u": rng.uniform(-1, 1, size=(N, T - 1, ACT)).astype(dtype),
        "g": rng.normal(size=(N, T - 1, GOAL)).astype(dtype),
    }


def main(out: Path):
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(59)
    d = base(rng, np.float64)
    d["info_is_success"] = (rng.random((N, T - 1, 1)) < 0.3).astype(np.float64)
    d["phase"] = rng.integers(-5, 5, size=(N, T)).astype(np.int32)
    with open(out / "wgcsl_info.pkl", "wb") as f:
        pickle.dump(d, f, protocol=3)

    d = base(rng, np.float32)
    d["info_is_success"] = rng.random((N, T - 1, 1)) < 0.3
    d["contact"] = np.asfortranarray(rng.normal(size=(N, T, 2)).astype(">f4"))
    d["episode_id"] = np.arange(N, dtype=np.int64) * 1_000_003
    d["seed_bytes"] = rng.integers(0, 256, size=(N, 4)).astype(np.uint8)
    d["tilt"] = rng.integers(-300, 300, size=(N, T - 1, 2, 2)).astype(np.int16)
    with open(out / "wgcsl_mixed.pkl", "wb") as f:
        pickle.dump(d, f, protocol=4)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
