"""The Makefile's set-up, dry-run against an empty dependency folder: on a fresh clone `make deps`
must fetch everything the build needs. A prerequisite variable defined below the rule that names it
expands to nothing (make reads prerequisites when it reads the rule), which a checkout with a
populated .deps/ hides and only a clean clone shows: CMake went missing that way once."""

import subprocess

from conftest import REPO


def dry_run(tmp_path, target):
    r = subprocess.run(["make", "-n", "-C", str(REPO), target, f"DEPS={tmp_path}/deps"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_deps_on_a_fresh_clone_fetches_every_dependency(tmp_path):
    out = dry_run(tmp_path, "deps")
    for wanted in ["mujoco==3.17.0", "gymnasium-robotics==1.4.2", "numpy==", "cmake==4.4.5"]:
        assert wanted in out, f"`make deps` on an empty {tmp_path}/deps does not fetch {wanted}:\n{out}"
    # The CMake check must fail the rule when the binary cannot run (no pipe hides its status).
    assert f"{tmp_path}/deps/cmake/bin/cmake --version >/dev/null" in out
