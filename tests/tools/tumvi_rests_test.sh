#!/usr/bin/env bash
# A rest is a rest, on real hand-held captures: `imucal calibrate` on the six TUM-VI room
# recordings (a BMI160 carried by hand, 41-88 deg/s on average, with motion-capture orientation;
# ../shared/data/real/tumvi-room), and every pose it uses or lists as a rest checked against the
# motion capture by tests/tools/rests_vs_mocap.py: the reference may turn at most 3 degrees
# through it (a hand's tremor) plus 5 deg/s (a drift as slow as an unknown bias can hide: these
# walks hold at most one rest, so nothing learns the bias), where a turn taken for a rest turns
# tens of degrees (the detector before issue 24: up to 180 degrees in 11 s). The
# calibration itself may pass, fail or be refused (a hand-held walk is no calibration capture);
# only the rests are judged. Skips (exit 0, "SKIP") without the data or python3.
# usage: tumvi_rests_test.sh IMUCAL SHARED_REAL_DIR
set -uo pipefail
(($# == 2)) || { echo "usage: $0 IMUCAL SHARED_REAL_DIR"; exit 1; }
imucal=$1
data=$2/tumvi-room
here=$(cd "$(dirname "$0")" && pwd)
command -v python3 >/dev/null || { echo "SKIP: python3 not installed"; exit 0; }
[[ -d $data ]] || { echo "SKIP: no $data"; exit 0; }
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
cols="t=Time,gx=angular_velocity.x,gy=angular_velocity.y,gz=angular_velocity.z"
cols+=",ax=linear_acceleration.x,ay=linear_acceleration.y,az=linear_acceleration.z"
failed=0
for room in 1 2 3 4 5 6; do
  rc=0
  "$imucal" calibrate "$data/room$room.csv" --columns "$cols" --time-unit s \
    --accel-unit m/s^2 --gyro-unit rad/s --json --out "$dir/room$room.json" \
    >"$dir/room$room.out" 2>"$dir/room$room.err" || rc=$?
  if [[ $rc -ne 0 && $rc -ne 3 && $rc -ne 4 ]] || [[ ! -s $dir/room$room.json ]]; then
    echo "room$room: exit $rc, no report: $(head -c 400 "$dir/room$room.err")"
    failed=1
    continue
  fi
  echo "room$room (exit $rc):"
  python3 "$here/rests_vs_mocap.py" "$dir/room$room.json" "$data/room${room}_gt.csv" || failed=1
done
((failed)) && { echo "FAIL"; exit 1; }
echo "PASS: 6 rooms"
