#!/usr/bin/env bash
# A throwaway PostgreSQL cluster for tests and benchmarks: never assumes a server is running,
# never touches the machine's own clusters.
#
#   deploy/pg-throwaway.sh start [DIR]   creates the cluster in DIR (default: a new temporary
#                                        directory), starts it on a free loopback port, and prints
#                                        its connection URL (postgresql://imucal@127.0.0.1:PORT/imucal)
#                                        on stdout; everything else goes to stderr
#   deploy/pg-throwaway.sh stop DIR      stops it (fast shutdown, waiting) and removes DIR
#
# PostgreSQL refuses to run as root, and CI runs as root: the cluster then belongs to the
# `postgres` system user (from Debian's postgresql package) and its commands run through runuser.
# Authentication is `trust` on loopback and the socket directory is DIR itself: the cluster is
# reachable only from this machine, for the life of one test run.
set -euo pipefail

die() { echo "pg-throwaway: $*" >&2; exit 1; }

bindir() {
  local d
  d=$(ls -d /usr/lib/postgresql/*/bin 2>/dev/null | sort -V | tail -1 || true)
  [ -n "$d" ] && [ -x "$d/initdb" ] || die "no PostgreSQL server binaries under /usr/lib/postgresql (install the postgresql package: deploy/install-deps.sh)"
  echo "$d"
}

# Runs a PostgreSQL command as the cluster's owner.
as_owner() {
  if [ "$(id -u)" -eq 0 ]; then
    id postgres >/dev/null 2>&1 || die "running as root and there is no postgres user to own the cluster"
    runuser -u postgres -- "$@"
  else
    "$@"
  fi
}

free_port() {
  python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'
}

start() {
  local dir="${1:-}"
  if [ -z "$dir" ]; then
    dir=$(mktemp -d /tmp/imucal-pg.XXXXXX)
    echo "pg-throwaway: cluster in $dir (stop it with: $0 stop $dir)" >&2
  fi
  mkdir -p "$dir"
  [ -z "$(ls -A "$dir")" ] || die "$dir is not empty"
  [ "$(id -u)" -ne 0 ] || chown postgres: "$dir"
  local bin port
  bin=$(bindir)
  port=$(free_port)
  as_owner "$bin/initdb" -D "$dir/data" -U imucal -A trust -E UTF8 --no-locale >&2 ||
    die "initdb failed in $dir/data"
  as_owner "$bin/pg_ctl" -D "$dir/data" -l "$dir/server.log" -w -t 60 start \
    -o "-c listen_addresses=127.0.0.1 -p $port -k $dir -c fsync=off -c full_page_writes=off" >&2 ||
    { cat "$dir/server.log" >&2; die "the server did not start (log above)"; }
  as_owner "$bin/createdb" -h 127.0.0.1 -p "$port" -U imucal imucal >&2 ||
    die "createdb imucal failed on port $port"
  echo "$port" > "$dir/port"
  echo "postgresql://imucal@127.0.0.1:$port/imucal"
}

stop() {
  local dir="${1:-}"
  [ -n "$dir" ] && [ -d "$dir/data" ] || die "stop: '$dir' holds no cluster"
  as_owner "$(bindir)/pg_ctl" -D "$dir/data" -m fast -w -t 60 stop >&2 || die "pg_ctl stop failed in $dir"
  rm -rf "$dir"
}

case "${1:-}" in
  start) start "${2:-}" ;;
  stop) stop "${2:-}" ;;
  *) echo "usage: $0 start [DIR] | stop DIR" >&2; exit 2 ;;
esac
