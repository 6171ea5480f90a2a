"""The GPU bundle's shell helpers (scripts/gpu_env.sh, the bundle's env.sh), run here with stand-ins
for the GPU's programs: a failed engine check is repeated with synchronous launches and no CUDA
graphs, then under compute-sanitizer where the machine has one, so that the launch at fault is
named; and `compare_ok` says 1 only when every figure of a comparison is within its tolerance."""

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import REPO

ENV_SH = REPO / "scripts" / "gpu_env.sh"


def helpers() -> str:
    """The helper functions of env.sh, without its unpacking (which needs a built bundle)."""
    text = ENV_SH.read_text()
    start = text.index("# Whether every figure of a bench/gpu_compare.py JSON")
    return text[start:]


# Where cuda_diagnose looks for compute-sanitizer besides the PATH: CUDA's installs.
CUDA_INSTALLS = "/usr/local/cuda*/"


def bash(tmp_path, script: str, path_dirs=(), system_path=True, cuda_installs=None):
    """`script` after env.sh's helpers, with `path_dirs` first on the PATH, then (with
    `system_path`) this Python's and the system's folders; `cuda_installs`, a glob standing in for
    CUDA's install folders where the helpers look for compute-sanitizer."""
    system = [str(Path(sys.executable).parent), "/usr/bin", "/bin"] if system_path else []
    env = dict(os.environ, PATH=":".join([*map(str, path_dirs), *system]))
    text = helpers()
    if cuda_installs is not None:
        assert CUDA_INSTALLS in text, f"{ENV_SH} no longer looks in {CUDA_INSTALLS}: update this test"
        text = text.replace(CUDA_INSTALLS, cuda_installs)
    (tmp_path / "helpers.sh").write_text(text)
    prelude = f"""
        set -uo pipefail
        here={REPO}/; work={tmp_path}/work; logs={tmp_path}/work/logs; out={tmp_path}/out
        mkdir -p "$logs" "$out"
        say() {{ echo "say: $*" >>"$out/said.log"; }}
        . {tmp_path}/helpers.sh
    """
    return subprocess.run([shutil.which("bash"), "-c", textwrap.dedent(prelude) + script], capture_output=True,
                          text=True, env=env)


def fake(path, body):
    path.write_text("#!/bin/bash\n" + body)
    path.chmod(0o755)


def test_compare_ok_wants_every_figure_within(tmp_path):
    good = {"cuda": {"weights": {"ok": True, "worst": 1e-7}, "metrics": {"ok": True}}}
    bad = {"cuda": {"weights": {"ok": True}, "metrics": {"ok": False, "why": "no logged values"}}}
    (tmp_path / "good.json").write_text(json.dumps(good))
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    (tmp_path / "empty.json").write_text("{}")
    r = bash(tmp_path, f"""
        for f in good bad empty missing; do echo "$f $(compare_ok {tmp_path}/$f.json)"; done
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split("\n")[:4] == ["good 1", "bad 0", "empty 0", "missing 0"], r.stdout


def test_a_failed_check_is_repeated_synchronously_then_under_the_sanitizer(tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    calls = tmp_path / "calls.log"
    # The trainer notes how it was called; under the sanitizer it reports an invalid read.
    fake(bin_dir / "pgser-train", f"""
echo "train graphs=${{PGSER_CUDA_GRAPHS:-}} blocking=${{CUDA_LAUNCH_BLOCKING:-}} $*" >>{calls}
echo "launching pgser_gather: an illegal memory access" >&2
exit 1
""")
    fake(bin_dir / "compute-sanitizer", f"""
echo "sanitizer $1 $2" >>{calls}
shift 4
"$@"
echo "========= Invalid __global__ read of size 4 bytes"
echo "========= ERROR SUMMARY: 1 error"
""")
    r = bash(tmp_path, f"""
        train={bin_dir}/pgser-train
        cuda_diagnose train-cuda $work/train-cpu --data scored.parquet --seeds 0,1,2 --device cuda
    """, path_dirs=[bin_dir])
    assert r.returncode == 0, r.stderr
    lines = calls.read_text().splitlines()
    assert lines[0].startswith("train graphs=0 blocking=1 --data scored.parquet --seeds 0,1,2 --device cuda --updates 50"), lines
    assert lines[1] == "sanitizer --tool memcheck", lines
    assert lines[2].startswith("train graphs=0 blocking= ") and "--updates 3" in lines[2], lines
    said = (tmp_path / "out" / "said.log").read_text()
    assert "launching pgser_gather: an illegal memory access" in said, said
    assert "Invalid __global__ read" in said and "ERROR SUMMARY: 1 error" in said, said


def test_without_a_sanitizer_the_run_says_so(tmp_path):
    """On every machine, one with CUDA's compute-sanitizer included: the PATH holds only the tools
    the helper calls (each a link to this machine's), and CUDA's install folders are looked for
    in an empty folder."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    fake(bin_dir / "pgser-train", "exit 0\n")
    for tool in ["timeout", "tail", "ls", "head", "grep", "tr", "mkdir", "cat"]:
        (bin_dir / tool).symlink_to(shutil.which(tool))
    # This Python (its venv's packages) as python3, for bench/gpu_compare.py.
    fake(bin_dir / "python3", f'exec {sys.executable} "$@"\n')
    r = bash(tmp_path, f"""
        train={bin_dir}/pgser-train
        cuda_diagnose check-cuda $work/check-cpu --device cuda
    """, path_dirs=[bin_dir], system_path=False, cuda_installs=f"{tmp_path}/no-cuda*/")
    assert r.returncode == 0, r.stderr
    said = (tmp_path / "out" / "said.log").read_text()
    assert "no compute-sanitizer on this machine" in said, said
    assert "compute-sanitizer memcheck" not in said, said
    # The repeated run trained and was compared with the CPU's (here: a CPU run that is missing).
    assert "cuda-blocking" in said, said


def test_the_bundle_refuses_a_binary_a_bare_gpu_machine_cannot_load(tmp_path):
    """gpu_bundle.sh's `runs_bare`: a binary that needs a library beyond glibc's, libgcc_s,
    libstdc++ and the bundled MuJoCo (as pgser needed Debian's libhdf5 before 0.3.0) stops the
    bundle, naming the library; one that needs only those passes."""
    text = (REPO / "scripts" / "gpu_bundle.sh").read_text()
    start = text.index("runs_bare() {")
    func = text[start : text.index("\n}\n", start) + 3]
    src = tmp_path / "main.c"
    src.write_text("int main(void) { return 0; }\n")
    good, bad = tmp_path / "good", tmp_path / "bad"
    subprocess.run(["gcc", src, "-o", good, "-lm"], check=True)
    extra = next(p for p in ["/lib/x86_64-linux-gnu/libz.so.1", "/usr/lib/x86_64-linux-gnu/libz.so.1"] if Path(p).exists())
    subprocess.run(["gcc", src, "-o", bad, "-Wl,--no-as-needed", extra], check=True)
    run = lambda exe: subprocess.run(["bash", "-c", func + f"runs_bare {exe}"], capture_output=True, text=True)
    ok = run(good)
    assert ok.returncode == 0, ok.stderr
    refused = run(bad)
    assert refused.returncode == 1
    assert "needs libz.so.1 beyond glibc" in refused.stderr and str(bad) in refused.stderr, refused.stderr
