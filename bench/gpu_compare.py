#!/usr/bin/env python3
"""The GPU bundle's correctness figures: each GPU backend's trained weights and Q-scores against
the CPU's (scripts/gpu_run.sh runs pgser on each backend first; this only reads the files).

For every backend B given, with the CPU's run as the reference:
  weights  every tensor of every `s*.ckpt` in B's training folder against the same tensor of the
           CPU's: the worst |b - c| / max(|c|, 1), where it is, and whether it is within --tol;
  metrics  every number the training logged (`s*.ckpt.metrics.jsonl`: the critic's loss and its
           mean Q on each logged batch, the actor's loss), the same measure: the critic's
           forward pass on the device, at every logged update rather than only the last;
  q        the `q` column of B's scored table against the CPU's, the same measure; every other
           column must be equal (which swaps are drawn is the CPU's work, whatever the device).
           Left out where SCORE_FILE is `-` (the bundle carries no pgser-etl: docs/gpu.md).

Why relative above 1: a weight of 40 and one of 0.01 have different rounding, and the question is
whether a kernel, a layout or an optimizer step is wrong (those move values by 1e-3 and more),
not which order a GPU sums in.

Usage: gpu_compare.py --tol 1e-4 --cpu-train DIR --cpu-score FILE \
           [--backend NAME TRAIN_DIR SCORE_FILE]... --json OUT.json
Needs numpy and pyarrow (both on the GPU machines' python3).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def worst(a, b):
    """(worst scaled difference, index, a's value, b's value, all finite) of two float arrays."""
    import numpy as np

    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.asarray(b, dtype=np.float64).ravel()
    if a.shape != b.shape:
        raise ValueError(f"shapes differ: {a.shape} vs {b.shape}")
    if a.size == 0:
        return 0.0, 0, 0.0, 0.0, True
    d = np.abs(a - b) / np.maximum(np.abs(b), 1.0)
    d = np.where(np.isfinite(d), d, np.inf)
    i = int(np.argmax(d))
    return float(d[i]), i, float(a[i]), float(b[i]), bool(np.isfinite(a).all())


def load_file(path: str) -> dict:
    """A safetensors file's float32 tensors (pgser's checkpoints hold nothing else), read by hand:
    an 8-byte little-endian header length, a JSON header, the data. No safetensors package needed."""
    import numpy as np

    raw = Path(path).read_bytes()
    n = int.from_bytes(raw[:8], "little")
    header = json.loads(raw[8:8 + n])
    body = raw[8 + n:]
    out = {}
    for name, t in header.items():
        if name == "__metadata__":
            continue
        if t["dtype"] != "F32":
            raise ValueError(f"{path}: {name} is {t['dtype']}, not F32")
        a, b = t["data_offsets"]
        out[name] = np.frombuffer(body[a:b], dtype="<f4").reshape(t["shape"])
    return out


class Mismatch(Exception):
    """A device's run that cannot be compared value by value (a file missing, other names)."""


def compare(pairs, tol: float, count: str, empty_why: str) -> dict:
    """The worst scaled difference over `pairs`, each (label, indexed, device values, cpu values),
    as a figure: where it is (label, with the index when `indexed`), how many pairs were read
    (under `count`), and whether it is within `tol`; or why there is no figure."""
    out = {"ok": True, "tol": tol, "worst": 0.0, "where": None, count: 0}
    try:
        for label, indexed, a, c in pairs:
            w, i, x, y, finite = worst(a, c)
            out[count] += 1
            if not finite:
                return {"ok": False, "why": f"{label}: not finite"}
            if w > out["worst"]:
                out.update(worst=w, where=f"{label}{f'[{i}]' if indexed else ''}: {x!r} vs cpu {y!r}")
    except Mismatch as e:
        return {"ok": False, "why": str(e)}
    if out[count] == 0:
        return {"ok": False, "why": empty_why}
    out["ok"] = out["worst"] <= tol
    return out


