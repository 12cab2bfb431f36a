#!/usr/bin/env python3
"""Checks an `imucal calibrate --json` report against the truth.json of write_columns.py, for
capture_classes_test.sh. Asserts only what the report's spec (../shared/spec/report.md) and the
README promise: the verdict, the poses found (used or not, with a reason), the file and line
range of each pose of a capture read from several files, and the calibrated parameters against
the simulated ones within tolerances derived from the simulated noise and quantisation.

Tolerances (see tolerances()): a pose's mean has the noise sigma / sqrt(samples); quantisation
adds step^2 / 12 to a sample's variance and, when the noise is below about half a step, a
systematic error of the mean that no averaging removes: E[round(x + n)] - x for Gaussian n is
the sawtooth x - round(x) smoothed by the noise, whose Fourier series bounds it by
step / pi * sum_k exp(-2 pi^2 k^2 sigma^2 / step^2) / k (and by step / 2). Biases are allowed
4 such pose errors, scales 4 pose errors / g; the gyroscope's scale 8 standard errors of the
angle of a 90-degree move, as the gyroscope integrates it (its noise over the longest move) and
as the accelerometer sees it (two poses' gravity directions), plus the angle a bias error leaves
over the longest move. A floor assumed level (six faces once) moves each bias by up to
g sin(t) / scale and each scale by up to 2 sin(t)^2 for a tilt of t. A noise-free capture is
held to the tolerances of the writer's default noise (0.02 m/s^2, 0.004 rad/s): exact data must
calibrate at least as well as noisy data (how much better is limited by the solver and the
model choices, not by the data, so no tighter bound is derived).
Each axis' bias and scale differ from the others' by more than these, so a swapped, negated or
unit-confused axis fails.

usage: capture_checks.py CHECK REPORT TRUTH [options]; prints what failed, exits 1 if anything
did. CHECK: params, files, steady, noisy, refused, names, effects, final, rates, same (see
main()).
"""
import argparse
import bisect
import json
import math
import os
import re
import sys

DEFAULT_NOISE = (0.02, 0.004)  # imu_sim's default accel (m/s^2) and gyro (rad/s) noise


def quantisation_bias(sigma, step):
    """Bound on |E[round((x + n) / step) * step] - x| over x, for n ~ N(0, sigma^2)."""
    if not step:
        return 0.0
    r = sigma / step
    total = sum(math.exp(-2 * math.pi ** 2 * k * k * r * r) / k for k in range(1, 200))
    return min(0.5, total / math.pi) * step


class Checker:
    def __init__(self):
        self.errors = []

    def check(self, what, ok):
        if not ok:
            self.errors.append(what)
        return ok

    def done(self, summary):
        if self.errors:
            print("\n".join("  " + e for e in self.errors))
            sys.exit(1)
        print("  " + summary)


def load(path):
    with open(path) as f:
        return json.load(f)


def used_poses(report):
    return [p for p in report["poses"] if p["used"]]


def noise_of(truth, sensor):
    """The per-sample noise a pose's mean is judged with (a noise-free capture: the default)."""
    i = 0 if sensor == "accel" else 1
    if not truth.get("noise", True):
        return DEFAULT_NOISE[i]
    return truth["accel_noise_m_s2" if i == 0 else "gyro_noise_rad_s"]


def tolerances(truth, report, faces_once):
    """Tolerances in m/s^2, rad/s and scale units (see the module docstring)."""
    g = truth["gravity_m_s2"]
    used = used_poses(report)
    n = min(p["samples"] for p in used) if used else 1
    a_step, g_step = truth.get("accel_step_m_s2"), truth.get("gyro_step_rad_s")
    sa, sg = noise_of(truth, "accel"), noise_of(truth, "gyro")
    noisy = truth.get("noisy_rest") or {}
    extra_a = 0.0
    # Holds with more noise (--hold-noise-factors): the noisiest hold's mean decides.
    factor = max(truth.get("hold_noise_factors") or [1.0])
    sa, sg = factor * sa, factor * sg
    if noisy:
        # The noisy pose's mean: its noise is F times the others', over its own samples, plus
        # what the settling offset or the vibration leaves in it.
        f = noisy["noise_factor"]
        n_noisy = noisy["hold_s"] * truth["rate_hz"] * 0.5
        sa = max(sa, f * sa * math.sqrt(n / n_noisy))
        sg = max(sg, f * sg * math.sqrt(n / n_noisy))
        extra_a = noisy.get("settle_mean_offset_m_s2", 0.0)
        if noisy["kind"] == "motor":
            extra_a = (math.sqrt(2) * f * noise_of(truth, "accel") /
                       (math.pi * noisy["motor_hz"] * noisy["hold_s"] * 0.5))
    # A pose mean's random error (standard deviation) and systematic error bound.
    mean_a = math.sqrt(sa ** 2 + (a_step or 0) ** 2 / 12) / math.sqrt(n)
    sys_a = quantisation_bias(sa, a_step) + extra_a
    pose_a = 4 * mean_a + sys_a
    pose_g = (4 * math.sqrt(sg ** 2 + (g_step or 0) ** 2 / 12) / math.sqrt(n) +
              quantisation_bias(sg, g_step))
    tol = {"accel bias": pose_a, "accel scale": pose_a / g, "gyro bias": pose_g}
    moves = truth.get("moves") or []
    if moves:
        rate = truth["rate_hz"]
        longest = max(m["t_end_s"] - m["t_start_s"] + 1 / rate for m in moves)
        sigma_gyro = math.sqrt(sg ** 2 + (g_step or 0) ** 2 / 12) * math.sqrt(longest * rate) / rate
        sigma_dirs = math.sqrt(2) * (mean_a + sys_a) / g
        tol["gyro scale"] = (8 * math.hypot(sigma_gyro, sigma_dirs) +
                             quantisation_bias(sg, g_step) * longest) / (math.pi / 2)
    if faces_once:
        t = math.radians(truth["floor_tilt_deg"])
        tol["accel bias"] += g * math.sin(t) / min(truth["accel_scale"])
        tol["accel scale"] += 2 * math.sin(t) ** 2
    return tol


