#!/usr/bin/env python3
"""Writes a simulated capture (tests/tools/imu_sim.py) as delimited text files the way vendors'
tools and hobbyists' scripts do, independently of imucal's importers, and OUT/truth.json with
what was simulated and where each pose is in which file.

Formats (--format):
  columns  a vendor CSV: one header line of the writer's names, in the order
           t,ax,ay,az,gx,gy,gz[,temp] (--header; default
           timestamp_us,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z,temp), time in --time-unit,
           specific force in m/s^2 and rate in rad/s (or raw counts with --counts), temperature
           in degC. --commented-header writes it as a comment ("# time ax ay ...");
           --delimiter comma|semicolon|tab|space.
  imucal   the capture CSV of imucal's capture-format spec, version 1: "# imucal-capture v1",
           "# accel_unit=m/s^2" (or counts), "# gyro_unit=rad/s" (or counts),
           "# gravity=G", "# rate_hz=R", then the column line t,ax,ay,az,gx,gy,gz,temp; t in s.

Files (--split):
  none  OUT/imu.csv: the whole capture, moves included.
  pose  one file per pose, holding that pose's hold only (the recording is stopped between
        poses, so the moves are not in any file): OUT/imu_posX.csv, imu_negZ.csv, ... named by
        the face the pose was meant for ("pos"/"neg" and the axis), or imu_poseNN[_face].csv
        when a face recurs or a pose is on no face. Each file has its own header and its own
        time base (--time-base zero: its first sample at 0; absolute: Unix time, the capture
        starting at --t0-s, so the gaps between files are the moves' durations).

Raw counts (--counts, needs --accel-step and --gyro-step): each value is round(u / step) as an
integer, where u is the simulated reading in m/s^2 or rad/s; the truth gives the model in counts
(bias / step in counts, scale * step in m/s^2 or rad/s per count).

--gyro-unit deg/s writes the rate in degrees per second (the simulated rad/s times 180 / pi), as
many vendors' tools do (not with --counts); the truth's gyro figures stay in rad/s and
"gyro_unit_written" says which unit the file holds.

Files others write (columns format):
  --no-gyro           an accelerometer-only logger: no gyroscope columns (the header's gx, gy, gz
                      names are dropped; imucal format: no gx,gy,gz columns and no gyro_unit).
  --interleave-empty  an interleaved log of several sensors: after each row of this sensor a row
                      whose fields are empty except another sensor's, alternately only the time
                      ("12.5,,,,,,,") and only the temperature (",,,,,,,25.00"). truth.json's
                      "interleaved" names the file and the first such line.
  --label-column      a last column "label" of free text as spreadsheets quote it (RFC 4180): a
                      comma inside quotes and a doubled quote for a quote, e.g.
                      "rest, face ""Z+"" " without the final space.

--nul-at LINE puts a NUL byte at the start of the time field on line LINE (1-based, the header
is line 1 of a columns file) of the first file written, as a corrupted SD card or a serial link
leaves it.

truth.json: imu_sim's truth with each pose's time range, plus "writer" (the options),
"files" (per file: name, the poses in it, the face it was meant for and the orientation it holds,
data lines [first, last], samples), each pose's "file" and "lines" (its hold's first and last
line), "columns_option" (the --columns value naming this file's columns) and "time_unit".

Standard library only. Usage: write_columns.py OUT_DIR [--format columns|imucal]
[--split none|pose] [--time-base zero|absolute] [--counts] ... and imu_sim's options.
"""
import argparse
import json
import math
import os
import sys

sys.dont_write_bytecode = True  # no __pycache__ in the source tree when ctest runs this
import imu_sim  # noqa: E402 (after the line above)

DEFAULT_HEADER = "timestamp_us,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z,temp"
ROLES = ["t", "ax", "ay", "az", "gx", "gy", "gz", "temp"]
DELIMITERS = {"comma": ",", "semicolon": ";", "tab": "\t", "space": " "}
TIME_UNITS = {"s": 1, "ms": 10**3, "us": 10**6, "ns": 10**9}
# Absolute time base: a Unix time (2023-11-14T22:13:20Z), as a logger's clock gives.
T0_S = 1_700_000_000


def face_file_label(face):
    """"Z+" -> "posZ", "X-" -> "negX" (file names avoid + and -)."""
    return ("pos" if face[1] == "+" else "neg") + face[0]


def file_names(poses, prefix):
    faces = [p.get("meant_face", p["face"]).split(" ")[0] for p in poses]
    unique = all(len(f) == 2 for f in faces) and len(set(faces)) == len(faces)
    if unique:
        return [f"{prefix}_{face_file_label(f)}.csv" for f in faces]
    return [f"{prefix}_pose{k:02d}" + (f"_{face_file_label(f)}" if len(f) == 2 else "") + ".csv"
            for k, f in enumerate(faces)]


