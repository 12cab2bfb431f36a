#!/usr/bin/env bash
# The importers through the real CLI, on files imucal did not write:
#  - a ROS 2 bag (sqlite3 and MCAP) and a EuRoC imu0/data.csv written by independent Python
#    writers (tests/tools/write_rosbag2.py, write_mcap.py, write_euroc.py: standard library and
#    the zstd/lz4 tools only, their own CDR, SQLite and MCAP), from a simulated six-face capture with a known bias and scale, calibrated with
#    `imucal calibrate --json` and compared with the writers' truth.json;
#  - the real captures in ../shared/data/real through the column mapping (docs/formats.md, "Vendor CSV").
# Skips (exit 0, "SKIP") without python3; the real-capture part skips without the shared data.
# usage: importers_cli_test.sh IMUCAL [REAL_DATA_DIR]
set -euo pipefail
imucal=$1
real_dir=${2:-}
here=$(cd "$(dirname "$0")" && pwd)
command -v python3 >/dev/null || { echo "SKIP: python3 not installed"; exit 0; }

dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
fail() { echo "FAIL: $*"; exit 1; }

# run NAME ARGS...: imucal calibrate ARGS, stdout to $dir/NAME.out, stderr to $dir/NAME.err;
# sets rc (the script goes on whatever the exit code).
run() {
  local name=$1; shift
  rc=0
  "$imucal" calibrate "$@" >"$dir/$name.out" 2>"$dir/$name.err" || rc=$?
}
expect_ok() {
  [[ $rc -eq 0 ]] || fail "$1: exit $rc: $(cat "$dir/$1.err")"
}

# check_truth REPORT TRUTH: the report's poses and parameters against what the writer simulated.
# Tolerances come from the simulated noise: sigma_pose = noise / sqrt(samples of one hold) is
# the noise of one pose's mean. Biases within 4 sigma_pose (a bias is fitted from at least the
# 4 placements of its axis' two faces, so this is 8 standard errors or more); accelerometer
# scales within 4 sigma_pose / g. Gyro scale: a 90-degree move's integrated angle has the noise
# sigma_move = noise * sqrt(move samples) / rate; scale within 8 sigma_move / (pi/2). Each axis'
# bias and scale differ from the others' by more than these, so a swapped or negated axis fails.
# (The misalignment angles are not compared: the table's tilt times the turns' error leaves
# about 1e-3 rad in the six-face frame, a property of the protocol, not of the importer.)
check_truth() {
  python3 - "$1" "$2" <<'PY'
import json, math, sys
report, truth = (json.load(open(p)) for p in sys.argv[1:3])
errors = []
def check(what, ok):
    if not ok:
        errors.append(what)
poses = report["poses"]
used = [p for p in poses if p["used"]]
check(f"{len(poses)} poses, {len(used)} used; the writer held {truth['pose_count']}",
      len(poses) == truth["pose_count"] and len(used) == truth["pose_count"])
check(f"protocol {report['protocol']}, simulated {truth['protocol']}",
      report["protocol"] == truth["protocol"])
check(f"verdict {report['verdict']}", report["verdict"] == "pass")
g = truth["gravity_m_s2"]
# Each pose, in time order, where the writer held it: its mean specific force through the true
# model points along the simulated up direction, within 6 standard errors of that mean's
# direction (noise / sqrt(samples) / g). A swapped or reordered axis, a wrong sign or a
# misplaced time would move it by degrees.
for p, want in zip(used, truth["poses"]):
    a = [truth["accel_scale"][i] * (p["accel_mean"][i] - truth["accel_bias_m_s2"][i])
         for i in range(3)]
    norm = math.sqrt(sum(c * c for c in a))
    cos = sum(c / norm * w for c, w in zip(a, want["up_body"]))
    angle = math.acos(max(-1.0, min(1.0, cos)))
    t = 6 * truth["accel_noise_m_s2"] / math.sqrt(p["samples"]) / g
    check(f"pose {p['index']} ({want['face']}): {math.degrees(angle):.3f} deg from the "
          f"simulated up direction (tolerance {math.degrees(t):.3f})", angle <= t)
rate = truth["rate_hz"]
hold_n = truth["hold_s"] * rate
sigma_accel = truth["accel_noise_m_s2"] / math.sqrt(hold_n)
sigma_gyro = truth["gyro_noise_rad_s"] / math.sqrt(hold_n)
sigma_move = truth["gyro_noise_rad_s"] * math.sqrt(truth["move_s"] * rate) / rate
tol = {"accel bias": 4 * sigma_accel, "accel scale": 4 * sigma_accel / g,
       "gyro bias": 4 * sigma_gyro,
       "gyro scale": 8 * sigma_move / (math.pi / 2)}
accel, gyro = report["parameters"]["accel"], report["parameters"]["gyro"]
check(f"units {accel['input_unit']} {gyro['input_unit']}",
      accel["input_unit"] == "m/s^2" and gyro["input_unit"] == "rad/s")
def near(what, got, want, t, se=None):
    for i in range(3):
        # A term the poses know only loosely widens the others' standard errors (the
        # second-order terms beside the biases on a six-face capture): 4 of them then.
        ti = max(t, 4 * se[i]) if se and se[i] is not None else t
        check(f"{what}[{i}] = {got[i]:.6g}, simulated {want[i]:.6g} (tolerance {ti:.3g})",
              abs(got[i] - want[i]) <= ti)
near("accel bias", accel["bias"], truth["accel_bias_m_s2"], tol["accel bias"],
     accel["stderr"]["bias"])
near("accel scale", accel["scale"], truth["accel_scale"], tol["accel scale"],
     accel["stderr"]["scale"])
near("gyro bias", gyro["bias"], truth["gyro_bias_rad_s"], tol["gyro bias"])
near("gyro scale", gyro["scale"], truth["gyro_scale"], tol["gyro scale"])
if errors:
    print("\n".join(errors))
    sys.exit(1)
print(f"  {len(used)} poses, bias and scale within " +
      ", ".join(f"{k} {v:.2g}" for k, v in tol.items()))
PY
}

