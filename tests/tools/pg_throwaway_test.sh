#!/usr/bin/env bash
# deploy/pg-throwaway.sh, as the PostgreSQL tests use it: a cluster starts in a fresh directory
# (as the postgres user when run as root, as CI does), answers on the URL it prints, keeps what
# is written (bytes included), refuses a directory that is not empty, and on stop leaves nothing
# answering on its port and no directory behind.
set -euo pipefail
script="$(cd "$(dirname "$0")/../.." && pwd)/deploy/pg-throwaway.sh"
dir=$(mktemp -d /tmp/imucal-pg-test.XXXXXX)
cleanup() { [ -d "$dir/data" ] && bash "$script" stop "$dir" 2>/dev/null || true; rm -rf "$dir"; }
trap cleanup EXIT
fail() { echo "FAIL: $*"; exit 1; }

url=$(bash "$script" start "$dir" 2>"$dir.err") || { cat "$dir.err"; fail "start"; }
rm -f "$dir.err"
[[ "$url" =~ ^postgresql://imucal@127\.0\.0\.1:[0-9]+/imucal$ ]] || fail "URL '$url'"
port=$(cat "$dir/port")
pg_isready -q -h 127.0.0.1 -p "$port" || fail "nothing answers on port $port"

got=$(psql "$url" -v ON_ERROR_STOP=1 -Atq <<'SQL'
CREATE TABLE t (id bigint PRIMARY KEY, payload bytea NOT NULL);
INSERT INTO t VALUES (1, '\x00ff10'::bytea), (2, decode('696d7563616c', 'hex'));
SELECT id || ':' || encode(payload, 'hex') FROM t ORDER BY id;
SQL
) || fail "psql"
[ "$got" = $'1:00ff10\n2:696d7563616c' ] || fail "read back '$got'"

if bash "$script" start "$dir" >/dev/null 2>&1; then fail "a second start in a used directory"; fi

bash "$script" stop "$dir" 2>/dev/null || fail "stop"
# pg_ctl stop -w returns once the server has removed its pid file, after closing its sockets.
if pg_isready -q -h 127.0.0.1 -p "$port"; then fail "a server still answers on port $port"; fi
[ ! -e "$dir" ] || fail "$dir still there after stop"
echo "PASS: throwaway cluster started, served, refused a used directory, stopped and removed"
