#!/usr/bin/env bash
# End-to-end test of `imucal guide` as a technician uses it: imucald on a free loopback port with
# a temp database; a shell in a detached tmux session (a real terminal) where the commands are
# TYPED with send-keys: `imucal --server ADDR guide --device D --protocol six-face` in one window,
# and in a second window the robot's `imucal upload capture.csv --device D --session S` (its
# progress bar shows there). Assertions read the windows with `tmux capture-pane -p`.
#   1. a clean six-face capture streamed as a robot streams it while capturing (`upload --pace
#      20`: twenty times real time), with poses after the protocol's: the guide's instructions,
#      progress, accepted poses; that it waits for the upload to finish before solving (the
#      robot still streams after the protocol's last pose), and then solves; the upload's
#      progress bar; every sample stored; both exit codes (typed `echo $?`).
#   2. a capture from `imucal simulate --botch-turn` (the first half turn stops a quarter turn
#      short, is held, then finished): the failed pair with its reason, the re-do prompt, the
#      re-done pair accepted, the last face, the result, the guide's exit code 0. Typed short, as
#      a technician would: `guide --device D` (six-face by default) and `upload FILE --device D`,
#      which streams into the session the guide opened. The upload at full speed: the guide
#      waits for it all the same, and it ends with every sample stored.
# Waiting on a pane's content is bounded polling with a deadline (tmux offers nothing to wait on
# for it); everything else waits on the command itself.
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
tm() { tmux -L "$sock" -f "$dir/tmux.conf" "$@"; }
pane() { tm capture-pane -p -J -S - -t "tech:$1"; }
pane_has() { pane "$1" | grep -qF -- "$2"; }
pane_matches() { pane "$1" | grep -qE -- "$2"; }
fail() {
  echo "FAIL: $*"
  for w in $(tm list-windows -t tech -F '#W' 2>/dev/null); do
    echo "---- window $w ----"; pane "$w" || true
  done
  echo "---- imucald log ----"; tail -20 "$dir/imucald.log" || true
  exit 1
}
# expect WINDOW TEXT WHAT: the window shows TEXT (fixed string), else fail with WHAT
expect() { pane_has "$1" "$2" || fail "$3 (no \"$2\" in window $1)"; }
expect_re() { pane_matches "$1" "$2" || fail "$3 (nothing matches /$2/ in window $1)"; }

# The shell's prompt is "tech$ ". at_new_prompt WINDOW N: the window shows more than N prompt
# lines and its last line is a bare prompt (the shell waits for the next command). capture-pane
# -J keeps trailing spaces.
at_new_prompt() {
  local text; text=$(pane "$1")
  (($(grep -c '^tech\$' <<<"$text") > $2)) && grep -v '^ *$' <<<"$text" | tail -1 | grep -qx 'tech\$ *'
}
# type WINDOW TEXT: the technician types TEXT and Enter
type_cmd() { tm send-keys -t "tech:$1" -l -- "$2"; tm send-keys -t "tech:$1" Enter; }
# exit_code WINDOW NAME: types `echo NAME-EXIT=$?` and sets $code to the code it shows
code=""
exit_code() {
  type_cmd "$1" "echo $2-EXIT=\$?"
  wait_for 10 pane_matches "$1" "^$2-EXIT=[0-9]+" || fail "no exit code shown in window $1"
  code=$(pane "$1" | grep -oE "^$2-EXIT=[0-9]+" | tail -1 | cut -d= -f2)
}

wait_for 20 "$imucal" --server "$addr" devices >/dev/null 2>&1 || fail "imucald did not come up"
for device in robot-tmux robot-botch; do
  "$imucal" --server "$addr" devices register "$device" --sensor-model sim --rate 200 \
    --accel-unit m/s^2 --gyro-unit rad/s >/dev/null
done
# One extra random pose after the protocol: the robot moves on after the last pose, which is
# what closes that pose for the online segmentation (as a technician picking the robot up).
"$imucal" simulate --out "$dir/capture.csv" --seed 11 --extra-poses 8 >/dev/null
"$imucal" simulate --out "$dir/botched.csv" --seed 11 --extra-poses 1 --botch-turn >/dev/null

# A plain shell in a 160x60 terminal with `imucal` on its PATH, in the captures' directory.
# HISTFILE is null so that the shells keep no history: bash writes $HOME/.bash_history when the
# tmux server hangs up on it, after `kill-server` has returned, and that raced cleanup's rm.
printf 'set -g history-limit 100000\n' >"$dir/tmux.conf"
shell=(env -i HOME="$dir" HISTFILE= TERM=xterm-256color PATH="$(cd "$(dirname "$imucal")" && pwd):/usr/bin:/bin"
       PS1='tech$ ' bash --norc --noprofile)
# The session's first window stays idle: each part opens its own two windows.
tm new-session -d -s tech -n idle -x 160 -y 60 -c "$dir" "${shell[@]}"
# open_window NAME: a new window with that shell, once its prompt shows
open_window() {
  tm new-window -d -t tech -n "$1" -c "$dir" "${shell[@]}"
  wait_for 10 at_new_prompt "$1" 0 || fail "no shell prompt in window $1"
}

