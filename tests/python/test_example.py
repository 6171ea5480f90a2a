"""examples/td3bc_torch.py end to end: PGSER with a PyTorch TD3+BC reaches FetchReach success
>= 0.9 on the sample data within a short budget. Needs PyTorch, which the test venv leaves out
(a multi-GB download): without it the test is skipped and says so; `make bench-venv` makes a
venv with it (run `pytest tests/python/test_example.py` with that venv's python after
installing the wheel there)."""

import importlib.util
import json
import subprocess
import sys

import pytest

from conftest import BIN, REPO


@pytest.mark.skipif(importlib.util.find_spec("torch") is None, reason="PyTorch is not installed in this venv")
def test_example_reaches_fetch_reach(tmp_path):
    p = subprocess.run(
        [sys.executable, REPO / "examples/td3bc_torch.py", "--out", tmp_path, "--pretrain-updates", "500",
         "--updates", "2000", "--eval-episodes", "50", "--pgser-train", BIN / "pgser-train"],
        capture_output=True, text=True, timeout=900,
    )
    assert p.returncode == 0, p.stderr
    summary = json.loads(p.stdout.strip().splitlines()[-1])
    assert summary["success"] >= 0.9, summary
