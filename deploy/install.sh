#!/usr/bin/env bash
# Installs imucald on a Debian 12 host, or upgrades it: binaries, systemd units, configuration
# and a first TLS certificate. Idempotent: run it again after `git pull` to upgrade (the
# database is migrated when imucald restarts; an edited /etc/imucald/imucald.toml is kept).
#
#   sudo deploy/install.sh                  # build if needed, install, (re)start if running
#   deploy/install.sh --destdir /tmp/stage  # stage into a directory (no systemctl, no root)
#
# Options: --prefix DIR (default /usr/local), --destdir DIR (default /), --build-dir DIR
# (default build-release: only the imucald and imucal targets are built there), --no-deps
# (skip deploy/install-deps.sh).
set -euo pipefail
cd "$(dirname "$0")/.."
prefix=/usr/local
destdir=""
build_dir=build-release
deps=1
while [ $# -gt 0 ]; do
  case "$1" in
    --prefix) prefix="$2"; shift 2 ;;
    --destdir) destdir="${2%/}"; shift 2 ;;
    --build-dir) build_dir="$2"; shift 2 ;;
    --no-deps) deps=0; shift ;;
    *) echo "install: unknown option $1 (see the top of $0)" >&2; exit 2 ;;
  esac
done
say() { echo "install: $*"; }

# 1. Build the two binaries (the toolchain and libraries come from Debian's archive).
[ "$deps" = 1 ] && deploy/install-deps.sh
if [ ! -f "$build_dir/build.ninja" ]; then
  cmake -S . -B "$build_dir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
        -DIMUCAL_BUILD_TESTS=OFF -DIMUCAL_BUILD_BENCH=OFF >/dev/null
fi
cmake --build "$build_dir" --target imucald imucal

# 2. Binaries (replaced atomically by install(1): a running imucald keeps its old inode).
bindir="$destdir$prefix/bin"
install -d "$bindir"
install -m 0755 "$build_dir/server/imucald" "$bindir/imucald"
install -m 0755 "$build_dir/client/imucal" "$bindir/imucal"
install -d "$destdir$prefix/share/doc/imucald" "$destdir$prefix/share/imucald"
install -m 0644 README.md "$destdir$prefix/share/doc/imucald/README.md"
install -m 0755 deploy/make-cert.sh "$destdir$prefix/share/imucald/make-cert.sh"
say "binaries in $bindir"

# 3. systemd units, pointed at this prefix.
unitdir="$destdir/etc/systemd/system"
install -d "$unitdir"
for unit in imucald.service imucald-backup.service imucald-backup.timer; do
  sed -e "s|/usr/local/bin/imucald|$prefix/bin/imucald|g" \
      -e "s|/usr/local/share/doc/imucald|$prefix/share/doc/imucald|g" \
      "deploy/$unit" > "$unitdir/$unit.tmp"
  chmod 0644 "$unitdir/$unit.tmp"
  mv "$unitdir/$unit.tmp" "$unitdir/$unit"
done
say "units in $unitdir"

# 4. Configuration: kept if present (the new example goes beside it as imucald.toml.dist).
confdir="$destdir/etc/imucald"
install -d -m 0755 "$confdir"
if [ -e "$confdir/imucald.toml" ]; then
  install -m 0644 deploy/imucald.toml "$confdir/imucald.toml.dist"
  say "kept $confdir/imucald.toml; the current example is imucald.toml.dist"
else
  install -m 0644 deploy/imucald.toml "$confdir/imucald.toml"
  say "wrote $confdir/imucald.toml"
fi

# 5. A self-signed certificate if there is none (the key readable by root only: systemd hands
#    it to the service as a credential).
install -d -m 0755 "$confdir/tls"
deploy/make-cert.sh "$confdir/tls"

# 6. On a live host: reload systemd, and restart a running imucald on upgrade (it drains,
#    then the new binary migrates the database on start).
if [ -z "$destdir" ] && [ -d /run/systemd/system ] && command -v systemctl >/dev/null; then
  systemctl daemon-reload
  if systemctl is-active --quiet imucald; then
    systemctl restart imucald
    say "restarted imucald (upgrade): journalctl -u imucald shows the migrations applied"
  else
    say "start it with: systemctl enable --now imucald imucald-backup.timer"
  fi
else
  say "no running systemd here (or --destdir): units installed, not started"
fi
