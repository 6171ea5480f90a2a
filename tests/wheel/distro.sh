#!/usr/bin/env bash
# The wheel on a second Linux and a second Python, as a user there would install it (make
# test-wheel-distro): a Debian 13 (trixie) root file system, built with debootstrap from Debian's
# package registry (Python 3.13, glibc 2.41, none of this machine's libraries), where a fresh venv
# installs the wheel from its file and its dependencies from PyPI and runs tests/wheel/check.sh
# with the demo. Then the same checks with this machine's Python. The Debian half needs root
# (debootstrap, chroot, a private mount namespace for /proc and /dev, gone when the check ends):
# without it, it says so and only this machine's half runs.
#
#   tests/wheel/distro.sh target/wheels/pgser-VERSION-cp310-abi3-manylinux_2_28_x86_64.whl
#
# The root is built once into $PGSER_DISTRO_ROOT (default .deps/debian13, about 1 minute and
# 290 MB) and reused; delete it to build it anew. Its mirror is the one this machine's apt
# sources name. pip inside it reaches PyPI with this machine's CA bundle copied over the root's.
set -euo pipefail
REPO=$(cd "$(dirname "$0")/../.." && pwd)
[ $# -eq 1 ] && [ -f "$1" ] || { echo "usage: tests/wheel/distro.sh WHEEL (make wheel builds it)" >&2; exit 2; }
WHEEL=$(realpath "$1")
ROOT=${PGSER_DISTRO_ROOT:-$REPO/.deps/debian13}
SUITE=trixie
if [ "$(id -u)" != 0 ] || ! unshare --mount true 2>/dev/null; then
  echo "distro.sh: the Debian 13 half NOT run: it needs root and a mount namespace (debootstrap, chroot, unshare)"
  echo "distro.sh: this machine: $(python3 --version)"
  exec "$REPO/tests/wheel/check.sh" --demo "$WHEEL"
fi

if [ ! -x "$ROOT/usr/bin/python3" ]; then
  command -v debootstrap >/dev/null 2>&1 || [ -x /usr/sbin/debootstrap ] || {
    DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends debootstrap >/dev/null ||
      { apt-get update >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends debootstrap >/dev/null; }
  }
  mirror=$(sed -n 's/^URIs: *\(http[^ ]*\/debian\)$/\1/p' /etc/apt/sources.list.d/*.sources 2>/dev/null | head -1)
  [ -n "$mirror" ] || mirror=$(sed -n 's/^deb \(http[^ ]*\/debian\) .*/\1/p' /etc/apt/sources.list 2>/dev/null | head -1)
  mirror=${mirror:-http://deb.debian.org/debian}
  echo "distro.sh: building a Debian $SUITE root in $ROOT from $mirror"
  rm -rf "$ROOT.part"
  PATH=/usr/sbin:/sbin:$PATH debootstrap --variant=minbase \
    --include=python3,python3-venv,python3-pip,ca-certificates,strace "$SUITE" "$ROOT.part" "$mirror" >"$ROOT.log" 2>&1 ||
    { tail -20 "$ROOT.log" >&2; echo "distro.sh: debootstrap failed (log: $ROOT.log)" >&2; exit 1; }
  mv "$ROOT.part" "$ROOT"
fi

# What check.sh reads from the clone, at the same paths under /pgser-check in the root.
CHECK=$ROOT/pgser-check
rm -rf "$CHECK"
mkdir -p "$CHECK/data" "$CHECK/tests/wheel" "$CHECK/tests/python" "$CHECK/tests/fixtures"
cp "$REPO"/data/*.pkl "$CHECK/data/"
cp -r "$REPO/tests/fixtures/passthrough" "$CHECK/tests/fixtures/"
mkdir -p "$CHECK/tests/fixtures/minari"
cp -r "$REPO/tests/fixtures/minari/fetchreach-hdf5-v0" "$CHECK/tests/fixtures/minari/"
cp "$REPO/tests/wheel/check.sh" "$CHECK/tests/wheel/"
cp "$REPO"/tests/python/*.py "$CHECK/tests/python/"
cp "$WHEEL" "$CHECK/"
cp /etc/ssl/certs/ca-certificates.crt "$ROOT/etc/ssl/certs/ca-certificates.crt"

t0=$(date +%s)
echo "distro.sh: Debian $SUITE: $(chroot "$ROOT" python3 --version), $(chroot "$ROOT" ldd --version | head -1)"
unshare --mount --fork sh -c '
  mount -t proc proc "$1/proc" && mount --rbind /dev "$1/dev" &&
  exec chroot "$1" /usr/bin/env -i PATH=/usr/local/bin:/usr/bin:/bin HOME=/root LANG=C.UTF-8 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 bash /pgser-check/tests/wheel/check.sh --demo "/pgser-check/$2"
' sh "$ROOT" "$(basename "$WHEEL")"
t1=$(date +%s)
echo "distro.sh: this machine: $(python3 --version)"
"$REPO/tests/wheel/check.sh" --demo "$WHEEL"
t2=$(date +%s)
rm -rf "$CHECK"
echo "distro.sh: ok: Debian $SUITE $((t1 - t0)) s, this machine $((t2 - t1)) s"
