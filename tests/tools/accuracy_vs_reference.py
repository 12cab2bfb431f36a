#!/usr/bin/env python3
"""Scores imucal's accelerometer against a full-model reference fit, on units it did not draw.

usage: accuracy_vs_reference.py IMUCAL [--seeds N] [--first-seed K] [--poses P]
                                [--median-max M] [--p90-max Q] [--worst-max W] [--work DIR]

For each seed: a unit drawn from wide priors (imu_sim.py --unit-seed: second-order terms of
1e-5..3e-4 per m/s^2 on every axis, angles, biases, scales), a calibration capture of it (P
random stops, IMU-TK style, 40 by default; with fewer, say 18, the second-order terms are only
weakly determined, which is where a rule that switches terms on and off loses accuracy) and a
validation capture of the same unit (40 other stops, other noise), both written by write_columns.py as imucal capture CSVs. Then:
  engine     `imucal calibrate` of the calibration capture, applied by `imucal apply` to the
             validation capture: the parameter set exactly as a robot applies it;
  reference  the full 12-parameter magnitude model (bias, scale, 3 angles, 3 second-order terms;
             the frame angles |a| = g cannot see) fitted here, by Gauss-Newton with nothing held,
             to the calibration capture's TRUE still intervals (the writer's, 0.3 s trimmed).
The validation error is the RMS over the validation holds of |mean a| - g. The ratio engine /
reference per seed is printed, with its median and worst; the run fails when the median exceeds
--median-max or the worst --worst-max (an accuracy loss fails CI). Standard library only; the
reference fit is this file's, not imucal's.
"""
import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.dont_write_bytecode = True  # no __pycache__ in the source tree when ctest runs this
from capture_checks import read_csv  # noqa: E402 (the path above)

TRIM_S = 0.3


def hold_means(truth, path):
    """Mean (ax, ay, az) of each simulated hold, trimmed, from an imucal CSV."""
    names, rows = read_csv(path)
    col = {n: i for i, n in enumerate(names)}
    t0 = rows[0][col["t"]]
    out = []
    for p in truth["poses"]:
        lo, hi = p["t_start_s"] + TRIM_S, p["t_end_s"] - TRIM_S
        s, n = [0.0, 0.0, 0.0], 0
        for r in rows:
            if lo <= r[col["t"]] - t0 <= hi:
                for i, name in enumerate(("ax", "ay", "az")):
                    s[i] += r[col[name]]
                n += 1
        out.append([x / n for x in s])
    return out


def model(theta, u):
    """imucal's accelerometer model (README): y = s (u - b), z = y + q y^2, a = L z."""
    b, s, (t_yx, t_zx, t_zy), q = theta[0:3], theta[3:6], theta[6:9], theta[9:12]
    y = [s[i] * (u[i] - b[i]) for i in range(3)]
    z = [y[i] + q[i] * y[i] * y[i] for i in range(3)]
    return [z[0], t_yx * z[0] + z[1], t_zx * z[0] + t_zy * z[1] + z[2]]


def solve(a, b):
    """Gaussian elimination with partial pivoting: a x = b (a square, lists)."""
    n = len(b)
    m = [row[:] + [b[i]] for i, row in enumerate(a)]
    for c in range(n):
        p = max(range(c, n), key=lambda r: abs(m[r][c]))
        m[c], m[p] = m[p], m[c]
        for r in range(c + 1, n):
            f = m[r][c] / m[c][c]
            for k in range(c, n + 1):
                m[r][k] -= f * m[c][k]
    x = [0.0] * n
    for r in range(n - 1, -1, -1):
        x[r] = (m[r][n] - sum(m[r][k] * x[k] for k in range(r + 1, n))) / m[r][r]
    return x


def reference_fit(means, g):
    """Gauss-Newton (Levenberg-damped) on |a(theta, u)| - g over the pose means, all 12 free."""
    theta = [0.0, 0.0, 0.0, 1.0, 1.0, 1.0] + [0.0] * 6
    res = lambda th: [math.sqrt(sum(c * c for c in model(th, u))) - g for u in means]  # noqa
    cost = sum(r * r for r in res(theta))
    lam = 1e-3
    for _ in range(100):
        r0 = res(theta)
        jac = []
        for k in range(12):
            h = 1e-7 * max(1.0, abs(theta[k]))
            tp = theta[:]
            tp[k] += h
            jac.append([(a - b) / h for a, b in zip(res(tp), r0)])
        jtj = [[sum(jac[i][n] * jac[j][n] for n in range(len(means))) for j in range(12)]
               for i in range(12)]
        jtr = [-sum(jac[i][n] * r0[n] for n in range(len(means))) for i in range(12)]
        for i in range(12):
            jtj[i][i] *= 1 + lam
        step = solve(jtj, jtr)
        cand = [t + d for t, d in zip(theta, step)]
        c_cost = sum(r * r for r in res(cand))
        if c_cost < cost:
            theta, lam = cand, lam / 10
            if cost - c_cost < 1e-15 * max(1.0, cost):
                break
            cost = c_cost
        else:
            lam *= 10
    return theta


