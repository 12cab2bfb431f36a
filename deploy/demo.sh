#!/usr/bin/env bash
# The README's main job. Installs and builds, then:
#   1. starts imucald on a local SQLite file (out/demo/imucal.db) on a free loopback port;
#   2. a simulated robot streams a six-face calibration session while `imucal guide` shows the
#      technician's guidance; the guide starts the solve when the protocol is complete;
#   3. the robot fetches its active parameters through the SDK and applies them;
#   4. prints the error before and after;
# then the offline path (calibrate a capture with extra poses, no server) for comparison.
set -euo pipefail
cd "$(dirname "$0")/.."
deploy/build.sh
dir="${IMUCAL_DEMO_DIR:-out/demo}"
mkdir -p "$dir"
rm -f "$dir"/imucal.db*

server_pid=""
trap '[ -n "$server_pid" ] && kill "$server_pid" 2>/dev/null; wait 2>/dev/null || true' EXIT
for attempt in 1 2 3 4 5; do
  port=$((20000 + RANDOM % 40000))
  ./build/server/imucald --listen "127.0.0.1:$port" --db "$dir/imucal.db" >"$dir/imucald.log" 2>&1 &
  server_pid=$!
  # Ready when it answers; gone when the port was taken (then try another port).
  if timeout 20 bash -c "until ./build/client/imucal --server 127.0.0.1:$port devices >/dev/null 2>&1; do
                           kill -0 $server_pid 2>/dev/null || exit 1; done"; then
    break
  fi
  server_pid=""
done
[ -n "$server_pid" ] || { echo "demo: imucald did not start (see $dir/imucald.log)" >&2; exit 1; }
echo "== imucald listening on 127.0.0.1:$port, database $dir/imucal.db"
./build/client/imucal demo --server "127.0.0.1:$port"

echo
echo "== offline, for comparison: six faces + 24 extra poses, no server"
./build/client/imucal demo --out-dir "$dir/offline"
