#!/usr/bin/env python3
"""The same unit, the same answer: imucal on a repeatability set, beside IMU-TK's own results.

Runs `imucal calibrate --json` on each capture of a directory laid out like
../shared/data/real/imutk-ros2-repeat (captureN/{acc,gyro}_data.txt with IMU-TK's
imutk_result_{acc,gyro}.calib beside them, captureN-rosbag2/ bags of the same samples) and
prints, as Markdown:
  - per capture: verdict (or refusal reason), model terms freed, effects found;
  - accelerometer and gyroscope bias and scale with their standard errors, IMU-TK's beside them;
  - the spread between captures: each parameter's largest pairwise difference over the captures
    imucal calibrated, in combined standard errors (|p_i - p_j| / sqrt(se_i^2 + se_j^2)).

Conventions. imucal: a = M (diag(scale) (u - b)) with |a| = 9.80665 m/s^2 at rest (report.md);
IMU-TK: a = T K (u - b) with |a| = 9.81744 m/s^2 (its default gravity), so its accelerometer
scale K is converted by 9.80665 / 9.81744 to compare. Gyro scale: imucal's matrix diagonal,
IMU-TK's K (no gravity involved). Misalignments use different triangular conventions and are
not compared. Usage: repeatability.py IMUCAL DATA_DIR [--json OUT]
"""
import argparse
import itertools
import json
import math
import os
import subprocess
import sys
import tempfile

IMUTK_GRAVITY = 9.81744
IMUCAL_GRAVITY = 9.80665


def read_calib(path):
    """IMU-TK's .calib: T (3x3), K (3x3), b (3), whitespace separated."""
    with open(path) as f:
        v = [float(x) for x in f.read().split()]
    if len(v) != 21:
        raise ValueError(f"{path}: expected 21 numbers (T, K, b), found {len(v)}")
    return {"T": [v[0:3], v[3:6], v[6:9]], "K": [v[9], v[13], v[17]], "b": v[18:21]}


def run(imucal, inputs, out_json):
    p = subprocess.run([imucal, "calibrate", *inputs, "--json", "--out", out_json],
                       capture_output=True, text=True)
    report = None
    if os.path.exists(out_json):
        with open(out_json) as f:
            report = json.load(f)
    return p.returncode, report, p.stderr


def params_of(report):
    """The compared parameters: (value, standard error or None) by name. The first twelve are
    the table's (bias and scale); the rest (angles, second-order terms, the gyro matrix's
    off-diagonal) join the z statistics only."""
    if not report or report.get("verdict") == "refused":
        return None
    a, g = report["parameters"]["accel"], report["parameters"]["gyro"]
    out = {}
    for k in range(3):
        ax = "xyz"[k]
        out[f"accel bias {ax}"] = (a["bias"][k], a["stderr"]["bias"][k])
        out[f"accel scale {ax}"] = (a["scale"][k], a["stderr"]["scale"][k])
        out[f"gyro bias {ax}"] = (g["bias"][k], g["stderr"]["bias"][k])
        out[f"gyro scale {ax}"] = (g["matrix"][k][k], g["stderr"]["matrix"][k][k])
    for k, name in enumerate(("t_yx", "t_zx", "t_zy")):
        out[f"accel {name}"] = (a["tri_angles"][k], a["stderr"]["tri_angles"][k])
    for k in range(3):
        out[f"accel quadratic {'xyz'[k]}"] = (a["quadratic"][k], a["stderr"]["quadratic"][k])
    for r in range(3):
        for c in range(3):
            if r != c:
                out[f"gyro matrix {'xyz'[r]}{'xyz'[c]}"] = (g["matrix"][r][c],
                                                            g["stderr"]["matrix"][r][c])
    return out


TABLE_KEYS = 12


def pairwise_z(runs):
    """Every parameter's difference between every two captures, in combined standard errors
    (|p_i - p_j| / sqrt(se_i^2 + se_j^2)); honest standard errors make these |N(0, 1)|."""
    out = []
    for (n1, p1), (n2, p2) in itertools.combinations(runs, 2):
        for k in p1:
            (v1, s1), (v2, s2) = p1[k], p2[k]
            if s1 and s2 and v1 is not None and v2 is not None:
                out.append((abs(v1 - v2) / math.hypot(s1, s2), k, n1, n2))
    return out


def imutk_params(d):
    acc = read_calib(os.path.join(d, "imutk_result_acc.calib"))
    gyr = read_calib(os.path.join(d, "imutk_result_gyro.calib"))
    out = {}
    for k in range(3):
        ax = "xyz"[k]
        out[f"accel bias {ax}"] = acc["b"][k]
        out[f"accel scale {ax}"] = acc["K"][k] * IMUCAL_GRAVITY / IMUTK_GRAVITY
        out[f"gyro bias {ax}"] = gyr["b"][k]
        out[f"gyro scale {ax}"] = gyr["K"][k]
    return out


def freed(report):
    if not report or "parameters" not in report:
        return ""
    q = report["parameters"]["accel"]["stderr"].get("quadratic", [None] * 3)
    terms = [f"q_{'xyz'[k]}" for k in range(3) if q[k] is not None]
    return ", ".join(terms) if terms else "none"


