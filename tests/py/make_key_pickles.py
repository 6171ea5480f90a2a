#!/usr/bin/env python3
"""WGCSL buffers (FetchReach's dimensions, T = 50, 2 episodes) with keys a table cannot keep,
written by real numpy and pickle: what `convert` must refuse by name, saying the `--drop` that
leaves each out, and convert once told.

  make_key_pickles.py OUT_DIR

Writes:
  int_key.pkl      protocol 4: key 1 (an int) and key (1, 2) (a tuple), both arrays [N]
  bytes_key.pkl    protocol 2 (bytes through _codecs.encode): key b'\\xff' (bytes that are not
                   UTF-8) holding an array [N], and b'phase' (UTF-8 bytes, as Python 2 wrote str
                   keys) an int32 array [N, T] that is kept as the column `phase`
  twice.pkl        protocol 4: `phase` twice, as the str 'phase' and the bytes b'phase', both
                   int32 arrays [N, T]
  metadata.pkl     protocol 4: `meta`, a dict (an experiment's settings), and `names`, a list of
                   str: neither a table column; and `info_is_success` [N, T-1, 1]
  arrays_pN.pkl    protocols 2 and 5: `labels`, a numpy array of str [N] (<U6), and `tags`, an
                   object array [N]: arrays of dtypes no column holds; and `info_is_success`
Values are seeded (numpy's default_rng), so the files are the same on every run.
"""
import pickle
import sys
from pathlib import Path

import numpy as np

T, OBS, GOAL, ACT, N = 50, 10, 3, 4, 2


def base(rng):
    return {
        "o": rng.normal(size=(N, T, OBS)),
        "ag": rng.normal(size=(N, T, GOAL)),
        "u": rng.uniform(-1, 1, size=(N, T - 1, ACT)),
        "g": rng.normal(size=(N, T - 1, GOAL)),
    }


def main(out: Path):
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(66)
    d = base(rng)
    d[1] = np.arange(N, dtype=np.int64)
    d[(1, 2)] = np.ones(N)
    with open(out / "int_key.pkl", "wb") as f:
        pickle.dump(d, f, protocol=4)

    d = base(rng)
    d[b"\xff"] = np.zeros(N)
    d[b"phase"] = rng.integers(-5, 5, size=(N, T)).astype(np.int32)
    with open(out / "bytes_key.pkl", "wb") as f:
        pickle.dump(d, f, protocol=2)

    d = base(rng)
    d["phase"] = rng.integers(-5, 5, size=(N, T)).astype(np.int32)
    d[b"phase"] = d["phase"] + 1
    with open(out / "twice.pkl", "wb") as f:
        pickle.dump(d, f, protocol=4)

    d = base(rng)
    d["meta"] = {"env": "FetchReach-v1", "seed": 3}
    d["names"] = ["first", "second"]
    d["info_is_success"] = (rng.random((N, T - 1, 1)) < 0.3).astype(np.float64)
    with open(out / "metadata.pkl", "wb") as f:
        pickle.dump(d, f, protocol=4)

    d = base(rng)
    d["labels"] = np.array(["first", "second"])
    d["tags"] = np.array([{"a": 1}, None], dtype=object)
    d["info_is_success"] = (rng.random((N, T - 1, 1)) < 0.3).astype(np.float64)
    for protocol in (2, 5):
        with open(out / f"arrays_p{protocol}.pkl", "wb") as f:
            pickle.dump(d, f, protocol=protocol)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
