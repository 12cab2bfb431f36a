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
"$imucald" --listen "$addr" --db "$dir/imucal.db" --insecure >"$dir/imucald.log" 2>&1 &
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
pane() { tmux -L "$sock" capture-pane -p -J -S - -t "${2:-guide}"; }
pane_has() { pane "" "${2:-guide}" | grep -qF -- "$1"; }
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

# The guide starts the solve as soon as the protocol is complete: a robot still streaming its
# trailing samples then finds its session closed for the solve and stops (as the demo's does).
if ! "$imucal" --server "$addr" upload "$dir/capture.csv" --session "$session" >"$dir/upload.log" 2>&1; then
  grep -qF "is solving, not open" "$dir/upload.log" || fail "upload failed: $(cat "$dir/upload.log")"
fi

wait_for 180 pane_has "GUIDE-EXIT=" || fail "the guide did not finish"
pane_has "NEXT:" || fail "no next-pose instruction"
pane_has "progress:" || fail "no progress line"
pane_has "[ok]   pose" || fail "no accepted pose"
pane_has "RESULT: version" || fail "no solve result"
pane_has "GUIDE-EXIT=0" || fail "the guide's exit code was not 0"
if [[ -n "${GUIDE_TMUX_SHOW:-}" ]]; then pane; fi

# 2. A failed pair and its re-do: the demo's robot (the SDK uploader) stops its first half turn a
# quarter turn short, holds, then finishes the turn; the guide (in the pane) must reject the pair
# with the reason, ask for the re-do, accept the re-done pair, and finish with a result.
tmux -L "$sock" new-session -d -s botch -x 160 -y 60 \
  "'$imucal' demo --server '$addr' --seed 11 --device robot-botch --botch-turn; echo DEMO-EXIT=\$?; read -r _"
wait_for 240 pane_has "DEMO-EXIT=" botch || { pane "" botch; fail "the botched demo did not finish"; }
botch_has() { pane_has "$1" botch || { echo "---- botch pane ----"; pane "" botch; fail "$2"; }; }
botch_has "[redo] pair Z+ (poses 0, 1) FAILED: turned" "no failed-pair verdict"
botch_has "-> REDO Z+" "no re-do prompt under the failed pair"
botch_has "NEXT: Pair Z+ failed (turned" "the next-pose guidance does not ask for the re-do"
botch_has "[ok]   pair Z+ (poses 0, 2)" "the re-done pair was not accepted"
botch_has "[ok]   pair X- " "the session did not go on to the last face"
botch_has "RESULT: version" "no solve result after the re-do"
botch_has "DEMO-EXIT=0" "the demo's exit code was not 0"
if [[ -n "${GUIDE_TMUX_SHOW:-}" ]]; then pane "" botch; fi
echo "PASS: guide_tmux_test"
