#!/usr/bin/env bash
# `imucal calibrate` end to end on the classes of capture people record, written by an
# independent writer (tests/tools/write_columns.py over imu_sim.py: standard library only,
# nothing from imucal): quantised sensors, no noise at all, turns about the vertical at a steady
# rate, six faces held once in six files, a duplicated face, a rest noisier than the others,
# stops shorter than the 1 s hold, a commented header, a NUL byte in a field, and temperature
# quadratics with a turnover, validated on a second capture with another temperature history,
# a gyro bias that moves each time the unit is moved, and a rate-dependent gyroscope scale,
# validated on the moves of a second capture; and files others write: accelerometer-only,
# an interleaved log with rows of empty fields, a quoted free-text column.
# Asserts only what the README ("Calibrate a capture of your own": exit 0 pass/warn, 2 bad input, 3 refused, 4 fail)
# and ../shared/spec/report.md promise: exit codes, the report's verdict and poses (file and
# lines for a capture from several files; a refusal still writes the report), the number of
# poses used, and the parameters against the writer's truth.json within tolerances derived from
# the simulated noise and quantisation (tests/tools/capture_checks.py says how). Message texts
# are not compared, beyond a refusal for short stops saying "too short" and a control byte being
# shown as \0.
# Runs every case and lists the failed ones. Skips (exit 0, "SKIP") without python3.
# usage: capture_classes_test.sh IMUCAL [CASE...]   (CASE: a name from the list below)
set -uo pipefail
(($# >= 1)) || { echo "usage: $0 IMUCAL [CASE...]"; exit 1; }
imucal=$1
shift
here=$(cd "$(dirname "$0")" && pwd)
command -v python3 >/dev/null || { echo "SKIP: python3 not installed"; exit 0; }

dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
export PYTHONDONTWRITEBYTECODE=1

# write NAME ARGS...: write_columns.py into $dir/NAME (stdout: the files written, in order).
write() {
  local name=$1; shift
  python3 "$here/write_columns.py" "$dir/$name" "$@" >"$dir/$name.files" ||
    { echo "  writer failed: $*"; return 1; }
}
# files NAME: the files write_columns wrote, in capture order.
files() { cat "$dir/$1.files"; }
# columns NAME: the --columns value naming the writer's header.
columns() { python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["columns_option"])' \
  "$dir/$1/truth.json"; }
# run NAME ARGS...: imucal calibrate ARGS, stdout to $dir/NAME.out, stderr to $dir/NAME.err;
# the report to $dir/NAME.json (--json --out); sets rc.
run() {
  local name=$1; shift
  rc=0
  "$imucal" calibrate "$@" --json --out "$dir/$name.json" >"$dir/$name.out" 2>"$dir/$name.err" ||
    rc=$?
}
checks() { python3 "$here/capture_checks.py" "$@"; }
# first_sentence NAME PATTERN...: the refusal's first sentence (stderr's first line that is not a
# note, up to its first ". ") matches every PATTERN (extended regex): it names the problem.
first_sentence() {
  local name=$1; shift
  local line p
  line=$(grep -v '^imucal: note:' "$dir/$name.err" | head -1)
  line=${line%%. *}
  for p in "$@"; do
    grep -qE -- "$p" <<<"$line" || { echo "  first sentence lacks /$p/: $line"; return 1; }
  done
  echo "  first sentence: ${line:0:160}"
}
# want_rc NAME CODES...: the exit code is one of CODES, and the report was written.
want_rc() {
  local name=$1; shift
  local c
  for c in "$@"; do
    if [[ $rc -eq $c ]]; then
      [[ -s "$dir/$name.json" ]] || { echo "  exit $rc but no report at --out"; return 1; }
      return 0
    fi
  done
  echo "  exit $rc, want $*: $(tail -c 600 "$dir/$name.err")"
  return 1
}

# Quantised coarsely: the gyroscope in steps of 0.01 rad/s and the accelerometer in steps of
# 0.01 m/s^2, both without noise (every axis constant through every rest: the noise learnt from
# a rest is zero). All 16 poses must be found and calibrated.
case_quantised_si() {
  write q1 --seed 11 --accel-step 0.01 --accel-noise 0 --gyro-step 0.01 --gyro-noise 0 ||
    return 1
  run q1 "$(files q1)" --columns "$(columns q1)" --time-unit us
  want_rc q1 0 && checks params "$dir/q1.json" "$dir/q1/truth.json"
}

# Quantised in raw counts, an MPU-6050 at +-2 g and +-250 deg/s (1/16384 g, 1/131 deg/s per
# count): the accelerometer's noise (0.02 m/s^2) spans many counts, the gyroscope's (0.00005
# rad/s) is below one count, so one sensor is quantised coarsely and the other is not.
case_quantised_counts() {
  write q2 --seed 12 --counts --accel-step 1/16384g --accel-noise 0.02 \
    --gyro-step 1/131deg --gyro-noise 0.00005 || return 1
  run q2 "$(files q2)" --columns "$(columns q2)" --time-unit us --accel-unit counts \
    --gyro-unit counts
  want_rc q2 0 && checks params "$dir/q2.json" "$dir/q2/truth.json"
}

# Six faces once, one file per face, each held 28-37 s, the gyroscope quantised to 0.01 rad/s
# without noise (a hobbyist's quantised unit).
case_quantised_faces() {
  write q3 --seed 13 --protocol faces-once --split pose --first-hold-s 30 --hold-range-s 28,37 \
    --floor-tilt-deg 0 --accel-noise 0.004 --gyro-step 0.01 --gyro-noise 0 || return 1
  mapfile -t f < <(files q3)
  run q3 "${f[@]}" --columns "$(columns q3)" --time-unit us
  want_rc q3 0 && checks params "$dir/q3.json" "$dir/q3/truth.json" --verdict warn \
    --faces-once --gyro bias --multi-file
}

# No noise at all, as the imucal capture CSV of the capture-format spec.
case_noise_free() {
  write n1 --seed 14 --format imucal --no-noise || return 1
  run n1 "$(files n1)"
  want_rc n1 0 && checks params "$dir/n1.json" "$dir/n1/truth.json"
}

# A quiet sensor (a tenth of the default noise: 0.002 m/s^2, 0.0004 rad/s per sample), no
# effect simulated, no quadratic term: the parameters must be the simulated ones within the
# tolerances this noise allows (a model term the data do not need must not move them).
case_low_noise() {
  write l1 --seed 14 --accel-noise 0.002 --gyro-noise 0.0004 || return 1
  run l1 "$(files l1)" --columns "$(columns l1)" --time-unit us
  want_rc l1 0 && checks params "$dir/l1.json" "$dir/l1/truth.json"
}

# Turns about the vertical at a steady rate on a level floor (the accelerometer does not change
# through a turn, the gyroscope is constant mid-turn), no effect simulated, at 20, 50, 96, 100
# and 200 deg/s (issue 24): must pass, no pose inside a turn (however slow: a 180-degree turn at
# 20 deg/s is 9 s of steady rate), the gyroscope's fit unharmed: its bias within 0.02 deg/s of
# the truth on every axis, and the noise-derived limits of `checks steady`. From 96 deg/s on,
# also the gravity direction after the moves within 0.06 deg RMS (the issue's aim; a 9 s turn at
# 20 deg/s integrates 0.07 deg of this gyroscope's noise on its own, so there the noise decides).
steady_case() {
  local name=$1 rate=$2 seed=$3
  shift 3
  write "$name" --seed "$seed" --turn-profile steady --turn-rate-deg-s "$rate" \
    --floor-tilt-deg 0 || return 1
  run "$name" "$(files "$name")" --columns "$(columns "$name")" --time-unit us
  want_rc "$name" 0 &&
    checks rests "$dir/$name.json" "$dir/$name/truth.json" &&
    checks steady "$dir/$name.json" "$dir/$name/truth.json" --verdict pass \
      --bias-aim-deg-s 0.02 "$@" &&
    checks params "$dir/$name.json" "$dir/$name/truth.json" --verdict pass
}
case_steady_turns() { steady_case s1 96 15 --gravity-aim-deg 0.06; }
case_steady_turns_20() { steady_case s20 20 40; }
case_steady_turns_50() { steady_case s50 50 41; }
case_steady_turns_100() { steady_case s100 100 42 --gravity-aim-deg 0.06; }
case_steady_turns_200() { steady_case s200 200 45 --gravity-aim-deg 0.06; }

# Held by hand (issue 24): a tremor on every hold and move (0.1 deg RMS per axis at 6-11 Hz:
# the gyroscope shakes by about 6 deg/s RMS: the learnt threshold takes a slow turn), and after
# every fifth pose a slow steady turn about the vertical at 24-41 deg/s, by 360 degrees (back to
# the same orientation) or 49. No used pose may lie in a turn; the capture still calibrates.
case_hand_held_turns() {
  write hh --seed 44 --protocol random --poses 30 --hand-tremor-deg 0.1 --slow-turn-every 5 \
    --slow-turn-angles-deg 360,360,49 || return 1
  run hh "$(files hh)" --columns "$(columns hh)" --time-unit us
  want_rc hh 0 4 && checks rests "$dir/hh.json" "$dir/hh/truth.json"
}

# A rotation table (issue 24): six-face pairs held 45 s each, the 180-degree turns at a steady
# 20 deg/s, and the table's servo buzzing in bursts through every hold (10x the noise, 0.3-1.2 s
# every 2-5 s). Each rest is one pose over most of it (never cut in pieces), every pair judged.
case_table_rests() {
  write tb --seed 45 --first-hold-s 45 --hold-s 45 --turn-profile steady --turn-rate-deg-s 20 \
    --hold-bursts 10 || return 1
  run tb "$(files tb)" --columns "$(columns tb)" --time-unit us
  want_rc tb 0 && checks rests "$dir/tb.json" "$dir/tb/truth.json" --one-per-hold 30 &&
    checks params "$dir/tb.json" "$dir/tb/truth.json"
}

# Per-file noise floors (issue 24): six files, one face each, the noise of every other file 5x
# the others' (a noisier support, another range setting). The thresholds are learnt per file:
# every file's rest is found and used.
case_file_noise_floors() {
  write nf --seed 46 --protocol faces-once --split pose --floor-tilt-deg 0 \
    --hold-noise-factors 1,5 || return 1
  mapfile -t f < <(files nf)
  run nf "${f[@]}" --columns "$(columns nf)" --time-unit us
  want_rc nf 0 && checks rests "$dir/nf.json" "$dir/nf/truth.json" --per-file &&
    checks params "$dir/nf.json" "$dir/nf/truth.json" --verdict warn --faces-once --gyro bias \
      --multi-file
}

# The hobbyist's capture: six files, one per face, each face once, given together; each file
# with its own header, time restarting at 0; the floor tilted 0.2 degrees. Calibrated by the
# 12-parameter least squares with the floor assumed level: verdict warn, saying so.
case_faces_files() {
  write p1 --seed 16 --protocol faces-once --split pose --floor-tilt-deg 0.2 || return 1
  mapfile -t f < <(files p1)
  run p1 "${f[@]}" --columns "$(columns p1)" --time-unit us
  want_rc p1 0 || return 1
  checks params "$dir/p1.json" "$dir/p1/truth.json" --verdict warn --faces-once --gyro bias \
    --multi-file &&
    checks files "$dir/p1.json" "$dir/p1/truth.json" --verdict warn &&
    python3 - "$dir/p1.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
errors = []
if "ls" not in [s.get("name") for s in r.get("stages", [])]:
    errors.append(f"no 'ls' stage (the 12-parameter least squares): {r.get('stages')}")
if not any("level" in w for w in r.get("warnings", [])):
    errors.append("no warning says the floor was assumed level")
print("\n".join("  " + e for e in errors) or "  ls stage, floor assumed level")
sys.exit(1 if errors else 0)
PY
}

# The same as imucal capture CSVs (the spec's format), one per face, on an absolute time base
# (Unix time: the gaps between the files are the unrecorded moves).
case_faces_files_imucal() {
  write p2 --seed 17 --format imucal --protocol faces-once --split pose --time-base absolute \
    --floor-tilt-deg 0.2 || return 1
  mapfile -t f < <(files p2)
  run p2 "${f[@]}"
  want_rc p2 0 &&
    checks params "$dir/p2.json" "$dir/p2/truth.json" --verdict warn --faces-once --gyro bias \
      --multi-file &&
    checks files "$dir/p2.json" "$dir/p2/truth.json" --verdict warn
}

# Six faces once in one file, the moves between them recorded (the gyroscope's scale is not
# asserted: six faces once promise the accelerometer's 12 parameters).
case_faces_once() {
  write f1 --seed 18 --protocol faces-once --floor-tilt-deg 0.2 || return 1
  run f1 "$(files f1)" --columns "$(columns f1)" --time-unit us
  want_rc f1 0 &&
    checks params "$dir/f1.json" "$dir/f1/truth.json" --verdict warn --faces-once --gyro bias
}

# A duplicated face: the file for +Z holds -Z's orientation, 0.005 degrees apart. Refused, or
# calibrated with verdict warn; either way the report's reasons or stderr name both files and
# the missing face.
case_duplicate_face() {
  write d1 --seed 19 --protocol faces-once --split pose --duplicate-face Z+=Z- || return 1
  mapfile -t f < <(files d1)
  run d1 "${f[@]}" --columns "$(columns d1)" --time-unit us
  want_rc d1 0 3 || return 1
  local verdict=refused
  [[ $rc -eq 0 ]] && verdict=warn
  if [[ $rc -eq 3 ]]; then
    first_sentence d1 'imu_posZ\.csv' 'imu_negZ\.csv' 'same orientation' 'Z\+ up' || return 1
  fi
  checks names "$dir/d1.json" --verdict $verdict --stderr "$dir/d1.err" \
    --want imu_posZ.csv --want imu_negZ.csv --want '+Z|Z+' &&
    checks files "$dir/d1.json" "$dir/d1/truth.json" --verdict $verdict
}

# Six-face pairs with X+ and X- held once (issue 24): those poses alone determine part of the
# model, so their held-out residuals are large whatever the fit. Not a failed fit: warn, saying
# which poses are held once and that the others predict each other; the parameters within the
# truth's tolerances. Never "the fit explains its own poses".
case_faces_held_once() {
  write fo --seed 47 --single-faces X+,X- || return 1
  run fo "$(files fo)" --columns "$(columns fo)" --time-unit us
  want_rc fo 0 || return 1
  checks params "$dir/fo.json" "$dir/fo/truth.json" --verdict warn || return 1
  python3 - "$dir/fo.json" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
reasons = r.get("verdict_reasons", [])
said = [w for w in reasons if "held once" in w]
bad = []
if not said or not all(f in said[0] for f in ("X+", "X-")):
    bad.append(f"no reason names X+ and X- as held once: {reasons}")
if any("explains its own poses" in w for w in reasons):
    bad.append(f"a reason blames the fit: {reasons}")
print("\n".join("  " + b for b in bad) or "  " + said[0][:120])
sys.exit(1 if bad else 0)
PY
}

# A rest noisier than the others stays one pose: a 7 s hold (the first of the Z- pair) with a
# hand pressing on the unit now and then (5x the noise RMS), a motor running (a vibration of 8x
# the noise RMS), or a sensor settling (5x the noise RMS, dying away, its mean converging
# exponentially, 0.1 mg on average from the end).
noisy_case() {
  local name=$1 kind=$2 factor=$3 seed=$4
  write "$name" --seed "$seed" --noisy-rest 6 --noisy-rest-kind "$kind" --noisy-rest-s 7 \
    --noisy-rest-factor "$factor" || return 1
  run "$name" "$(files "$name")" --columns "$(columns "$name")" --time-unit us
  want_rc "$name" 0 &&
    checks noisy "$dir/$name.json" "$dir/$name/truth.json" &&
    checks params "$dir/$name.json" "$dir/$name/truth.json"
}
case_noisy_rest_hand() { noisy_case r1 hand 5 20; }
case_noisy_rest_motor() { noisy_case r2 motor 8 21; }
case_noisy_rest_settling() { noisy_case r3 settling 5 22; }

# Stops too short: an IMU-TK style capture, a 10 s rest then 40 stops of 0.3-0.8 s; and the
# same with the first stop as short. Refused (exit 3), saying the stops are too short, and the
# refusal still writes the report with every pose and why it is not used.
short_case() {
  local name=$1 first=$2 seed=$3
  write "$name" --seed "$seed" --protocol random --poses 40 --first-hold-s "$first" \
    --hold-range-s 0.3,0.8 || return 1
  run "$name" "$(files "$name")" --columns "$(columns "$name")" --time-unit us
  want_rc "$name" 3 || return 1
  first_sentence "$name" 'too short' 'hold each pose' || return 1
  checks refused "$dir/$name.json" --verdict refused
}
case_short_stops() { short_case g1 10 23; }
case_short_stops_all() { short_case g2 0.6 24; }

# A commented header line (# time ax ay az gx gy gz), space-delimited, named with --columns.
case_commented_header() {
  write h1 --seed 25 --commented-header --delimiter space --time-unit s \
    --header time,ax,ay,az,gx,gy,gz || return 1
  run h1 "$(files h1)" --columns "$(columns h1)" --time-unit s
  want_rc h1 0 && checks params "$dir/h1.json" "$dir/h1/truth.json"
}

# A NUL byte at the start of line 2's time field: bad input (exit 2) naming the file and line,
# the byte shown as \0 and the message not cut off by it.
case_nul_byte() {
  write z1 --seed 26 --nul-at 2 || return 1
  rc=0
  "$imucal" calibrate "$(files z1)" --columns "$(columns z1)" --time-unit us \
    >"$dir/z1.out" 2>"$dir/z1.err" || rc=$?
  [[ $rc -eq 2 ]] || { echo "  exit $rc, want 2: $(head -c 600 "$dir/z1.err")"; return 1; }
  local err
  err=$(tr '\0' '@' <"$dir/z1.err")
  [[ $(tr -d '\0' <"$dir/z1.err" | wc -c) -eq $(wc -c <"$dir/z1.err") ]] ||
    { echo "  stderr holds a raw NUL: $err"; return 1; }
  grep -qF '\0' "$dir/z1.err" ||
    { printf '  the byte is not shown as \\0: %s\n' "$err"; return 1; }
  # The field goes on after the byte (its value was "\0" then "0"): the message is not cut.
  grep -qE '\\0[^[:space:]]' "$dir/z1.err" ||
    { echo "  the message stops at the byte: $err"; return 1; }
  grep -qE 'imu\.csv(:2\b|.*line 2\b)' "$dir/z1.err" ||
    { echo "  the message does not name imu.csv and line 2: $err"; return 1; }
  echo "  $(head -1 "$dir/z1.err")"
}

# Temperature quadratics with a turnover, from the independent simulator: a gyroscope x bias of
# 0.002 deg/s/degC^2 and an accelerometer z bias of 0.02 mg/degC^2, both about 30 degC, in the
# true rate and specific force, over a warm-up from 22 to 42 degC (60 s time constant) in an
# IMU-TK style capture of 40 stops (six faces and four extra poses leave too few degrees of
# freedom beyond the accelerometer's model for a two-term effect). Each must be found in its
# centred form ((temperature-R) with (temperature-R)^2, R the parameter set's effect_reference)
# within 3 standard errors, and hold on a second capture of the same unit whose temperature
# falls linearly from 40 to 24 degC: `imucal apply` of the report leaves its holds under half
# the error the model without its effects leaves, and within 3 times the error the truth itself
# leaves (the truth's is the holds' noise alone; the calibration adds its own parameter errors,
# the effect's coefficients within their standard errors among them: 1.04-2.3 times on seeds
# 27-81 of this case. The bench compares with a reference fit given the true form instead).
case_temperature_turnover() {
  local quads=(--gyro-temp-quad x,3.4906585e-5,30 --accel-temp-quad z,1.96133e-4,30)
  local shape=(--format imucal --protocol random --poses 40)
  write t1 --seed 27 "${shape[@]}" --temp-history warmup:22,42,60 "${quads[@]}" || return 1
  write t2 --seed 28 "${shape[@]}" --temp-history ramp:40,24 "${quads[@]}" || return 1
  run t1 "$(files t1)"
  want_rc t1 0 || return 1
  "$imucal" apply --params "$dir/t1.json" "$(files t2)" "$dir/t2.applied.csv" >/dev/null \
    2>"$dir/t2.apply.err" || { echo "  apply failed: $(cat "$dir/t2.apply.err")"; return 1; }
  python3 -c 'import json,sys; r=json.load(open(sys.argv[1])); p=r["parameters"]
p["effects"]=[]; p.pop("effect_reference",None); json.dump(p,open(sys.argv[2],"w"))' \
    "$dir/t1.json" "$dir/t1.without.json" || return 1
  "$imucal" apply --params "$dir/t1.without.json" "$(files t2)" "$dir/t2.without.csv" \
    >/dev/null 2>"$dir/t2.apply.err" || { echo "  apply failed: $(cat "$dir/t2.apply.err")"; return 1; }
  checks effects "$dir/t1.json" "$dir/t1/truth.json" --val-truth "$dir/t2/truth.json" \
    --val-raw "$(files t2)" --applied "$dir/t2.applied.csv" \
    --applied-without "$dir/t2.without.csv" --ratio 3
}

# A gyro bias that moves each time the unit is moved and holds while it rests (what the
# imutk-ros2-repeat captures show): the report's gyro_wander must name a new offset per pose on
# every axis, of the size the writer drew (the realised offsets' scatter, within 15%), say that
# the bias holds within the poses, and predict nothing from the neighbouring poses; the same
# capture without the offsets must leave no wander on at least two axes.
case_gyro_bias_shift() {
  local shape=(--format imucal --protocol random --poses 40 --gyro-noise 5e-4)
  write s1 --seed 31 "${shape[@]}" --gyro-bias-shift 7e-4 || return 1
  write s0 --seed 31 "${shape[@]}" || return 1
  run s1 "$(files s1)"
  want_rc s1 0 || return 1
  run s0 "$(files s0)"
  want_rc s0 0 || return 1
  python3 - "$dir/s1.json" "$dir/s1/truth.json" "$dir/s0.json" <<'PY'
import json, math, sys
r, t, r0 = (json.load(open(p)) for p in sys.argv[1:4])
w, w0 = r["gyro_wander"], r0["gyro_wander"]
holds = t["gyro_bias_shift"]["per_hold_rad_s"]
bad = []
for a in range(3):
    vals = [h[a] for h in holds]
    m = sum(vals) / len(vals)
    sd = math.sqrt(sum((v - m) ** 2 for v in vals) / (len(vals) - 1))
    ax = w["axes"][a]
    if ax["model"] not in ("shift", "shift+walk"):
        bad.append(f"axis {a}: model {ax['model']}, want shift")
    if abs(ax["shift"] / sd - 1) > 0.15:
        bad.append(f"axis {a}: shift {ax['shift']:.3g} rad/s, the offsets drawn scatter {sd:.3g}")
if not w["within_pose_ratio"] < 1.3:
    bad.append(f"within-pose ratio {w['within_pose_ratio']:.2f}, want < 1.3")
if not w["drift_within_pose_ratio"] > 2:
    bad.append(f"a drift would give {w['drift_within_pose_ratio']:.2f}, want > 2")
if not w["heldout_after"] > 0.9 * w["heldout_before"]:
    bad.append(f"held out {w['heldout_before']:.3g} -> {w['heldout_after']:.3g}: predicted?")
if sum(a["model"] == "none" for a in w0["axes"]) < 2:
    bad.append("without the offsets: " + ", ".join(a["model"] for a in w0["axes"]))
for b in bad:
    print("  " + b)
sys.exit(1 if bad else 0)
PY
}

# A rate-dependent gyroscope scale, which only the moves show: the z rate reads 1 + S |w| times
# the true one, S = 0.001 per rad/s (0.17 % more per 100 deg/s), on 40 random stops reached by
# hand-fast moves (90-180 degrees in 0.7 s, up to 500 deg/s). The term is found (gyro z ~
# gz*|gz|, within 3 standard errors), validated on another capture of the same sensor through
# `imucal apply` (the gravity direction after its moves, against the truth's and against the
# parameters without the term), and a capture of the same shape without it finds none.
case_rate_scale() {
  local shape=(--format imucal --protocol random --poses 40 --move-s 0.7
    --move-angle-range-deg 90,180)
  write s1 --seed 31 "${shape[@]}" --gyro-rate-scale z,0.001 || return 1
  write s2 --seed 32 "${shape[@]}" --gyro-rate-scale z,0.001 || return 1
  write s3 --seed 33 "${shape[@]}" || return 1
  run s1 "$(files s1)"
  want_rc s1 0 || return 1
  run s3 "$(files s3)"
  want_rc s3 0 || return 1
  "$imucal" apply --params "$dir/s1.json" "$(files s2)" "$dir/s2.applied.csv" >/dev/null \
    2>"$dir/s2.apply.err" || { echo "  apply failed: $(cat "$dir/s2.apply.err")"; return 1; }
  python3 -c 'import json,sys,re; r=json.load(open(sys.argv[1])); p=r["parameters"]
p["effects"]=[e for e in p["effects"] if not re.search("g[xyz]", e["regressor"])]
json.dump(p,open(sys.argv[2],"w"))' "$dir/s1.json" "$dir/s1.without.json" || return 1
  "$imucal" apply --params "$dir/s1.without.json" "$(files s2)" "$dir/s2.without.csv" \
    >/dev/null 2>"$dir/s2.apply.err" || { echo "  apply failed: $(cat "$dir/s2.apply.err")"; return 1; }
  checks rates "$dir/s1.json" "$dir/s1/truth.json" --val-truth "$dir/s2/truth.json" \
    --val-raw "$(files s2)" --applied "$dir/s2.applied.csv" \
    --applied-without "$dir/s2.without.csv" --clean "$dir/s3.json" --ratio 1.5
}

# The report's figures are the final parameter set's, as a robot applies it: the gravity
# direction after the moves, recomputed by capture_checks.py from `imucal apply`'s samples alone.
# On a simulated capture with steady turns, and on a real one (Xsens, whose gyroscope's
# g-sensitivity the effects stage adds: the fit's own figure, before it, is twice as large).
case_final_figures() {
  write f1 --seed 27 || return 1
  run f1 "$(files f1)" --columns "$(columns f1)" --time-unit us
  want_rc f1 0 || return 1
  "$imucal" apply --params "$dir/f1.json" "$(files f1)" "$dir/f1.applied.csv" \
    --columns "$(columns f1)" --time-unit us 2>"$dir/f1.apply.err" ||
    { echo "  apply failed: $(cat "$dir/f1.apply.err")"; return 1; }
  checks final "$dir/f1.json" --applied "$dir/f1.applied.csv" || return 1
  local x="$here/../../../shared/data/real/xsens-imutk"
  [[ -d $x ]] || { echo "  no $x: the real capture is not checked"; return 0; }
  run x1 "$x/xsens_acc.mat" "$x/xsens_gyro.mat"
  want_rc x1 0 || return 1
  "$imucal" apply --params "$dir/x1.json" "$x/xsens_acc.mat" "$x/xsens_gyro.mat" \
    "$dir/x1.applied.csv" 2>"$dir/x1.apply.err" ||
    { echo "  apply failed: $(cat "$dir/x1.apply.err")"; return 1; }
  checks final "$dir/x1.json" --applied "$dir/x1.applied.csv"
}

# A gyroscope written in deg/s with no unit given (a vendor's CSV): the unit is inferred from the
# moves (the rates integrated between rests against the accelerometer's turn of gravity), the
# report's input_units records gyro deg/s inferred, and the gyro matrix is the writer's scale
# times pi/180 rad/s per deg/s (within 1%).
case_gyro_deg_s() {
  write u1 --seed 41 --gyro-unit deg/s || return 1
  run u1 "$(files u1)" --columns "$(columns u1)" --time-unit us
  want_rc u1 0 || return 1
  python3 - "$dir/u1.json" "$dir/u1/truth.json" <<'PY'
import json, math, sys
r, t = (json.load(open(p)) for p in sys.argv[1:3])
bad = []
u = r.get("input_units", {})
if u.get("gyro") != "deg/s" or u.get("gyro_source") != "inferred":
    bad.append(f"input_units {u}, want gyro deg/s inferred")
m = r["parameters"]["gyro"]["matrix"]
for j in range(3):
    want = t["gyro_scale"][j] * math.pi / 180
    if abs(m[j][j] / want - 1) > 0.01:
        bad.append(f"gyro matrix ({j},{j}) {m[j][j]:.6g}, want {want:.6g} rad/s per deg/s")
print("\n".join("  " + b for b in bad) or f"  gyro deg/s inferred, matrix diagonal within 1%")
sys.exit(1 if bad else 0)
PY
}

# Data in m/s^2 declared --accel-unit g: refused (exit 3, unit_mismatch), the first sentence of
# stderr names the unit the data look like (m/s^2). Before, it passed and exported Ta ~ 9.7.
case_wrong_declared_unit() {
  write u2 --seed 42 || return 1
  run u2 "$(files u2)" --columns "$(columns u2)" --time-unit us --accel-unit g
  want_rc u2 3 || return 1
  local first
  first=$(head -1 "$dir/u2.err" | sed 's/^imucal: //; s/\. .*//')
  [[ $first == *"m/s^2"* && $first == *"--accel-unit g"* ]] ||
    { echo "  stderr's first sentence does not name m/s^2 and --accel-unit g: $first"; return 1; }
  grep -q '"unit_mismatch"' "$dir/u2.json" || { echo "  refusal.reason is not unit_mismatch"; return 1; }
  echo "  $first"
}

# `imucal noise` on a calibration capture (moves between 3 s holds, a 10 s first rest): refused
# with "the record is not at rest", or its longest rest used and said; never the moving figures
# (the gyro white-noise density within 30% of the writer's).
case_noise_moving() {
  write m1 --seed 43 --format imucal || return 1
  rc=0
  "$imucal" noise "$(files m1)" --json >"$dir/m1.out" 2>"$dir/m1.err" || rc=$?
  if [[ $rc -eq 3 ]]; then
    grep -q '^imucal: the record is not at rest' "$dir/m1.err" ||
      { echo "  exit 3, but stderr does not start 'the record is not at rest': $(head -c 300 "$dir/m1.err")"; return 1; }
    echo "  refused: $(head -c 160 "$dir/m1.err")"
    return 0
  fi
  [[ $rc -eq 0 ]] || { echo "  exit $rc: $(head -c 300 "$dir/m1.err")"; return 1; }
  python3 - "$dir/m1.out" "$dir/m1/truth.json" <<'PY'
import json, math, sys
r, t = (json.load(open(p)) for p in sys.argv[1:3])
want = t["gyro_noise_rad_s"] / math.sqrt(t["rate_hz"])
bad = []
rest = r.get("rest", {"whole": True, "note": ""})
if rest["whole"] or "rest" not in rest["note"]:
    bad.append(f"the moves were not cut, or not said: {rest}")
for a in ("gyro_x", "gyro_y", "gyro_z"):
    n = r["axes"][a]["noise_density"]["value"]
    if n is None or abs(n / want - 1) > 0.3:
        bad.append(f"{a} N {n}, want {want:.3g}")
print("\n".join("  " + b for b in bad) or "  longest rest used and said")
sys.exit(1 if bad else 0)
PY
}

# A 40-minute rest with bias random walks (K reached within minutes), and the same rest with 10 s
# of handling 40% in (picked up, put down 2 degrees off): every figure (N, B, K, bounds too) of
# the handled rest within 20% of the untouched one's, and the output (text, --json, noise.json)
# says how much was cut.
case_noise_handling() {
  local shape=(--seed 44 --format imucal --protocol rest --first-hold-s 2400
    --gyro-random-walk 7e-5 --accel-random-walk 3.5e-4)
  write n0 "${shape[@]}" || return 1
  write n1 "${shape[@]}" --handling-s 10 || return 1
  local n
  for n in n0 n1; do
    "$imucal" noise "$(files $n)" --json --out "$dir/$n.dir" >"$dir/$n.out" 2>"$dir/$n.err" ||
      { echo "  noise $n failed: $(head -c 300 "$dir/$n.err")"; return 1; }
  done
  "$imucal" noise "$(files n1)" >"$dir/n1.txt" 2>&1 || { echo "  text run failed"; return 1; }
  grep -q "cut" "$dir/n1.txt" || { echo "  the text output does not say what was cut"; return 1; }
  python3 - "$dir/n0.out" "$dir/n1.out" "$dir/n1.dir/noise.json" <<'PY'
import json, sys
r0, r1, f1 = (json.load(open(p)) for p in sys.argv[1:4])
bad = []
for r in (r1, f1):
    rest = r.get("rest", {"whole": True, "cut_s": 0, "note": ""})
    if rest["whole"] or not 5 <= rest["cut_s"] <= 30 or "cut" not in rest["note"]:
        bad.append(f"the handling is not said to be cut: {rest}")
worst = 0
for a, v0 in r0["axes"].items():
    for fig, x0 in v0.items():
        a0, a1 = x0["value"], r1["axes"][a][fig]["value"]
        if a0 is None or a1 is None:
            bad.append(f"{a} {fig}: {a0} vs {a1}")
            continue
        worst = max(worst, abs(a1 / a0 - 1))
        if abs(a1 / a0 - 1) > 0.2:
            bad.append(f"{a} {fig}: {a1:.4g} with handling, {a0:.4g} without")
print("\n".join("  " + b for b in bad) or
      f"  {r1['rest']['cut_s']:.1f} s cut; figures within {100 * worst:.1f}% of the untouched rest")
sys.exit(1 if bad else 0)
PY
}

# A gyroscope quantised to 0.01 rad/s with noise far below the step (5e-4 rad/s): the axes whose
# bias sits far from a rounding edge read one value through every rest. Their reported bias
# standard error must not sit below the grid's own rounding, step/sqrt(12) (0.9 of it allowed).
case_quantised_stuck() {
  write k1 --seed 45 --gyro-step 0.01 --gyro-noise 0.0005 || return 1
  run k1 "$(files k1)" --columns "$(columns k1)" --time-unit us
  want_rc k1 0 || return 1
  python3 - "$dir/k1.json" "$dir/k1/truth.json" <<'PY'
import json, math, sys
r, t = (json.load(open(p)) for p in sys.argv[1:3])
step, noise = t["gyro_step_rad_s"], t["gyro_noise_rad_s"]
se = r["parameters"]["gyro"]["stderr"]["bias"]
bad, stuck = [], []
for j, b in enumerate(t["gyro_bias_rad_s"]):
    to_edge = abs(abs(b / step - round(b / step)) - 0.5) * step
    if to_edge < 5 * noise:
        continue  # the noise flips it across the edge: dithered, no floor to check
    stuck.append("xyz"[j])
    if not se[j] >= 0.9 * step / math.sqrt(12):
        bad.append(f"gyro {'xyz'[j]} bias stderr {se[j]:.3g}, below {step / math.sqrt(12):.3g}")
if not stuck:
    bad.append("no axis is stuck: the case checks nothing")
print("\n".join("  " + b for b in bad) or
      f"  stuck axes {', '.join(stuck)}: bias stderr >= step/sqrt(12) = {step / math.sqrt(12):.3g}")
sys.exit(1 if bad else 0)
PY
}

# An accelerometer-only logger: no gyroscope columns at all, as a vendor CSV and as the imucal
# capture CSV. The accelerometer is calibrated alone: exit 0, its parameters within the
# tolerances of the simulated noise, and no key naming the gyroscope in the parameter set. The
# IMU-TK protocol (stops reached by tilts about random axes): a turn about the vertical, as
# six-face pairs make, leaves the accelerometer unchanged and cannot be seen without a gyroscope.
case_accel_only() {
  write a1 --seed 31 --no-gyro --protocol random || return 1
  run a1 "$(files a1)" --columns "$(columns a1)" --time-unit us
  want_rc a1 0 && checks params "$dir/a1.json" "$dir/a1/truth.json" --gyro absent || return 1
  write a2 --seed 31 --no-gyro --protocol random --format imucal || return 1
  run a2 "$(files a2)"
  want_rc a2 0 && checks params "$dir/a2.json" "$dir/a2/truth.json" --gyro absent
}

# An interleaved log: after each of the sensor's rows a row of another sensor's, whose mapped
# fields are empty. Without --skip-incomplete-rows: bad input (exit 2) naming the file and the
# first such line, and the flag; with it: the same parameters as the same capture written clean.
case_interleaved_empty_rows() {
  write i1 --seed 32 --interleave-empty || return 1
  write i0 --seed 32 || return 1
  run i1 "$(files i1)" --columns "$(columns i1)" --time-unit us
  [[ $rc -eq 2 ]] || { echo "  exit $rc without --skip-incomplete-rows, want 2"; return 1; }
  local line
  line=$(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["interleaved"]["first_line"])' \
    "$dir/i1/truth.json")
  grep -qF "$(files i1):$line:" "$dir/i1.err" ||
    { echo "  the error does not name $(files i1):$line: $(head -c 400 "$dir/i1.err")"; return 1; }
  grep -qF -- "--skip-incomplete-rows" "$dir/i1.err" ||
    { echo "  the error does not name --skip-incomplete-rows"; return 1; }
  run i1s "$(files i1)" --columns "$(columns i1)" --time-unit us --skip-incomplete-rows
  want_rc i1s 0 || return 1
  # The import's notes are in the text output.
  "$imucal" calibrate "$(files i1)" --columns "$(columns i1)" --time-unit us \
    --skip-incomplete-rows --no-effects >"$dir/i1t.out" 2>&1
  grep -qF "skipped $(python3 -c 'import json,sys; print(json.load(open(sys.argv[1]))["files"][0]["samples"])' \
    "$dir/i1/truth.json") rows with empty fields (first at $(files i1):$line)" "$dir/i1t.out" ||
    { echo "  no note of the skipped rows: $(grep skipped "$dir/i1t.out")"; return 1; }
  run i0 "$(files i0)" --columns "$(columns i0)" --time-unit us
  want_rc i0 0 && checks same "$dir/i1s.json" "$dir/i0.json" &&
    checks params "$dir/i1s.json" "$dir/i1/truth.json"
}

# A free-text label column as spreadsheets write it: quoted, with a comma and doubled quotes
# inside ("rest, face ""Z+"""). RFC 4180 makes that one field: the capture reads as without it.
case_quoted_label() {
  write ql --seed 33 --label-column || return 1
  run ql "$(files ql)" --columns "$(columns ql)" --time-unit us
  want_rc ql 0 && checks params "$dir/ql.json" "$dir/ql/truth.json"
}

cases=(quantised_si quantised_counts quantised_faces noise_free low_noise steady_turns
  steady_turns_20 steady_turns_50 steady_turns_100 steady_turns_200 hand_held_turns table_rests
  file_noise_floors faces_held_once faces_files
  faces_files_imucal faces_once duplicate_face noisy_rest_hand noisy_rest_motor
  noisy_rest_settling short_stops short_stops_all commented_header nul_byte final_figures
  temperature_turnover gyro_bias_shift rate_scale)
cases+=(gyro_deg_s wrong_declared_unit noise_moving noise_handling quantised_stuck)
cases+=(accel_only interleaved_empty_rows quoted_label)
(($# > 0)) && cases=("$@")
failed=()
for c in "${cases[@]}"; do
  declare -F "case_$c" >/dev/null || { echo "unknown case $c"; exit 1; }
  echo "== $c"
  if "case_$c"; then echo "   ok"; else echo "   FAIL: $c"; failed+=("$c"); fi
done
if ((${#failed[@]})); then
  echo "FAIL: ${#failed[@]} of ${#cases[@]} cases: ${failed[*]}"
  exit 1
fi
echo "PASS: ${#cases[@]} cases"
