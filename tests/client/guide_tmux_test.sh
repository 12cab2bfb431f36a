#!/usr/bin/env bash
# End-to-end test of `imucal guide` as a technician sees it: imucald on a free loopback port with
# a temp database, the guide running in a detached tmux pane (a real terminal), a simulated robot
# streaming its capture with `imucal upload`, and assertions on `tmux capture-pane -p`.
# Waiting is bounded polling with a deadline (no fixed sleeps).
# usage: guide_tmux_test.sh IMUCAL IMUCALD
set -euo pipefail
imucal=$1
imucald=$2
command -v tmux >/dev/null || { echo "SKIP: tmux not installed"; exit 0; }

dir=$(mktemp -d)
sock="imucal-guide-test-$$"
server_pid=""
cleanup() {
  tmux -L "$sock" kill-server 2>/dev/null || true
  if [[ -n "$server_pid" ]]; then kill "$server_pid" 2>/dev/null || true; wait "$server_pid" 2>/dev/null || true; fi
  rm -rf "$dir"
}
trap cleanup EXIT

port=$(python3 -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
addr="127.0.0.1:$port"
"$imucald" --listen "$addr" --db "$dir/imucal.db" >"$dir/imucald.log" 2>&1 &
server_pid=$!

# until CMD succeeds or SECONDS_LEFT run out
wait_for() {
  local seconds=$1; shift
  local deadline=$((SECONDS + seconds))
  until "$@"; do
    if ((SECONDS >= deadline)); then return 1; fi
    sleep 0.2
  done
}
pane() { tmux -L "$sock" capture-pane -p -J -S - -t guide; }
pane_has() { pane | grep -qF -- "$1"; }
fail() {
  echo "FAIL: $*"
  echo "---- pane ----"; pane || true
  echo "---- imucald log ----"; tail -20 "$dir/imucald.log" || true
  exit 1
}

wait_for 20 "$imucal" --server "$addr" devices >/dev/null 2>&1 || fail "imucald did not come up"
"$imucal" --server "$addr" devices register robot-tmux --sensor-model sim --rate 200 \
  --accel-unit m/s^2 --gyro-unit rad/s >/dev/null
# One extra random pose after the protocol: the robot moves on after the last pose, which is
# what closes that pose for the online segmentation (as a technician picking the robot up).
"$imucal" simulate --out "$dir/capture.csv" --seed 11 --extra-poses 1 >/dev/null
session=$("$imucal" --server "$addr" session start --device robot-tmux --protocol six-face --json |
  python3 -c 'import json, sys; print(json.load(sys.stdin)["id"])')

tmux -L "$sock" new-session -d -s guide -x 160 -y 60 \
  "'$imucal' --server '$addr' guide --session '$session'; echo GUIDE-EXIT=\$?; read -r _"
wait_for 20 pane_has "Calibrating robot-tmux" || fail "the guide did not start"

"$imucal" --server "$addr" upload "$dir/capture.csv" --session "$session" >"$dir/upload.log" 2>&1 ||
  fail "upload failed: $(cat "$dir/upload.log")"

wait_for 180 pane_has "GUIDE-EXIT=" || fail "the guide did not finish"
pane_has "NEXT:" || fail "no next-pose instruction"
pane_has "progress:" || fail "no progress line"
pane_has "[ok]   pose" || fail "no accepted pose"
pane_has "RESULT: version" || fail "no solve result"
pane_has "GUIDE-EXIT=0" || fail "the guide's exit code was not 0"
if [[ -n "${GUIDE_TMUX_SHOW:-}" ]]; then pane; fi
echo "PASS: guide_tmux_test"
