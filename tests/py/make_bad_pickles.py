#!/usr/bin/env python3
"""Write BAD inputs for the pgser-etl convert tests.

Usage: make_bad_pickles.py OUTDIR

OUTDIR/manifest.json is a JSON list; each entry has:
  file        file name relative to OUTDIR
  task        value for --task
  extra_args  further convert arguments
  expect      lowercase substring the one-line error message must contain
  why         what is wrong with the input
and, for the code-execution attempts only:
  marker      file name (relative to OUTDIR) that the payload would create
              if it were ever executed; it must never appear
  global      the refused global the message should name

Vocabulary of `expect`: empty, not a pickle, truncated, unknown opcode,
refused global, past the end, expected a dict, missing key, episode count,
steps, dimension, float, dtype, array, non-finite, out-of-band,
no episodes, episodes, malformed, memo, threshold.

"not a pickle" files are the ones whose FIRST byte is not 0x80 (PROTO) and
cannot begin a protocol 0/1 pickle either (CSV text starting 'e' = APPENDS,
PNG 0x89 = NEWFALSE without PROTO, .npy 0x93 = STACK_GLOBAL without PROTO,
gzip 0x1f, JSON '{' which is not an opcode).  "unknown opcode" files start
with a valid PROTO header and hit an undefined opcode byte later.

SAFETY: this script never unpickles anything.  The malicious files are built
byte by byte; do NOT pickle.load them.  If one were executed it would create
OUTDIR/EXECUTED_<name>.
"""
import json
import os
import pickle
import shlex
import struct
import sys

import numpy as np

T, OBS, GOAL, ACT = 50, 10, 3, 4  # FetchReach


def good_dict(n=3, t=T, obs=OBS, goal=GOAL, act=ACT, seed=7, dtype=np.float64):
    rng = np.random.default_rng(seed)
    return {
        "o": rng.standard_normal((n, t, obs)).astype(dtype),
        "ag": rng.standard_normal((n, t, goal)).astype(dtype),
        "u": rng.standard_normal((n, t - 1, act)).astype(dtype),
        "g": rng.standard_normal((n, t - 1, goal)).astype(dtype),
    }


# ---------------------------------------------------------------- opcodes
# Small helpers so each raw pickle below reads like a pickletools listing.
PROTO = lambda n: b"\x80" + bytes([n])          # PROTO n
STOP = b"."
MARK = b"("
TUPLE = b"t"
TUPLE1 = b"\x85"
TUPLE2 = b"\x86"
REDUCE = b"R"
BUILD = b"b"
EMPTY_DICT = b"}"
EMPTY_LIST = b"]"
EMPTY_TUPLE = b")"
SETITEM = b"s"
SETITEMS = b"u"
NONE = b"N"
MEMOIZE = b"\x94"
STACK_GLOBAL = b"\x93"
INST = lambda mod, name: b"i" + mod.encode() + b"\n" + name.encode() + b"\n"
OBJ = b"o"
NEXT_BUFFER = b"\x97"


def GLOBAL(mod, name):                          # c<mod>\n<name>\n
    return b"c" + mod.encode() + b"\n" + name.encode() + b"\n"


def UNICODE(s):                                 # V<raw-unicode-escape>\n (proto 0)
    assert "\n" not in s and "\\" not in s
    return b"V" + s.encode("raw_unicode_escape") + b"\n"


def BINUNICODE(s):                              # X <u32 len> utf8
    b = s.encode()
    return b"X" + struct.pack("<I", len(b)) + b


def SHORT_BINUNICODE(s):                        # \x8c <u8 len> utf8
    b = s.encode()
    assert len(b) < 256
    return b"\x8c" + bytes([len(b)]) + b


def BINPUT(i):                                  # q <u8 memo index>
    return b"q" + bytes([i])


def BINGET(i):                                  # h <u8 memo index>
    return b"h" + bytes([i])


def FRAME(n):                                   # \x95 <u64 frame length>
    return b"\x95" + struct.pack("<Q", n)


