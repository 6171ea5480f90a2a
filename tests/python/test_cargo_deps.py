"""A clone where `make deps` has not run: `cargo build` must stop with one line that says what to
run, not deep inside CMake. Two things say it, as cargo runs pgser's build script and
hdf5-metno-src's (which runs CMake) side by side and either may fail first: build.rs, and
scripts/cmake, where .cargo/config.toml points CMAKE. Both are run here directly, against a copy of
the clone's layout without .deps (a real build from a fresh clone takes most of an hour)."""

import re
import shutil
import subprocess
import tomllib

from conftest import REPO


def test_cargo_takes_cmake_through_the_wrapper():
    env = tomllib.loads((REPO / ".cargo" / "config.toml").read_text())["env"]
    assert env["CMAKE"] == {"value": "scripts/cmake", "relative": True}
    assert (REPO / "scripts" / "cmake").stat().st_mode & 0o111, "scripts/cmake must be executable"


def wrapper_in(root):
    (root / "scripts").mkdir()
    shutil.copy2(REPO / "scripts" / "cmake", root / "scripts" / "cmake")
    return root / "scripts" / "cmake"


def test_without_make_deps_the_wrapper_says_what_to_run(tmp_path):
    r = subprocess.run([wrapper_in(tmp_path), "-S", "src", "-B", "build"], capture_output=True, text=True)
    assert r.returncode == 1 and r.stdout == "", r
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    assert lines[0].startswith(f"pgser: {tmp_path}/.deps/cmake/bin/cmake is missing: run `make deps` in {tmp_path}")
    assert "CMAKE" in lines[0] and "MUJOCO_DYNAMIC_LINK_DIR" in lines[0]


def test_with_make_deps_the_wrapper_is_that_cmake(tmp_path):
    wrapper = wrapper_in(tmp_path)
    fake = tmp_path / ".deps" / "cmake" / "bin" / "cmake"
    fake.parent.mkdir(parents=True)
    fake.write_text('#!/bin/sh\nprintf "%s|" "$@"; exit 3\n')
    fake.chmod(0o755)
    r = subprocess.run([wrapper, "-S", "a b", "--build", ""], capture_output=True, text=True)
    assert (r.returncode, r.stdout, r.stderr) == (3, "-S|a b|--build||", "")
    # The clone's own: the CMake `make deps` fetched.
    r = subprocess.run([REPO / "scripts" / "cmake", "--version"], capture_output=True, text=True)
    assert r.returncode == 0 and r.stdout.startswith("cmake version 4.4.5"), r


def build_script():
    """pgser's compiled build script (target/release/build/pgser-HASH/build-script-build), the
    newest when there are several."""
    found = [d / "build-script-build" for d in (REPO / "target" / "release" / "build").glob("pgser-*")
             if re.fullmatch(r"pgser-[0-9a-f]{16}", d.name) and (d / "build-script-build").exists()]
    assert found, "no build script of pgser in target/release/build: run `cargo build --release` first"
    return max(found, key=lambda p: p.stat().st_mtime)


def test_without_make_deps_build_rs_says_what_to_run_and_builds_nothing(tmp_path):
    env = {"PATH": "/usr/bin:/bin", "CARGO_MANIFEST_DIR": str(tmp_path), "CARGO_FEATURE_HDF5": "1",
           "MUJOCO_DYNAMIC_LINK_DIR": f"{tmp_path}/.deps/mujoco", "CMAKE": f"{tmp_path}/scripts/cmake"}
    r = subprocess.run([build_script()], capture_output=True, text=True, env=env)
    errors = [line for line in r.stdout.splitlines() if line.startswith("cargo::error=")]
    assert errors == [
        f"cargo::error=MuJoCo 3.17.0 ({tmp_path}/.deps/mujoco/libmujoco.so) and CMake "
        f"({tmp_path}/.deps/cmake/bin/cmake) missing: run `make deps` in {tmp_path} (or set "
        "MUJOCO_DYNAMIC_LINK_DIR and CMAKE to your own)"
    ], r.stdout
    assert "rustc-link-arg" not in r.stdout, "nothing after the error"
    # A CMake of the user's own is not second-guessed; MuJoCo alone is then missing.
    r = subprocess.run([build_script()], capture_output=True, text=True,
                       env={**env, "CMAKE": "/opt/cmake/bin/cmake"})
    assert "cargo::error=MuJoCo 3.17.0" in r.stdout and "CMake (" not in r.stdout, r.stdout
