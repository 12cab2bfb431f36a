#!/usr/bin/env bash
# Several imucald replicas on one throwaway PostgreSQL, on this machine, without Docker: to try
# what README "Scaling out: replicas on PostgreSQL" describes (shared versions, solve claims, fetch
# caches that follow each other's promotes) and to watch it (each replica's /metrics).
#
#   deploy/replicas.sh start N [DIR]   starts a throwaway cluster (deploy/pg-throwaway.sh) in
#                                      DIR/pg and N imucald on loopback (replica-1 .. replica-N),
#                                      one after another, each once it serves; prints their gRPC
#                                      addresses on stdout, one a line; everything else on
#                                      stderr. DIR (default: a new temporary directory) must be
#                                      empty or absent.
#   deploy/replicas.sh stop DIR        SIGTERM to each replica (it drains), SIGKILL to one still
#                                      there after 60 s, stops the cluster, removes DIR.
#
# DIR holds: db.url (the cluster's URL), replicas (one line per replica: name, pid, gRPC
# address, metrics URL), replica-I.pid, replica-I.log (imucald's JSON log), pg/ (the cluster).
# The replicas serve plaintext without authentication (imucald's `insecure`, refused anywhere
# but loopback): `imucal --server ADDR devices` needs no token. The cluster runs with
# fsync=off (pg-throwaway.sh): fine for trying things, not for measuring durability.
# The imucald binary: $IMUCALD, else build/server/imucald of this checkout, else imucald on PATH.
set -Eeuo pipefail  # -E: the ERR trap of `start` holds inside the functions it calls

here="$(cd "$(dirname "$0")" && pwd)"
die() { echo "replicas: $*" >&2; exit 1; }

imucald_binary() {
  if [ -n "${IMUCALD:-}" ]; then echo "$IMUCALD"
  elif [ -x "$here/../build/server/imucald" ]; then echo "$here/../build/server/imucald"
  elif command -v imucald >/dev/null; then command -v imucald
  else die "no imucald: build it (ninja -C build imucald) or set IMUCALD=/path/to/imucald"
  fi
}

# The value of "key":"..." in the replica's server_start log line (JSON), or nothing yet.
start_field() {
  { grep -m1 '"event":"server_start"' "$1" 2>/dev/null || true; } |
    sed -n "s/.*\"$2\":\"\([^\"]*\)\".*/\1/p"
}

# Whether `pid` is alive and is an imucald (not a process that reused a dead one's pid).
is_imucald() {
  [ -n "$1" ] && [ "$(cat "/proc/$1/comm" 2>/dev/null)" = imucald ]
}

# Stops the replicas listed in DIR (SIGTERM, up to 60 s each to drain, then SIGKILL).
stop_replicas() {
  local dir="$1" f pid i
  for f in "$dir"/replica-*.pid; do
    [ -e "$f" ] || continue
    pid=$(cat "$f")
    is_imucald "$pid" && kill -TERM "$pid" 2>/dev/null || true
  done
  for f in "$dir"/replica-*.pid; do
    [ -e "$f" ] || continue
    pid=$(cat "$f")
    for ((i = 0; i < 600; i++)); do is_imucald "$pid" || break; sleep 0.1; done
    if is_imucald "$pid"; then
      echo "replicas: $(basename "$f" .pid) (pid $pid) did not stop in 60 s: SIGKILL" >&2
      kill -KILL "$pid" 2>/dev/null || true
    fi
    rm -f "$f"
  done
}

start() {
  local n="${1:-}" dir="${2:-}"
  [[ "$n" =~ ^[1-9][0-9]*$ ]] || die "start: N must be a positive number, got '$n'"
  if [ -z "$dir" ]; then
    dir=$(mktemp -d /tmp/imucal-replicas.XXXXXX)
  else
    mkdir -p "$dir"
    [ -z "$(ls -A "$dir")" ] || die "$dir is not empty"
    dir="$(cd "$dir" && pwd)"
  fi
  echo "replicas: in $dir (stop them with: $0 stop $dir)" >&2
  # The cluster's files belong to the postgres user when this runs as root: it must be able to
  # reach DIR/pg (traverse DIR, not read it).
  chmod 0711 "$dir"
  local imucald
  imucald=$(imucald_binary)
  # Whatever fails from here on leaves nothing running and no DIR.
  trap 'echo "replicas: start failed; stopping what was started" >&2; stop_replicas "$dir";
        [ -d "$dir/pg/data" ] && bash "$here/pg-throwaway.sh" stop "$dir/pg" 2>/dev/null;
        rm -rf "$dir"' ERR
  bash "$here/pg-throwaway.sh" start "$dir/pg" >"$dir/db.url" 2>"$dir/pg-throwaway.log" ||
    { cat "$dir/pg-throwaway.log" >&2; false; }
  local url i log pid address metrics
  url=$(cat "$dir/db.url")
  : >"$dir/replicas"
  for ((i = 1; i <= n; i++)); do
    log="$dir/replica-$i.log"
    # Port 0: the kernel picks free ports; the server_start log line says which.
    "$imucald" --listen 127.0.0.1:0 --metrics-listen 127.0.0.1:0 --db "$url" --insecure \
      --replica-id "replica-$i" --log-format json </dev/null >>"$log" 2>&1 &
    pid=$!
    echo "$pid" >"$dir/replica-$i.pid"
    # The first replica applies the migrations; each starts once the one before serves.
    for ((t = 0; t < 300; t++)); do
      address=$(start_field "$log" address)
      [ -n "$address" ] && break
      is_imucald "$pid" || break
      sleep 0.1
    done
    if [ -z "$address" ]; then
      cat "$log" >&2
      echo "replicas: replica-$i did not start (its log above)" >&2
      false
    fi
    metrics=$(start_field "$log" metrics)
    echo "replica-$i $pid $address $metrics" >>"$dir/replicas"
    echo "replicas: replica-$i pid $pid serves $address, metrics $metrics" >&2
    echo "$address"
  done
  trap - ERR
  echo "replicas: $n on $url (fsync=off)" >&2
}

stop() {
  local dir="${1:-}"
  [ -n "$dir" ] && [ -f "$dir/replicas" ] || die "stop: '$dir' holds no replicas"
  stop_replicas "$dir"
  if [ -d "$dir/pg/data" ]; then bash "$here/pg-throwaway.sh" stop "$dir/pg"; fi
  rm -rf "$dir"
}

case "${1:-}" in
  start) start "${2:-}" "${3:-}" ;;
  stop) stop "${2:-}" ;;
  *) echo "usage: $0 start N [DIR] | stop DIR" >&2; exit 2 ;;
esac