def check_params(c, report, truth, args):
    """The parameters against the truth, and each used pose's direction."""
    tol = tolerances(truth, report, args.faces_once)
    params = report.get("parameters") or {}
    accel, gyro = params.get("accel") or {}, params.get("gyro") or {}
    counts = truth.get("counts") if truth.get("writer", {}).get("counts") else None
    unit_a, unit_g = ("counts", "counts") if counts else ("m/s^2", "rad/s")
    if args.gyro == "absent":
        # An accelerometer-only capture: the parameter set has no gyro part at all, no key
        # naming the gyroscope anywhere in it (absent, not zero).
        keys = gyro_keys(params)
        c.check(f"the parameter set names the gyroscope: {keys[:5]}", not keys)
        unit_g = None
    if not c.check(f"input units {accel.get('input_unit')} {gyro.get('input_unit')}, "
                   f"want {unit_a} {unit_g}",
                   accel.get("input_unit") == unit_a and gyro.get("input_unit") == unit_g):
        return tol
    want = {"accel bias": truth["accel_bias_m_s2"], "accel scale": truth["accel_scale"],
            "gyro bias": truth["gyro_bias_rad_s"], "gyro scale": truth["gyro_scale"]}
    t_abs = dict(tol)
    if counts:
        # In counts: bias / step counts, scale * step per count; tolerances likewise.
        a_step, g_step = counts["accel_step_m_s2"], counts["gyro_step_rad_s"]
        want = {"accel bias": counts["accel_bias_counts"],
                "accel scale": counts["accel_scale_m_s2_per_count"],
                "gyro bias": counts["gyro_bias_counts"],
                "gyro scale": counts["gyro_scale_rad_s_per_count"]}
        t_abs["accel bias"] = tol["accel bias"] / a_step
        t_abs["gyro bias"] = tol["gyro bias"] / g_step
    got = {"accel bias": accel.get("bias"), "accel scale": accel.get("scale"),
           "gyro bias": gyro.get("bias"), "gyro scale": gyro.get("scale")}
    names = ["accel bias", "accel scale"]
    if args.gyro in ("bias", "all"):
        names.append("gyro bias")
    if args.gyro == "all":
        c.check("gyroscope not calibrated", gyro.get("calibrated") is True)
        names.append("gyro scale")
    for name in names:
        v = got[name]
        if not c.check(f"{name}: {v}", isinstance(v, list) and len(v) == 3 and
                       all(isinstance(x, (int, float)) for x in v)):
            continue
        for i in range(3):
            # Scales are relative: the tolerance is per unit of scale (times the step in counts).
            t = t_abs[name] * (abs(want[name][i]) if name.endswith("scale") else 1.0)
            c.check(f"{name}[{i}] = {v[i]:.6g}, simulated {want[name][i]:.6g} (tolerance "
                    f"{t:.3g})", abs(v[i] - want[name][i]) <= t * (1 + 1e-9))
    return tol


def gyro_keys(value, path=""):
    """The paths of every key that names the gyroscope ("gyro" in it), recursively."""
    found = []
    if isinstance(value, dict):
        for k, v in value.items():
            p = f"{path}.{k}" if path else k
            if "gyro" in k:
                found.append(p)
            found += gyro_keys(v, p)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            found += gyro_keys(v, f"{path}[{i}]")
    return found


def same_params(c, report, other):
    """Two reports' parameter sets agree in every fitted value (not in dates or sources)."""
    a, b = report.get("parameters") or {}, other.get("parameters") or {}
    for key in ("accel", "gyro", "effects", "quality"):
        c.check(f"parameters.{key} differ: {json.dumps(a.get(key))[:200]} vs "
                f"{json.dumps(b.get(key))[:200]}", a.get(key) == b.get(key))


