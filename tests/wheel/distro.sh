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
# sources name. pip inside it reaches PyPI, or the index this machine's pip is set to, as pip here
# does: with this machine's CA bundle copied over the root's, its pip settings (every PIP_*
# variable, the proxy variables, and its pip.conf files copied in) and the files they name.
# tests/python/test_wheel_distro.py runs this script with stand-ins for debootstrap and chroot.
set -euo pipefail

# The variables pip and its HTTP client read: pip's own (index, extra index, trusted hosts, CA
# file, ...) and the proxies, in both cases. `env -i` enters the root with none of this machine's
# variables, so without these a machine behind a mirror or a proxy could not install there.
PASSED_VARS='^(PIP_[A-Z0-9_]+|(http|https|ftp|all|no)_proxy|(HTTP|HTTPS|FTP|ALL|NO)_PROXY|REQUESTS_CA_BUNDLE|SSL_CERT_FILE)$'

# PASSED: NAME=VALUE of each such variable set here, for the root's `env -i`.
chroot_env() {
  PASSED=()
  local name
  while read -r name; do
    [[ $name =~ $PASSED_VARS ]] && PASSED+=("$name=${!name}")
  done < <(compgen -e | sort)
  return 0
}

# Copies FILE to PATH inside ROOT, replacing what is there; never through a link of the root's
# that points out of it (an absolute link resolves on this machine).
put_in_root() {
  local root dest
  root=$(realpath "$1")
  dest=$(realpath -m "$root$3")
  case $dest in
    "$root"/*) mkdir -p "$(dirname "$dest")" && cp --remove-destination "$2" "$dest" ;;
    *) echo "distro.sh: $2 not copied into the root: $3 leads out of it through a link" >&2 ;;
  esac
}

# Copies into ROOT this machine's pip configuration at the paths pip reads there (HOME=/root): the
# global files, the user's (from $XDG_CONFIG_HOME or ~/.config, and the older ~/.pip), the file
# $PIP_CONFIG_FILE names, and the files a setting names (CA and client certificates), each at its
# own path. The pip.conf files an earlier run copied are removed first, so the root follows this
# machine.
copy_pip_config() {
  local root=$1 f c v i
  rm -f "$root/etc/pip.conf" "$root/etc/xdg/pip/pip.conf" "$root/root/.config/pip/pip.conf" "$root/root/.pip/pip.conf"
  # (this machine's file, its path in the root) pairs.
  local -a pairs=(/etc/pip.conf /etc/pip.conf /etc/xdg/pip/pip.conf /etc/xdg/pip/pip.conf
    "${XDG_CONFIG_HOME:-$HOME/.config}/pip/pip.conf" /root/.config/pip/pip.conf "$HOME/.pip/pip.conf" /root/.pip/pip.conf)
  case ${PIP_CONFIG_FILE:-} in /*) pairs+=("$PIP_CONFIG_FILE" "$PIP_CONFIG_FILE") ;; esac
  local -a named=()
  for v in PIP_CERT PIP_CLIENT_CERT REQUESTS_CA_BUNDLE SSL_CERT_FILE; do
    [ -z "${!v:-}" ] || named+=("${!v}")
  done
  for ((i = 0; i < ${#pairs[@]}; i += 2)); do
    f=${pairs[i]}
    [ -f "$f" ] || continue
    put_in_root "$root" "$f" "${pairs[i + 1]}"
    # cert = /path, client-cert = /path: read in the root at the same path.
    while read -r c; do named+=("$c"); done < <(sed -n 's/^[[:space:]]*\(client-\)\{0,1\}cert[[:space:]]*[=:][[:space:]]*\(\/[^[:space:]]*\)[[:space:]]*$/\2/p' "$f")
  done
  for f in ${named[@]+"${named[@]}"}; do
    case $f in /*) ;; *) continue ;; esac
    [ -f "$f" ] || continue
    put_in_root "$root" "$f" "$f"
  done
}

# An existing ROOT without python3: what debootstrap left when stopped (its debootstrap/ folder), a
# root this script built (its marker), or an empty folder is removed, to be built anew; anything
# else is not this script's to delete, and stops it. (Moving the new root onto an existing folder
# would put it inside that folder.)
clear_root() {
  local root=$1
  [ -e "$root" ] || [ -L "$root" ] || return 0
  if [ -d "$root" ] && [ ! -L "$root" ] &&
    { [ -d "$root/debootstrap" ] || [ -f "$root/.pgser-distro-root" ] || [ -z "$(ls -A "$root")" ]; }; then
    echo "distro.sh: $root has no usr/bin/python3 (an unfinished root): removing it"
    rm -rf --one-file-system "$root"
  else
    echo "distro.sh: $root exists but is no Debian root of this script (no usr/bin/python3): move it aside, or set PGSER_DISTRO_ROOT to a new folder" >&2
    return 1
  fi
}

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
  clear_root "$ROOT"
  command -v debootstrap >/dev/null 2>&1 || [ -x /usr/sbin/debootstrap ] || {
    DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends debootstrap >/dev/null ||
      { apt-get update >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends debootstrap >/dev/null; }
  }
  mirror=$(sed -n 's/^URIs: *\(http[^ ]*\/debian\)$/\1/p' /etc/apt/sources.list.d/*.sources 2>/dev/null | head -1)
  [ -n "$mirror" ] || mirror=$(sed -n 's/^deb \(http[^ ]*\/debian\) .*/\1/p' /etc/apt/sources.list 2>/dev/null | head -1)
  mirror=${mirror:-http://deb.debian.org/debian}
  echo "distro.sh: building a Debian $SUITE root in $ROOT from $mirror"
  rm -rf "$ROOT.part"
  PATH=$PATH:/usr/sbin:/sbin debootstrap --variant=minbase \
    --include=python3,python3-venv,python3-pip,ca-certificates,strace "$SUITE" "$ROOT.part" "$mirror" >"$ROOT.log" 2>&1 ||
    { tail -20 "$ROOT.log" >&2; echo "distro.sh: debootstrap failed (log: $ROOT.log)" >&2; exit 1; }
  touch "$ROOT.part/.pgser-distro-root"
  # -T: never into a folder that is there after all.
  mv -T "$ROOT.part" "$ROOT"
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
[ ! -f /etc/ssl/certs/ca-certificates.crt ] || put_in_root "$ROOT" /etc/ssl/certs/ca-certificates.crt /etc/ssl/certs/ca-certificates.crt
copy_pip_config "$ROOT"
chroot_env

t0=$(date +%s)
echo "distro.sh: Debian $SUITE: $(chroot "$ROOT" python3 --version), $(chroot "$ROOT" ldd --version | head -1)"
# After the root and the wheel's name, the passed variables: env -i sets them after its own, so
# this machine's win (PIP_DISABLE_PIP_VERSION_CHECK included).
unshare --mount --fork sh -c '
  root=$1 wheel=$2 && shift 2 &&
  mount -t proc proc "$root/proc" && mount --rbind /dev "$root/dev" &&
  exec chroot "$root" /usr/bin/env -i PATH=/usr/local/bin:/usr/bin:/bin HOME=/root LANG=C.UTF-8 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 "$@" bash /pgser-check/tests/wheel/check.sh --demo "/pgser-check/$wheel"
' sh "$ROOT" "$(basename "$WHEEL")" ${PASSED[@]+"${PASSED[@]}"}
t1=$(date +%s)
echo "distro.sh: this machine: $(python3 --version)"
"$REPO/tests/wheel/check.sh" --demo "$WHEEL"
t2=$(date +%s)
rm -rf "$CHECK"
echo "distro.sh: ok: Debian $SUITE $((t1 - t0)) s, this machine $((t2 - t1)) s"
