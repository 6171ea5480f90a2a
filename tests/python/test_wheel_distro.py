"""tests/wheel/distro.sh (make test-wheel-distro) run against stand-ins for what it runs as root
(id, unshare, mount, debootstrap, chroot) and for check.sh, in a copy of the clone's layout: no
Debian root is built and nothing is downloaded. The stand-in chroot records the command the root
is entered with, so the tests see what pip in there is given: this machine's pip settings (its
PIP_* and proxy variables, its pip.conf files and the certificates they name), without which a
machine behind a mirror or a proxy cannot install there. And an unfinished root is built anew,
not inside the old folder; a folder that is no root of the script's is left alone."""

import os
import shutil
import subprocess
from pathlib import Path

from conftest import REPO

FAKES = {
    "id": 'echo 0\n',
    "mount": 'exit 0\n',
    # `unshare --mount true` (the check that it may) succeeds; else drop the options and run.
    "unshare": 'if [ "$1 $2" = "--mount true" ]; then exit 0; fi\nshift 2\nexec "$@"\n',
    # A root of one file, as the last argument but one names it.
    "debootstrap": 'echo "$*" >> "$FAKE_LOG/debootstrap"\nt=${@: -2:1}\n'
                   'mkdir -p "$t/usr/bin" "$t/etc/ssl/certs" "$t/root" "$t/proc" "$t/dev"\n'
                   'printf "#!/bin/sh\\n" > "$t/usr/bin/python3"\nchmod +x "$t/usr/bin/python3"\n',
    "chroot": 'shift\ncase "$1" in\n  python3) echo "Python 3.13.5" ;;\n  ldd) echo "ldd (Debian GLIBC 2.41-12) 2.41" ;;\n'
              '  *) printf "%s\\n" "$@" > "$FAKE_LOG/chroot" ;;\nesac\n',
}


def layout(tmp_path):
    """A clone with the files distro.sh copies into the root, the script itself, a stand-in
    check.sh; the stand-ins on a PATH of their own; a wheel file; a HOME."""
    repo = tmp_path / "repo"
    for d in ["data", "tests/wheel", "tests/python", "tests/fixtures/passthrough",
              "tests/fixtures/minari/fetchreach-hdf5-v0"]:
        (repo / d).mkdir(parents=True)
    (repo / "data" / "a.pkl").write_text("pkl")
    (repo / "tests" / "python" / "test_a.py").write_text("")
    shutil.copy2(REPO / "tests" / "wheel" / "distro.sh", repo / "tests" / "wheel" / "distro.sh")
    check = repo / "tests" / "wheel" / "check.sh"
    check.write_text('#!/bin/bash\necho "check.sh $*" >> "$FAKE_LOG/host"\n')
    check.chmod(0o755)
    fakes, log, home = tmp_path / "fakes", tmp_path / "log", tmp_path / "home"
    for d in (fakes, log, home):
        d.mkdir()
    for name, body in FAKES.items():
        (fakes / name).write_text("#!/bin/bash\n" + body)
        (fakes / name).chmod(0o755)
    wheel = tmp_path / "pgser-0.4.0-cp310-abi3-manylinux_2_28_x86_64.whl"
    wheel.write_text("wheel")
    # Only what the test sets: none of this machine's pip or proxy settings.
    env = {"PATH": f"{fakes}:/usr/bin:/bin", "HOME": str(home), "LANG": "C.UTF-8", "FAKE_LOG": str(log),
           "PGSER_DISTRO_ROOT": str(tmp_path / "root")}
    return repo, wheel, env, log


def distro(repo, wheel, env):
    return subprocess.run(["/bin/bash", str(repo / "tests" / "wheel" / "distro.sh"), str(wheel)],
                          capture_output=True, text=True, env=env)


