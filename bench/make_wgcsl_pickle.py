#!/usr/bin/env python3
"""Write a synthetic but realistic WGCSL-style offline dataset pickle.

The file is a pickled ``dict`` of C-order float64 numpy arrays, the layout the
WGCSL / baselines-HER replay buffer is saved in::

    o   [N, T,   obs_dim]     observations (T = 50 for the Fetch tasks)
    u   [N, T-1, act_dim]     actions
    g   [N, T-1, goal_dim]    desired goal (constant within an episode)
    ag  [N, T,   goal_dim]    achieved goal

Key order follows the baselines buffer (o, u, g, [info_is_success,] ag).

The trajectories are a cheap kinematic imitation of the Fetch robotics
environments (smooth AR(1) actions, a gripper that integrates them, an object
that only moves when the gripper touches it, MuJoCo-like jitter), so a
compressor sees data that behaves like real rollouts rather than white noise.

The pickle stream is written by hand, opcode for opcode what ``pickle.dump``
produces for the same dict (protocol 3 or 4), except that the array payloads
are streamed straight from the arrays' memory instead of going through
``ndarray.__reduce__``, which would first copy each array into a ``bytes``
object.  Peak memory is therefore the arrays themselves plus one 1024-episode
chunk of temporaries.

Usage:
    make_wgcsl_pickle.py --episodes N --task FetchPush --out PATH
                         [--protocol {3,4}] [--seed S] [--with-info]
                         [--numpy-module numpy.core.multiarray]
"""
from __future__ import annotations

import argparse
import os
import struct
import sys
import time

import numpy as np

# Default size: >= 300 MiB of array payload for FetchPush
# (one FetchPush episode is (50*25 + 50*3 + 49*4 + 49*3) * 8 = 13,944 bytes).
DEFAULT_EPISODES = 22_600
HORIZON = 50  # observation steps per episode; actions/goals have HORIZON - 1
CHUNK = 1024  # episodes generated per RNG stream (fixed => output independent of memory)

# task -> (obs_dim, goal_dim, act_dim)
TASKS = {
    "FetchReach": (10, 3, 4),
    "FetchPush": (25, 3, 4),
    "FetchSlide": (25, 3, 4),
    "FetchPickAndPlace": (25, 3, 4),
    "FetchPick": (25, 3, 4),
}

TABLE_Z = 0.42469975  # object resting height in the Fetch tasks
GRIP_HOME = np.array([1.34184, 0.74910, 0.53472])


# --------------------------------------------------------------------------
# trajectory synthesis
# --------------------------------------------------------------------------

def _jitter(rng, shape, scale=2e-6):
    return rng.normal(0.0, scale, shape)