def effects(report):
    if not report:
        return ""
    es = [f"{e['sensor']} {e['axis']} ~ {e['regressor']}" for e in report.get("effects", [])
          if e.get("applied", True)]
    return "; ".join(es) if es else "none"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("imucal")
    ap.add_argument("data_dir")
    ap.add_argument("--json", help="write the figures as JSON here")
    ap.add_argument("--z-rms-max", type=float, default=None,
                    help="fail when the RMS of the pairwise z exceeds this")
    ap.add_argument("--z-max", type=float, default=None,
                    help="fail when any pairwise z exceeds this")
    args = ap.parse_args()
    runs = []  # (name, rc, report, imutk or None)
    tmp = tempfile.mkdtemp(prefix="imucal-repeat-")
    for name in sorted(os.listdir(args.data_dir)):
        d = os.path.join(args.data_dir, name)
        if not os.path.isdir(d):
            continue
        if os.path.exists(os.path.join(d, "acc_data.txt")):
            inputs = [os.path.join(d, "acc_data.txt"), os.path.join(d, "gyro_data.txt")]
            tk = imutk_params(d) if os.path.exists(
                os.path.join(d, "imutk_result_acc.calib")) else None
        elif os.path.exists(os.path.join(d, "metadata.yaml")):
            inputs, tk = [d], None
        else:
            continue
        rc, report, err = run(args.imucal, inputs, os.path.join(tmp, name + ".json"))
        runs.append((name, rc, report, tk, err))

    print("| capture | exit | verdict | reasons | quadratic terms freed | effects |")
    print("|---|---|---|---|---|---|")
    for name, rc, rep, _, err in runs:
        verdict = rep.get("verdict", "?") if rep else "(no report)"
        reasons = "; ".join(rep.get("verdict_reasons", [])) if rep else err.strip()[-200:]
        if rep and rep.get("refusal"):
            reasons = rep["refusal"]["reason"] + ": " + rep["refusal"]["message"]
        print(f"| {name} | {rc} | {verdict} | {reasons[:160]} | {freed(rep)} | {effects(rep)} |")

    solved = [(n, params_of(r), tk) for n, _, r, tk, _ in runs if params_of(r)]
    keys = list(solved[0][1].keys())[:TABLE_KEYS] if solved else []
    print()
    print("| parameter | " + " | ".join(f"{n} imucal | {n} IMU-TK" for n, _, _ in solved) +
          " | spread (combined SE) |")
    print("|---|" + "---|" * (2 * len(solved) + 1))
    spreads = {}
    text_runs = [(n, p) for n, p, tk in solved if tk is not None]
    for k in keys:
        cells = []
        for n, p, tk in solved:
            v, se = p[k]
            cells.append(f"{v:.6g} ± {se:.2g}" if se is not None else f"{v:.6g}")
            cells.append(f"{tk[k]:.6g}" if tk else "")
        worst = 0.0
        for (n1, p1), (n2, p2) in itertools.combinations(text_runs, 2):
            (v1, s1), (v2, s2) = p1[k], p2[k]
            if s1 and s2:
                worst = max(worst, abs(v1 - v2) / math.hypot(s1, s2))
        spreads[k] = worst
        print(f"| {k} | " + " | ".join(cells) + f" | {worst:.1f} |")
    zs = pairwise_z(text_runs)
    bad = []
    if zs:
        z_rms = math.sqrt(sum(z * z for z, *_ in zs) / len(zs))
        worst = max(zs)
        print()
        print(f"pairwise differences over {len(text_runs)} captures: {len(zs)} parameter pairs, "
              f"RMS {z_rms:.2f} combined SE (1 if honest), mean |z| "
              f"{sum(z for z, *_ in zs) / len(zs):.2f} (0.80 if honest), "
              f"{sum(z > 2 for z, *_ in zs)} above 2, {sum(z > 3 for z, *_ in zs)} above 3; "
              f"largest {worst[0]:.1f} ({worst[1]}, {worst[2]} vs {worst[3]})")
        for z, k, n1, n2 in sorted(zs, reverse=True)[:8]:
            print(f"  {z:4.1f}  {k}  ({n1} vs {n2})")
        if args.z_rms_max is not None and z_rms > args.z_rms_max:
            bad.append(f"RMS of the pairwise z {z_rms:.2f} above {args.z_rms_max}")
        if args.z_max is not None and worst[0] > args.z_max:
            bad.append(f"largest pairwise z {worst[0]:.1f} above {args.z_max}")
    elif args.z_rms_max is not None or args.z_max is not None:
        bad.append("fewer than two captures calibrated: nothing to compare")
    for b in bad:
        print("FAIL: " + b)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"runs": [{"name": n, "exit": rc, "verdict": (r or {}).get("verdict"),
                                 "reasons": (r or {}).get("verdict_reasons"),
                                 "refusal": (r or {}).get("refusal"),
                                 "params": params_of(r)} for n, rc, r, _, _ in runs],
                       "spread_combined_se": spreads,
                       "pairwise_z": [{"z": z, "parameter": k, "captures": [n1, n2]}
                                      for z, k, n1, n2 in zs]}, f, indent=1)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