def test_the_debian_root_gets_this_machines_pip_settings(tmp_path):
    repo, wheel, env, log = layout(tmp_path)
    home = Path(env["HOME"])
    (home / ".config" / "pip").mkdir(parents=True)
    ca = tmp_path / "ca" / "mirror.pem"
    ca.parent.mkdir()
    ca.write_text("a mirror's CA")
    (home / ".config" / "pip" / "pip.conf").write_text(f"[global]\nindex-url = https://mirror.example/simple\ncert = {ca}\n")
    extra = tmp_path / "extra.conf"
    extra.write_text("[install]\ntimeout = 60\n")
    settings = {
        "PIP_INDEX_URL": "https://mirror.example/simple",
        "PIP_EXTRA_INDEX_URL": "https://other.example/simple https://third.example/simple",
        "PIP_TRUSTED_HOST": "mirror.example",
        "PIP_CONFIG_FILE": str(extra),
        "https_proxy": "http://proxy.example:3128", "HTTPS_PROXY": "http://proxy.example:3128",
        "http_proxy": "http://proxy.example:3128", "no_proxy": "localhost,.example", "NO_PROXY": "localhost",
    }
    env.update(settings, UNRELATED="not passed")
    p = distro(repo, wheel, env)
    assert p.returncode == 0, p.stderr
    args = (log / "chroot").read_text().splitlines()
    # env -i, its own settings, then this machine's, then the check.
    assert args[:2] == ["/usr/bin/env", "-i"], args
    first_of_check = args.index("bash")
    assigned = args[2:first_of_check]
    for k, v in settings.items():
        assert f"{k}={v}" in assigned, (k, assigned)
    assert not any(a.startswith("UNRELATED=") for a in assigned), assigned
    assert args[first_of_check:] == ["bash", "/pgser-check/tests/wheel/check.sh", "--demo", f"/pgser-check/{wheel.name}"]
    root = Path(env["PGSER_DISTRO_ROOT"])
    # The user's pip.conf where pip in the root (HOME=/root) reads it, the certificate it names
    # and $PIP_CONFIG_FILE's file at their own paths; /etc/pip.conf as this machine has it, or not.
    assert (root / "root/.config/pip/pip.conf").read_text() == (home / ".config/pip/pip.conf").read_text()
    assert (root / str(ca).lstrip("/")).read_text() == "a mirror's CA"
    assert (root / str(extra).lstrip("/")).read_text() == extra.read_text()
    host_conf = Path("/etc/pip.conf")
    assert (root / "etc/pip.conf").exists() == host_conf.is_file()
    # Then the same check on this machine.
    assert (log / "host").read_text() == f"check.sh --demo {wheel}\n"

    # Settings dropped here since are dropped in the root too.
    (home / ".config" / "pip" / "pip.conf").unlink()
    for k in settings:
        del env[k]
    p = distro(repo, wheel, env)
    assert p.returncode == 0, p.stderr
    assert not (root / "root/.config/pip/pip.conf").exists()
    args = (log / "chroot").read_text().splitlines()
    assert not any(a.startswith(("PIP_INDEX_URL=", "https_proxy=")) for a in args), args


def test_an_unfinished_root_is_built_anew_in_its_place(tmp_path):
    """A root debootstrap did not finish (its debootstrap/ folder, no python3): removed, and the new
    root put where it was, not inside it."""
    repo, wheel, env, log = layout(tmp_path)
    root = Path(env["PGSER_DISTRO_ROOT"])
    (root / "debootstrap").mkdir(parents=True)
    (root / "etc").mkdir()
    p = distro(repo, wheel, env)
    assert p.returncode == 0, p.stderr
    assert (root / "usr/bin/python3").is_file(), sorted(x.name for x in root.iterdir())
    assert sorted(x.name for x in root.iterdir()) == [".pgser-distro-root", "dev", "etc", "proc", "root", "usr"]
    assert not (tmp_path / "root.part").exists()
    assert f"{root} has no usr/bin/python3 (an unfinished root): removing it" in p.stdout
    # Built once: the next run uses it as it is.
    p = distro(repo, wheel, env)
    assert p.returncode == 0, p.stderr
    assert len((log / "debootstrap").read_text().splitlines()) == 1


def test_a_folder_that_is_no_root_is_left_alone(tmp_path):
    repo, wheel, env, log = layout(tmp_path)
    root = Path(env["PGSER_DISTRO_ROOT"])
    root.mkdir()
    (root / "mine.txt").write_text("keep")
    p = distro(repo, wheel, env)
    assert p.returncode == 1
    assert p.stderr.strip().splitlines()[-1] == (
        f"distro.sh: {root} exists but is no Debian root of this script (no usr/bin/python3): move it aside, "
        "or set PGSER_DISTRO_ROOT to a new folder")
    assert (root / "mine.txt").read_text() == "keep"
    assert sorted(os.listdir(root)) == ["mine.txt"]
    assert not (log / "debootstrap").exists()
