#!/usr/bin/env python3
"""Random WGCSL buffers written by numpy, for the convert -> export round trip: each holds o, ag,
u, g and 1-4 extra arrays of random dtypes, byte orders, layouts and shapes.

  make_random_pickles.py OUT_DIR COUNT

Writes OUT_DIR/r0.pkl ... r{COUNT-1}.pkl, file i from numpy's default_rng(i): N of 1-4 episodes,
T of 3-7 steps, o/ag/u/g float64 or float32 (finite, as convert requires); each extra array per
step [N, T, ...], per transition [N, T-1, ...] or per episode [N, ...], with 0-2 more dimensions
of 1-3, of a dtype a column keeps (f8 f4 b1 i1 i2 i4 i8 u1 u2 u4 u8), big-endian with chance 0.3
(two bytes and more), in Fortran order with chance 0.3, its values any bits (floats: NaN and
Inf too; bools 0 or 1); the file pickled with protocol 2, 3, 4 or 5. The same files every run.
"""
import pickle
import sys
from pathlib import Path

import numpy as np

TYPES = ["f8", "f4", "b1", "i1", "i2", "i4", "i8", "u1", "u2", "u4", "u8"]


def extra(rng, shape):
    t = TYPES[rng.integers(len(TYPES))]
    size = int(t[1:])
    order = ">" if size > 1 and rng.random() < 0.3 else "<"
    dtype = np.dtype(order + t)
    count = int(np.prod(shape))
    if t == "b1":
        a = (rng.random(count) < 0.5).astype(dtype)
    else:
        # Any bit pattern, as a file may hold it (for floats: NaN, Inf, subnormals).
        a = np.frombuffer(rng.integers(0, 256, count * size, dtype=np.uint8).tobytes(), dtype)
    a = a.reshape(shape)
    return np.asfortranarray(a) if rng.random() < 0.3 else a


def buffer(seed):
    rng = np.random.default_rng(seed)
    n, t = 1 + int(rng.integers(4)), 3 + int(rng.integers(5))
    float_type = np.float64 if rng.random() < 0.5 else np.float32
    d = {
        "o": rng.normal(size=(n, t, 3)).astype(float_type),
        "ag": rng.normal(size=(n, t, 2)).astype(float_type),
        "u": rng.uniform(-1, 1, size=(n, t - 1, 2)).astype(float_type),
        "g": rng.normal(size=(n, t - 1, 2)).astype(float_type),
    }
    for k in range(1 + int(rng.integers(4))):
        shape = [n] + [[t], [t - 1], []][int(rng.integers(3))]
        shape += [1 + int(rng.integers(3)) for _ in range(int(rng.integers(3)))]
        d[f"extra_{k}"] = extra(rng, shape)
    return d, 2 + int(rng.integers(4))


def main(out: Path, count: int):
    out.mkdir(parents=True, exist_ok=True)
    for seed in range(count):
        d, protocol = buffer(seed)
        with open(out / f"r{seed}.pkl", "wb") as f:
            pickle.dump(d, f, protocol=protocol)


if __name__ == "__main__":
    main(Path(sys.argv[1]), int(sys.argv[2]))
