#!/usr/bin/env bash
# Installs star as two systemd services (star-camera, star-track).
#
# Usage: scripts/install.sh [--root DIR] [--prefix DIR] [--binary PATH] [--no-activate]
#   --root DIR     install under DIR instead of / (staging, packaging, tests);
#                  DESTDIR=DIR in the environment does the same
#   --prefix DIR   where the binary and the systemd data files go (default /usr/local)
#   --binary PATH  the binary to install (default: target/release/star, or
#                  $CARGO_TARGET_DIR/release/star)
#   --no-activate  do not run systemd-sysusers / systemd-tmpfiles / daemon-reload
#
# Files (ROOT = --root, PREFIX = --prefix):
#   ROOT/PREFIX/bin/star
#   ROOT/PREFIX/lib/systemd/system/star-camera.service, star-track.service
#     (ExecStart rewritten to PREFIX/bin/star)
#   ROOT/PREFIX/lib/sysusers.d/star.conf   user `star` in video, dialout, render
#   ROOT/PREFIX/lib/tmpfiles.d/star.conf   /tmp/iceoryx2 for iceoryx2
#   ROOT/PREFIX/share/star/star.toml       the shipped default config, for reference
#   ROOT/etc/star/star.toml                only if absent: an existing config is kept
# systemd searches /usr/local/lib/{systemd/system,sysusers.d,tmpfiles.d} and
# /usr/lib/..., so --prefix /usr/local (default) or /usr need no extra setup.
# When installing to / as root on a running systemd, the user and
# /tmp/iceoryx2 are created and systemd reloaded; the units are not enabled:
#   systemctl enable --now star-camera.service star-track.service
set -euo pipefail

repo="$(cd "$(dirname "$0")/.." && pwd)"
root="${DESTDIR:-}"
prefix="/usr/local"
binary="${CARGO_TARGET_DIR:-$repo/target}/release/star"
activate=1

die() { echo "install.sh: $*" >&2; exit 1; }

while (($#)); do
  case "$1" in
    --root) (($# >= 2)) || die "--root needs a directory"; root="$2"; shift 2 ;;
    --root=*) root="${1#*=}"; shift ;;
    --prefix) (($# >= 2)) || die "--prefix needs a directory"; prefix="$2"; shift 2 ;;
    --prefix=*) prefix="${1#*=}"; shift ;;
    --binary) (($# >= 2)) || die "--binary needs a path"; binary="$2"; shift 2 ;;
    --binary=*) binary="${1#*=}"; shift ;;
    --no-activate) activate=0; shift ;;
    -h|--help) sed -n '2,25p' "$0"; exit 0 ;;
    *) die "unknown argument '$1' (see --help)" ;;
  esac
done

[[ "$prefix" == /* ]] || die "--prefix must be absolute, got '$prefix'"
[[ -z "$root" || "$root" == /* ]] || die "--root must be absolute, got '$root'"
root="${root%/}"
[[ -x "$binary" ]] || die "binary '$binary' not found or not executable (build it: cargo build --release)"

bindir="$prefix/bin"
unitdir="$prefix/lib/systemd/system"
sysusersdir="$prefix/lib/sysusers.d"
tmpfilesdir="$prefix/lib/tmpfiles.d"
datadir="$prefix/share/star"
confdir="/etc/star"

echo "install.sh: installing into root '${root:-/}', prefix '$prefix'"
install -d "$root$bindir" "$root$unitdir" "$root$sysusersdir" "$root$tmpfilesdir" "$root$datadir" "$root$confdir"
install -m 0755 "$binary" "$root$bindir/star"
for unit in star-camera.service star-track.service; do
  sed "s#/usr/local/bin/star#$bindir/star#g" "$repo/systemd/$unit" > "$root$unitdir/$unit.tmp"
  chmod 0644 "$root$unitdir/$unit.tmp"
  mv "$root$unitdir/$unit.tmp" "$root$unitdir/$unit"
done
install -m 0644 "$repo/systemd/star.sysusers" "$root$sysusersdir/star.conf"
install -m 0644 "$repo/systemd/star.tmpfiles" "$root$tmpfilesdir/star.conf"
install -m 0644 "$repo/config/star.toml" "$root$datadir/star.toml"
if [[ -e "$root$confdir/star.toml" ]]; then
  echo "install.sh: keeping existing $root$confdir/star.toml (default is in $root$datadir/star.toml)"
else
  install -m 0644 "$repo/config/star.toml" "$root$confdir/star.toml"
  echo "install.sh: installed default config $root$confdir/star.toml"
fi

if [[ -z "$root" && "$activate" == 1 && "$(id -u)" == 0 && -d /run/systemd/system ]]; then
  systemd-sysusers "$sysusersdir/star.conf"
  systemd-tmpfiles --create "$tmpfilesdir/star.conf"
  systemctl daemon-reload
  echo "install.sh: done; start with: systemctl enable --now star-camera.service star-track.service"
else
  echo "install.sh: done (user, tmpfiles and daemon-reload not applied: staging root, not root, or no running systemd)"
fi