def match_poses(c, report, truth, multi_file):
    """Each simulated hold against the used poses: in a single file by time, from several files
    by file. Returns [(truth pose, report pose)]."""
    used = used_poses(report)
    pairs = []
    for k, want in enumerate(truth["poses"]):
        if multi_file:
            hits = [p for p in used if os.path.basename(str(p.get("file"))) == want["file"]]
        else:
            hits = [p for p in used
                    if p["t_start"] <= want["t_end_s"] and want["t_start_s"] <= p["t_end"]]
        c.check(f"simulated pose {k} ({want['face']}, "
                + (want["file"] if multi_file else
                   f"{want['t_start_s']:.2f}-{want['t_end_s']:.2f} s")
                + f"): {len(hits)} used poses, want 1", len(hits) == 1)
        if len(hits) == 1:
            pairs.append((want, hits[0]))
    c.check(f"{len(used)} used poses, the writer held {truth['pose_count']}",
            len(used) == truth["pose_count"])
    return pairs


def check_directions(c, pairs, truth):
    """Each used pose's mean specific force through the true model points along the simulated
    up direction, within 6 standard errors of the mean's direction plus the quantisation bias
    (a swapped axis, a wrong sign or a misplaced pose moves it by degrees)."""
    counts = truth.get("counts") if truth.get("writer", {}).get("counts") else None
    bias = counts["accel_bias_counts"] if counts else truth["accel_bias_m_s2"]
    scale = counts["accel_scale_m_s2_per_count"] if counts else truth["accel_scale"]
    g = truth["gravity_m_s2"]
    sa = noise_of(truth, "accel")
    step = truth.get("accel_step_m_s2") or 0.0
    noisy = truth.get("noisy_rest") or {}
    for want, p in pairs:
        a = [scale[i] * (p["accel_mean"][i] - bias[i]) for i in range(3)]
        norm = math.sqrt(sum(x * x for x in a))
        cos = sum(x / norm * w for x, w in zip(a, want["up_body"]))
        angle = math.acos(max(-1.0, min(1.0, cos)))
        k = truth["poses"].index(want)
        s = sa * (noisy["noise_factor"] if noisy and noisy["pose"] == k else 1.0)
        factors = truth.get("hold_noise_factors")
        if factors:  # --hold-noise-factors: this hold's own noise
            s *= factors[k % len(factors)]
        err = (6 * math.sqrt(s ** 2 + step ** 2 / 12) / math.sqrt(p["samples"]) +
               math.sqrt(3) * quantisation_bias(s, step) +
               (noisy.get("settle_mean_offset_m_s2", 0.0) * math.sqrt(3) if noisy else 0.0))
        c.check(f"pose {p['index']} ({want['face']}): {math.degrees(angle):.4f} deg from the "
                f"simulated up direction (tolerance {math.degrees(err / g):.4f})",
                angle <= err / g)


def check_files(c, report, truth):
    """A capture from several files: every pose names its file and its line range, inside
    that file's data lines; each used pose's lines overlap the hold the writer put there."""
    files = {f["name"]: f for f in truth["files"]}
    for p in report["poses"]:
        name = os.path.basename(str(p.get("file")))
        lines = p.get("lines")
        if not c.check(f"pose {p['index']}: file {p.get('file')!r}, not one of {list(files)}",
                       name in files):
            continue
        if not c.check(f"pose {p['index']}: lines {lines!r}, want [first, last]",
                       isinstance(lines, list) and len(lines) == 2 and
                       all(isinstance(x, int) for x in lines)):
            continue
        first, last = files[name]["lines"]
        c.check(f"pose {p['index']} in {name}: lines {lines}, the file's data are lines "
                f"{first}-{last}", first <= lines[0] <= lines[1] <= last)
        if p["used"]:
            want = truth["poses"][files[name]["poses"][0]]["lines"]
            c.check(f"pose {p['index']} in {name}: lines {lines} miss the hold {want}",
                    lines[0] <= want[1] and want[0] <= lines[1])


def check_rests(c, report, truth, args):
    """A rest is a rest: every used pose lies inside one of the writer's holds (never in a move,
    however steady or slow), and, with --one-per-hold, every long hold is one used pose over at
    least 80% of it (a rest is not cut into pieces); with --per-file, each file's hold is."""
    used = used_poses(report)
    if args.per_file:
        files = {f["name"]: f for f in truth["files"]}
        for name, f in files.items():
            mine = [p for p in used if os.path.basename(str(p.get("file"))) == name]
            c.check(f"{name}: {len(mine)} used poses, want 1 (its hold, lines {f['lines']})",
                    len(mine) == 1)
        c.done(f"{len(files)} files, one used pose each")
        return
    holds = [(p["t_start_s"], p["t_end_s"]) for p in truth["poses"]]
    slack = 0.15
    for p in used:
        inside = [h for h in holds if h[0] - slack <= p["t_start"] and p["t_end"] <= h[1] + slack]
        c.check(f"used pose {p['index']} ({p['t_start']:.2f}-{p['t_end']:.2f} s) is not inside "
                f"any hold: it takes a move for a rest", len(inside) == 1)
    if args.one_per_hold is not None:
        for lo, hi in holds:
            if hi - lo < args.one_per_hold:
                continue
            hits = [p for p in report["poses"] if p["t_start"] < hi and lo < p["t_end"]]
            desc = [(p["index"], round(p["t_start"], 2), round(p["t_end"], 2), p["used"])
                    for p in hits]
            c.check(f"the hold at {lo:.2f}-{hi:.2f} s is {desc}, want one used pose over "
                    f">= 80% of it", len(hits) == 1 and hits[0]["used"] and
                    hits[0]["t_end"] - hits[0]["t_start"] >= 0.8 * (hi - lo))
    turns = truth.get("slow_turns") or []
    c.done(f"{len(used)} used poses, each inside a hold; {len(turns)} slow turns not taken for "
           f"rests")


