#!/usr/bin/env python3
"""Write GOOD WGCSL-style pickles for the pgser-etl convert tests.

Usage: make_pickles.py OUTDIR

Every file is a dict with exactly the keys ``o`` [N,T,obs], ``ag`` [N,T,goal],
``u`` [N,T-1,act], ``g`` [N,T-1,goal] (plus ``info_is_success`` in one
variant, which convert must skip).  The data is deterministic
(``np.random.default_rng(seed)``) and deliberately nasty for bit-equality
checks: magnitudes from 1e-30 to 1e30, negative zero, subnormals, the
smallest/largest normals, and in one file values beyond the float32 range.

OUTDIR/manifest.json is a JSON list; each entry has:
  file        file name relative to OUTDIR
  task        value for --task
  extra_args  further convert arguments (e.g. ["--threshold", "0.05"])
  protocol    pickle protocol used (0..5)
  dtype       "float64" | "float32"
  order       "C" | "F" | "mixed" | "noncontig"
  endian      "little" | "big" | "mixed"
  note        free text: what this variant exercises
  episodes    N, steps T, obs_dim, goal_dim, act_dim  (shape facts)
  float32_ok  false when --float32 would overflow values to +-inf

Needs only numpy.  Never reads a pickle back except to self-check (these are
our own, trusted files).
"""
import json
import os
import pickle
import sys

import numpy as np

TASKS = {
    # name: (T, obs, goal, act)
    "FetchReach": (50, 10, 3, 4),
    "FetchPush": (50, 25, 3, 4),
}

# Special float64 values, all inside the float32 range except the ones in
# F64_HUGE.  Subnormal f64 values become (signed) zero in float32, which is
# still finite.
F64_SPECIALS = [
    -0.0, 0.0, 1.0, -1.0, 0.1, 1.0 / 3.0, -2.5, np.pi,
    5e-324, -5e-324,                    # smallest subnormal
    2.225073858507201e-308,             # largest subnormal
    2.2250738585072014e-308,            # smallest normal
    1e-310, -3.3e-315,                  # more subnormals
    1.2345678901234567e-300, -9.87654321e-200,
    3.0e38, -3.3e38,                    # near the float32 maximum
    1.401298464324817e-45,              # float32 smallest subnormal (exact)
    1.1754943508222875e-38,             # float32 smallest normal (exact)
    123456789.123456789, -0.000123456789,
]
F64_HUGE = [1.7976931348623157e308, -1.7976931348623157e308, 1e300, -4.2e250]
F32_SPECIALS = [
    -0.0, 0.0, 1.0, -1.0, 0.1, -2.5, np.pi,
    1e-45, -1e-45,                      # smallest float32 subnormal
    1.1754942e-38,                      # largest float32 subnormal
    1.1754944e-38,                      # smallest float32 normal
    1e-40, -3e-42,
    3.4028235e38, -3.4028235e38,        # float32 max
    16777217.0, -0.000123456789, 1e30,
]


POW10 = np.array([float(f"1e{k}") for k in range(-30, 31)])


def nasty(rng, shape, dtype=np.float64, huge=False):
    """Deterministic array with varied magnitudes and special values."""
    dtype = np.dtype(dtype)
    mant = rng.standard_normal(shape)
    if dtype == np.float32:
        exp = rng.integers(-20, 21, size=shape)
    else:
        exp = rng.integers(-30, 31, size=shape)
    # powers of ten from Python literals (np.power differs in the last bit
    # between numpy versions; this keeps the data version-independent)
    x = mant * POW10[exp + 30]
    specials = list(F32_SPECIALS if dtype == np.float32 else F64_SPECIALS)
    if huge:
        specials += F64_HUGE
    x = x.astype(dtype)
    flat = x.reshape(-1)
    if flat.size:
        k = min(flat.size, 3 * len(specials))
        idx = rng.choice(flat.size, size=k, replace=False)
        vals = np.array([specials[i % len(specials)] for i in range(k)], dtype=np.float64)
        flat[idx] = vals.astype(dtype)
    assert np.all(np.isfinite(x))
    return x


def episodes(seed, n, T, obs, goal, act, dtype=np.float64, huge=False):
    rng = np.random.default_rng(seed)
    return {
        "o": nasty(rng, (n, T, obs), dtype, huge),
        "ag": nasty(rng, (n, T, goal), dtype, huge),
        "u": nasty(rng, (n, T - 1, act), dtype, huge),
        "g": nasty(rng, (n, T - 1, goal), dtype, huge),
    }


