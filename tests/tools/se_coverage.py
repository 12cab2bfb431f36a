#!/usr/bin/env python3
"""Are imucal's standard errors honest? Errors against the truth, in standard errors, on units
imucal did not draw.

usage: se_coverage.py IMUCAL [--seeds N] [--poses P] [--rms-min A] [--rms-max B] [--work DIR]

For each seed a unit is drawn from wide priors and written by the independent writer
(write_columns.py --unit-seed: second-order terms of 1e-5..3e-4 per m/s^2, angles, biases,
scales; a random-stops capture of P poses, 40 by default), calibrated by `imucal calibrate`, and
every estimated parameter's error against the writer's truth is divided by the standard error the
report gives (z). Per group (accel bias, scale, angles, second-order terms; gyro scale, bias) the
RMS of z is printed: 1 when the standard errors are exact, below 1 when they are cautious, above
when they claim more than the data hold. The run fails when a group's RMS leaves
[--rms-min, --rms-max]. Standard library only.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))


def z_scores(imucal, seed, poses, work):
    d = os.path.join(work, f"s{seed}")
    p = subprocess.run([sys.executable, os.path.join(HERE, "write_columns.py"), d, "--seed",
                        str(1000 + seed), "--poses", str(poses), "--format", "imucal",
                        "--protocol", "random", "--unit-seed", str(seed)],
                       capture_output=True, text=True)
    if p.returncode:
        raise RuntimeError(f"seed {seed}: writer failed: {p.stderr[-400:]}")
    truth = json.load(open(os.path.join(d, "truth.json")))
    out = os.path.join(d, "report.json")
    p = subprocess.run([imucal, "calibrate", os.path.join(d, "imu.csv"), "--json", "--out", out],
                       capture_output=True, text=True)
    if p.returncode not in (0, 4):
        raise RuntimeError(f"seed {seed}: calibrate exit {p.returncode}: {p.stderr[-400:]}")
    params = json.load(open(out))["parameters"]
    z = {}
    a = params["accel"]
    for k in ("bias", "scale", "tri_angles", "quadratic"):
        for i in range(3):
            se = a["stderr"][k][i]
            if se and se > 0:
                z.setdefault(f"accel {k}", []).append((a[k][i] - truth["accel_model"][k][i]) / se)
    g = params["gyro"]
    se = g.get("stderr", {})
    for i in range(3):
        s = (se.get("matrix") or [[0] * 3] * 3)[i][i]
        if s and s > 0:  # the writer's gyro has no misalignment: the diagonal is the scale
            z.setdefault("gyro scale", []).append((g["matrix"][i][i] - truth["gyro_scale"][i]) / s)
        s = (se.get("bias") or [0] * 3)[i]
        if s and s > 0:
            z.setdefault("gyro bias", []).append((g["bias"][i] - truth["gyro_bias_rad_s"][i]) / s)
    return z


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("imucal")
    ap.add_argument("--seeds", type=int, default=30)
    ap.add_argument("--poses", type=int, default=40)
    ap.add_argument("--rms-min", type=float, default=None)
    ap.add_argument("--rms-max", type=float, default=None)
    ap.add_argument("--work", default=None, help="keep the captures and reports here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or tmp
        groups = {}
        for seed in range(1, args.seeds + 1):
            for k, v in z_scores(args.imucal, seed, args.poses, work).items():
                groups.setdefault(k, []).extend(v)
    bad = []
    print(f"{args.seeds} units, {args.poses} poses each: error / standard error per group")
    for k, v in groups.items():
        rms = math.sqrt(sum(x * x for x in v) / len(v))
        print(f"  {k:22s} n={len(v):3d}  RMS {rms:.2f}  largest {max(abs(x) for x in v):.1f}")
        if (args.rms_min is not None and rms < args.rms_min) or \
           (args.rms_max is not None and rms > args.rms_max):
            bad.append(f"{k}: RMS {rms:.2f} outside [{args.rms_min}, {args.rms_max}]")
    if not groups:
        bad.append("no standard errors to score")
    for b in bad:
        print("FAIL " + b, file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