def check_reasons(c, report):
    """Every pose found says whether it is used, and why not when it is not."""
    for p in report.get("poses", []):
        c.check(f"pose {p.get('index')}: no boolean 'used'", isinstance(p.get("used"), bool))
        c.check(f"pose {p.get('index')}: unused without a reason",
                p.get("used") is True or bool(str(p.get("reason", "")).strip()))


def report_text(report, skip_keys=("file", "lines")):
    """Every string in the report except the keys that merely name a pose's source."""
    out = []

    def walk(x, key=None):
        if isinstance(x, dict):
            for k, v in x.items():
                if k not in skip_keys:
                    walk(v, k)
        elif isinstance(x, list):
            for v in x:
                walk(v, key)
        elif isinstance(x, str):
            out.append(x)
    walk(report)
    return "\n".join(out)


def read_csv(path):
    """(columns, rows) of an imucal CSV: '#' lines skipped, the first other line names them."""
    names, rows = None, []
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            if names is None:
                names = line.strip().split(",")
                continue
            rows.append([float(v) for v in line.split(",")])
    return names, rows


def hold_errors(truth, names, rows, calibrate):
    """Per simulated hold (0.3 s trimmed each side): |mean a| - g and |mean w| of the samples
    that calibrate(row) maps to (a, w)."""
    col = {n: i for i, n in enumerate(names)}
    t = [r[col["t"]] for r in rows]
    t0 = t[0]
    accel_err, gyro_err = [], []
    for p in truth["poses"]:
        lo, hi = p["t_start_s"] + 0.3, p["t_end_s"] - 0.3
        sa, sw, n = [0.0] * 3, [0.0] * 3, 0
        for r, tk in zip(rows, t):
            if lo <= tk - t0 <= hi:
                a, w = calibrate(r, col)
                sa = [x + y for x, y in zip(sa, a)]
                sw = [x + y for x, y in zip(sw, w)]
                n += 1
        accel_err.append(math.sqrt(sum((x / n) ** 2 for x in sa)) - truth["gravity_m_s2"])
        gyro_err.append(math.sqrt(sum((x / n) ** 2 for x in sw)))
    rms = lambda v: math.sqrt(sum(x * x for x in v) / len(v))  # noqa: E731
    return rms(accel_err), rms(gyro_err)


def truth_calibrate(truth):
    """The simulated truth as a calibration: y = scale (u - bias) minus the temperature
    quadratics (imu_sim.py's model)."""
    temp = truth["temperature"]

    def apply(r, col):
        u_a = [r[col[k]] for k in ("ax", "ay", "az")]
        u_w = [r[col[k]] for k in ("gx", "gy", "gz")]
        a = [s * (u - b) for s, u, b in zip(truth["accel_scale"], u_a, truth["accel_bias_m_s2"])]
        w = [s * (u - b) for s, u, b in zip(truth["gyro_scale"], u_w, truth["gyro_bias_rad_s"])]
        tc = r[col["temp"]]
        for q in temp["gyro_temp_quad"]:
            w["xyz".index(q["axis"])] -= q["c_rad_s_per_degc2"] * (tc - q["turnover_c"]) ** 2
        for q in temp["accel_temp_quad"]:
            a["xyz".index(q["axis"])] -= q["c_m_s2_per_degc2"] * (tc - q["turnover_c"]) ** 2
        return a, w
    return apply


def calibrated_columns(r, col):
    return ([r[col[k]] for k in ("ax", "ay", "az")], [r[col[k]] for k in ("gx", "gy", "gz")])