def native(a):
    """Little-endian, C-order copy (the layout pgser writes)."""
    return np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<")))


def be(a):
    return a.astype(a.dtype.newbyteorder(">"))


def fort(a):
    return np.asfortranarray(a)


def readonly(a):
    a = a.copy()
    a.flags.writeable = False
    return a


def noncontig(a):
    """Same values, but a strided (non-contiguous) view."""
    big = np.empty(a.shape[:-1] + (2 * a.shape[-1],), dtype=a.dtype)
    big[..., ::2] = a
    v = big[..., ::2]
    assert not v.flags.c_contiguous and not v.flags.f_contiguous
    return v


def main(outdir):
    os.makedirs(outdir, exist_ok=True)
    manifest = []

    def write(name, d, protocol, task, dtype, order, endian, note,
              extra_args=(), float32_ok=True):
        path = os.path.join(outdir, name)
        with open(path, "wb") as f:
            pickle.dump(d, f, protocol=protocol)
        # self-check: our own trusted file loads back to the same bits
        with open(path, "rb") as f:
            back = pickle.load(f)
        assert list(back) == list(d), name
        for k in d:
            a, b = np.asarray(d[k]), back[k]
            # numpy's ndarray.__setstate__ (protocols 0-4) converts
            # non-native byte order to native, so compare values natively.
            assert a.dtype.kind == b.dtype.kind == "f", (name, k)
            assert a.dtype.itemsize == b.dtype.itemsize, (name, k)
            assert a.shape == b.shape, (name, k)
            assert np.array_equal(native(a).view(f"u{a.dtype.itemsize}"),
                                  native(b).view(f"u{b.dtype.itemsize}")), (name, k)
        n, T, obs = d["o"].shape
        manifest.append({
            "file": name,
            "task": task,
            "extra_args": list(extra_args),
            "protocol": protocol,
            "dtype": dtype,
            "order": order,
            "endian": endian,
            "note": note,
            "episodes": int(n),
            "steps": int(T),
            "obs_dim": int(obs),
            "goal_dim": int(d["ag"].shape[2]),
            "act_dim": int(d["u"].shape[2]),
            "float32_ok": float32_ok,
        })

    R = TASKS["FetchReach"]
    P = TASKS["FetchPush"]

    # --- one file per protocol, float64 C order little endian -------------
    for proto, n in [(0, 2), (1, 2), (2, 3), (3, 3), (4, 4), (5, 3)]:
        d = episodes(100 + proto, n, *R)
        notes = {
            0: "protocol 0: text opcodes; array bytes via _codecs.encode(UNICODE raw-unicode-escape, 'latin1'); dtype memo reused via GET",
            1: "protocol 1: BINUNICODE + _codecs.encode(..., 'latin1') for array bytes",
            2: "protocol 2: _codecs.encode(BINUNICODE, 'latin1') for array bytes, NEWTRUE/NEWFALSE",
            3: "protocol 3: canonical WGCSL form; BINBYTES array data",
            4: "protocol 4: FRAME, STACK_GLOBAL, MEMOIZE",
            5: "protocol 5 in-band, writable arrays: numpy._core.numeric._frombuffer(BYTEARRAY8, dtype, shape, 'C')",
        }
        write(f"fetchreach_p{proto}_f64_C.pkl", d, proto, "FetchReach",
              "float64", "C", "little", notes[proto])

    # protocol 5 with read-only arrays: numpy emits bytes (BINBYTES) not BYTEARRAY8
    d = {k: readonly(v) for k, v in episodes(201, 3, *R).items()}
    write("fetchreach_p5_f64_C_readonly.pkl", d, 5, "FetchReach", "float64",
          "C", "little", "protocol 5, read-only arrays: _frombuffer gets BINBYTES (bytes) instead of BYTEARRAY8")

    # protocol 5 with a non-contiguous array: numpy falls back to _reconstruct
    d = episodes(202, 3, *R)
    d = {k: noncontig(v) for k, v in d.items()}
    write("fetchreach_p5_f64_noncontig.pkl", d, 5, "FetchReach", "float64",
          "noncontig", "little", "protocol 5, strided views: numpy falls back to _reconstruct + BUILD (no _frombuffer)")

    # --- float32 ---------------------------------------------------------
    for proto in (2, 3, 5):
        d = episodes(300 + proto, 3, *R, dtype=np.float32)
        write(f"fetchreach_p{proto}_f32_C.pkl", d, proto, "FetchReach",
              "float32", "C", "little", f"float32 arrays, protocol {proto}")

    # --- Fortran order ---------------------------------------------------
    for proto in (2, 3, 4, 5):
        d = {k: fort(v) for k, v in episodes(400 + proto, 3, *R).items()}
        note = ("Fortran order: BUILD state is_fortran=True, bytes in F order"
                if proto < 5 else "Fortran order, protocol 5: _frombuffer(..., order='F')")
        write(f"fetchreach_p{proto}_f64_F.pkl", d, proto, "FetchReach",
              "float64", "F", "little", note)

    # --- big endian ------------------------------------------------------
    for proto in (0, 3, 4, 5):
        d = {k: be(v) for k, v in episodes(500 + proto, 3, *R).items()}
        write(f"fetchreach_p{proto}_f64_BE.pkl", d, proto, "FetchReach",
              "float64", "C", "big", "big-endian '>f8': dtype BUILD state byteorder '>'")
    d = {k: fort(be(v)) for k, v in episodes(510, 3, *R, dtype=np.float32).items()}
    write("fetchreach_p4_f32_F_BE.pkl", d, 4, "FetchReach", "float32", "F",
          "big", "float32, Fortran order AND big endian")
    d = {k: fort(be(v)) for k, v in episodes(511, 2, *R, dtype=np.float32).items()}
    write("fetchreach_p5_f32_F_BE.pkl", d, 5, "FetchReach", "float32", "F",
          "big", "float32, Fortran order AND big endian, protocol 5 _frombuffer order='F'")

    # --- mixed order / endianness in one file (all float64) --------------
    for proto in (2, 4, 5):
        e = episodes(600 + proto, 4, *R)
        d = {"o": e["o"], "ag": fort(e["ag"]), "u": be(e["u"]), "g": fort(be(e["g"]))}
        write(f"fetchreach_p{proto}_f64_mixed.pkl", d, proto, "FetchReach",
              "float64", "mixed", "mixed",
              "o: C little, ag: F little, u: C big, g: F big")

    # --- an extra key convert keeps as a column of its own ---------------
    d = episodes(700, 3, *R)
    rng = np.random.default_rng(701)
    d["info_is_success"] = (rng.random((3, R[0] - 1, 1)) < 0.3).astype(np.float64)
    write("fetchreach_p3_f64_info.pkl", d, 3, "FetchReach", "float64", "C",
          "little", "extra key info_is_success [N,T-1,1] float64 (kept as a passthrough column)")

    # --- FetchPush -------------------------------------------------------
    d = episodes(800, 2, *P)
    write("fetchpush_p3_f64_C.pkl", d, 3, "FetchPush", "float64", "C", "little",
          "FetchPush dims obs=25")
    d = episodes(801, 7, *P)
    write("fetchpush_p4_f64_C_n7.pkl", d, 4, "FetchPush", "float64", "C", "little",
          "7 episodes; o is 70000 bytes > 64 KiB so protocol 4 writes it OUTSIDE a FRAME (several FRAMEs)")
    d = episodes(802, 7, *P)
    write("fetchpush_p5_f64_C_n7.pkl", d, 5, "FetchPush", "float64", "C", "little",
          "7 episodes; protocol 5 BYTEARRAY8 larger than the frame target, written outside a FRAME")

    # --- values beyond the float32 range ---------------------------------
    d = episodes(900, 2, *R, huge=True)
    write("fetchreach_p3_f64_hugeexp.pkl", d, 3, "FetchReach", "float64", "C",
          "little", "contains |x| up to 1.797e308: --float32 turns these into +-inf",
          float32_ok=False)

    # --- PointReach-like unknown task -----------------------------------
    d = episodes(1000, 5, 30, 2, 2, 2)
    write("pointreach_p3_f64_C.pkl", d, 3, "PointReach", "float64", "C",
          "little", "unknown task, T=30 obs=goal=act=2: needs --threshold",
          extra_args=["--threshold", "0.05"])
    d = {k: fort(be(v)) for k, v in episodes(1001, 6, 30, 2, 2, 2).items()}
    write("pointreach_p5_f64_F_BE.pkl", d, 5, "PointReach", "float64", "F",
          "big", "unknown task, protocol 5, Fortran big endian",
          extra_args=["--threshold", "0.05"])

    with open(os.path.join(outdir, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=1)
        f.write("\n")
    print(f"wrote {len(manifest)} good pickles to {outdir}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: make_pickles.py OUTDIR")
    main(sys.argv[1])
