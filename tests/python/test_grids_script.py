"""scripts/grids.sh, the background runner of the Table 2 grids: `times` sums each grid's wall
time over the runs its log records (the figure issue notes report), and leaves out a run the
machine stopped under (no end line) rather than guessing its length; `stop` with nothing
running says so and succeeds. Run on a log written here, in a GRID_ROOT of its own."""

import os
import subprocess

from conftest import REPO

SCRIPT = REPO / "scripts" / "grids.sh"

LOG = """\
== 2026-01-01T00:00:00Z pipelines/a.toml
pipeline a: [6/37] agent td3_baseline_s0: running with 14 more in one stack
pgser-etl: error: pipeline a: stopped by SIGTERM at update 100 of 300
== 2026-01-01T01:30:00Z pipelines/a.toml: ended, rc 1
== 2026-01-01T02:00:00Z pipelines/a.toml
== 2026-01-01T02:10:30Z pipelines/a.toml: ended, rc 0
== 2026-01-01T03:00:00Z pipelines/b.toml
== 2026-01-02T04:00:00Z pipelines/b.toml
== 2026-01-02T04:05:59Z pipelines/b.toml: ended, rc 0
== 2026-01-02T04:06:00Z all grids up to date
"""


def grids(root, *args):
    env = dict(os.environ, GRID_ROOT=str(root))
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, env=env)


def test_times_sums_each_grids_runs_and_skips_those_without_an_end(tmp_path):
    (tmp_path / "grids.log").write_text(LOG)
    p = grids(tmp_path, "times")
    assert p.returncode == 0, p.stderr
    assert p.stdout.splitlines() == [
        # 1 h 30 min + 10 min 30 s
        "pipelines/a.toml: 1 h 40 min over 2 run(s)",
        # the first run has no end line (the next start came first): not counted
        "pipelines/b.toml: 0 h 05 min over 2 run(s); 1 run(s) without an end line, not counted",
    ]


def test_times_without_a_log_is_an_error(tmp_path):
    p = grids(tmp_path, "times")
    assert p.returncode == 1
    assert f"no log at {tmp_path}/grids.log" in p.stderr


def test_stop_with_nothing_running(tmp_path):
    p = grids(tmp_path, "stop")
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "(no grid running)"