def check_effects(c, report, truth, args):
    """The simulated temperature quadratics found in their centred form, each a pair
    (temperature-R) and (temperature-R)^2 on the right sensor and axis with R the parameter
    set's effect_reference, the square's coefficient within 3 standard errors of the truth (the
    highest power's coefficient does not depend on the centre); then on the validation capture
    (another temperature history), the calibrated holds' error within --ratio of what the truth
    itself leaves, and below what the model without its effects leaves."""
    params = report.get("parameters", {})
    ref = params.get("effect_reference", {}).get("temperature", 0.0)
    effects = report.get("effects", [])
    pattern = re.compile(r"^\(temperature([-+])([0-9.eE+-]+)\)(\^2)?$")
    temp = truth["temperature"]
    wanted = ([("gyro", q["axis"], q["c_rad_s_per_degc2"]) for q in temp["gyro_temp_quad"]] +
              [("accel", q["axis"], q["c_m_s2_per_degc2"]) for q in temp["accel_temp_quad"]])
    for sensor, axis, coeff in wanted:
        square = linear = None
        for e in effects:
            m = pattern.match(e.get("regressor", ""))
            if e.get("sensor") != sensor or e.get("axis") != axis or not m:
                continue
            centre = float(m.group(2)) * (1 if m.group(1) == "-" else -1)
            c.check(f"{sensor} {axis} ~ {e['regressor']} centred on the stated reference {ref}",
                    abs(centre - ref) < 1e-9)
            if m.group(3):
                square = e
            else:
                linear = e
        c.check(f"{sensor} {axis}: a centred quadratic (temperature-R)^2 found among "
                f"{[(e['sensor'], e['axis'], e['regressor']) for e in effects]}",
                square is not None)
        c.check(f"{sensor} {axis}: its lower power (temperature-R) beside it", linear is not None)
        if square is not None:
            se = square.get("stderr") or 0
            c.check(f"{sensor} {axis}: coefficient {square['coefficient']:.4g} +- {se:.2g}, "
                    f"truth {coeff:.4g}: within 3 standard errors",
                    abs(square["coefficient"] - coeff) <= 3 * se)
            c.check(f"{sensor} {axis}: applied", square.get("applied", True))
    val_truth = load(args.val_truth)
    names, rows = read_csv(args.val_raw)
    floor = hold_errors(val_truth, names, rows, truth_calibrate(val_truth))
    names, rows = read_csv(args.applied)
    found = hold_errors(val_truth, names, rows, calibrated_columns)
    names, rows = read_csv(args.applied_without)
    without = hold_errors(val_truth, names, rows, calibrated_columns)
    for k, (sensor, unit, scale) in enumerate((("accel", "mg", 1e3 / 9.80665),
                                               ("gyro", "deg/s", math.degrees(1)))):
        if not any(s == sensor for s, _, _ in wanted):
            continue
        c.check(f"validation {sensor}: {found[k] * scale:.4f} {unit} with the effects, within "
                f"{args.ratio} x the truth's {floor[k] * scale:.4f} {unit}",
                found[k] <= args.ratio * floor[k])
        c.check(f"validation {sensor}: {found[k] * scale:.4f} {unit} with the effects, below "
                f"half of {without[k] * scale:.4f} {unit} without them",
                found[k] < 0.5 * without[k])
    return found, floor, without


def move_errors(truth, rows):
    """Per simulated move (between consecutive holds of `truth`), the gravity-direction error in
    rad: the rates of `rows` ((t, a, w) per sample, t from the first sample) integrated with the
    midpoint rule from the last sample of one hold to the first of the next, the true up before
    it carried over and compared with the true up after it."""
    t = [r[0] - rows[0][0] for r in rows]
    out = []
    poses = truth["poses"]
    for a, b in zip(poses, poses[1:]):
        first = bisect.bisect_right(t, a["t_end_s"] + 1e-9) - 1
        last = bisect.bisect_left(t, b["t_start_s"] - 1e-9)
        q = (1.0, 0.0, 0.0, 0.0)
        for i in range(first, last):
            dt = t[i + 1] - t[i]
            phi = [0.5 * (rows[i][2][k] + rows[i + 1][2][k]) * dt for k in range(3)]
            th = math.sqrt(sum(x * x for x in phi))
            sc = 0.5 - th * th / 48 if th < 1e-4 else math.sin(th / 2) / th
            q = qmul(q, (math.cos(th / 2), sc * phi[0], sc * phi[1], sc * phi[2]))
        pred, after = rotate_back(q, unit(a["up_body"])), unit(b["up_body"])
        cross = [pred[1] * after[2] - pred[2] * after[1], pred[2] * after[0] - pred[0] * after[2],
                 pred[0] * after[1] - pred[1] * after[0]]
        out.append(math.atan2(math.sqrt(sum(x * x for x in cross)),
                              sum(p * q for p, q in zip(pred, after))))
    return out


def truth_rates(truth, names, rows):
    """The raw capture calibrated with the simulated truth, its rate-dependent scale taken off
    (y - S |y| y, the inverse of imu_sim's y = w + S |w| w to second order in S): (t, a, w)."""
    col = {n: i for i, n in enumerate(names)}
    terms = truth.get("gyro_rate_scale", {}).get("terms", [])
    out = []
    for r in rows:
        a = [s * (r[col[k]] - b) for s, k, b in zip(truth["accel_scale"], ("ax", "ay", "az"),
                                                    truth["accel_bias_m_s2"])]
        w = [s * (r[col[k]] - b) for s, k, b in zip(truth["gyro_scale"], ("gx", "gy", "gz"),
                                                    truth["gyro_bias_rad_s"])]
        for term in terms:
            i = "xyz".index(term["axis"])
            w[i] -= term["s_per_rad_s"] * abs(w[i]) * w[i]
        out.append((r[col["t"]], a, w))
    return out


