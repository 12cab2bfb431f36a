#!/usr/bin/env python3
"""Checks imucal's still poses against a motion-capture reference: a rest is a rest.

usage: rests_vs_mocap.py REPORT.json GT.csv [--max-deg D]

REPORT.json is `imucal calibrate --json --out` of a capture whose times are the reference's
(TUM-VI: Unix seconds in both). GT.csv holds the orientation of the IMU: a header line, then
time [s], translation x y z, rotation quaternion x y z w (TUM-VI's roomN_gt.csv layout). For every
pose the report uses, and every one it lists without calling it turning, the reference's largest
rotation from the pose's first reference orientation within the pose must stay under D degrees
(default 3: a hand's tremor, not a turn) plus R deg/s times the pose's duration (--max-rate-deg-s,
default 5: with no second rest to learn the gyroscope's bias from, a drift slower than a MEMS
gyroscope's turn-on bias cannot be told from it, by imucal or anyone; a turn taken for a rest
turns tens of degrees at tens of deg/s).
Poses the reference does not cover (markers lost) are counted and skipped. Standard library only;
nothing from imucal.
"""
import argparse
import bisect
import csv
import json
import math
import sys


def read_gt(path):
    times, quats = [], []
    with open(path, newline="") as f:
        rows = csv.reader(f)
        next(rows)
        for row in rows:
            t = float(row[0])
            x, y, z, w = (float(v) for v in row[4:8])
            n = math.sqrt(x * x + y * y + z * z + w * w)
            times.append(t)
            quats.append((w / n, x / n, y / n, z / n))
    return times, quats


def angle_deg(q1, q2):
    """The rotation angle between two unit quaternions (w, x, y, z)."""
    d = abs(sum(a * b for a, b in zip(q1, q2)))
    return math.degrees(2 * math.acos(min(1.0, d)))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report")
    parser.add_argument("gt")
    parser.add_argument("--max-deg", type=float, default=3.0)
    parser.add_argument("--max-rate-deg-s", type=float, default=5.0)
    args = parser.parse_args()
    with open(args.report) as f:
        report = json.load(f)
    times, quats = read_gt(args.gt)
    bad, checked, uncovered = [], 0, 0
    for p in report.get("poses", []):
        if not p.get("used") and "turning" in str(p.get("reason", "")):
            continue
        lo = bisect.bisect_left(times, p["t_start"])
        hi = bisect.bisect_right(times, p["t_end"])
        span = p["t_end"] - p["t_start"]
        # Covered: reference samples over at least 80% of the pose, no hole over 0.1 s.
        if hi - lo < 2 or times[hi - 1] - times[lo] < 0.8 * span or any(
                times[k + 1] - times[k] > 0.1 for k in range(lo, hi - 1)):
            uncovered += 1
            continue
        checked += 1
        worst = max(angle_deg(quats[lo], quats[k]) for k in range(lo, hi))
        if worst > args.max_deg + args.max_rate_deg_s * span:
            bad.append(f"pose {p['index']} ({p['t_start']:.2f}-{p['t_end']:.2f} s, used "
                       f"{p['used']}): the reference turned {worst:.1f} deg through it")
    for b in bad:
        print("  " + b)
    print(f"  {checked} poses checked against the reference, {uncovered} not covered, "
          f"{len(bad)} turned more than {args.max_deg} deg + {args.max_rate_deg_s} deg/s")
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
