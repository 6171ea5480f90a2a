#!/usr/bin/env python3
"""Generate the committed pickle fixtures in tests/fixtures/ with REAL numpy.

These files are committed so the Rust tests can check pickles written by
both numpy 1.x (globals under ``numpy.core``) and numpy 2.x (``numpy._core``)
without needing Python at test time.

Usage (run once per numpy major version, then write the README):

  python3 -m venv /tmp/np1 && /tmp/np1/bin/pip install 'numpy<2'
  python3 -m venv /tmp/np2 && /tmp/np2/bin/pip install 'numpy>=2'
  /tmp/np1/bin/python tests/py/make_committed_fixtures.py write tests/fixtures
  /tmp/np2/bin/python tests/py/make_committed_fixtures.py write tests/fixtures
  /tmp/np2/bin/python tests/py/make_committed_fixtures.py readme tests/fixtures

`write` creates np<MAJOR>_p2.pkl, _p3, _p4, _p5 (float64, C order, little
endian; protocol 5 in-band) and np<MAJOR>_p4_f32_F_BE.pkl (float32, Fortran
order, big endian), all FetchReach-shaped with 3 episodes, and merges their
entries into OUTDIR/manifest.json (same fields as make_pickles.py's manifest
plus "numpy", "python" and "globals").

`readme` checks with pickletools (no unpickling) which globals each file
names, asserts the numpy 1 / numpy 2 module paths, checks that all files of
the same variant hold bit-identical arrays (this step does unpickle, so it
needs numpy; the files are our own), and writes OUTDIR/README.md with the
sha256 of every file.
"""
import hashlib
import json
import os
import pickle
import pickletools
import platform
import sys

T, OBS, GOAL, ACT, N = 50, 10, 3, 4, 3  # FetchReach, 3 episodes

VARIANTS = [
    # suffix, protocol, dtype, order, endian
    ("p2", 2, "float64", "C", "little"),
    ("p3", 3, "float64", "C", "little"),
    ("p4", 4, "float64", "C", "little"),
    ("p5", 5, "float64", "C", "little"),
    ("p4_f32_F_BE", 4, "float32", "F", "big"),
]

SPECIALS = [-0.0, 0.0, 5e-324, -2.2250738585072014e-308, 1e-310, 3.0e38,
            -1.5e-45, 1.1754943508222875e-38, 123456.789, -1.0]


def make_data(dtype):
    """Identical values under numpy 1.26 and 2.x (PCG64 + integers/normal)."""
    import numpy as np
    rng = np.random.default_rng(20240501)
    out = {}
    for key, shape in (("o", (N, T, OBS)), ("ag", (N, T, GOAL)),
                       ("u", (N, T - 1, ACT)), ("g", (N, T - 1, GOAL))):
        mant = rng.standard_normal(shape)
        exp = rng.integers(-12, 13, size=shape)
        # exact powers of ten from Python literals: np.power's result differs
        # in the last bit between numpy 1.26 and 2.x
        pow10 = np.array([float(f"1e{k}") for k in range(-12, 13)])
        x = (mant * pow10[exp + 12]).reshape(-1)
        idx = rng.choice(x.size, size=len(SPECIALS), replace=False)
        x[idx] = SPECIALS
        out[key] = x.reshape(shape).astype(dtype)
    return out


def write(outdir):
    import numpy as np
    major = int(np.__version__.split(".")[0])
    os.makedirs(outdir, exist_ok=True)
    mpath = os.path.join(outdir, "manifest.json")
    manifest = []
    if os.path.exists(mpath):
        with open(mpath) as f:
            manifest = json.load(f)
    for suffix, proto, dtype, order, endian in VARIANTS:
        d = make_data(np.dtype(dtype))
        if endian == "big":
            d = {k: v.astype(v.dtype.newbyteorder(">")) for k, v in d.items()}
        if order == "F":
            d = {k: np.asfortranarray(v) for k, v in d.items()}
        name = f"np{major}_{suffix}.pkl"
        with open(os.path.join(outdir, name), "wb") as f:
            pickle.dump(d, f, protocol=proto)
        entry = {
            "file": name, "task": "FetchReach", "extra_args": [],
            "protocol": proto, "dtype": dtype, "order": order, "endian": endian,
            "note": f"written by numpy {np.__version__}",
            "episodes": N, "steps": T, "obs_dim": OBS, "goal_dim": GOAL, "act_dim": ACT,
            "float32_ok": True,
            "numpy": np.__version__, "python": platform.python_version(),
            "globals": sorted(pickle_globals(os.path.join(outdir, name))),
        }
        manifest = [e for e in manifest if e["file"] != name] + [entry]
    manifest.sort(key=lambda e: e["file"])
    with open(mpath, "w") as f:
        json.dump(manifest, f, indent=1)
        f.write("\n")
    print(f"numpy {np.__version__}: wrote {len(VARIANTS)} fixtures to {outdir}")