def check_rates(c, report, truth, args):
    """The simulated rate-dependent gyroscope scale found as `gz*|gz|`-style terms on the right
    axis (gyro, AXIS ~ gAXIS*|gAXIS|), the coefficient within 3 standard errors of S, applied,
    and no other rate term; on a capture without one (--clean) no rate term at all; then on the
    validation capture (the same sensor, other moves) the gravity-direction error after its
    moves from `imucal apply`'s samples within --ratio of what the truth leaves, and under half
    of what the parameters without the term leave."""
    rate_terms = [e for e in report.get("effects", []) if re.search(r"g[xyz]", e["regressor"])]
    wanted = truth["gyro_rate_scale"]["terms"]
    for term in wanted:
        ax = term["axis"]
        name = f"g{ax}*|g{ax}|"
        got = [e for e in rate_terms if e["sensor"] == "gyro" and e["axis"] == ax and
               e["regressor"] == name]
        c.check(f"gyro {ax} ~ {name} found among "
                f"{[(e['axis'], e['regressor']) for e in rate_terms]}", len(got) == 1)
        if got:
            e = got[0]
            se = e.get("stderr") or 0
            c.check(f"gyro {ax} ~ {name}: coefficient {e['coefficient']:.4g} +- {se:.2g}, truth "
                    f"{term['s_per_rad_s']:.4g}: within 3 standard errors",
                    abs(e["coefficient"] - term["s_per_rad_s"]) <= 3 * se)
            c.check(f"gyro {ax} ~ {name}: applied", e.get("applied", True))
    c.check(f"no other rate term: {[(e['axis'], e['regressor']) for e in rate_terms]}",
            len(rate_terms) == len(wanted))
    if args.clean:
        clean = load(args.clean)
        extra = [(e["sensor"], e["axis"], e["regressor"]) for e in clean.get("effects", [])
                 if re.search(r"g[xyz]", e["regressor"])]
        c.check(f"the capture without a rate term: none found ({extra})", not extra)
    val_truth = load(args.val_truth)
    names, rows = read_csv(args.val_raw)
    rms = lambda v: math.sqrt(sum(x * x for x in v) / len(v))  # noqa: E731
    floor = rms(move_errors(val_truth, truth_rates(val_truth, names, rows)))
    found = rms(move_errors(val_truth, read_applied(args.applied)))
    without = rms(move_errors(val_truth, read_applied(args.applied_without)))
    c.check(f"validation moves: {math.degrees(found):.4f} deg with the term, within {args.ratio} "
            f"x the truth's {math.degrees(floor):.4f} deg", found <= args.ratio * floor)
    c.check(f"validation moves: {math.degrees(found):.4f} deg with the term, below half of "
            f"{math.degrees(without):.4f} deg without it", found < 0.5 * without)
    return found, floor, without


def read_applied(path):
    """`imucal apply`'s output (capture-format.md: '#' metadata, a header, then rows): time (s),
    accel (m/s^2), gyro (rad/s) per row."""
    rows, cols = [], None
    with open(path) as f:
        for line in f:
            if line.startswith("#") or not line.strip():
                continue
            fields = line.strip().split(",")
            if cols is None:
                cols = {name: k for k, name in enumerate(fields)}
                continue
            v = [float(x) for x in fields]
            rows.append((v[cols["t"]], [v[cols[a]] for a in ("ax", "ay", "az")],
                         [v[cols[g]] for g in ("gx", "gy", "gz")]))
    return rows


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def rotate_back(q, v):
    """R(q)^T v: v from the frame after the move into the frame before it, inverted."""
    w, x, y, z = q
    qc = (w, -x, -y, -z)
    r = qmul(qmul(qc, (0.0, *v)), q)
    return r[1:]


def unit(v):
    n = math.sqrt(sum(x * x for x in v))
    return [x / n for x in v]


