#!/usr/bin/env python3
"""Which Arrow type holds an image column best: fixed_size_binary[H*W*C] (pgser's `obs` in an
image table) against fixed_size_list<uint8>[H*W*C] (what a passthrough array of bytes is), and
zstd levels 1 and 3. Each is written by pyarrow as pgser writes tables (zstd, no dictionary, no
statistics on the images, row groups of whole 1001-step episodes) and read back whole, best of
three; prints one JSON line per variant: file MB, write and read seconds, read MB/s of images.

    bench_image_column.py SHARD.npz [--rows 20000] [--group-rows 2002]

SHARD.npz is any file with uint8 `observations` [N, H, W, C] (bench/make_shards.py --visual
64, or a real OGBench visual dataset). Never for tests.
"""
from __future__ import annotations

import argparse
import json
import os
import tempfile
import time

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq


def column(images: np.ndarray, kind: str) -> pa.Array:
    n, row = len(images), images[0].size
    flat = pa.py_buffer(np.ascontiguousarray(images).reshape(-1))
    if kind == "binary":
        return pa.FixedSizeBinaryArray.from_buffers(pa.binary(row), n, [None, flat])
    values = pa.Array.from_buffers(pa.uint8(), n * row, [None, flat])
    return pa.FixedSizeListArray.from_arrays(values, row)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("shard")
    p.add_argument("--rows", type=int, default=20000)
    p.add_argument("--group-rows", type=int, default=2002)
    a = p.parse_args()
    images = np.load(a.shard)["observations"][: a.rows]
    assert images.dtype == np.uint8, images.dtype
    raw_mb = images.nbytes / 1e6
    with tempfile.TemporaryDirectory() as d:
        for kind in ("binary", "list"):
            for level in (1, 3):
                path = os.path.join(d, f"{kind}-{level}.parquet")
                table = pa.table({"obs": column(images, kind)})
                t0 = time.perf_counter()
                pq.write_table(table, path, compression="zstd", compression_level=level, use_dictionary=False,
                               write_statistics=False, row_group_size=a.group_rows)
                write_s = time.perf_counter() - t0
                best = float("inf")
                for _ in range(3):
                    t0 = time.perf_counter()
                    back = pq.read_table(path)
                    best = min(best, time.perf_counter() - t0)
                assert back.num_rows == len(images)
                print(json.dumps({
                    "type": "fixed_size_binary" if kind == "binary" else "fixed_size_list<uint8>",
                    "zstd": level, "rows": len(images), "images_mb": round(raw_mb, 1),
                    "file_mb": round(os.path.getsize(path) / 1e6, 1), "write_s": round(write_s, 3),
                    "read_s": round(best, 3), "read_mb_s": round(raw_mb / best),
                }), flush=True)


if __name__ == "__main__":
    main()
