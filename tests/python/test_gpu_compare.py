"""bench/gpu_compare.py, the GPU bundle's correctness figures: weights and Q of a GPU backend
against the CPU's. A difference is measured relative above 1, the worst one is named, and a
backend within the tolerance passes while one a step off does not; a column that does not depend
on the device must be equal. Run on checkpoints and tables written here."""

import json
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from conftest import REPO

SCRIPT = REPO / "bench" / "gpu_compare.py"


def write_ckpt(path, tensors):
    """A safetensors file of float32 tensors, as pgser writes them."""
    header, body = {"__metadata__": {"format": "pgser-agent"}}, b""
    for name, a in tensors.items():
        data = np.asarray(a, dtype="<f4").tobytes()
        header[name] = {"dtype": "F32", "shape": list(np.shape(a)), "data_offsets": [len(body), len(body) + len(data)]}
        body += data
    h = json.dumps(header).encode()
    path.write_bytes(len(h).to_bytes(8, "little") + h + body)


def run(tmp, backends):
    args = [sys.executable, str(SCRIPT), "--tol", "1e-4", "--cpu-train", str(tmp / "cpu"), "--cpu-score",
            str(tmp / "cpu.parquet"), "--json", str(tmp / "out.json")]
    for b in backends:
        args += ["--backend", b, str(tmp / b), str(tmp / f"{b}.parquet")]
    r = subprocess.run(args, capture_output=True, text=True, check=True)
    return json.loads((tmp / "out.json").read_text()), r.stdout


def test_within_and_beyond_the_tolerance(tmp_path):
    rng = np.random.default_rng(0)
    w = {"actor.0.weight": rng.normal(size=(4, 3)) * 50, "critic1.0.bias": rng.normal(size=5)}
    q = rng.normal(size=20) * 30
    swap = np.arange(20)
    for name, dw, dq in [("cpu", 0, 0), ("near", 3e-5, 2e-5), ("far", 0, 0)]:
        (tmp_path / name).mkdir()
        for s in range(2):
            write_ckpt(tmp_path / name / f"s{s}.ckpt", {k: v * (1 + dw) for k, v in w.items()})
            lines = [{"updates": u, "critic_loss": 0.5 / u * (1 + dw), "q_mean": -3.0 - u * (1 + dw)} for u in (10, 20)]
            (tmp_path / name / f"s{s}.ckpt.metrics.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
        pq.write_table(pa.table({"swap": swap, "q": (q * (1 + dq)).astype(np.float32)}), tmp_path / f"{name}.parquet")
    # "far": one bias off by 1e-3 (a step's worth), and one swap drawn elsewhere.
    bad = dict(w, **{"critic1.0.bias": w["critic1.0.bias"] + np.array([0, 0, 1e-3, 0, 0])})
    write_ckpt(tmp_path / "far" / "s1.ckpt", bad)
    pq.write_table(pa.table({"swap": swap[::-1].copy(), "q": q.astype(np.float32)}), tmp_path / "far.parquet")

    doc, out = run(tmp_path, ["near", "far"])
    assert doc["near"]["weights"]["ok"] and doc["near"]["q"]["ok"], doc["near"]
    assert 1e-5 < doc["near"]["weights"]["worst"] < 1e-4
    assert doc["near"]["weights"]["tensors"] == 4
    far = doc["far"]["weights"]
    c = np.float32(w["critic1.0.bias"][2])
    expected = abs(float(np.float32(c + 1e-3)) - float(c)) / max(abs(float(c)), 1.0)  # relative above 1
    assert not far["ok"] and abs(far["worst"] - expected) < 1e-9, far
    assert far["where"].startswith("s1.ckpt critic1.0.bias[2]"), far["where"]
    assert not doc["far"]["q"]["ok"] and "column swap differs" in doc["far"]["q"]["why"]
    assert doc["near"]["metrics"]["ok"] and doc["near"]["metrics"]["values"] == 8, doc["near"]["metrics"]
    assert doc["far"]["metrics"]["ok"]  # its losses were left equal
    assert "near weights: within 0.0001" in out and "far weights: NOT within 0.0001" in out


def test_a_backend_that_wrote_nothing_is_reported_not_fatal(tmp_path):
    (tmp_path / "cpu").mkdir()
    write_ckpt(tmp_path / "cpu" / "s0.ckpt", {"a": np.ones(3)})
    pq.write_table(pa.table({"q": np.ones(3, dtype=np.float32)}), tmp_path / "cpu.parquet")
    doc, out = run(tmp_path, ["cuda"])
    assert not doc["cuda"]["weights"]["ok"] and "missing" in doc["cuda"]["weights"]["why"]
    assert not doc["cuda"]["q"]["ok"] and "missing" in doc["cuda"]["q"]["why"]


def test_a_q_far_off_in_the_logged_metrics_fails_and_no_score_is_left_out(tmp_path):
    for name, q in [("cpu", -3.0), ("cuda", -3.01)]:
        (tmp_path / name).mkdir()
        write_ckpt(tmp_path / name / "s0.ckpt", {"a": np.ones(3)})
        (tmp_path / name / "s0.ckpt.metrics.jsonl").write_text(json.dumps({"updates": 10, "q_mean": q}) + "\n")
    args = [sys.executable, str(SCRIPT), "--cpu-train", str(tmp_path / "cpu"), "--backend", "cuda",
            str(tmp_path / "cuda"), "-", "--json", str(tmp_path / "out.json")]
    subprocess.run(args, check=True, capture_output=True)
    doc = json.loads((tmp_path / "out.json").read_text())["cuda"]
    assert doc["weights"]["ok"] and "q" not in doc
    m = doc["metrics"]
    assert not m["ok"] and "update 10 q_mean" in m["where"] and abs(m["worst"] - 0.01 / 3.0) < 1e-9, m
