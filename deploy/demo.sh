#!/usr/bin/env bash
# The README's main job. Installs and builds, then:
#   0. makes a local CA and a server certificate for 127.0.0.1 (openssl), so that everything
#      below runs over TLS, and tokens: imucald writes the first admin token, the admin makes a
#      technician token and a robot token bound to the demo robot;
#   1. starts imucald on a local SQLite file (out/demo/imucal.db) on a free loopback port;
#   2. a simulated robot (its own token) streams a six-face calibration session while
#      `imucal guide` (the technician's token) shows the technician's guidance; the guide starts
#      the solve when the protocol is complete;
#   3. the robot fetches its active parameters through the SDK and applies them;
#   4. prints the error before and after;
# then the offline path (calibrate a capture with extra poses, no server) for comparison.
# IMUCAL_DEMO_BUILD=DIR uses the binaries of an existing build tree instead of building ./build.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -n "${IMUCAL_DEMO_BUILD:-}" ]; then
  build="$IMUCAL_DEMO_BUILD"
else
  deploy/build.sh --run
  build=build
fi
imucald="$build/server/imucald"
imucal="$build/client/imucal"
dir="${IMUCAL_DEMO_DIR:-out/demo}"
device=demo-robot-7
mkdir -p "$dir"
rm -f "$dir"/imucal.db* "$dir"/*.token

# A throwaway CA and the server's certificate (EC P-256, valid 30 days), made fresh each run.
tls="$dir/tls"
rm -rf "$tls"
mkdir -p "$tls"
(
  umask 077
  openssl req -x509 -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes -days 30 \
    -keyout "$tls/ca.key" -out "$tls/ca.pem" -subj "/CN=imucal demo CA" 2>/dev/null
  openssl req -newkey ec -pkeyopt ec_paramgen_curve:P-256 -nodes \
    -keyout "$tls/server.key" -out "$tls/server.csr" -subj "/CN=localhost" 2>/dev/null
  printf 'subjectAltName=DNS:localhost,IP:127.0.0.1\nextendedKeyUsage=serverAuth\n' \
    >"$tls/server.ext"
  openssl x509 -req -in "$tls/server.csr" -CA "$tls/ca.pem" -CAkey "$tls/ca.key" \
    -CAcreateserial -days 30 -out "$tls/server.pem" -extfile "$tls/server.ext" 2>/dev/null
)
export IMUCAL_CA_CERT="$tls/ca.pem"  # every imucal below trusts the demo CA

server_pid=""
trap '[ -n "$server_pid" ] && kill "$server_pid" 2>/dev/null; wait 2>/dev/null || true' EXIT
for attempt in 1 2 3 4 5; do
  port=$((20000 + RANDOM % 40000))
  "$imucald" --listen "127.0.0.1:$port" --db "$dir/imucal.db" \
    --tls-cert "$tls/server.pem" --tls-key "$tls/server.key" \
    --admin-token-file "$dir/admin.token" >"$dir/imucald.log" 2>&1 &
  server_pid=$!
  # Ready when it answers the admin (the first admin token is written before it listens); gone
  # when the port was taken (then try another port).
  if timeout 20 bash -c "until [ -s '$dir/admin.token' ] &&
                           '$imucal' --server 127.0.0.1:$port --token-file '$dir/admin.token' \
                             admin token list >/dev/null 2>&1; do
                           kill -0 $server_pid 2>/dev/null || exit 1; done"; then
    break
  fi
  server_pid=""
done
[ -n "$server_pid" ] || { echo "demo: imucald did not start (see $dir/imucald.log)" >&2; exit 1; }
echo "== imucald listening on 127.0.0.1:$port (TLS, CA $tls/ca.pem), database $dir/imucal.db"
admin=("$imucal" --server "127.0.0.1:$port" --token-file "$dir/admin.token")
"${admin[@]}" admin token create --role technician --label "demo technician" \
  --out "$dir/technician.token"
"${admin[@]}" admin token create --role robot --device "$device" --label "demo robot" \
  --out "$dir/robot.token"
"$imucal" demo --server "127.0.0.1:$port" --device "$device" \
  --token-file "$dir/technician.token" --robot-token-file "$dir/robot.token"

echo
echo "== offline, for comparison: six faces + 24 extra poses, no server"
"$imucal" demo --out-dir "$dir/offline"
