#!/usr/bin/env bash
# deploy/replicas.sh, as a developer uses it: two imucald replicas start on one throwaway
# PostgreSQL, each answers a call on the address it printed, a device registered through one is
# listed by the other (the database is shared), and stop leaves no imucald and no postgres
# process of the run and removes the directory.
#   tests/tools/replicas_test.sh IMUCALD IMUCAL
set -euo pipefail
imucald="${1:?usage: replicas_test.sh IMUCALD IMUCAL}"
imucal="${2:?usage: replicas_test.sh IMUCALD IMUCAL}"
script="$(cd "$(dirname "$0")/../.." && pwd)/deploy/replicas.sh"
dir=$(mktemp -d /tmp/imucal-replicas-test.XXXXXX)
cleanup() { [ -f "$dir/replicas" ] && bash "$script" stop "$dir" 2>/dev/null || true; rm -rf "$dir"; }
trap cleanup EXIT
fail() { echo "FAIL: $*"; exit 1; }
# Whether `pid` runs (a zombie, exited and waiting for its parent to reap it, does not).
running() { [ -e "/proc/$1/stat" ] && [ "$(sed 's/.*) //' "/proc/$1/stat" | cut -d' ' -f1)" != Z ]; }

mapfile -t addresses < <(IMUCALD="$imucald" bash "$script" start 2 "$dir" 2>"$dir.err") ||
  { cat "$dir.err"; fail "start"; }
[ "${#addresses[@]}" -eq 2 ] || { cat "$dir.err"; fail "start printed ${#addresses[@]} addresses"; }
rm -f "$dir.err"
# What stop must end: the replicas' pids and the cluster's postmaster (its pid file's first line).
mapfile -t pids < <(cat "$dir"/replica-*.pid)
postmaster=$(head -1 "$dir/pg/data/postmaster.pid")
[ "${#pids[@]}" -eq 2 ] && [ -n "$postmaster" ] || fail "pid files"
for pid in "${pids[@]}" "$postmaster"; do running "$pid" || fail "pid $pid is not running"; done

# Each answers; the device registered through replica 1 is listed by replica 2.
"$imucal" --server "${addresses[0]}" devices register replicas-test-1 --sensor-model MPU-6050 \
  --rate 200 --accel-unit m/s^2 --gyro-unit rad/s >/dev/null || fail "register through ${addresses[0]}"
for address in "${addresses[@]}"; do
  got=$("$imucal" --server "$address" devices) || fail "devices through $address"
  grep -q replicas-test-1 <<<"$got" || fail "$address does not list the device: $got"
done

bash "$script" stop "$dir" 2>/dev/null || fail "stop"
for pid in "${pids[@]}" "$postmaster"; do
  if running "$pid"; then fail "pid $pid still running after stop: $(ps -o pid,stat,cmd -p "$pid")"; fi
done
if pgrep -f -- "$dir" >/dev/null; then fail "a process still names $dir: $(pgrep -af -- "$dir")"; fi
[ ! -e "$dir" ] || fail "$dir still there after stop"
echo "PASS: 2 replicas on one PostgreSQL answered and shared a device; stop left no process and no directory"
