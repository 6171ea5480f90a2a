"""OGBench from Python: `pgser.Policy(checkpoint).act` on batches, and examples/ogbench_eval.py end
to end (a PointMaze dataset made by `pgser-etl collect --policy oracle`, trained on a tiny budget,
evaluated with OGBench's protocol in ogbench's own environment)."""

import json
import subprocess
import sys

import numpy as np
import pytest

import pgser
from conftest import BIN, REPO, run

ogbench = pytest.importorskip("ogbench", reason="ogbench is not installed in this venv")


@pytest.fixture(scope="module")
def stitch(tmp_path_factory):
    d = tmp_path_factory.mktemp("ogbench")
    data = d / "pointmaze-medium-stitch-v0.npz"
    run(BIN / "pgser-etl", "collect", "--task", "pointmaze-medium-stitch-v0", "--policy", "oracle",
        "--episodes", "300", "-o", data)
    return data


def test_policy_acts_on_batches(stitch, tmp_path):
    table, ckpt = tmp_path / "t.parquet", tmp_path / "a.ckpt"
    run(BIN / "pgser-etl", "convert", stitch, "-o", table)
    run(BIN / "pgser-train", "--data", table, "-o", ckpt, "--updates", "50", "--batch-size", "32",
        "--eval-episodes", "0")
    p = pgser.Policy(str(ckpt))
    assert p.task == ("pointmaze-medium-v0", 2, 2, 2)
    rng = np.random.default_rng(0)
    obs, goals = rng.uniform(-4, 24, (7, 2)), rng.uniform(-4, 24, (7, 2))
    a = p.act(obs, goals)
    assert a.shape == (7, 2) and a.dtype == np.float32 and np.all(np.abs(a) < 1)
    # Row by row, in float32 input, as one row: the same actions (float32 rounding of the input aside).
    assert np.array_equal(np.vstack([p.act(o, g) for o, g in zip(obs, goals)]), a)
    np.testing.assert_allclose(p.act(obs.astype(np.float32), goals.astype(np.float32)), a, atol=1e-5)
    with pytest.raises(ValueError, match=r"observations must be \(n, 2\)"):
        p.act(np.zeros((3, 3)), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="3 observations but 2 goals"):
        p.act(np.zeros((3, 2)), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="checkpoint's actor on batches"):
        pgser.Policy("FetchReach", "expert").act(np.zeros(10), np.zeros(3))
    with pytest.raises(ValueError, match="unknown task"):
        pgser.Policy(str(tmp_path / "missing.ckpt"))


def test_example_evaluates_in_ogbenchs_environment(stitch, tmp_path):
    p = subprocess.run(
        [sys.executable, REPO / "examples/ogbench_eval.py", stitch, "--out", tmp_path, "--updates", "300",
         "--batch-size", "64", "--episodes", "2", "--pgser-etl", BIN / "pgser-etl", "--pgser-train",
         BIN / "pgser-train"],
        capture_output=True, text=True, timeout=600,
    )
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout.strip().splitlines()[-1])
    assert r["dataset"] == "pointmaze-medium-stitch-v0" and len(r["task_success"]) == 5, r
    assert all(s in (0.0, 0.5, 1.0) for s in r["task_success"]), r
    assert r["success"] == pytest.approx(np.mean(r["task_success"]))
    assert "task1" in p.stderr and "success" in p.stderr, p.stderr


def test_ogbench_goal_is_the_goal_map_of_the_tables():
    cube = np.load(REPO / "tests/fixtures/ogbench/cube/cube-double-play-v0.npz")
    np.testing.assert_array_equal(pgser.ogbench_goal("cube-double-v0", cube["observations"]), cube["oracle_reps"])
    assert pgser.ogbench_goal("cube-double-v0", cube["observations"][0]).shape == (6,)
    scene = np.load(REPO / "tests/fixtures/ogbench/scene/scene-play-v0.npz")
    np.testing.assert_array_equal(pgser.ogbench_goal("scene-v0", scene["observations"]), scene["oracle_reps"])
    np.testing.assert_array_equal(pgser.ogbench_goal("antmaze-large-v0", np.arange(29.0)), [0.0, 1.0])
    # A puzzle's goal is its button states, not observation values: no map from observations.
    with pytest.raises(ValueError, match="its button states"):
        pgser.ogbench_goal("puzzle-3x3-v0", np.zeros(10))


@pytest.mark.parametrize("dataset,extra", [("antmaze/antmaze-medium-navigate-v0.npz", []),
                                           ("antmaze/antmaze-medium-navigate-v0.npz", ["--full-goal", "0.5"]),
                                           ("cube/cube-single-play-v0.npz", []),
                                           ("scene/scene-play-v0.npz", [])])
def test_example_evaluates_where_pgser_does_not_simulate(dataset, extra, tmp_path):
    """The example on environments only OGBench simulates: an ant in its maze and the cube arm
    (tiny random-action datasets from ogbench's own environments), its goal map applied to
    OGBench's full goal observations."""
    p = subprocess.run(
        [sys.executable, REPO / "examples/ogbench_eval.py", REPO / "tests/fixtures/ogbench" / dataset, "--out",
         tmp_path, "--updates", "20", "--batch-size", "16", "--episodes", "1", "--pgser-etl", BIN / "pgser-etl",
         "--pgser-train", BIN / "pgser-train", *extra],
        capture_output=True, text=True, timeout=600,
    )
    assert p.returncode == 0, p.stderr
    r = json.loads(p.stdout.strip().splitlines()[-1])
    assert len(r["task_success"]) == 5 and 0.0 <= r["success"] <= 1.0, r
    goal_dim = pgser.read_footer(tmp_path / "traj.parquet")["goal_dim"]
    assert goal_dim == (29 if extra else {"antmaze": 2, "cube": 3, "scene": 7}[dataset.split("/")[0]])
