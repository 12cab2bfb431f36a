#!/usr/bin/env python3
"""Writes a simulated six-face capture as a EuRoC MAV dataset's IMU file, independently of
imucal's importer: OUT/mav0/imu0/data.csv with the dataset's exact header, one row per sample
(timestamp in integer nanoseconds, angular rate in rad/s, specific force in m/s^2, sensor
frame), and OUT/truth.json with what the simulation used (tests/tools/imu_sim.py).

Standard library only. Usage: write_euroc.py OUT_DIR [--seed N] [--crlf] ...
"""
import argparse
import json
import os
import sys

sys.dont_write_bytecode = True  # no __pycache__ in the source tree when ctest runs this
import imu_sim  # noqa: E402 (after the line above)

EUROC_HEADER = ("#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]")
# The datasets' stamps are Unix times in ns (MH_01_easy starts at 1403636579758555392).
T0_NS = 1403636579758555392


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir")
    parser.add_argument("--crlf", action="store_true", help="Windows line endings")
    imu_sim.add_arguments(parser)
    args = parser.parse_args()
    samples, truth = imu_sim.simulate(args)

    imu_dir = os.path.join(args.out_dir, "mav0", "imu0")
    os.makedirs(imu_dir, exist_ok=True)
    path = os.path.join(imu_dir, "data.csv")
    eol = "\r\n" if args.crlf else "\n"
    period_ns = round(1e9 / args.rate_hz)
    with open(path, "w", newline="") as f:
        f.write(EUROC_HEADER + eol)
        for k, (_, gyro, accel) in enumerate(samples):
            # Integer stamps from the sample counter: no float rounding drift over the capture.
            f.write(",".join([str(T0_NS + k * period_ns)] + [repr(v) for v in gyro + accel]) + eol)
    truth["file"] = os.path.relpath(path, args.out_dir)
    truth["first_timestamp_ns"] = T0_NS
    with open(os.path.join(args.out_dir, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    print(path)


if __name__ == "__main__":
    main()