def time_text(k, k_first, args):
    """Sample k's time in the file's unit: from the sample counter, so integer units have no
    float rounding drift over the capture."""
    per_s = TIME_UNITS[args.time_unit]
    offset = T0_S * per_s if args.time_base == "absolute" else 0
    first = 0 if args.time_base == "absolute" else k_first
    if args.time_unit in ("us", "ns"):
        return str(offset + round((k - first) * per_s / args.rate_hz))
    value = offset + (k - first) * per_s / args.rate_hz
    return f"{value:.6f}" if args.time_unit == "s" else f"{value:.3f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out_dir")
    parser.add_argument("--format", choices=["columns", "imucal"], default="columns")
    parser.add_argument("--split", choices=["none", "pose"], default="none")
    parser.add_argument("--prefix", default="imu", help="file name prefix")
    parser.add_argument("--time-base", choices=["zero", "absolute"], default="zero")
    parser.add_argument("--header", default=DEFAULT_HEADER,
                        help="columns: names of t,ax,ay,az,gx,gy,gz[,temp] in that order")
    parser.add_argument("--time-unit", choices=list(TIME_UNITS), default="us",
                        help="columns: unit of the time column (imucal: always s)")
    parser.add_argument("--delimiter", choices=list(DELIMITERS), default="comma")
    parser.add_argument("--commented-header", action="store_true",
                        help="columns: the header line starts with '# '")
    parser.add_argument("--counts", action="store_true",
                        help="raw integer counts (needs --accel-step and --gyro-step)")
    parser.add_argument("--temp-c", type=float, default=25.0, help="the temperature column")
    parser.add_argument("--gyro-unit", choices=["rad/s", "deg/s"], default="rad/s",
                        help="the unit the rate is written in")
    parser.add_argument("--nul-at", type=int, metavar="LINE", help="a NUL byte on this line")
    parser.add_argument("--crlf", action="store_true", help="Windows line endings")
    parser.add_argument("--no-gyro", action="store_true", help="no gyroscope columns")
    parser.add_argument("--interleave-empty", action="store_true",
                        help="columns: a row of empty fields after each row")
    parser.add_argument("--label-column", action="store_true",
                        help="columns: a quoted free-text label column with commas")
    imu_sim.add_arguments(parser)
    args = parser.parse_args()
    if args.counts and (args.accel_step is None or args.gyro_step is None):
        parser.error("--counts needs --accel-step and --gyro-step")
    if args.counts and args.gyro_unit != "rad/s":
        parser.error("--gyro-unit applies to values in SI, not to --counts")
    if args.format == "imucal":
        args.time_unit = "s"
        names = list(ROLES)
        delimiter = ","
    else:
        names = args.header.split(",")
        if len(names) not in (7, 8):
            parser.error(f"--header names t,ax,ay,az,gx,gy,gz[,temp]: got {len(names)}")
        delimiter = DELIMITERS[args.delimiter]
    if args.format == "imucal" and (args.interleave_empty or args.label_column):
        parser.error("--interleave-empty and --label-column are for --format columns")
    if args.label_column and args.delimiter != "comma":
        parser.error("--label-column needs --delimiter comma")
    roles = ROLES[:len(names)]
    if args.no_gyro:  # the roles and names of the columns written, in file order
        keep = [i for i, role in enumerate(roles) if role not in ("gx", "gy", "gz")]
        roles, names = [roles[i] for i in keep], [names[i] for i in keep]
    has_temp = "temp" in roles
    args.full_truth = True
    samples, truth = imu_sim.simulate(args)
    poses = truth["poses"]
    rate = args.rate_hz

    # Which samples go to which file: the whole capture, or each pose's hold.
    def sample_index(t_s):
        return int(round(t_s * rate))
    if args.split == "none":
        chunks = [("imu.csv" if args.prefix == "imu" else f"{args.prefix}.csv",
                   0, len(samples) - 1, list(range(len(poses))))]
    else:
        chunks = [(name, sample_index(p["t_start_s"]), sample_index(p["t_end_s"]), [k])
                  for k, (name, p) in enumerate(zip(file_names(poses, args.prefix), poses))]

    if args.format == "imucal":
        unit = "counts" if args.counts else None
        preamble = ["# imucal-capture v1",
                    f"# accel_unit={unit or 'm/s^2'}",
                    f"# gyro_unit={unit or args.gyro_unit}",
                    f"# gravity={args.gravity!r}",
                    f"# rate_hz={rate!r}",
                    ",".join(names)]
        if args.no_gyro:
            preamble.remove(f"# gyro_unit={unit or 'rad/s'}")
    else:
        header = delimiter.join(names + (["label"] if args.label_column else []))
        if args.commented_header:
            header = "# " + header
        preamble = [header]

    def values(gyro, accel):
        gyro = [] if args.no_gyro else gyro
        if args.counts:
            return ([str(int(round(v / args.accel_step))) for v in accel] +
                    [str(int(round(v / args.gyro_step))) for v in gyro])
        if args.gyro_unit == "deg/s":
            gyro = [v * 180.0 / math.pi for v in gyro]
        return [repr(v) for v in accel + gyro]

    def label(t_s):
        """Free text with a comma and a quote, quoted as RFC 4180 says."""
        held = [p for p in poses if p["t_start_s"] <= t_s <= p["t_end_s"]]
        text = f'rest, face "{held[0]["face"]}"' if held else "moving, by hand"
        return '"' + text.replace('"', '""') + '"'

    def empty_row(k, row):
        """Another sensor's row: only the time, or only the temperature, filled."""
        other = [""] * len(row)
        if k % 2 == 0 or not has_temp:
            other[0] = row[0]
        else:
            other[roles.index("temp")] = row[roles.index("temp")]
        return delimiter.join(other)

    os.makedirs(args.out_dir, exist_ok=True)
    eol = "\r\n" if args.crlf else "\n"
    files = []
    for n, (name, first, last, pose_ids) in enumerate(chunks):
        lines = list(preamble)
        line_of = {}  # sample -> its 1-based line
        for k in range(first, last + 1):
            gyro, accel = samples[k][1], samples[k][2]
            row = [time_text(k, first, args)] + values(gyro, accel)
            if has_temp:  # the simulated temperature history, else --temp-c
                temp = samples[k][3] if len(samples[k]) > 3 else args.temp_c
                row.append(f"{temp:.3f}" if len(samples[k]) > 3 else f"{temp:.2f}")
            line_of[k] = len(lines) + 1
            lines.append(delimiter.join(row + ([label(k / rate)] if args.label_column else [])))
            if args.interleave_empty:
                if "interleaved" not in truth:
                    truth["interleaved"] = {"file": name, "first_line": len(lines) + 1}
                lines.append(empty_row(k, row + ([""] if args.label_column else [])))
        first_line = line_of[first]
        if n == 0 and args.nul_at:
            fields = lines[args.nul_at - 1].split(delimiter)
            fields[0] = "\0" + fields[0]
            lines[args.nul_at - 1] = delimiter.join(fields)
            truth["nul"] = {"file": name, "line": args.nul_at, "field": names[0]}
        with open(os.path.join(args.out_dir, name), "w", newline="") as f:
            f.write(eol.join(lines) + eol)
        for k in pose_ids:
            p = poses[k]
            p["file"] = name
            p["lines"] = [line_of[sample_index(p["t_start_s"])],
                          line_of[sample_index(p["t_end_s"])]]
        files.append({"name": name, "poses": pose_ids,
                      "meant_face": [poses[k].get("meant_face", poses[k]["face"])
                                     for k in pose_ids],
                      "face": [poses[k]["face"] for k in pose_ids],
                      "up_body": [poses[k]["up_body"] for k in pose_ids],
                      "lines": [first_line, line_of[last]],
                      "samples": last - first + 1,
                      "t_start_s": first / rate})

    truth["writer"] = {"format": args.format, "split": args.split, "time_base": args.time_base,
                       "header": names, "delimiter": args.delimiter,
                       "commented_header": args.commented_header, "counts": args.counts,
                       "temp_c": args.temp_c, "crlf": args.crlf, "no_gyro": args.no_gyro,
                       "interleave_empty": args.interleave_empty,
                       "label_column": args.label_column}
    truth["files"] = files
    truth["gyro_unit_written"] = "counts" if args.counts else args.gyro_unit
    truth["time_unit"] = args.time_unit
    truth["columns_option"] = ",".join(f"{role}={name}" for role, name in zip(roles, names))
    if args.counts:
        a_step, g_step = args.accel_step, args.gyro_step
        truth["counts"] = {
            "accel_step_m_s2": a_step, "gyro_step_rad_s": g_step,
            "accel_bias_counts": [b / a_step for b in truth["accel_bias_m_s2"]],
            "accel_scale_m_s2_per_count": [s * a_step for s in truth["accel_scale"]],
            "gyro_bias_counts": [b / g_step for b in truth["gyro_bias_rad_s"]],
            "gyro_scale_rad_s_per_count": [s * g_step for s in truth["gyro_scale"]]}
    with open(os.path.join(args.out_dir, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    for name, *_ in chunks:
        print(os.path.join(args.out_dir, name))


if __name__ == "__main__":
    main()
