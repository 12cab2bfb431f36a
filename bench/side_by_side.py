#!/usr/bin/env python3
"""Times `imucal calibrate` and another calibration program on one capture, side by side.

The two run as processes in N interleaved pairs (the order alternates), so both see the same
machine; each pair gives a wall-time ratio (ours / theirs). Prints the median wall and CPU
(user + sys) time of each, and the median per-pair ratio.

The reference in docs/figures.md is IMU-TK (github.com/Kyle-ak/imu_tk, commit 1fd1e1ab), built
outside this repository with -O3: its apps/test_imu_calib.cpp unchanged, and, in place of
src/visualization.cpp, plot functions that do nothing (the app plots and waits for a key in its
verbose mode). Its own settings are the app's (5000 initial samples, g = 9.81744).

  python3 bench/side_by_side.py --imucal build/client/imucal --other /path/to/imutk_calib \\
      --pairs 41 ../shared/data/real/xsens-imutk/xsens_acc.mat \\
      ../shared/data/real/xsens-imutk/xsens_gyro.mat -- --gravity 9.81744
"""
import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time


def run(cmd, cwd):
    """Wall seconds and user + sys CPU seconds of one process; exits on a non-zero status."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=cwd)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        sys.exit(f"side_by_side: {' '.join(cmd)} exited with {code}")
    return wall, usage.ru_utime + usage.ru_stime


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--imucal", default="build/client/imucal")
    parser.add_argument("--other", required=True, help="the other program; given the FILES")
    parser.add_argument("--pairs", type=int, default=41)
    parser.add_argument("files", nargs="+", help="the capture's files, as both programs take them")
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1:] if "--" in argv else []  # after --: imucal's own flags
    args = parser.parse_args(argv[:argv.index("--")] if "--" in argv else argv)
    files = [os.path.abspath(f) for f in args.files]
    cmds = {
        "other": [os.path.abspath(args.other)] + files,
        "imucal": [os.path.abspath(args.imucal), "calibrate"] + files + extra,
    }
    wall = {k: [] for k in cmds}
    cpu = {k: [] for k in cmds}
    ratios = []
    with tempfile.TemporaryDirectory() as cwd:  # where the other program writes its files
        for i in range(args.pairs):
            order = ("other", "imucal") if i % 2 == 0 else ("imucal", "other")
            pair = {name: run(cmds[name], cwd) for name in order}
            for name, (w, c) in pair.items():
                wall[name].append(w)
                cpu[name].append(c)
            ratios.append(pair["imucal"][0] / pair["other"][0])
    print(f"{args.pairs} pairs, load average at the end {os.getloadavg()[0]:.2f}")
    for name in ("other", "imucal"):
        print(f"{name:7s} wall median {statistics.median(wall[name]):.4f} s "
              f"(min {min(wall[name]):.4f}, max {max(wall[name]):.4f}), "
              f"CPU median {statistics.median(cpu[name]):.4f} s: {' '.join(cmds[name])}")
    print(f"imucal / other, median of the pairs' wall ratios: {statistics.median(ratios):.4f} "
          f"(min {min(ratios):.4f}, max {max(ratios):.4f})")


if __name__ == "__main__":
    main()