def gen_chunk(rng: np.random.Generator, n: int, task: str, T: int = HORIZON):
    """Return o, u, g, ag, success for n episodes (fresh arrays)."""
    obs_dim, goal_dim, act_dim = TASKS[task]
    Ta = T - 1

    # Actions: AR(1) in [-1, 1], smooth like a policy plus exploration noise.
    u = np.empty((n, Ta, act_dim))
    a = rng.uniform(-1, 1, (n, act_dim))
    for t in range(Ta):
        a = np.clip(0.8 * a + 0.35 * rng.standard_normal((n, act_dim)), -1.0, 1.0)
        u[:, t] = a

    grip = np.empty((n, T, 3))
    fingers = np.empty((n, T, 2))
    grip[:, 0] = GRIP_HOME + rng.uniform(-0.01, 0.01, (n, 3))
    fingers[:, 0] = 0.0245 + _jitter(rng, (n, 2), 1e-4)

    if task == "FetchReach":
        for t in range(Ta):
            grip[:, t + 1] = np.clip(grip[:, t] + 0.03 * u[:, t, :3] + _jitter(rng, (n, 3), 2e-4),
                                     [1.05, 0.40, 0.40], [1.55, 1.10, 0.90])
            fingers[:, t + 1] = np.clip(fingers[:, t] + 0.002 * u[:, t, 3:4], 0.0, 0.05) + _jitter(rng, (n, 2))
        goal = GRIP_HOME + rng.uniform(-0.15, 0.15, (n, 3))
        ag = grip
        grip_velp = np.diff(grip, axis=1, prepend=grip[:, :1])
        gripper_vel = np.diff(fingers, axis=1, prepend=fingers[:, :1])
        o = np.concatenate([grip, fingers, grip_velp, gripper_vel], axis=2)
    else:
        obj = np.empty((n, T, 3))
        rot = np.empty((n, T, 3))
        obj[:, 0, 0] = GRIP_HOME[0] + rng.uniform(-0.15, 0.15, n)
        obj[:, 0, 1] = GRIP_HOME[1] + rng.uniform(-0.15, 0.15, n)
        obj[:, 0, 2] = TABLE_Z
        rot[:, 0] = 0.0
        rot[:, 0, 2] = rng.uniform(-np.pi, np.pi, n)
        for t in range(Ta):
            step = 0.03 * u[:, t, :3] + _jitter(rng, (n, 3), 2e-4)
            grip[:, t + 1] = np.clip(grip[:, t] + step, [1.05, 0.40, 0.40], [1.55, 1.10, 0.90])
            fingers[:, t + 1] = np.clip(fingers[:, t] + 0.002 * u[:, t, 3:4], 0.0, 0.05) + _jitter(rng, (n, 2))
            # the object is pushed along when the gripper is close to it
            d = np.linalg.norm(grip[:, t + 1] - obj[:, t], axis=1)
            touch = (d < 0.06)[:, None]
            push = np.where(touch, 0.8 * (grip[:, t + 1] - grip[:, t]), 0.0)
            push[:, 2] = 0.0
            obj[:, t + 1] = obj[:, t] + push + _jitter(rng, (n, 3))
            if task in ("FetchPickAndPlace", "FetchPick"):
                lift = touch[:, 0] & (fingers[:, t + 1, 0] < 0.02)
                obj[lift, t + 1, 2] = np.maximum(grip[lift, t + 1, 2] - 0.02, TABLE_Z)
            spin = np.where(touch, rng.normal(0, 0.05, (n, 3)), 0.0)
            rot[:, t + 1] = rot[:, t] + spin + _jitter(rng, (n, 3), 1e-5)
        goal = obj[:, 0].copy()
        if task == "FetchSlide":
            goal[:, 0] += 0.4 + rng.uniform(-0.3, 0.3, n)
            goal[:, 1] += rng.uniform(-0.3, 0.3, n)
        else:
            goal[:, :2] += rng.uniform(-0.15, 0.15, (n, 2))
        if task in ("FetchPickAndPlace", "FetchPick"):
            up = rng.uniform(size=n) < 0.5
            goal[up, 2] += rng.uniform(0, 0.45, up.sum())
        ag = obj
        grip_velp = np.diff(grip, axis=1, prepend=grip[:, :1])
        object_velp = np.diff(obj, axis=1, prepend=obj[:, :1]) - grip_velp
        object_velr = np.diff(rot, axis=1, prepend=rot[:, :1])
        gripper_vel = np.diff(fingers, axis=1, prepend=fingers[:, :1])
        o = np.concatenate([grip, obj, obj - grip, fingers, rot,
                            object_velp, object_velr, grip_velp, gripper_vel], axis=2)
    assert o.shape[2] == obs_dim, o.shape
    g = np.broadcast_to(goal[:, None, :goal_dim], (n, Ta, goal_dim))
    dist = np.linalg.norm(ag[:, 1:] - g, axis=2)
    success = (dist < 0.05).astype(np.float64)[:, :, None]
    return o, u, g, ag, success


def generate(episodes: int, task: str, seed: int, with_info: bool) -> dict:
    obs_dim, goal_dim, act_dim = TASKS[task]
    T = HORIZON
    arrays = {
        "o": np.empty((episodes, T, obs_dim)),
        "u": np.empty((episodes, T - 1, act_dim)),
        "g": np.empty((episodes, T - 1, goal_dim)),
    }
    if with_info:
        arrays["info_is_success"] = np.empty((episodes, T - 1, 1))
    arrays["ag"] = np.empty((episodes, T, goal_dim))
    for c, lo in enumerate(range(0, episodes, CHUNK)):
        hi = min(lo + CHUNK, episodes)
        rng = np.random.default_rng([seed, c])
        # always draw a full chunk so the data do not depend on `episodes`
        o, u, g, ag, success = gen_chunk(rng, CHUNK, task)
        k = hi - lo
        arrays["o"][lo:hi] = o[:k]
        arrays["u"][lo:hi] = u[:k]
        arrays["g"][lo:hi] = g[:k]
        arrays["ag"][lo:hi] = ag[:k]
        if with_info:
            arrays["info_is_success"][lo:hi] = success[:k]
    return arrays


# --------------------------------------------------------------------------
# pickle stream writer (mirrors CPython's pickler for this object graph)
# --------------------------------------------------------------------------

FRAME_SIZE_TARGET = 64 * 1024
FRAME_SIZE_MIN = 4