def final_moves(report, rows):
    """Each reported move's gravity-direction error (deg), recomputed from the calibrated samples
    alone: the body rate integrated from the last sample of one pose to the first of the next
    (trapezoids, body-frame right products), the ups the poses' mean calibrated accelerometer."""
    t = [r[0] for r in rows]
    poses = {p["index"]: p for p in report["poses"]}

    def span(p):
        b = bisect.bisect_left(t, p["t_start"] - 1e-9)
        e = bisect.bisect_right(t, p["t_end"] + 1e-9)
        return b, e

    def up(p):
        b, e = span(p)
        return unit([sum(rows[i][1][k] for i in range(b, e)) for k in range(3)])

    out = []
    for m in report["moves"]:
        a, b = poses[m["poses"][0]], poses[m["poses"][1]]
        first, last = span(a)[1] - 1, span(b)[0]
        q = (1.0, 0.0, 0.0, 0.0)
        for i in range(first, last):
            dt = t[i + 1] - t[i]
            phi = [0.5 * (rows[i][2][k] + rows[i + 1][2][k]) * dt for k in range(3)]
            th = math.sqrt(sum(x * x for x in phi))
            s = 0.5 - th * th / 48 if th < 1e-4 else math.sin(th / 2) / th
            q = qmul(q, (math.cos(th / 2), s * phi[0], s * phi[1], s * phi[2]))
        pred, after = rotate_back(q, up(a)), up(b)
        cross = [pred[1] * after[2] - pred[2] * after[1], pred[2] * after[0] - pred[0] * after[2],
                 pred[0] * after[1] - pred[1] * after[0]]
        out.append(math.degrees(math.atan2(math.sqrt(sum(x * x for x in cross)),
                                           sum(p * q for p, q in zip(pred, after)))))
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("check", choices=["params", "files", "steady", "noisy", "refused", "rests",
                                          "names", "effects", "final", "rates", "same"])
    parser.add_argument("report")
    parser.add_argument("truth", nargs="?")
    parser.add_argument("--verdict", default="pass,warn", help="allowed verdicts")
    parser.add_argument("--faces-once", action="store_true",
                        help="six faces once: the floor is assumed level")
    parser.add_argument("--gyro", choices=["none", "bias", "all", "absent"], default="all",
                        help="which gyroscope parameters the capture determines (absent: an "
                             "accelerometer-only capture, no gyro key in the parameter set)")
    parser.add_argument("--multi-file", action="store_true",
                        help="poses are matched to the simulated holds by file")
    parser.add_argument("--stderr", help="names: the command's stderr, searched too")
    parser.add_argument("--want", action="append", default=[],
                        help="names: a string that must be said (A|B: either)")
    parser.add_argument("--val-truth", help="effects: the validation capture's truth.json")
    parser.add_argument("--val-raw", help="effects: the validation capture (raw)")
    parser.add_argument("--applied",
                        help="final: `imucal apply`'s output for the capture; effects: for the "
                             "validation capture")
    parser.add_argument("--applied-without", help="effects: the same without the effects")
    parser.add_argument("--clean", help="rates: the report of a capture without a rate term")
    parser.add_argument("--bias-aim-deg-s", type=float, default=None,
                        help="steady: the gyro bias within this of the truth, every axis")
    parser.add_argument("--gravity-aim-deg", type=float, default=None,
                        help="steady: the gravity direction after the moves, RMS, at most")
    parser.add_argument("--one-per-hold", type=float, default=None, metavar="MIN_S",
                        help="rests: every hold of MIN_S or more is one used pose")
    parser.add_argument("--per-file", action="store_true",
                        help="rests: every file's hold is one used pose (a split capture)")
    parser.add_argument("--ratio", type=float, default=1.3,
                        help="effects: validation error allowed, times the truth's")
    args = parser.parse_args()
    c = Checker()
    report = load(args.report)
    truth = load(args.truth) if args.truth else None
    verdicts = args.verdict.split(",")
    c.check(f"verdict {report.get('verdict')!r}, want one of {verdicts}",
            report.get("verdict") in verdicts)

    if args.check == "effects":
        found, floor, without = check_effects(c, report, truth, args)
        c.done("validation accel %.3f mg (truth %.3f, without effects %.3f), gyro %.4f deg/s "
               "(truth %.4f, without effects %.4f)" % (
                   found[0] * 1e3 / 9.80665, floor[0] * 1e3 / 9.80665,
                   without[0] * 1e3 / 9.80665, math.degrees(found[1]), math.degrees(floor[1]),
                   math.degrees(without[1])))
    elif args.check == "rates":
        found, floor, without = check_rates(c, report, truth, args)
        c.done("validation: the gravity direction after the moves %.4f deg RMS with the term "
               "(truth %.4f, without it %.4f)" % (math.degrees(found), math.degrees(floor),
                                                   math.degrees(without)))
    elif args.check == "same":
        # TRUTH is another report here: the same capture read another way.
        same_params(c, report, truth)
        c.done("the same parameters as " + os.path.basename(args.truth))
    elif args.check == "params":
        pairs = match_poses(c, report, truth, args.multi_file)
        check_directions(c, pairs, truth)
        tol = check_params(c, report, truth, args)
        c.done(f"{len(pairs)} poses, verdict {report.get('verdict')}; within " +
               ", ".join(f"{k} {v:.2g}" for k, v in tol.items()))
    elif args.check == "final":
        # The report's figures are the parameter set's as a robot applies it: the gravity
        # direction after the moves, recomputed here from `imucal apply`'s samples alone.
        errors = final_moves(report, read_applied(args.applied))
        rms = math.sqrt(sum(e * e for e in errors) / len(errors))
        want = report["residual"]["gravity_direction_rms_deg"]
        c.check(f"gravity direction after {len(errors)} moves from the applied samples "
                f"{rms:.4f} deg RMS, the report says {want:.4f}",
                len(errors) > 0 and abs(rms - want) <= 0.02 * want + 1e-3)
        c.done(f"the report's {want:.4f} deg RMS after the moves is the applied parameters' "
               f"({rms:.4f} deg)")
    elif args.check == "files":
        check_files(c, report, truth)
        check_reasons(c, report)
        c.done(f"{len(report['poses'])} poses, each with its file and lines")
    elif args.check == "steady":
        # No used pose inside a turn's constant-rate middle: a steady rate is not rest. (An
        # unused one that still split the move shows in the gravity direction below.)
        for m in truth["moves"]:
            if m["profile"] != "steady":
                continue
            lo, hi = m["t_start_s"] + m["ramp_s"], m["t_end_s"] - m["ramp_s"]
            for p in used_poses(report):
                c.check(f"used pose {p['index']} ({p['t_start']:.2f}-{p['t_end']:.2f} s) lies "
                        f"in the steady turn at {lo:.2f}-{hi:.2f} s",
                        p["t_end"] < lo or p["t_start"] > hi)
        # The gravity direction after the moves: the move's integrated gyroscope noise and the
        # two poses' direction noise; RMS within 3, max within 5 of that standard error.
        res = report.get("residual", {})
        rate, g = truth["rate_hz"], truth["gravity_m_s2"]
        used = used_poses(report)
        n = min(p["samples"] for p in used) if used else 1
        longest = max(m["t_end_s"] - m["t_start_s"] + 1 / rate for m in truth["moves"])
        sigma = math.sqrt((noise_of(truth, "gyro") * math.sqrt(longest * rate) / rate) ** 2 +
                          2 * (noise_of(truth, "accel") / math.sqrt(n) / g) ** 2)
        for key, k in (("gravity_direction_rms_deg", 3), ("gravity_direction_max_deg", 5)):
            v = res.get(key)
            c.check(f"residual.{key} = {v}, want <= {k} x {math.degrees(sigma):.3f} deg",
                    isinstance(v, (int, float)) and v <= k * math.degrees(sigma))
        # Static gyroscope rate: each pose's mean rate after calibration is noise / sqrt(n)
        # per axis, sqrt(3) times that as a vector; allowed 3 times that.
        v = res.get("gyro_static_rms")
        lim = 3 * math.sqrt(3) * noise_of(truth, "gyro") / math.sqrt(n)
        c.check(f"residual.gyro_static_rms = {v} rad/s, want <= {lim:.3g}",
                isinstance(v, (int, float)) and v <= lim)
        # The aims, absolute (issue 24: a steady turn must not harm the gyro's fit).
        bias = ((report.get("parameters") or {}).get("gyro") or {}).get("bias") or [0] * 3
        err = max(abs(math.degrees(b - t)) for b, t in zip(bias, truth["gyro_bias_rad_s"]))
        if args.bias_aim_deg_s is not None:
            c.check(f"gyro bias {bias} rad/s is {err:.4f} deg/s off the truth, aim "
                    f"{args.bias_aim_deg_s}", err <= args.bias_aim_deg_s)
        if args.gravity_aim_deg is not None:
            v = res.get("gravity_direction_rms_deg")
            c.check(f"gravity direction after the moves {v} deg RMS, aim {args.gravity_aim_deg}",
                    isinstance(v, (int, float)) and v <= args.gravity_aim_deg)
        c.done(f"no pose mid-turn; gyro bias {err:.4f} deg/s off the truth; gravity after the "
               f"moves {res.get('gravity_direction_rms_deg')}"
               f" deg RMS (limit {3 * math.degrees(sigma):.3f}), static gyro "
               f"{res.get('gyro_static_rms')} rad/s (limit {lim:.3g})")
    elif args.check == "rests":
        check_rests(c, report, truth, args)
    elif args.check == "noisy":
        # The noisy rest stays one pose: one pose found across its hold, used, no fragments
        # beside it, covering at least 40% of it. A settling sensor's start may be left out:
        # its extra noise, 5x dying as exp(-3t/T), is still 1.6x the quiet rest's at 0.46 T,
        # and the variance test decides at a rest's edges. A fragment may not be kept instead.
        k = truth["noisy_rest"]["pose"]
        want = truth["poses"][k]
        hits = [p for p in report["poses"]
                if p["t_start"] <= want["t_end_s"] and want["t_start_s"] <= p["t_end"]]
        hold = want["t_end_s"] - want["t_start_s"]
        desc = [(p["index"], round(p["t_start"], 2), round(p["t_end"], 2), p["used"],
                 p.get("reason", "")) for p in hits]
        c.check(f"the {truth['noisy_rest']['kind']} rest at {want['t_start_s']:.2f}-"
                f"{want['t_end_s']:.2f} s: poses {desc}, want one used pose over >= 40% of it",
                len(hits) == 1 and hits[0]["used"] and
                hits[0]["t_end"] - hits[0]["t_start"] >= 0.4 * hold)
        c.done(f"the {hold:.1f} s {truth['noisy_rest']['kind']} rest is one pose")
    elif args.check == "refused":
        c.check("no poses list", isinstance(report.get("poses"), list))
        check_reasons(c, report)
        c.done(f"refused report with {len(report.get('poses', []))} poses, each used or why not")
    elif args.check == "names":
        text = report_text(report)
        if args.stderr:
            with open(args.stderr, errors="replace") as f:
                text += "\n" + f.read()
        for want in args.want:
            c.check(f"neither the report's reasons nor stderr say {want!r}",
                    any(w in text for w in want.split("|")))
        c.done("named: " + ", ".join(args.want))


if __name__ == "__main__":
    main()
