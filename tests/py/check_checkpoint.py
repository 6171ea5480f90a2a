"""Read a pgser checkpoint with nothing but the safetensors layout and numpy, and recompute the
policy and Q values the Rust side produced for the same inputs.

Usage: check_checkpoint.py MODEL.ckpt PROBE.json
The safetensors format is an 8-byte little-endian header length, a JSON header (tensor dtype,
shape, byte offsets, and `__metadata__`), then the raw data: simple enough to read by hand, which
is the point of the check (any reader, no pgser code).
"""
import json
import struct
import sys

import numpy as np


def read_safetensors(path):
    raw = open(path, "rb").read()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + n])
    meta = header.pop("__metadata__", {})
    data = raw[8 + n :]
    tensors = {}
    for name, info in header.items():
        assert info["dtype"] == "F32", (name, info["dtype"])
        a, b = info["data_offsets"]
        tensors[name] = np.frombuffer(data[a:b], dtype="<f4").reshape(info["shape"])
    return tensors, meta


def mlp(t, prefix, x):
    """nn.Sequential(Linear, ReLU, ..., Linear) with weights [out, in], indices 0, 2, 4, ..."""
    k = 0
    while f"{prefix}.{k + 2}.weight" in t:
        x = np.maximum(x @ t[f"{prefix}.{k}.weight"].T + t[f"{prefix}.{k}.bias"], 0)
        k += 2
    return x @ t[f"{prefix}.{k}.weight"].T + t[f"{prefix}.{k}.bias"]


def main():
    t, meta = read_safetensors(sys.argv[1])
    probe = json.load(open(sys.argv[2]))
    assert meta["format"] == "pgser-agent", meta
    config, task = json.loads(meta["config"]), json.loads(meta["task"])
    assert task["name"] == "FetchReach" and task["T"] == 50, task
    assert config["algo"] in ("td3", "td3bc") and config["gamma"] == 0.98, config
    assert json.loads(meta["train"])["seed"] == 4
    assert any("actor" in k for k in t) and any("critic" in k for k in t)
    assert t["actor.0.weight"].shape == (config["hidden"], task["obs_dim"] + task["goal_dim"])

    n = probe["n"]
    obs = np.array(probe["obs"], np.float32).reshape(n, task["obs_dim"])
    goal = np.array(probe["goal"], np.float32).reshape(n, task["goal_dim"])
    action = np.array(probe["action"], np.float32).reshape(n, task["act_dim"])
    clip = float(meta["normalizer_clip"])
    norm = lambda x, w: np.clip((x - t[f"normalizer.{w}_mean"]) / t[f"normalizer.{w}_std"], -clip, clip)
    sg = np.concatenate([norm(obs, "obs"), norm(goal, "goal")], axis=1)
    pi = np.tanh(mlp(t, "actor", sg))
    sga = np.concatenate([sg, action], axis=1)
    q = np.minimum(mlp(t, "critic1", sga), mlp(t, "critic2", sga))[:, 0]
    np.testing.assert_allclose(pi.ravel(), probe["act"], rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(q, probe["q"], rtol=1e-4, atol=1e-4)
    print("ok", n, "rows")


if __name__ == "__main__":
    main()