# run_guided N DEVICE CAPTURE [short|paced]: in fresh windows guideN and robotN, types the guide
# for DEVICE, then the robot's upload of CAPTURE into the guide's session; returns when both are
# back at their prompt, with the session's id in $session. "short" types what a technician
# would: the guide without --protocol (six-face is its default) and `upload --device` alone,
# which streams into the device's open, still empty session (the guide's). "paced" uploads at
# twenty times the capture's real-time rate, as a robot streams while it captures.
session=""
total=""  # the last expect_upload's capture size
run_guided() {
  local guide=guide$1 robot=robot$1 device=$2 capture=$3 short=${4:-}
  open_window "$guide"
  open_window "$robot"
  if [[ "$short" == short ]]; then
    type_cmd "$guide" "imucal --server $addr guide --device $device"
  else
    type_cmd "$guide" "imucal --server $addr guide --device $device --protocol six-face"
  fi
  wait_for 20 pane_has "$guide" "Calibrating $device: session " || fail "the guide did not start"
  # The guide opened the device's session, and a device has one open session at a time:
  # `upload --device` alone opens a new one and is refused, so the robot streams into the
  # session the guide names on screen, as its "Start the robot's capture now" line says.
  session=$(pane "$guide" |
            sed -nE "s/^Calibrating $device: session ([^ ]+) \(protocol six-face\)\.\$/\1/p")
  [[ -n "$session" ]] || fail "the guide did not name its session"
  expect "$guide" "(e.g. imucal upload FILE --session $session)" \
    "the guide does not say how to stream into its session"
  if [[ "$short" == short ]]; then
    type_cmd "$robot" "imucal --server $addr upload $capture --device $device"
    wait_for 20 pane_has "$robot" "streaming into $device's open session $session" ||
      fail "upload --device did not stream into the guide's session $session"
  elif [[ "$short" == paced ]]; then
    type_cmd "$robot" "imucal --server $addr upload $capture --device $device --session $session --pace 20"
  else
    type_cmd "$robot" "imucal --server $addr upload $capture --device $device --session $session"
  fi
  wait_for 120 at_new_prompt "$robot" 1 || fail "the upload did not finish"
  wait_for 180 at_new_prompt "$guide" 1 || fail "the guide did not finish"
}

# expect_upload N: the robot's upload in window robotN exited 0 having sent every sample (the
# guide does not solve while it streams, so the solve never cuts it short), its progress bar at
# 100%, and the session holds every sample of the capture.
bar_re='^\[#{30}\] 100%  ([0-9]+)/\1 samples'
expect_upload() {
  local robot=robot$1 stored
  exit_code "$robot" UPLOAD
  [[ "$code" == 0 ]] || fail "the upload's exit code was $code, not 0 (cut short by the solve?)"
  expect_re "$robot" "$bar_re" "the bar did not reach every sample"
  expect "$robot" "uploaded " "no upload summary"
  total=$(pane "$robot" | grep -oE "$bar_re" | tail -1 | sed -E 's|.* ([0-9]+)/.*|\1|')
  stored=$("$imucal" --server "$addr" session show "$session" --json |
           python3 -c 'import json, sys; print(json.load(sys.stdin)["samples"])')
  [[ "$stored" == "$total" ]] || fail "the session holds $stored samples of the capture's $total"
}

# 1. A clean six-face session, the robot streaming as it captures.
run_guided 1 robot-tmux capture.csv paced
expect_upload 1
expect guide1 "NEXT:" "no next-pose instruction"
expect guide1 "progress:" "no progress line"
expect guide1 "[ok]   pose" "no accepted pose"
expect guide1 "protocol complete: waiting for the robot's upload to finish before solving" \
  "the guide did not say that it waits for the upload"
expect_re guide1 "^upload complete: starting the solve \(job solve-[0-9]+\) on $total samples" \
  "the guide did not solve the whole capture after the upload"
expect guide1 "RESULT: version" "no solve result"
exit_code guide1 GUIDE
[[ "$code" == 0 ]] || fail "the guide's exit code was $code, not 0"
if [[ -n "${GUIDE_TMUX_SHOW:-}" ]]; then pane guide1; pane robot1; fi

# 2. A failed pair and its re-do: the guide must reject the pair with the reason, ask for the
# re-do, accept the re-done pair, go on to the last face, and finish with a result.
run_guided 2 robot-botch botched.csv short
expect_upload 2
expect guide2 "[redo] pair Z+ (poses 0, 1) FAILED: turned" "no failed-pair verdict with its reason"
expect guide2 "-> REDO Z+" "no re-do prompt under the failed pair"
expect guide2 "NEXT: Pair Z+ failed (turned" "the next-pose guidance does not ask for the re-do"
expect guide2 "[ok]   pair Z+ (poses 0, 2)" "the re-done pair was not accepted"
expect guide2 "[ok]   pair X- " "the session did not go on to the last face"
expect guide2 "RESULT: version" "no solve result after the re-do"
exit_code guide2 GUIDE
[[ "$code" == 0 ]] || fail "the guide's exit code was $code, not 0"
if [[ -n "${GUIDE_TMUX_SHOW:-}" ]]; then pane guide2; pane robot2; fi
echo "PASS: guide_tmux_test"
