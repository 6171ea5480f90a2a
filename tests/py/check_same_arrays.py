#!/usr/bin/env python3
"""Two pickled dicts of numpy arrays hold the same arrays: the same keys, and for each the same
dtype (byte order included), shape and values bit for bit. What a WGCSL buffer must be after
`convert` then `export --format wgcsl`.

  check_same_arrays.py SOURCE.pkl EXPORTED.pkl [--except KEY ...]

Prints "OK <n> arrays" and exits 0, or each difference and exits 1. Trusted test files only.
"""
import argparse
import sys

import numpy as np

import stored_pickle


def load(path):
    # As stored: numpy's pickle.load gives a big-endian array back as a native one.
    return stored_pickle.load(path)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("source")
    ap.add_argument("exported")
    ap.add_argument("--except", dest="skip", nargs="*", default=[])
    a = ap.parse_args()
    src, out = load(a.source), load(a.exported)
    problems = []
    want = [k for k in src if k not in a.skip]
    if sorted(out) != sorted(want):
        problems.append(f"keys {sorted(out)}, want {sorted(want)}")
    for k in want:
        if k not in out:
            continue
        x, y = np.asarray(src[k]), np.asarray(out[k])
        if x.dtype != y.dtype or x.dtype.byteorder != y.dtype.byteorder or x.shape != y.shape:
            problems.append(f"{k}: {y.dtype.str}{y.shape}, want {x.dtype.str}{x.shape}")
        elif np.ascontiguousarray(x).tobytes() != np.ascontiguousarray(y).tobytes():
            problems.append(f"{k}: values differ")
    for p in problems:
        print(p)
    if problems:
        sys.exit(1)
    print(f"OK {len(want)} arrays")


if __name__ == "__main__":
    main()
