"""examples/gciql_jax.py end to end: OGBench's GCIQL in plain JAX, trained for 300 updates on
pgser's OGBench batches from a table folder (the committed PointMaze file OGBench's generator
wrote, one shard per episode, converted by `pgser-etl convert DIR`). Training must do what GCIQL's
losses ask: the critics' loss falls, and the critics tell a reached goal (reward 0, nothing to
come) from another row's state (-1 a step) by a margin they did not have at initialisation.
The same `train()` takes OGBench's own batches (bench/ogbench_peer.py's GoalSampler): the agent
switches between them by the one dataset object it is given."""

import argparse
import importlib.util
import json
import subprocess
import sys

import numpy as np
import pytest

from conftest import BIN, REPO, run

NAME = "pointmaze-medium-navigate-v0"
pytestmark = pytest.mark.skipif(importlib.util.find_spec("jax") is None,
                                reason="jax is not installed in this venv (tests/requirements.txt installs it)")


def load(name, path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    d = tmp_path_factory.mktemp("gciql")
    src, table = d / "src", d / "table"
    run(sys.executable, REPO / "tests/py/make_ogbench_shards.py", REPO / "tests/fixtures/ogbench" / f"{NAME}.npz", src, 1)
    run(BIN / "pgser-etl", "convert", src, "-o", table)
    return table, src


def test_gciql_learns_from_a_sharded_table(folder):
    table, _ = folder
    p = subprocess.run([sys.executable, REPO / "examples/gciql_jax.py", table, "--steps", "300", "--seed", "0"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    lines = p.stdout.strip().splitlines()
    # A line of losses every 50 steps, then the summary.
    assert sum(line.startswith("step ") for line in lines) == 7, p.stdout
    s = json.loads(lines[-1])
    assert s["task"] == "pointmaze-medium-v0" and s["steps"] == 300
    assert s["critic_loss_last"] < 0.6 * s["critic_loss_first"], s
    before = s["before"]["q_reached"] - s["before"]["q_random"]
    after = s["after"]["q_reached"] - s["after"]["q_random"]
    assert after > 0.4 and after > before + 0.3, s
    assert s["after"]["v_reached"] > s["after"]["v_random"], s


def test_train_takes_ogbenchs_own_batches_unchanged(folder):
    _, src = folder
    example = load("gciql_jax", REPO / "examples/gciql_jax.py")
    peer = load("ogbench_peer", REPO / "bench/ogbench_peer.py")
    parts = [peer.load_regular(str(f)) for f in peer.shards(str(src))]
    data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    cfg = dict(example.CONFIG, batch_size=64, value_hidden_dims=(32, 32), actor_hidden_dims=(32, 32))
    ns = argparse.Namespace(**{k: cfg[k] for k in ("discount", "value_p_curgoal", "value_p_trajgoal",
                                                     "actor_p_curgoal", "actor_p_trajgoal")})
    dataset = peer.GoalSampler(data, ns, np.random.default_rng(0))
    _, history = example.train(dataset, cfg, steps=40, log=None)
    assert len(history) == 40 and all(np.isfinite(h["critic_loss"]) for h in history)
    assert np.mean([h["critic_loss"] for h in history[-10:]]) < np.mean([h["critic_loss"] for h in history[:10]])