def main(outdir):
    outdir = os.path.abspath(outdir)
    os.makedirs(outdir, exist_ok=True)
    manifest = []
    names = set()

    def add(name, data, expect, why, task="FetchReach", extra_args=(), **more):
        assert name not in names, name
        names.add(name)
        assert isinstance(data, (bytes, bytearray))
        assert len(data) < 50_000, (name, len(data))
        with open(os.path.join(outdir, name), "wb") as f:
            f.write(data)
        entry = {"file": name, "task": task, "extra_args": list(extra_args),
                 "expect": expect, "why": why}
        entry.update(more)
        manifest.append(entry)

    def marker(tag):
        """(marker file name, shell command that would create it)."""
        m = f"EXECUTED_{tag}"
        path = os.path.join(outdir, m)
        # never leave a stale marker from an earlier run behind
        if os.path.exists(path):
            os.remove(path)
        return m, path

    good3 = pickle.dumps(good_dict(), protocol=3)

    # ------------------------------------------------------------ not pickles
    add("empty.pkl", b"", "empty", "zero-byte file")
    add("csv_text.pkl", b"episode,step,obs_0,obs_1\n0,0,0.5,0.25\n0,1,0.5,0.125\n",
        "not a pickle", "CSV text; first byte 'e' (0x65 = APPENDS) cannot start a pickle")
    add("png_header.pkl",
        b"\x89PNG\r\n\x1a\n" + b"\x00\x00\x00\rIHDR" + b"\x00" * 17,
        "not a pickle", "PNG signature; first byte 0x89 (NEWFALSE) without a PROTO header")
    add("npy_file.pkl",
        b"\x93NUMPY\x01\x00v\x00{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }"
        + b" " * 42 + b"\n" + b"\x00" * 24,
        "not a pickle", ".npy file; first byte 0x93 (STACK_GLOBAL) without PROTO")
    add("gzip_pickle.pkl", b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x00\x03" + b"\x00" * 20,
        "not a pickle", "gzip-compressed data; first byte 0x1f is not an opcode")
    add("json_text.pkl", b'{"o": [[0.1, 0.2]], "ag": []}\n',
        "not a pickle", "JSON text; first byte '{' is not an opcode")

    # ------------------------------------------------------------- truncated
    # protocol 3 dict: \x80\x03 } q\x00 ( X'o' ... BINBYTES <len> <data...>
    # cut in the middle of the first array's BINBYTES payload.
    # find o's BINBYTES opcode: a 'B' byte followed by the u32 length 12000
    pos = good3.find(b"B")
    while pos != -1:
        ln = struct.unpack("<I", good3[pos + 1:pos + 5])[0]
        if ln == 3 * T * OBS * 8:
            break
        pos = good3.find(b"B", pos + 1)
    assert pos != -1
    cut = pos + 5 + ln // 2
    add("truncated_mid_array.pkl", good3[:cut], "truncated",
        f"protocol 3 pickle cut at byte {cut}, in the middle of o's BINBYTES data ({ln} bytes declared)")
    assert good3.endswith(b"u.")
    add("truncated_before_stop.pkl", good3[:-1], "truncated",
        "protocol 3 pickle with the final STOP ('.') removed; ends right after SETITEMS")
    add("truncated_after_proto.pkl", good3[:2], "truncated",
        "only the PROTO 3 header: \\x80\\x03 then EOF")
    p5 = pickle.dumps(good_dict(seed=8), protocol=5)
    # first BYTEARRAY8 (o's data, 12000 bytes < 64 KiB, so inside the first
    # FRAME); keep its 8-byte length and 100 data bytes, drop the rest.
    i = p5.find(b"\x96")
    assert i != -1
    add("truncated_p5_in_frame.pkl", p5[:i + 9 + 100], "truncated",
        "protocol 5 pickle cut 100 bytes into the first BYTEARRAY8 (and inside its FRAME)")

    # -------------------------------------------------------- unknown opcode
    # \x80\x03 } q\x00 ( X'o' q\x01 \xff
    add("unknown_opcode_ff.pkl",
        PROTO(3) + EMPTY_DICT + BINPUT(0) + MARK + BINUNICODE("o") + BINPUT(1) + b"\xff" + STOP,
        "unknown opcode", "byte 0xff where an opcode is expected (after PROTO 3, EMPTY_DICT, MARK, BINUNICODE)")
    # \x80\x05 \x99 : one past the highest opcode (READONLY_BUFFER = 0x98)
    add("unknown_opcode_99.pkl", PROTO(5) + b"\x99" + STOP,
        "unknown opcode", "0x99, one past the highest protocol-5 opcode READONLY_BUFFER (0x98)")
    # \x80\x02 ] \x0a  : newline is not an opcode
    add("unknown_opcode_newline.pkl", PROTO(2) + EMPTY_LIST + b"\n" + STOP,
        "unknown opcode", "0x0a (newline) used as an opcode after EMPTY_LIST")

    # ------------------------------------------------------ refused globals
    def refused(tag, glob, data_fn, why):
        m, path = marker(tag)
        data = data_fn(path)
        add(f"evil_{tag}.pkl", data, "refused global", why, marker=m, **{"global": glob})

    touch = lambda path: "touch " + shlex.quote(path)

    # protocol 2:  \x80\x02 } ( V'o' c'os\nsystem\n' X<cmd> \x85 R u .
    # i.e. {'o': os.system('touch MARKER')}
    refused("os_system", "os.system", lambda p: (
        PROTO(2) + EMPTY_DICT + MARK + BINUNICODE("o")
        + GLOBAL("os", "system") + BINUNICODE(touch(p)) + TUPLE1 + REDUCE
        + SETITEMS + STOP),
        "dict value built by REDUCE of GLOBAL os.system('touch MARKER'), protocol 2")

    # protocol 0 (text):  ( d V o \n c posix\nsystem\n ( V <cmd> \n t R s .
    refused("posix_system_p0", "posix.system", lambda p: (
        MARK + b"d" + UNICODE("o") + GLOBAL("posix", "system")
        + MARK + UNICODE(touch(p)) + TUPLE + REDUCE + SETITEM + STOP),
        "protocol 0 text pickle: GLOBAL 'posix system' + REDUCE inside a DICT/SETITEM")

    # protocol 2: c builtins\neval\n X "open(MARKER,'w').close()" \x85 R .
    refused("builtins_eval", "builtins.eval", lambda p: (
        PROTO(2) + GLOBAL("builtins", "eval")
        + BINUNICODE(f"open({p!r}, 'w').close()") + TUPLE1 + REDUCE + STOP),
        "GLOBAL builtins.eval + REDUCE with a Python expression that creates the marker")

    # protocol 2 with the Python 2 name: c __builtin__\neval\n (fix_imports maps it to builtins)
    refused("py2_builtin_eval", "eval", lambda p: (
        PROTO(2) + GLOBAL("__builtin__", "eval")
        + BINUNICODE(f"open({p!r}, 'w').close()") + TUPLE1 + REDUCE + STOP),
        "GLOBAL __builtin__.eval (Python 2 module name, mapped to builtins by fix_imports)")

    # protocol 4: \x80\x04 \x95<frame> \x8c'subprocess' \x94 \x8c'Popen' \x94 \x93
    #             ( \x8c'touch' X<path> l \x85 R .   -> Popen(['touch', MARKER])
    def popen(p):
        body = (SHORT_BINUNICODE("subprocess") + MEMOIZE + SHORT_BINUNICODE("Popen")
                + MEMOIZE + STACK_GLOBAL + MEMOIZE
                + MARK + SHORT_BINUNICODE("touch") + BINUNICODE(p) + b"l"
                + TUPLE1 + REDUCE + STOP)
        return PROTO(4) + FRAME(len(body)) + body
    refused("subprocess_popen", "subprocess.Popen", popen,
            "protocol 4 STACK_GLOBAL subprocess.Popen + REDUCE with LIST ['touch', MARKER]")

    # protocol 0 INST:  ( V<cmd>\n i os\nsystem\n .   -> os.system(cmd)
    refused("inst_os_system", "os.system", lambda p: (
        MARK + UNICODE(touch(p)) + INST("os", "system") + STOP),
        "INST opcode: MARK, args, then 'ios\\nsystem\\n' calls os.system(args)")

    # protocol 1 OBJ:  ( c os\nsystem\n X<cmd> o .   -> os.system(cmd)
    refused("obj_os_system", "os.system", lambda p: (
        MARK + GLOBAL("os", "system") + BINUNICODE(touch(p)) + OBJ + STOP),
        "OBJ opcode: MARK, class=os.system, args, 'o' calls class(*args)")

    # numpy.load(PAYLOAD, None, True): allow_pickle=True loads PAYLOAD, a second
    # malicious pickle that runs os.system('touch MARKER').
    m, path = marker("numpy_load")
    payload_name = "evil_numpy_load_payload.pkl"
    payload = (PROTO(2) + GLOBAL("os", "system") + BINUNICODE(touch(path))
               + TUPLE1 + REDUCE + STOP)
    add(payload_name, payload, "refused global",
        "payload loaded by evil_numpy_load.pkl: os.system('touch MARKER'), protocol 2",
        marker=m, **{"global": "os.system"})
    # \x80\x02 c numpy\nload\n ( X<payload path> N \x88 t R .
    ppath = os.path.join(outdir, payload_name)
    add("evil_numpy_load.pkl",
        PROTO(2) + GLOBAL("numpy", "load") + MARK + BINUNICODE(ppath) + NONE
        + b"\x88" + TUPLE + REDUCE + STOP,
        "refused global",
        "GLOBAL numpy.load(payload, None, allow_pickle=True): a numpy global that is not on the allow-list",
        marker=m, **{"global": "numpy.load"})

    # builtins.getattr(builtins.__import__('os'), 'system')('touch MARKER')
    # \x80\x02 c builtins\ngetattr\n c builtins\n__import__\n X'os' \x85 R X'system' \x86 R
    #          X<cmd> \x85 R .
    refused("builtins_getattr", "builtins.getattr", lambda p: (
        PROTO(2) + GLOBAL("builtins", "getattr")
        + GLOBAL("builtins", "__import__") + BINUNICODE("os") + TUPLE1 + REDUCE
        + BINUNICODE("system") + TUPLE2 + REDUCE
        + BINUNICODE(touch(p)) + TUPLE1 + REDUCE + STOP),
        "getattr(__import__('os'), 'system')(cmd): first global met is builtins.getattr")

    # numpy.testing._private.utils.runstring(code, {}) == exec(code, {})
    # \x80\x04 \x8c'numpy.testing._private.utils' \x8c'runstring' \x93 X<code> } \x86 R .
    refused("numpy_runstring", "numpy.testing._private.utils.runstring", lambda p: (
        PROTO(4) + SHORT_BINUNICODE("numpy.testing._private.utils")
        + SHORT_BINUNICODE("runstring") + STACK_GLOBAL
        + BINUNICODE(f"open({p!r}, 'w').close()") + EMPTY_DICT + TUPLE2 + REDUCE + STOP),
        "a numpy.* global that runs exec(): an allow-list must be exact, not a 'numpy.' prefix")

    # A real-looking WGCSL dict whose 'u' value is replaced by os.system(...):
    # the first three arrays are fine numpy arrays, the refusal must come anyway.
    def dict_then_evil(p):
        d = good_dict(seed=9)
        del d["u"], d["g"]
        head = pickle.dumps(d, protocol=3)
        assert head.endswith(SETITEMS + STOP)
        # reopen the dict: MARK, more key/values, SETITEMS
        return (head[:-1] + MARK + BINUNICODE("u") + GLOBAL("os", "system")
                + BINUNICODE(touch(p)) + TUPLE1 + REDUCE + SETITEMS + STOP)
    refused("dict_then_os_system", "os.system", dict_then_evil,
            "valid o/ag arrays first (numpy _reconstruct), then 'u': os.system(cmd)")

    # ------------------------------------------------------ absurd lengths
    head4 = PROTO(4) + EMPTY_DICT + MARK + SHORT_BINUNICODE("o")
    # \x80\x04 } ( \x8c'o' \x8e <u64 2**40> xxxx
    add("len_binbytes8_2e40.pkl", head4 + b"\x8e" + struct.pack("<Q", 2**40) + b"abcd",
        "past the end", "BINBYTES8 declares 2^40 bytes; 4 present")
    add("len_binbytes8_2e63.pkl", head4 + b"\x8e" + struct.pack("<Q", 2**63) + b"abcd",
        "past the end", "BINBYTES8 declares 2^63 bytes (overflows a signed 64-bit offset)")
    add("len_binbytes8_max.pkl", head4 + b"\x8e" + struct.pack("<Q", 2**64 - 1) + b"abcd",
        "past the end", "BINBYTES8 declares 2^64-1 bytes (offset + len wraps around u64)")
    add("len_binunicode8_2e40.pkl", head4 + b"\x8d" + struct.pack("<Q", 2**40) + b"abcd",
        "past the end", "BINUNICODE8 declares 2^40 bytes")
    add("len_bytearray8_2e63.pkl",
        PROTO(5) + EMPTY_DICT + MARK + SHORT_BINUNICODE("o") + b"\x96" + struct.pack("<Q", 2**63) + b"abcd",
        "past the end", "BYTEARRAY8 (protocol 5) declares 2^63 bytes")
    add("len_binbytes_4g.pkl",
        PROTO(3) + EMPTY_DICT + MARK + BINUNICODE("o") + b"B" + struct.pack("<I", 0xFFFFFFFF) + b"abcd",
        "past the end", "BINBYTES declares 2^32-1 bytes")
    add("len_binunicode_4g.pkl",
        PROTO(3) + EMPTY_DICT + MARK + b"X" + struct.pack("<I", 0xFFFFFFFF) + b"o",
        "past the end", "BINUNICODE (a dict key) declares 2^32-1 bytes")
    add("len_binstring_2g.pkl",
        PROTO(2) + b"T" + struct.pack("<i", 0x7FFFFFFF) + b"abc",
        "past the end", "BINSTRING declares 2^31-1 bytes")
    add("len_short_binbytes.pkl",
        PROTO(3) + EMPTY_DICT + MARK + BINUNICODE("o") + b"C\xff" + b"only ten b",
        "past the end", "SHORT_BINBYTES declares 255 bytes, 10 present")
    add("len_long4_huge.pkl",
        PROTO(2) + b"\x8b" + struct.pack("<i", 0x7FFFFFFF) + b"\x01\x02",
        "past the end", "LONG4 declares a 2^31-1 byte integer")
    add("len_frame_huge.pkl",
        PROTO(4) + FRAME(2**62) + EMPTY_DICT + STOP,
        "past the end", "FRAME declares 2^62 bytes")
    add("len_frame_max.pkl",
        PROTO(4) + FRAME(2**64 - 1) + EMPTY_DICT + STOP,
        "past the end", "FRAME declares 2^64-1 bytes")

    # ----------------------------------------------------- structural errors
    # \x80\x03 K\x01 t .   TUPLE with no MARK on the stack
    add("malformed_no_mark.pkl", PROTO(3) + b"K\x01" + TUPLE + STOP,
        "malformed", "TUPLE with no MARK on the stack")
    # \x80\x03 } u .   SETITEMS with no MARK
    add("malformed_setitems_no_mark.pkl", PROTO(3) + EMPTY_DICT + SETITEMS + STOP,
        "malformed", "SETITEMS with no MARK")
    # \x80\x03 R .   REDUCE on an empty stack
    add("malformed_underflow_reduce.pkl", PROTO(3) + REDUCE + STOP,
        "malformed", "REDUCE on an empty stack (stack underflow)")
    # \x80\x03 } X'o' s .   SETITEM needs dict, key, value: only dict+key
    add("malformed_underflow_setitem.pkl", PROTO(3) + EMPTY_DICT + BINUNICODE("o") + SETITEM + STOP,
        "malformed", "SETITEM with only dict and key on the stack")
    # \x80\x03 .   STOP with an empty stack
    add("malformed_stop_empty.pkl", PROTO(3) + STOP,
        "malformed", "STOP with nothing on the stack")
    # \x80\x03 h\x05 .   BINGET of memo slot 5, never PUT
    add("memo_binget_unset.pkl", PROTO(3) + EMPTY_DICT + BINPUT(0) + BINGET(5) + STOP,
        "memo", "BINGET 5, only memo slot 0 was set")
    # \x80\x03 j\xff\xff\xff\xff .   LONG_BINGET 2^32-1
    add("memo_long_binget_huge.pkl", PROTO(3) + b"j" + struct.pack("<I", 0xFFFFFFFF) + STOP,
        "memo", "LONG_BINGET 4294967295 on an empty memo")
    # protocol 0: ( d g 7 \n .   GET 7 with nothing stored
    add("memo_get_p0.pkl", MARK + b"d" + b"p0\n" + b"g7\n" + STOP,
        "memo", "protocol 0 GET 7, only memo slot 0 was PUT")

    # ------------------------------------------------ semantic / shape errors
    d = good_dict()
    add("toplevel_list.pkl", pickle.dumps([d["o"], d["ag"], d["u"], d["g"]], protocol=3),
        "expected a dict", "top level is a list of the four arrays")
    add("toplevel_int.pkl", pickle.dumps(42, protocol=3),
        "expected a dict", "top level is the int 42")
    add("toplevel_ndarray.pkl", pickle.dumps(d["o"], protocol=4),
        "expected a dict", "top level is a bare ndarray (o)")

    dd = dict(d)
    del dd["u"]
    add("missing_u.pkl", pickle.dumps(dd, protocol=3), "missing key", "dict has o, ag, g but no u")
    dd = dict(d)
    del dd["ag"]
    add("missing_ag.pkl", pickle.dumps(dd, protocol=4), "missing key", "dict has o, u, g but no ag")

    dd = dict(d)
    dd["u"] = d["u"][:-1]
    add("ragged_n_u.pkl", pickle.dumps(dd, protocol=3), "episode count",
        "o/ag/g have 3 episodes, u has 2")
    dd = dict(d)
    dd["g"] = good_dict(t=T + 1)["g"]  # [3, T, 3]
    add("ragged_t_g.pkl", pickle.dumps(dd, protocol=3), "steps",
        "g has T=50 steps instead of T-1=49")
    dd = dict(d)
    dd["o"] = good_dict(t=T + 1)["o"]  # [3, 51, 10]
    add("ragged_t_o_vs_ag.pkl", pickle.dumps(dd, protocol=3), "steps",
        "o has 51 steps, ag has 50")

    add("dims_obs11.pkl", pickle.dumps(good_dict(obs=11), protocol=3), "dimension",
        "FetchReach with obs dim 11 (expected 10)")
    add("dims_act3.pkl", pickle.dumps(good_dict(act=3), protocol=3), "dimension",
        "FetchReach with action dim 3 (expected 4)")
    add("dims_fetchpush_as_reach.pkl", pickle.dumps(good_dict(n=2, obs=25), protocol=4), "dimension",
        "FetchPush-shaped data (obs 25) converted with --task FetchReach")

    dd = dict(d)
    dd["o"] = (d["o"] * 100).astype(np.int64)
    add("int64_o.pkl", pickle.dumps(dd, protocol=3), "float", "o is int64")
    dd = dict(d)
    dd["u"] = d["u"] > 0
    add("bool_u.pkl", pickle.dumps(dd, protocol=3), "float", "u is bool")
    dd = dict(d)
    dd["g"] = d["g"].astype(object)
    add("object_g.pkl", pickle.dumps(dd, protocol=2), "dtype",
        "g is an object-dtype array (its BUILD state is a list of Python floats)")
    dd = dict(d)
    dd["u"] = d["u"].tolist()
    add("list_u.pkl", pickle.dumps(dd, protocol=3), "array", "u is a list of lists of floats, not an ndarray")

    dd = dict(d)
    o = d["o"].copy()
    o[1, 7, 3] = np.nan
    dd["o"] = o
    add("nan_o.pkl", pickle.dumps(dd, protocol=3), "non-finite", "o[1,7,3] is NaN")
    dd = dict(d)
    o = d["o"].copy()
    o[2, 49, 0] = np.inf
    dd["o"] = o
    add("inf_o.pkl", pickle.dumps(dd, protocol=3), "non-finite", "o[2,49,0] is +Inf")
    dd = dict(d)
    u = d["u"].copy()
    u[0, 0, 2] = -np.inf
    dd["u"] = u
    add("neginf_u_p5.pkl", pickle.dumps(dd, protocol=5), "non-finite", "u[0,0,2] is -Inf (protocol 5)")

    bufs = []
    add("oob_p5.pkl", pickle.dumps(good_dict(seed=10), protocol=5, buffer_callback=bufs.append),
        "out-of-band", "protocol 5 with buffer_callback: each array is NEXT_BUFFER (0x97), data not in the file")
    ro = {k: v.copy() for k, v in good_dict(seed=11).items()}
    for v in ro.values():
        v.flags.writeable = False
    bufs = []
    add("oob_p5_readonly.pkl", pickle.dumps(ro, protocol=5, buffer_callback=bufs.append),
        "out-of-band", "protocol 5 out-of-band with read-only arrays: NEXT_BUFFER followed by READONLY_BUFFER (0x98)")

    add("zero_episodes.pkl", pickle.dumps(good_dict(n=0), protocol=3), "no episodes",
        "all four arrays have N=0")
    add("episodes_999.pkl", good3, "episodes",
        "a valid 3-episode file but --episodes 999", extra_args=["--episodes", "999"])

    pt = good_dict(n=2, t=30, obs=2, goal=2, act=2, seed=12)
    add("point_no_threshold.pkl", pickle.dumps(pt, protocol=3), "threshold",
        "unknown task PointReach without --threshold", task="PointReach")

    with open(os.path.join(outdir, "manifest.json"), "w") as f:
        json.dump(manifest, f, indent=1)
        f.write("\n")
    print(f"wrote {len(manifest)} bad inputs to {outdir}")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: make_bad_pickles.py OUTDIR")
    main(sys.argv[1])