def pair_files(dev_dir: Path, cpu_dir: Path, pattern: str):
    """(name, device file, cpu file) for each of the CPU run's files matching `pattern`."""
    for name in sorted(p.name for p in cpu_dir.glob(pattern)):
        if not (dev_dir / name).exists():
            raise Mismatch(f"{dev_dir / name} missing")
        yield name, dev_dir / name, cpu_dir / name


def weights(dev_dir: Path, cpu_dir: Path, tol: float) -> dict:
    def pairs():
        for name, dev, cpu in pair_files(dev_dir, cpu_dir, "s*.ckpt"):
            a, c = load_file(str(dev)), load_file(str(cpu))
            if sorted(a) != sorted(c):
                raise Mismatch(f"{name}: tensor names differ")
            for k in sorted(c):
                yield f"{name} {k}", True, a[k], c[k]

    return compare(pairs(), tol, "tensors", f"no s*.ckpt in {cpu_dir}")


def metrics(dev_dir: Path, cpu_dir: Path, tol: float) -> dict:
    def pairs():
        for name, dev_file, cpu_file in pair_files(dev_dir, cpu_dir, "s*.ckpt.metrics.jsonl"):
            dev = [json.loads(x) for x in dev_file.read_text().splitlines() if x.strip()]
            cpu = [json.loads(x) for x in cpu_file.read_text().splitlines() if x.strip()]
            if [r.get("updates") for r in dev] != [r.get("updates") for r in cpu]:
                raise Mismatch(f"{name}: logged at other updates")
            for d, c in zip(dev, cpu):
                for k, v in c.items():
                    if k != "updates" and isinstance(v, (int, float)):
                        yield f"{name} update {c['updates']} {k}", False, [d.get(k, float("nan"))], [v]

    return compare(pairs(), tol, "values", f"no logged values in {cpu_dir}")


def scores(dev_file: Path, cpu_file: Path, tol: float) -> dict:
    import pyarrow.parquet as pq

    a, c = pq.read_table(dev_file), pq.read_table(cpu_file)
    if a.schema.names != c.schema.names or a.num_rows != c.num_rows:
        return {"ok": False, "why": "columns or row counts differ"}
    for name in c.schema.names:
        if name != "q" and not a.column(name).equals(c.column(name)):
            return {"ok": False, "why": f"column {name} differs (it does not depend on the device)"}
    w, i, x, y, finite = worst(a.column("q").to_numpy(), c.column("q").to_numpy())
    ok = finite and w <= tol
    return {"ok": ok, "tol": tol, "worst": w, "rows": c.num_rows, "where": f"row {i}: {x!r} vs cpu {y!r}"}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tol", type=float, default=1e-4)
    ap.add_argument("--cpu-train", type=Path, required=True)
    ap.add_argument("--cpu-score", type=Path)
    ap.add_argument("--backend", nargs=3, action="append", default=[], metavar=("NAME", "TRAIN_DIR", "SCORE_FILE"))
    ap.add_argument("--json", type=Path, required=True)
    a = ap.parse_args(argv)
    doc = {}

    def figure(f, *args):
        try:
            return f(*args)
        except Exception as e:  # a missing or unreadable run is a figure too
            return {"ok": False, "why": f"{type(e).__name__}: {e}"}

    for name, train_dir, score_file in a.backend:
        r = {"weights": figure(weights, Path(train_dir), a.cpu_train, a.tol),
             "metrics": figure(metrics, Path(train_dir), a.cpu_train, a.tol)}
        if score_file != "-":
            r["q"] = (figure(scores, Path(score_file), a.cpu_score, a.tol) if a.cpu_score and Path(score_file).exists()
                      else {"ok": False, "why": f"{score_file} missing"})
        doc[name] = r
        for what in r:
            v = r[what]
            fig = f"worst {v['worst']:.2e} ({v.get('where')})" if "worst" in v else v.get("why")
            print(f"{name} {what}: {'within' if v['ok'] else 'NOT within'} {a.tol:g}: {fig}", flush=True)
    a.json.write_text(json.dumps(doc, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
