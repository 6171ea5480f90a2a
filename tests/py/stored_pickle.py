"""Load a pickle of numpy arrays as the file stores them, byte order included.

numpy's own unpickling gives a big-endian array of a protocol 0-4 pickle back in native order
(`pickle.load` of a `>f4` array is `<f4`, its values swapped), so a check built on `pickle.load`
cannot see whether a writer kept the byte order. Here Python's own pickle machine runs the file
and only numpy's reconstruction callables are stood in for: `numpy.dtype` (the byte order
arrives with BUILD's state, `(3, '>', ...)`), `_reconstruct` (then BUILD with `(version, shape,
dtype, is_fortran, raw bytes)`), protocol 5's `_frombuffer(buffer, dtype, shape, order)` and a
scalar's `scalar(dtype, raw bytes)`. Each array is then `np.frombuffer` of the file's bytes in
the stored dtype and order. `load` also checks each array against numpy's own `pickle.load`,
value for value, so that this reader and numpy's cannot disagree on anything but the byte
order's label.

Trusted test files only: like pickle.load, this runs what the file names.
"""
import pickle
import warnings

import numpy as np

_NUMPY_MODULES = {"numpy", "numpy.core.multiarray", "numpy._core.multiarray", "numpy.core.numeric",
                  "numpy._core.numeric"}


class _DType:
    """`numpy.dtype(descr, align, copy)` with its BUILD state kept: state[1] is the byte order."""

    def __init__(self, descr, *args):
        self.descr = descr
        self.state = None

    def __setstate__(self, state):
        self.state = state

    def dtype(self):
        dt = np.dtype(self.descr)
        order = self.state[1] if self.state else "|"
        return dt.newbyteorder(order) if order in "<>" else dt


class _Array:
    """`_reconstruct(ndarray, (0,), b'b')`, filled in by BUILD."""

    value = None

    def __setstate__(self, state):
        shape, dtype, fortran, raw = state[1:] if len(state) == 5 else state  # (version, ...) or not
        if isinstance(raw, str):  # protocol 0-2 bytes that came as text
            raw = raw.encode("latin1")
        self.value = np.frombuffer(raw, dtype.dtype()).reshape(shape, order="F" if fortran else "C")


def _reconstruct(cls, shape, typecode):
    return _Array()


def _scalar(dtype, raw):
    return np.frombuffer(raw.encode("latin1") if isinstance(raw, str) else raw, dtype.dtype())[0]


def _frombuffer(buf, dtype, shape, order):
    return np.frombuffer(bytes(buf), dtype.dtype()).reshape(shape, order=order)


class _Unpickler(pickle.Unpickler):
    def find_class(self, module, name):
        if module in _NUMPY_MODULES:
            if name == "dtype":
                return _DType
            if name == "_reconstruct":
                return _reconstruct
            if name == "_frombuffer":
                return _frombuffer
            if name == "scalar":
                return _scalar
        return super().find_class(module, name)


def _unwrap(v):
    if isinstance(v, _Array):
        return v.value
    if isinstance(v, dict):
        return {k: _unwrap(x) for k, x in v.items()}
    return v


def load(path):
    """The pickled object with every array in its stored dtype (byte order included) and layout;
    raises AssertionError where numpy's own `pickle.load` reads other values."""
    with open(path, "rb") as f:
        stored = _unwrap(_Unpickler(f).load())
    with open(path, "rb") as f, warnings.catch_warnings():
        # numpy 2 warns when loading numpy-1 pickles (numpy.core.* names)
        warnings.simplefilter("ignore", DeprecationWarning)
        theirs = pickle.load(f)
    if isinstance(stored, dict):
        for k, a in stored.items():
            if isinstance(a, np.ndarray):
                b = theirs[k]
                same = (a.shape == b.shape and a.dtype.kind == b.dtype.kind and a.dtype.itemsize == b.dtype.itemsize
                        and native(a).tobytes() == native(b).tobytes())
                assert same, f"{path}: key {k!r}: this reader gives {a.dtype.str}{a.shape}, numpy {b.dtype.str}{b.shape}"
    return stored


def native(a):
    """Native little-endian, C-order copy (pgser's Parquet layout)."""
    a = np.asarray(a)
    return np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<")))
