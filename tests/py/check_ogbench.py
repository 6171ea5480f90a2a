"""Load OGBench dataset files with the real `ogbench` package, for tests/ogbench.rs.

    check_ogbench.py same NAME EXPECTED.npz GOT.npz
        `ogbench.make_env_and_datasets(NAME, dataset_path=...)` loads both files (each with its
        `-val.npz` beside it) the way OGBench's agents do, regular and compact: every array of the
        train and val datasets must be equal, value for value and dtype for dtype, except the
        compact `actions` of each episode's last row, which a pgser table does not hold (OGBench's
        own regular loader drops that row; GOT has zeros there).

    check_ogbench.py collected EXPECTED.npz GOT.npz
        The raw files (and their `-val.npz`), as np.load reads them: GOT (pgser-etl collect
        --policy oracle) must have EXPECTED's keys, dtypes and shapes, and equal arrays, except
        each episode's first qvel row (OGBench's reset leaves a random velocity there that its
        first step zeroes; pgser's leaves 0).

Prints one JSON line of what was compared; exits non-zero with the first difference.
"""

import json
import sys
import warnings

import numpy as np

warnings.filterwarnings("ignore")
import ogbench  # noqa: E402


def load(name, path, compact):
    _, train, val = ogbench.make_env_and_datasets(name, dataset_path=path, compact_dataset=compact)
    return {"train": train, "val": val}


def collected(want_path, got_path):
    compared = []
    for suffix in ("", "-val"):
        w = np.load(want_path.replace(".npz", f"{suffix}.npz"))
        g = np.load(got_path.replace(".npz", f"{suffix}.npz"))
        if list(w.keys()) != list(g.keys()):
            sys.exit(f"{suffix or 'train'}: keys {list(g.keys())} instead of {list(w.keys())}")
        firsts = np.r_[0, np.flatnonzero(w["terminals"])[:-1] + 1]
        for k in w.keys():
            a, b = w[k], g[k]
            if a.dtype != b.dtype or a.shape != b.shape:
                sys.exit(f"{suffix or 'train'} {k}: {b.dtype}{b.shape} instead of {a.dtype}{a.shape}")
            if k == "qvel":
                a, b = np.delete(a, firsts, axis=0), np.delete(b, firsts, axis=0)
            if not np.array_equal(a, b):
                i = np.argwhere(a != b)[0]
                sys.exit(f"{suffix or 'train'} {k}: first difference at {tuple(i)}: {b[tuple(i)]} vs {a[tuple(i)]}")
            compared.append(f"{suffix or 'train'}/{k}")
    print(json.dumps({"compared": compared}))


def main():
    mode = sys.argv[1]
    if mode == "collected":
        return collected(*sys.argv[2:4])
    name, want_path, got_path = sys.argv[2:5]
    assert mode == "same", mode
    compared = []
    for compact in (False, True):
        want, got = load(name, want_path, compact), load(name, got_path, compact)
        for split in ("train", "val"):
            w, g = want[split], got[split]
            if sorted(w) != sorted(g):
                sys.exit(f"{split} (compact={compact}): keys {sorted(g)} instead of {sorted(w)}")
            for k in w:
                a, b = w[k], g[k]
                if a.dtype != b.dtype or a.shape != b.shape:
                    sys.exit(f"{split} {k} (compact={compact}): {b.dtype}{b.shape} instead of {a.dtype}{a.shape}")
                if compact and k == "actions":
                    keep = w["valids"] == 1  # rows whose action has a next state
                    a, b = a[keep], b[keep]
                if not np.array_equal(a, b):
                    i = np.argwhere(a != b)[0]
                    sys.exit(f"{split} {k} (compact={compact}): first difference at {tuple(i)}: {b[tuple(i)]} vs {a[tuple(i)]}")
                compared.append(f"{split}/{k}{'/compact' if compact else ''}")
    print(json.dumps({"compared": compared}))


if __name__ == "__main__":
    main()
