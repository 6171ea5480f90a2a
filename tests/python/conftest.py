"""Shared fixtures of the Python module's tests: real tables made from the committed FetchReach
sample by pgser itself (the module's convert and score, the CLI's pgser-train), once per session."""

import json
import os
import subprocess
import types
from pathlib import Path

import mujoco
import pytest
from gymnasium_robotics.utils import mujoco_utils

# The workaround of tests/py/env_parity.py, no numbers change: with mujoco 3.17 the enum
# `mjtJoint` no longer compares equal to the np.int32 in `model.jnt_type`, so gymnasium-robotics'
# joint-type asserts fail. Its helpers get a view of the mujoco module whose mjtJoint members are
# plain ints (the same values); everything else is the real module.
_mj = types.ModuleType("mujoco")
_mj.__dict__.update(mujoco.__dict__)
_mj.mjtJoint = types.SimpleNamespace(**{k: int(v) for k, v in mujoco.mjtJoint.__members__.items()})
mujoco_utils.mujoco = _mj

REPO = Path(__file__).resolve().parents[2]
# The pgser-etl / pgser-train these tests run: the clone's release build, or, where
# tests/wheel/check.sh runs them against an installed wheel, the wheel's own commands.
BIN = Path(os.environ["PGSER_BIN"]) if os.environ.get("PGSER_BIN") else REPO / "target" / "release"


def bench_module(name):
    """A script of bench/ as a module (the peers the samplers are tested against)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, REPO / "bench" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def ogbench_folder(tmp_path_factory):
    """(table folder, shard folder, the fixture's arrays): the committed PointMaze file OGBench's
    generator wrote, 4 episodes of T = 101, cut into one shard per episode and converted."""
    import sys

    import numpy as np

    fixture = REPO / "tests/fixtures/ogbench/pointmaze-medium-navigate-v0.npz"
    d = tmp_path_factory.mktemp("ogbench_folder")
    src, table = d / "src", d / "table"
    run(sys.executable, REPO / "tests/py/make_ogbench_shards.py", fixture, src, 1)
    run(BIN / "pgser-etl", "convert", src, "-o", table)
    with np.load(fixture) as f:
        arrays = {k: f[k] for k in f.files}
    return table, src, arrays


def run(*args):
    """Run a pgser binary; fail the test with its stderr when it fails."""
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    assert p.returncode == 0, f"{args[0]} failed: {p.stderr}"
    return p


@pytest.fixture(scope="session")
def tables(tmp_path_factory):
    """(trajectory table, critic checkpoint, scored table) of the FetchReach sample."""
    import pgser

    d = tmp_path_factory.mktemp("tables")
    traj = d / "reach.parquet"
    data = REPO / "data"
    pgser.convert([data / "fetch_reach_expert_50.pkl", data / "fetch_reach_random_200.pkl"], traj)
    ckpt = d / "q.ckpt"
    run(BIN / "pgser-train", "--data", traj, "-o", ckpt, "--updates", "10", "--hidden", "32",
        "--batch-size", "64", "--eval-episodes", "0")
    scored = d / "scored.parquet"
    pgser.score(ckpt, traj, scored, swaps=2, include_original=True)
    return traj, ckpt, scored


def footer(path):
    import pyarrow.parquet as pq

    return json.loads(pq.read_metadata(path).metadata[b"pgser"])