class PickleStream:
    """Emit protocol 3/4 opcodes for a dict of numpy arrays, streaming payloads."""

    def __init__(self, f, protocol: int, numpy_module: str):
        if protocol not in (3, 4):
            raise ValueError("protocol must be 3 or 4")
        self.f = f
        self.proto = protocol
        self.npmod = numpy_module
        self.memo: dict = {}
        self.frame = bytearray() if protocol >= 4 else None
        f.write(b"\x80" + bytes([protocol]))

    # -- low level -------------------------------------------------------
    def w(self, b: bytes):
        if self.frame is not None:
            self.frame += b
        else:
            self.f.write(b)

    def commit_frame(self):
        if self.frame is None or not self.frame:
            return
        if len(self.frame) >= FRAME_SIZE_MIN:
            self.f.write(b"\x95" + struct.pack("<Q", len(self.frame)))
        self.f.write(self.frame)
        self.frame = bytearray()

    def boundary(self):
        if self.frame is not None and len(self.frame) >= FRAME_SIZE_TARGET:
            self.commit_frame()

    def put(self, key):
        idx = len(self.memo)
        self.memo[key] = idx
        if self.proto >= 4:
            self.w(b"\x94")  # MEMOIZE
        elif idx < 256:
            self.w(b"q" + bytes([idx]))  # BINPUT
        else:
            self.w(b"r" + struct.pack("<I", idx))  # LONG_BINPUT

    def get(self, key) -> bool:
        idx = self.memo.get(key)
        if idx is None:
            return False
        self.w(b"h" + bytes([idx]) if idx < 256 else b"j" + struct.pack("<I", idx))
        return True

    # -- objects ---------------------------------------------------------
    # Every save_* starts with boundary(): CPython's Pickler.save() commits a
    # full (>= 64 KiB) frame before it saves the next object, never in the
    # middle of one.
    def save_str(self, s: str, memo_key=None):
        self.boundary()
        key = memo_key or ("str", s)
        if self.get(key):
            return
        b = s.encode("utf-8")
        if self.proto >= 4 and len(b) < 256:
            self.w(b"\x8c" + bytes([len(b)]) + b)  # SHORT_BINUNICODE
        else:
            self.w(b"X" + struct.pack("<I", len(b)) + b)  # BINUNICODE
        self.put(key)

    def save_int(self, n: int):
        self.boundary()
        if 0 <= n <= 0xFF:
            self.w(b"K" + bytes([n]))  # BININT1
        elif 0 <= n <= 0xFFFF:
            self.w(b"M" + struct.pack("<H", n))  # BININT2
        elif -0x80000000 <= n <= 0x7FFFFFFF:
            self.w(b"J" + struct.pack("<i", n))  # BININT
        else:
            enc = n.to_bytes((n.bit_length() + 8) // 8, "little", signed=True)
            self.w(b"\x8a" + bytes([len(enc)]) + enc)  # LONG1

    def save_const(self, v):
        self.boundary()
        self.w({None: b"N", True: b"\x88", False: b"\x89"}[v])

    def save_global(self, module: str, name: str):
        self.boundary()
        key = ("global", module, name)
        if self.get(key):
            return
        if self.proto >= 4:
            self.save_str(module)
            self.save_str(name)
            self.w(b"\x93")  # STACK_GLOBAL
        else:
            self.w(b"c" + module.encode() + b"\n" + name.encode() + b"\n")  # GLOBAL
        self.put(key)

    def tuple_begin(self, n: int):
        self.boundary()
        if n > 3:
            self.w(b"(")  # MARK

    def tuple_end(self, n: int, key):
        if n == 0:
            self.w(b")")  # EMPTY_TUPLE (not memoized)
            return
        self.w((b"\x85", b"\x86", b"\x87")[n - 1] if n <= 3 else b"t")  # TUPLE1/2/3, TUPLE
        self.put(key)

    def save_int_tuple(self, items, key):
        self.tuple_begin(len(items))
        for v in items:
            self.save_int(v)
        self.tuple_end(len(items), key)

    def save_bytes_header(self, n: int) -> bool:
        """Emit the opcode for an n-byte bytes object. True => payload goes unframed."""
        self.boundary()
        if n <= 0xFF:
            self.w(b"C" + bytes([n]))  # SHORT_BINBYTES
            return False
        if n > 0xFFFFFFFF:
            if self.proto < 4:
                raise ValueError("protocol 3 cannot hold a >4 GiB array; use --protocol 4")
            hdr = b"\x8e" + struct.pack("<Q", n)  # BINBYTES8
        else:
            hdr = b"B" + struct.pack("<I", n)  # BINBYTES
        if n >= FRAME_SIZE_TARGET:  # large payloads are written outside any frame
            self.commit_frame()
            self.f.write(hdr)
            return True
        self.w(hdr)
        return False

    def save_dtype_f8(self):
        # numpy: dtype('f8').__reduce__() ->
        #   (dtype, ('f8', False, True), (3, '<', None, None, None, -1, -1, 0))
        self.boundary()
        key = ("dtype", "<f8")
        if self.get(key):
            return
        self.save_global("numpy", "dtype")
        self.tuple_begin(3)
        self.save_str("f8")
        self.save_const(False)
        self.save_const(True)
        self.tuple_end(3, ("dtype-args",))
        self.w(b"R")  # REDUCE
        self.put(key)
        self.tuple_begin(8)
        self.save_int(3)
        self.save_str("<")
        for _ in range(3):
            self.save_const(None)
        self.save_int(-1)
        self.save_int(-1)
        self.save_int(0)
        self.tuple_end(8, ("dtype-state",))
        self.w(b"b")  # BUILD

    def save_array(self, name: str, a: np.ndarray):
        if a.dtype != np.float64 or not a.flags.c_contiguous:
            raise ValueError("only C-contiguous float64 arrays are supported")
        if a.dtype.byteorder not in ("=", "<") or sys.byteorder != "little":
            raise ValueError("little-endian arrays only")
        # numpy: ndarray.__reduce__() ->
        #   (_reconstruct, (ndarray, (0,), b'b'), (1, shape, dtype, False, rawdata))
        self.boundary()
        self.save_global(self.npmod, "_reconstruct")
        self.tuple_begin(3)
        self.save_global("numpy", "ndarray")
        self.save_int_tuple((0,), ("zero-tuple", name))
        self.boundary()
        if not self.get(("bytes", b"b")):
            self.w(b"C\x01b")
            self.put(("bytes", b"b"))
        self.tuple_end(3, ("reconstruct-args", name))
        self.w(b"R")  # REDUCE
        self.put(("array", name))
        self.tuple_begin(5)
        self.save_int(1)
        self.save_int_tuple(a.shape, ("shape", name))
        self.save_dtype_f8()
        self.save_const(False)
        payload = memoryview(a).cast("B")
        if self.save_bytes_header(a.nbytes):
            self.f.write(payload)  # straight from the array, no copy
        else:
            self.w(payload.tobytes())
        self.put(("data", name))
        self.tuple_end(5, ("state", name))
        self.w(b"b")  # BUILD

    def dump_dict(self, d: dict):
        self.boundary()
        self.w(b"}")  # EMPTY_DICT
        self.put(("dict",))
        items = list(d.items())
        for i in range(0, len(items), 1000):  # CPython batches SETITEMS by 1000
            batch = items[i:i + 1000]
            if len(batch) > 1:
                self.w(b"(")  # MARK
            for k, v in batch:
                self.save_str(k, ("key", k))
                self.save_array(k, v)
            self.w(b"u" if len(batch) > 1 else b"s")  # SETITEMS / SETITEM
        self.w(b".")  # STOP
        self.commit_frame()


def default_numpy_module() -> str:
    # WGCSL's released datasets were pickled under numpy 1.x ("numpy.core");
    # numpy 2 still loads that name.
    return "numpy.core.multiarray"


def write_pickle(path: str, arrays: dict, protocol: int, numpy_module: str):
    tmp = f"{path}.tmp-{os.getpid()}"
    try:
        with open(tmp, "wb") as f:
            PickleStream(f, protocol, numpy_module).dump_dict(arrays)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=DEFAULT_EPISODES,
                    help=f"number of episodes (default {DEFAULT_EPISODES}: >= 300 MiB for FetchPush)")
    ap.add_argument("--task", default="FetchPush", choices=sorted(TASKS))
    ap.add_argument("--out", required=True, help="output .pkl path")
    ap.add_argument("--protocol", type=int, default=4, choices=(3, 4))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--with-info", action="store_true",
                    help="also store info_is_success [N,T-1,1] like the baselines buffer")
    ap.add_argument("--numpy-module", default=default_numpy_module(),
                    help="module named in the pickle for _reconstruct "
                         "(default numpy.core.multiarray as in numpy-1.x pickles; "
                         "numpy 2 itself writes numpy._core.multiarray)")
    args = ap.parse_args(argv)
    if args.episodes < 1:
        ap.error("--episodes must be >= 1")

    t0 = time.perf_counter()
    arrays = generate(args.episodes, args.task, args.seed, args.with_info)
    t1 = time.perf_counter()
    write_pickle(args.out, arrays, args.protocol, args.numpy_module)
    t2 = time.perf_counter()
    size = os.path.getsize(args.out)
    shapes = ", ".join(f"{k}{list(v.shape)}" for k, v in arrays.items())
    print(f"wrote {args.out}: {size / 1e6:.1f} MB ({size / 2**20:.1f} MiB), protocol {args.protocol}, "
          f"{args.task}, {shapes}; generate {t1 - t0:.1f} s, write {t2 - t1:.1f} s")


if __name__ == "__main__":
    main()