# --- ROS 2 bag (Humble layout): /imu/data and /temperature -------------------------------------
python3 "$here/write_rosbag2.py" "$dir/bag" --seed 3 >/dev/null
echo "rosbag2 (humble): auto-detected format, the only Imu topic"
run bag_auto "$dir/bag" --json
expect_ok bag_auto
check_truth "$dir/bag_auto.out" "$dir/bag.truth.json" || fail "rosbag2 without --topic"

echo "rosbag2 (humble): --topic /imu/data, summary names the format"
run bag_topic "$dir/bag" --topic /imu/data --format rosbag2
expect_ok bag_topic
head -1 "$dir/bag_topic.out" | grep -qF "(rosbag2, " || fail "summary: $(head -1 "$dir/bag_topic.out")"
run bag_topic_json "$dir/bag" --topic /imu/data --json
expect_ok bag_topic_json
check_truth "$dir/bag_topic_json.out" "$dir/bag.truth.json" || fail "rosbag2 --topic /imu/data"

echo "rosbag2: a missing topic and a topic of another type are bad input (exit 2), named"
run bag_missing "$dir/bag" --topic /imu/missing --json
[[ $rc -eq 2 ]] || fail "--topic /imu/missing: exit $rc, want 2"
grep -qF "/imu/missing" "$dir/bag_missing.err" || fail "error does not name the topic: $(cat "$dir/bag_missing.err")"
[[ ! -s "$dir/bag_missing.out" ]] || fail "--topic /imu/missing printed a report"
run bag_wrong_type "$dir/bag" --topic /temperature --json
[[ $rc -eq 2 ]] || fail "--topic /temperature: exit $rc, want 2"
grep -F "/temperature" "$dir/bag_wrong_type.err" | grep -qF "sensor_msgs/msg/Temperature" ||
  fail "error does not name the topic and its type: $(cat "$dir/bag_wrong_type.err")"

