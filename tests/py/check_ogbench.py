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

    check_ogbench.py whole EXPECTED.npz GOT.npz
        The two archives as files, not as OGBench loads them: the same members in the same zip
        order, each member's .npy header (dtype descr with its byte order, fortran_order, shape,
        read with numpy's own np.lib.format) and the bytes after it equal; and np.load of both
        gives equal arrays of equal dtypes.

    check_ogbench.py edit SRC.npz OUT.npz KEY=DTYPE ... KEY[ROW]+=DELTA ...
        Writes SRC's arrays to OUT (np.savez_compressed, SRC's member order), KEY cast to DTYPE
        (`actions=float64`) or row ROW of KEY shifted by DELTA (`next_observations[5]+=0.25`):
        the files of the tests that what a user's file holds comes back whole.

    check_ogbench.py regular SRC.npz OUT.npz
        Writes what `ogbench.load_dataset(SRC, add_info=True)` returns (its regular layout, with
        qpos, qvel and button_states per transition) to OUT.

Prints one JSON line of what was compared; exits non-zero with the first difference.
"""

import json
import re
import sys
import warnings
import zipfile

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


def npy_members(path):
    """Each member of the zip at `path`, in archive order: (name, (descr, fortran_order, shape),
    the bytes after the header), the header read by numpy's own np.lib.format."""
    out = []
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            with z.open(info) as f:
                version = np.lib.format.read_magic(f)
                read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                shape, fortran, dtype = read(f)
                out.append((info.filename, (np.lib.format.dtype_to_descr(dtype), fortran, shape), f.read()))
    return out


def whole(want_path, got_path):
    want, got = npy_members(want_path), npy_members(got_path)
    names = [m[0] for m in want]
    if [m[0] for m in got] != names:
        sys.exit(f"members {[m[0] for m in got]} instead of {names} (zip order)")
    for (name, wh, wb), (_, gh, gb) in zip(want, got):
        if wh != gh:
            sys.exit(f"{name}: header (descr, fortran_order, shape) {gh} instead of {wh}")
        if wb != gb:
            i = next(k for k in range(min(len(wb), len(gb))) if wb[k] != gb[k]) if len(wb) == len(gb) else None
            sys.exit(f"{name}: the bytes after the header differ ({len(gb)} vs {len(wb)} bytes, first at byte {i})")
    w, g = np.load(want_path), np.load(got_path)
    for k in w.keys():
        a, b = w[k], g[k]
        if a.dtype != b.dtype or a.shape != b.shape or not np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
            sys.exit(f"np.load: {k}: {b.dtype}{b.shape} vs {a.dtype}{a.shape}, or other values")
    print(json.dumps({"members": names, "headers": {n: [str(h[0]), h[1], list(h[2])] for n, h, _ in want}}))


def edit(src, out, changes):
    z = np.load(src)
    arrays = {k: z[k] for k in z.keys()}
    for change in changes:
        shift = re.fullmatch(r"(\w+)\[(\d+)\]\+=(.+)", change)
        if shift:
            key, row, delta = shift.group(1), int(shift.group(2)), float(shift.group(3))
            a = arrays[key].copy()
            a[row] += delta
            arrays[key] = a
        else:
            key, dtype = change.split("=")
            arrays[key] = arrays[key].astype(dtype)
    np.savez_compressed(out, **arrays)
    print(json.dumps({k: [v.dtype.str, list(v.shape)] for k, v in arrays.items()}))


def regular(src, out):
    d = ogbench.load_dataset(src, add_info=True)
    np.savez_compressed(out, **d)
    print(json.dumps({k: [v.dtype.str, list(v.shape)] for k, v in d.items()}))


def main():
    mode = sys.argv[1]
    if mode == "regular":
        return regular(*sys.argv[2:4])
    if mode == "collected":
        return collected(*sys.argv[2:4])
    if mode == "whole":
        return whole(*sys.argv[2:4])
    if mode == "edit":
        return edit(sys.argv[2], sys.argv[3], sys.argv[4:])
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