def pickle_globals(path):
    """Globals named by GLOBAL / STACK_GLOBAL, found without unpickling."""
    with open(path, "rb") as f:
        data = f.read()
    found = set()
    memo = {}
    pushed = []  # recent pushed values; strings or None
    for op, arg, _ in pickletools.genops(data):
        name = op.name
        if name == "GLOBAL":
            found.add(arg.replace(" ", "."))
            pushed.append(None)
        elif name in ("SHORT_BINUNICODE", "BINUNICODE", "BINUNICODE8", "UNICODE"):
            pushed.append(arg)
        elif name == "MEMOIZE":
            memo[len(memo)] = pushed[-1] if pushed else None
        elif name in ("PUT", "BINPUT", "LONG_BINPUT"):
            memo[arg] = pushed[-1] if pushed else None
        elif name in ("GET", "BINGET", "LONG_BINGET"):
            pushed.append(memo.get(arg))
        elif name == "STACK_GLOBAL":
            mod, nm = pushed[-2], pushed[-1]
            found.add(f"{mod}.{nm}")
            pushed.append(None)
        elif name in ("FRAME", "PROTO", "STOP"):
            pass
        else:
            pushed.append(None)
    return found


def sha256(path):
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def readme(outdir):
    with open(os.path.join(outdir, "manifest.json")) as f:
        manifest = json.load(f)
    rows = []
    total = 0
    for e in manifest:
        path = os.path.join(outdir, e["file"])
        g = pickle_globals(path)
        major = e["numpy"].split(".")[0]
        core = "numpy.core" if major == "1" else "numpy._core"
        if e["protocol"] == 5 and e["order"] in ("C", "F"):
            want = f"{core}.numeric._frombuffer"
        else:
            want = f"{core}.multiarray._reconstruct"
        assert want in g, (e["file"], want, g)
        other = "numpy._core" if major == "1" else "numpy.core."
        assert not any(x.startswith(other) for x in g), (e["file"], g)
        assert g <= {want, "numpy.dtype", "numpy.ndarray", "_codecs.encode"}, (e["file"], g)
        size = os.path.getsize(path)
        total += size
        rows.append((e, sha256(path), size, sorted(g)))

    # all files of one variant must hold the same bits, whichever numpy wrote them
    same = "not checked (numpy not importable)"
    try:
        import numpy as np
        by_variant = {}
        for e in manifest:
            with open(os.path.join(outdir, e["file"]), "rb") as f:
                d = pickle.load(f)  # our own committed files
            key = e["file"].split("_", 1)[1]
            norm = {k: np.ascontiguousarray(v.astype(v.dtype.newbyteorder("<"))).tobytes()
                    for k, v in d.items()}
            by_variant.setdefault(key, []).append((e["file"], norm))
        for key, files in by_variant.items():
            for fname, norm in files[1:]:
                assert norm == files[0][1], (fname, files[0][0])
        same = "yes: every npX_<variant>.pkl pair holds bit-identical arrays"
    except ImportError:
        pass

    lines = [
        "# Committed pickle fixtures",
        "",
        "WGCSL-style pickles written by REAL numpy, so the Rust tests cover both",
        "numpy 1.x and numpy 2.x output without Python at test time. Each is a dict",
        f"with keys `o` [3,{T},{OBS}], `ag` [3,{T},{GOAL}], `u` [3,{T - 1},{ACT}], "
        f"`g` [3,{T - 1},{GOAL}] (FetchReach dims, 3 episodes).",
        "Values include -0.0, float64 subnormals and magnitudes 1e-12..1e12 plus 3e38.",
        "",
        "Regenerate with `tests/py/make_committed_fixtures.py` (see its docstring:",
        "`write` once under numpy<2 and once under numpy>=2, then `readme`).",
        "`manifest.json` has one entry per file in the same format as",
        "`tests/py/make_pickles.py`'s manifest, plus `numpy`, `python`, `globals`.",
        "",
        "| file | numpy | protocol | dtype | order | endian | bytes | sha256 |",
        "| --- | --- | --- | --- | --- | --- | --- | --- |",
    ]
    for e, digest, size, _ in rows:
        lines.append(f"| {e['file']} | {e['numpy']} | {e['protocol']} | {e['dtype']} | "
                     f"{e['order']} | {e['endian']} | {size} | `{digest}` |")
    lines += [
        "",
        f"Total: {total} bytes.",
        "",
        "## Globals each file names (checked with pickletools, nothing unpickled)",
        "",
        "numpy 1.x writes `numpy.core.multiarray._reconstruct` (protocols 2-4) and",
        "`numpy.core.numeric._frombuffer` (protocol 5, in-band, contiguous arrays);",
        "numpy 2.x writes `numpy._core.multiarray._reconstruct` and",
        "`numpy._core.numeric._frombuffer`. Both also name `numpy.ndarray` (with",
        "`_reconstruct`) and `numpy.dtype`; protocol 2 also names `_codecs.encode`,",
        "because array bytes are stored as `_codecs.encode(<latin-1 str>, 'latin1')`.",
        "",
        "| file | globals |",
        "| --- | --- |",
    ]
    for e, _, _, g in rows:
        lines.append(f"| {e['file']} | " + ", ".join(f"`{x}`" for x in g) + " |")
    lines += [
        "",
        f"Same data across numpy versions: {same}.",
        "",
    ]
    with open(os.path.join(outdir, "README.md"), "w") as f:
        f.write("\n".join(lines))
    print(f"README.md written: {len(rows)} files, {total} bytes")


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] not in ("write", "readme"):
        sys.exit("usage: make_committed_fixtures.py write|readme OUTDIR")
    (write if sys.argv[1] == "write" else readme)(sys.argv[2])