# --- ROS 2 bag (Jazzy layout) with a second Imu topic: the choice needs --topic ---------------
python3 "$here/write_rosbag2.py" "$dir/bag2" --seed 4 --distro jazzy --decoy-imu /imu2/data >/dev/null
echo "rosbag2 (jazzy): two Imu topics without --topic is bad input naming both"
run bag2_ambiguous "$dir/bag2" --json
[[ $rc -eq 2 ]] || fail "two Imu topics, no --topic: exit $rc, want 2"
for t in /imu/data /imu2/data; do
  grep -qF "$t" "$dir/bag2_ambiguous.err" || fail "error does not name $t: $(cat "$dir/bag2_ambiguous.err")"
done
echo "rosbag2 (jazzy): --topic /imu/data selects the capture"
run bag2_topic "$dir/bag2" --topic /imu/data --json
expect_ok bag2_topic
check_truth "$dir/bag2_topic.out" "$dir/bag2.truth.json" || fail "rosbag2 jazzy --topic /imu/data"

# --- ROS 2 MCAP (rosbag2's default storage since Iron), from tests/tools/write_mcap.py --------
python3 "$here/write_mcap.py" "$dir/capture.mcap" --seed 3 --compression lz4 >/dev/null
echo "mcap: a bare .mcap file (lz4 chunks, summary) is auto-detected and calibrates"
run mcap_auto "$dir/capture.mcap"
expect_ok mcap_auto
head -1 "$dir/mcap_auto.out" | grep -qF "(mcap, " || fail "summary: $(head -1 "$dir/mcap_auto.out")"
run mcap_json "$dir/capture.mcap" --json
expect_ok mcap_json
check_truth "$dir/mcap_json.out" "$dir/capture.mcap.truth.json" || fail "mcap file"
python3 "$here/write_mcap.py" "$dir/mcap_bag" --bag-dir --seed 4 --compression zstd \
  --no-summary --decoy-imu /imu2/data >/dev/null
echo "mcap: a bag directory (zstd chunks, no summary) with two Imu topics needs --topic"
run mcap_bag_ambiguous "$dir/mcap_bag" --json
[[ $rc -eq 2 ]] || fail "mcap bag, two Imu topics, no --topic: exit $rc, want 2"
grep -qF "/imu2/data" "$dir/mcap_bag_ambiguous.err" || fail "error does not name /imu2/data: $(cat "$dir/mcap_bag_ambiguous.err")"
run mcap_bag "$dir/mcap_bag" --topic /imu/data --json
expect_ok mcap_bag
check_truth "$dir/mcap_bag.out" "$dir/mcap_bag.truth.json" || fail "mcap bag --topic /imu/data"

# --- imucal noise: a 5-minute rest of known white noise, written here --------------------------
echo "noise: N of each axis within 10% of the simulated density; B, K upper bounds; YAML keys"
python3 - "$dir/rest.csv" <<'PY'
import math, random, sys
random.seed(11)
rate, n = 200, 200 * 300
with open(sys.argv[1], "w") as f:
    f.write("# imucal-capture v1\n# device=rest\n# accel_unit=m/s^2\n# gyro_unit=rad/s\n"
            "# gravity=9.80665\n# rate_hz=200\nt,ax,ay,az,gx,gy,gz\n")
    for i in range(n):
        a = [2e-3 * math.sqrt(rate) * random.gauss(0, 1) for _ in range(3)]
        g = [2e-4 * math.sqrt(rate) * random.gauss(0, 1) for _ in range(3)]
        a[2] += 9.80665
        f.write("%.6f,%s\n" % (i / rate, ",".join("%.8g" % v for v in a + g)))