def rms(v):
    return math.sqrt(sum(x * x for x in v) / len(v))


def run(cmd):
    p = subprocess.run(cmd, capture_output=True, text=True)
    return p.returncode, p.stderr


def score_seed(imucal, seed, work, cal_poses):
    common = ["--format", "imucal", "--protocol", "random", "--unit-seed", str(seed)]
    cal, val = os.path.join(work, f"cal{seed}"), os.path.join(work, f"val{seed}")
    for out, s, poses in ((cal, 1000 + seed, cal_poses), (val, 2000 + seed, 40)):
        rc, err = run([sys.executable, os.path.join(HERE, "write_columns.py"), out,
                       "--seed", str(s), "--poses", str(poses)] + common)
        if rc:
            raise RuntimeError(f"writer failed: {err}")
    truth_cal = json.load(open(os.path.join(cal, "truth.json")))
    truth_val = json.load(open(os.path.join(val, "truth.json")))
    g = truth_cal["gravity_m_s2"]
    report = os.path.join(work, f"r{seed}.json")
    rc, err = run([imucal, "calibrate", os.path.join(cal, "imu.csv"), "--json", "--out", report])
    if rc not in (0, 4):
        raise RuntimeError(f"seed {seed}: calibrate exit {rc}: {err[-400:]}")
    applied = os.path.join(work, f"a{seed}.csv")
    rc, err = run([imucal, "apply", "--params", report, os.path.join(val, "imu.csv"), applied])
    if rc:
        raise RuntimeError(f"seed {seed}: apply exit {rc}: {err[-400:]}")
    engine = rms([math.sqrt(sum(c * c for c in a)) - g for a in hold_means(truth_val, applied)])
    theta = reference_fit(hold_means(truth_cal, os.path.join(cal, "imu.csv")), g)
    val_raw = hold_means(truth_val, os.path.join(val, "imu.csv"))
    ref = rms([math.sqrt(sum(c * c for c in model(theta, u))) - g for u in val_raw])
    quad = json.load(open(report))["parameters"]["accel"].get("quadratic")
    return engine, ref, quad, truth_cal["accel_model"]["quadratic"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("imucal")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--poses", type=int, default=40, help="stops of the calibration capture")
    parser.add_argument("--median-max", type=float, default=None)
    parser.add_argument("--worst-max", type=float, default=None)
    parser.add_argument("--p90-max", type=float, default=None,
                        help="fail when the 90th percentile of the ratios exceeds this")
    parser.add_argument("--work", default=None, help="keep the files here")
    args = parser.parse_args()
    if args.work is None:
        with tempfile.TemporaryDirectory(prefix="imucal-accuracy-") as work:
            return score(args, work)
    os.makedirs(args.work, exist_ok=True)
    return score(args, args.work)


def score(args, work):
    ratios = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        engine, ref, quad, true_quad = score_seed(args.imucal, seed, work, args.poses)
        ratios.append(engine / ref)
        print(f"  unit {seed}: validation |a| - g {engine * 1e3 / 9.80665:.3f} mg RMS, reference "
              f"{ref * 1e3 / 9.80665:.3f} mg, ratio {engine / ref:.2f}; quadratic "
              f"{['%.1e' % q for q in quad]} (true {['%.1e' % q for q in true_quad]})")
    med, worst = statistics.median(ratios), max(ratios)
    p90 = sorted(ratios)[min(len(ratios) - 1, int(0.9 * len(ratios)))]
    print(f"  {len(ratios)} units: engine / reference median {med:.2f}x, 90th percentile "
          f"{p90:.2f}x, worst {worst:.2f}x")
    bad = []
    if args.median_max is not None and med > args.median_max:
        bad.append(f"median {med:.2f}x above {args.median_max}")
    if args.p90_max is not None and p90 > args.p90_max:
        bad.append(f"90th percentile {p90:.2f}x above {args.p90_max}")
    if args.worst_max is not None and worst > args.worst_max:
        bad.append(f"worst {worst:.2f}x above {args.worst_max}")
    for b in bad:
        print("FAIL: " + b)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
