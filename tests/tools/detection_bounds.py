#!/usr/bin/env python3
"""Detection bounds on captures the project did not shape (issue 25, item 4).

The independent writer (write_columns.py, imu_sim.py) draws a unit from wide priors and a
temperature path. On each seed:
  1. a capture with no effect, on a linear ramp: imucal states, per output, the smallest
     temperature curvature it would have found 9 times in 10 (effect_diagnostics.detection_bounds);
  2. the same unit, path and noise with a curvature of 3x that bound on the gyro's x axis and on
     the accelerometer's z axis, its turnover at the bound's reference: it must be found;
  3. the same with 0.2x the bound: it must not be;
  4. the same unit at a constant temperature: the bound must be absent (null: the temperature
     does not vary) or at least 10x the ramp's;
  5. the gyro's rate-dependent scale on z (effect_diagnostics.move_search.detection_bounds,
     `gz*|gz|`), on 36 hand-paced moves between random orientations: 3x its bound found, 0.2x
     not.

Usage: detection_bounds.py IMUCAL [--seeds N]
"""
import argparse
import json
import os
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))


def calibrate(imucal, tmp, name, seed, extra):
    out = os.path.join(tmp, name)
    subprocess.run([sys.executable, os.path.join(HERE, "write_columns.py"), "--format", "imucal",
                    "--seed", str(seed), "--unit-seed", str(seed)] + extra + [out],
                   check=True, stdout=subprocess.DEVNULL)
    run = subprocess.run([imucal, "calibrate", os.path.join(out, "imu.csv"), "--json"],
                         capture_output=True, text=True)
    if run.returncode not in (0, 4):
        sys.exit(f"{name}: imucal exited {run.returncode}: {run.stderr.strip()}")
    return json.loads(run.stdout)


def curvature_bound(report, sensor, axis):
    for b in report["effect_diagnostics"].get("detection_bounds", []):
        if b["sensor"] == sensor and b["axis"] == axis and re.fullmatch(
                r"\(temperature-[0-9.]+\)\^2", b["regressor"]):
            return b
    return None


def found_curvature(report, sensor, axis):
    return any(e["sensor"] == sensor and e["axis"] == axis and
               re.fullmatch(r"\(temperature-[0-9.]+\)\^2", e["regressor"])
               for e in report.get("effects", []))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("imucal")
    ap.add_argument("--seeds", type=int, default=3)
    args = ap.parse_args()
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(1, args.seeds + 1):
            clean = calibrate(args.imucal, tmp, f"clean{seed}", seed,
                              ["--temp-history", "ramp:25,33"])
            flat = calibrate(args.imucal, tmp, f"flat{seed}", seed,
                             ["--temp-history", "plateau:30"])
            for sensor, axis, flag in (("gyro", "x", "--gyro-temp-quad"),
                                       ("accel", "z", "--accel-temp-quad")):
                bound = curvature_bound(clean, sensor, axis)
                if bound is None or bound["coefficient"] is None:
                    failures.append(f"seed {seed}: no finite {sensor} {axis} curvature bound")
                    continue
                b = bound["coefficient"]
                tref = re.search(r"temperature-([0-9.]+)", bound["regressor"]).group(1)
                for times, want in ((3.0, True), (0.2, False)):
                    r = calibrate(args.imucal, tmp, f"fx{seed}{sensor}{times}", seed,
                                  ["--temp-history", "ramp:25,33", flag,
                                   f"{axis},{times * b:.6g},{tref}"])
                    got = found_curvature(r, sensor, axis)
                    print(f"seed {seed} {sensor} {axis}: bound {b:.3g} ({bound['human']}), "
                          f"{times}x -> {'found' if got else 'not found'}")
                    if got != want:
                        failures.append(f"seed {seed} {sensor} {axis}: {times}x the bound "
                                        f"{'found' if got else 'not found'}")
                fb = curvature_bound(flat, sensor, axis)
                flat_c = None if fb is None else fb["coefficient"]
                print(f"seed {seed} {sensor} {axis}: plateau bound {flat_c}")
                if flat_c is not None and flat_c < 10 * b:
                    failures.append(f"seed {seed} {sensor} {axis}: plateau bound {flat_c:.3g} "
                                    f"under 10x the ramp's {b:.3g}")
            # 36 hand-paced moves between random orientations: what a rate term needs to show.
            moves = ["--protocol", "random", "--poses", "36", "--move-s", "1"]
            clean_moves = calibrate(args.imucal, tmp, f"moves{seed}", seed, moves)
            rate = next((b for b in clean_moves["effect_diagnostics"]["move_search"].get(
                "detection_bounds", []) if b["axis"] == "z"), None)
            if rate is None or rate["coefficient"] is None:
                failures.append(f"seed {seed}: no finite rate-scale bound on z")
            else:
                for times, want in ((3.0, True), (0.2, False)):
                    r = calibrate(args.imucal, tmp, f"rate{seed}{times}", seed,
                                  moves + ["--gyro-rate-scale",
                                   f"z,{times * rate['coefficient']:.6g}"])
                    got = any(e["sensor"] == "gyro" and e["axis"] == "z" and
                              e["regressor"] == "gz*|gz|" for e in r.get("effects", []))
                    print(f"seed {seed} gyro z rate scale: bound {rate['human']} ({rate['from']}), "
                          f"{times}x -> {'found' if got else 'not found'}")
                    if got != want:
                        failures.append(f"seed {seed} gyro z rate scale: {times}x the bound "
                                        f"{'found' if got else 'not found'}")
    for f in failures:
        print("FAIL:", f)
    print("ok" if not failures else f"{len(failures)} failures")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