PY
rc=0
"$imucal" noise "$dir/rest.csv" --out "$dir/noise" --json >"$dir/noise.out" 2>"$dir/noise.err" || rc=$?
expect_ok noise
python3 - "$dir/noise.out" <<'PY' || fail "noise figures"
import json, sys
j = json.load(open(sys.argv[1]))
bad = []
for axis, f in j["axes"].items():
    truth = 2e-3 if axis.startswith("accel") else 2e-4
    n = f["noise_density"]
    if not (abs(n["value"] / truth - 1) < 0.10 and not n["upper_bound"]):
        bad.append(f"{axis} N {n}")
    for k in ("bias_instability", "random_walk"):
        if not f[k]["upper_bound"]:
            bad.append(f"{axis} {k} is not an upper bound on white noise: {f[k]}")
print("\n".join(bad) if bad else "  N within 10% on 6 axes; B and K upper bounds")
sys.exit(1 if bad else 0)
PY
for key in accelerometer_noise_density accelerometer_random_walk gyroscope_noise_density \
           gyroscope_random_walk rostopic update_rate; do
  grep -q "^$key: " "$dir/noise/imu.yaml" || fail "imu.yaml has no $key"
  grep -q "^  $key: " "$dir/noise/kalibr_imu_chain.yaml" || fail "kalibr_imu_chain.yaml has no $key"
done
grep -q "UPPER BOUND" "$dir/noise/imu.yaml" || fail "imu.yaml does not say the random walk is a bound"
head -1 "$dir/noise/kalibr_imu_chain.yaml" | grep -qx '%YAML:1.0' || fail "OpenVINS file header"
[[ -s "$dir/noise/allan_gyro.svg" ]] || fail "no Allan plot"

# --- EuRoC imu0/data.csv ----------------------------------------------------------------------
python3 "$here/write_euroc.py" "$dir/euroc" --seed 5 >/dev/null
echo "EuRoC: auto-detected format"
run euroc_auto "$dir/euroc/mav0/imu0/data.csv"
expect_ok euroc_auto
head -1 "$dir/euroc_auto.out" | grep -qF "(euroc, " || fail "summary: $(head -1 "$dir/euroc_auto.out")"
run euroc_json "$dir/euroc/mav0/imu0/data.csv" --json
expect_ok euroc_json
check_truth "$dir/euroc_json.out" "$dir/euroc/truth.json" || fail "EuRoC"
python3 "$here/write_euroc.py" "$dir/euroc_crlf" --seed 6 --crlf >/dev/null
echo "EuRoC: CRLF line endings, --format euroc"
run euroc_crlf "$dir/euroc_crlf/mav0/imu0/data.csv" --format euroc --json
expect_ok euroc_crlf
check_truth "$dir/euroc_crlf.out" "$dir/euroc_crlf/truth.json" || fail "EuRoC with CRLF"

# --- The real captures through the column mapping ---------------------------------------------
mpu=$real_dir/mpu6050-tedaldi-raw/example_data_calibration.csv
ferraris=$real_dir/imucal-ferraris/example_ferraris_session.csv
ferraris_list=$real_dir/imucal-ferraris/example_ferraris_session_list.json
if [[ -z "$real_dir" || ! -f "$mpu" || ! -f "$ferraris" || ! -f "$ferraris_list" ]]; then
  echo "SKIP: real captures not found under '$real_dir'"
  echo "PASS (synthetic formats only)"
  exit 0
fi

echo "MPU-6050 (raw counts, rate from the preamble): 10 hand-held poses"
run mpu "$mpu" --columns ax=ax,ay=ay,az=az,gx=gx,gy=gy,gz=gz --rate-from-preamble Fs \
  --accel-unit counts --gyro-unit counts --json
expect_ok mpu
# tests/core/real_data_test.cc: ten hand-held orientations after the rest, as the source
# repository's own detector found; hand-held moves exceed a degree, so never a pass.
python3 - "$dir/mpu.out" <<'PY' || fail "MPU-6050"
import json, sys
r = json.load(open(sys.argv[1]))
used = [p for p in r["poses"] if p["used"]]
errors = []
if len(used) != 10: errors.append(f"{len(used)} used poses, want 10")
if r["verdict"] not in ("pass", "warn"): errors.append(f"verdict {r['verdict']}")
if r["parameters"]["accel"]["input_unit"] != "counts": errors.append("accel unit")
if not r["parameters"]["gyro"]["calibrated"]: errors.append("gyroscope not calibrated")
print("\n".join(errors) or f"  {len(used)} poses, verdict {r['verdict']}")
sys.exit(1 if errors else 0)
PY

echo "Ferraris example (m/s^2, deg/s, sample counter at 102.4 Hz): six faces and three turns"
rate=102.4
run ferraris "$ferraris" --columns t=n_samples,ax=acc_x,ay=acc_y,az=acc_z,gx=gyr_x,gy=gyr_y,gz=gyr_z \
  --time-unit index --rate "$rate" --accel-unit m/s^2 --gyro-unit deg/s --json
expect_ok ferraris
# Against the dataset's own annotation (example_ferraris_session_list.json, sample indices):
# each static section x_p (X+), x_a (X-), ... lies inside one used pose on that face; each
# rotation section x_rot, y_rot, z_rot inside one found turn (one 360-degree turn about that
# axis), with a pose just before and after it. So at least 6 + 2 * 3 poses; one more at most,
# the rest before the first section.
python3 - "$dir/ferraris.out" "$ferraris_list" "$rate" <<'PY' || fail "Ferraris example"
import json, sys
r, sections = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
rate = float(sys.argv[3])
used = [p for p in r["poses"] if p["used"]]
errors = []
def face(u):
    i = max(range(3), key=lambda k: abs(u[k]))
    return "XYZ"[i] + ("+" if u[i] > 0 else "-")
def inside(a, b, start, end, slack_s=0.0):
    return a - slack_s <= start and end <= b + slack_s
if r["protocol"] != "ferraris": errors.append(f"protocol {r['protocol']}")
for name, s in sections.items():
    start, end = s["start"] / rate, s["end"] / rate
    axis = name[0].upper()
    if name.endswith("_rot"):
        turns = [t for t in r["turns"] if inside(t["t_start"], t["t_end"], start, end, 0.5)]
        if len(turns) != 1:
            errors.append(f"{name} ({start:.1f}-{end:.1f} s): {len(turns)} turns found around it")
            continue
        t = turns[0]
        ax = t["axis_body"]
        if t["turns"] != 1 or "XYZ"[max(range(3), key=lambda k: abs(ax[k]))] != axis:
            errors.append(f"{name}: turn {t}")
        if not any(abs(p["t_end"] - t["t_start"]) < 1.0 for p in used):
            errors.append(f"{name}: no pose ends where the turn starts")
        if not any(abs(p["t_start"] - t["t_end"]) < 1.0 for p in used):
            errors.append(f"{name}: no pose starts where the turn ends")
    else:
        want = axis + ("+" if name.endswith("_p") else "-")
        poses = [p for p in used if p["t_start"] <= end and start <= p["t_end"]]
        if len(poses) != 1 or face(poses[0]["accel_mean"]) != want or \
           not inside(poses[0]["t_start"] - 1.5, poses[0]["t_end"] + 1.5, start, end):
            errors.append(f"{name} ({start:.1f}-{end:.1f} s, {want}): poses " +
                          str([(p["index"], p["t_start"], p["t_end"]) for p in poses]))
n_static = sum(1 for k in sections if not k.endswith("_rot"))
n_rot = len(sections) - n_static
if not n_static + 2 * n_rot <= len(used) <= n_static + 2 * n_rot + 1:
    errors.append(f"{len(used)} used poses, want {n_static + 2 * n_rot} or one more")
if len(r["turns"]) != n_rot: errors.append(f"{len(r['turns'])} turns, want {n_rot}")
if r["verdict"] == "fail": errors.append("verdict fail")
print("\n".join(errors) or f"  {len(used)} poses, {len(r['turns'])} turns, verdict {r['verdict']}")
sys.exit(1 if errors else 0)
PY
echo PASS
