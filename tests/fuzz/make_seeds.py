#!/usr/bin/env python3
"""Writes the fuzz seed corpora (tests/fuzz/corpus/<target>/): small inputs generated here, one
or a few per shape the parser knows (not copies of ../shared data). Rerun after a format
change: python3 tests/fuzz/make_seeds.py"""
import math
import os
import struct

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "corpus")


def write(target, name, data):
    d = os.path.join(ROOT, target)
    os.makedirs(d, exist_ok=True)
    if isinstance(data, str):
        data = data.encode()
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def rows(n, temp=True, t0=0.0, dt=0.005):
    out = []
    for i in range(n):
        k = float(i)
        r = [t0 + k * dt, 0.01 * math.sin(k), -0.02 * math.cos(k), 9.80665 + 0.01 * math.sin(3 * k),
             1e-3 * math.cos(k), -1e-3 * math.sin(2 * k), 2e-3]
        if temp:
            r.append(25.0 + 0.01 * k)
        out.append(r)
    return out


def fmt(v):
    return repr(round(v, 9))


# capture_csv: the imucal capture format.
header = "# imucal-capture v1\n# device=robot-7\n# accel_unit=m/s^2\n# gyro_unit=rad/s\n" \
         "# gravity=9.80665\n# rate_hz=200\n"
write("capture_csv", "basic.csv", header + "t,ax,ay,az,gx,gy,gz,temp\n" +
      "".join(",".join(fmt(v) for v in r) + "\n" for r in rows(6)))
write("capture_csv", "crlf_extra.csv", "\ufeff# imucal-capture v1\r\n# accel_unit = g \r\n#\r\n"
      "# gyro_unit=deg/s\r\n# operator=ada\r\nt,ax,ay,az,gx,gy,gz,label\r\n" +
      "".join(",".join(fmt(v) for v in r[:7]) + ",3\r\n" for r in rows(4, temp=False)))
write("capture_csv", "counts_empty.csv", "# imucal-capture v1\n# accel_unit=counts\n"
      "# gyro_unit=counts\nt,ax,ay,az,gx,gy,gz\n")

# imutk: accelerometer file, NUL, gyroscope file ("t x y z").
acc = "".join("%s %s %s %s\n" % (fmt(r[0]), fmt(r[1]), fmt(r[2]), fmt(r[3])) for r in rows(8))
gyr = "".join("%s %s %s %s\n" % (fmt(r[0]), fmt(r[4]), fmt(r[5]), fmt(r[6])) for r in rows(8))
write("imutk", "si.txt", acc + "\0" + gyr)
acc_c = "".join("%d %d %d %d\n" % (i, 32768 + i, 32000 - i, 48000) for i in range(8))
gyr_c = "".join("%d %d %d %d\n" % (i, 32768, 32770 - i, 32760 + i) for i in range(8))
write("imutk", "counts.txt", acc_c + "\0" + gyr_c)

# columns: byte 0 picks the option set (fuzz_targets.cc FuzzColumns).
write("columns", "0_named.csv", "\x00t,ax,ay,az,gx,gy,gz,temp\n" +
      "".join(",".join(fmt(v) for v in r) + "\n" for r in rows(5)))
write("columns", "1_numbered.csv", "\x01" +
      "".join("%d," % i + ",".join(fmt(v) for v in r[1:7]) + "\n" for i, r in enumerate(rows(5))))
write("columns", "2_preamble.csv", "\x02Fs,100\nlabel,acc_x,acc_y,acc_z,gyr_x,gyr_y,gyr_z\n" +
      "".join("still,%d,%d,%d,%d,%d,%d\n" % (100 + i, -20, 16384, 3, -2, 1) for i in range(5)))
write("columns", "3_sorted_ms.csv", "\x03time,ax,ay,az,gx,gy,gz\n" +
      "".join("%d," % t + ",".join(fmt(v) for v in rows(1)[0][1:7]) + "\n" for t in (20, 0, 10, 30)))
write("columns", "4_semicolon_ns.csv", "\x04exported by vendor tool\n" +
      "".join("%d;" % (i * 5000000) + ";".join(fmt(v) for v in r[1:7]) + "\n"
              for i, r in enumerate(rows(5))))

write("columns", "5_accel_only_interleaved.csv", "\x05t,label,ax,ay,az,mag\n" +
      "".join("%s,\"rest, face \"\"Z+\"\"\",%s,\n%s,,,,,4%d.5\n" %
              (fmt(r[0]), ",".join(fmt(v) for v in r[1:4]), fmt(r[0]), i)
              for i, r in enumerate(rows(5))))

# euroc: imu0/data.csv.
write("euroc", "data.csv",
      "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
      "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n" +
      "".join("%d,%s\n" % (1403636579758555392 + i * 5000000,
                           ",".join(fmt(v) for v in r[4:7] + r[1:4])) for i, r in enumerate(rows(6))))


# rosbag2_cdr: sensor_msgs/msg/Imu in plain CDR, both byte orders.
def imu_cdr(little, sec, nanosec, frame_id, w, a):
    e = "<" if little else ">"
    body = b""
    body += struct.pack(e + "iI", sec, nanosec)
    s = frame_id.encode() + b"\0"
    body += struct.pack(e + "I", len(s)) + s
    while len(body) % 8:  # float64 alignment, relative to the end of the encapsulation header
        body += b"\0"
    body += struct.pack(e + "4d", 0, 0, 0, 1) + struct.pack(e + "9d", *([0.0] * 9))
    body += struct.pack(e + "3d", *w) + struct.pack(e + "9d", *([0.0] * 9))
    body += struct.pack(e + "3d", *a) + struct.pack(e + "9d", *([0.0] * 9))
    return bytes([0, 1 if little else 0, 0, 0]) + body


write("rosbag2_cdr", "le_imu_link.cdr", imu_cdr(True, 1700000000, 123456789, "imu_link",
                                                (0.01, -0.02, 0.003), (0.1, 0.2, 9.81)))
write("rosbag2_cdr", "be_empty_frame.cdr", imu_cdr(False, 0, 0, "", (0, 0, 0), (0, 0, 9.8)))


# sample_batch: imucal.v1.SampleBatch wire bytes (fields 1 session_id, 2 seq, 3..6 packed double).
def varint(v):
    out = b""
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out += bytes([b | 0x80])
        else:
            return out + bytes([b])


def packed(field, values):
    data = b"".join(struct.pack("<d", v) for v in values)
    return varint(field << 3 | 2) + varint(len(data)) + data


def batch(n, seq, temp=True):
    rs = rows(n, temp)
    msg = varint(1 << 3 | 2) + varint(3) + b"s-1" + varint(2 << 3) + varint(seq)
    msg += packed(3, [r[0] for r in rs])
    msg += packed(4, [v for r in rs for v in r[1:4]])
    msg += packed(5, [v for r in rs for v in r[4:7]])
    if temp:
        msg += packed(6, [r[7] for r in rs])
    return msg


write("sample_batch", "three_samples.pb", batch(3, 1))
write("sample_batch", "no_temp.pb", batch(5, 7, temp=False))


# rosbag2_metadata: a bag directory's metadata.yaml (importers/ros_imu.h ParseBagMetadata).
def bag_metadata(storage, files, quote="", eol="\n"):
    lines = ["rosbag2_bagfile_information:", "  version: 5",
             "  storage_identifier: %s%s%s" % (quote, storage, quote), "  relative_file_paths:"]
    lines += ["    - %s%s%s" % (quote, f, quote) for f in files]
    lines += ["  duration:", "    nanoseconds: 2000000000", "  message_count: 400",
              "  topics_with_message_count:", "    - topic_metadata:", "        name: /imu",
              "        type: sensor_msgs/msg/Imu", "        serialization_format: cdr",
              "      message_count: 400", "  compression_format: \"\"", "  compression_mode: \"\""]
    return eol.join(lines) + eol


write("rosbag2_metadata", "one_file.yaml", bag_metadata("sqlite3", ["bag_0.db3"]))
write("rosbag2_metadata", "split_quoted_crlf.yaml",
      bag_metadata("sqlite3", ["bag_0.db3", "bag_1.db3", "bag_10.db3"], quote="'", eol="\r\n"))
write("rosbag2_metadata", "mcap.yaml", bag_metadata("mcap", ["bag_0.mcap"], quote='"'))
write("rosbag2_metadata", "no_paths.yaml",
      "rosbag2_bagfile_information:\n  version: 1\n  storage_identifier: sqlite3\n")


# mcap: small ROS 2 MCAP files (importers/mcap.h) from tests/tools/write_mcap.py, three Imu
# messages and a temperature, in each layout the reader knows (under libFuzzer's 4096 bytes).
def mcap_seeds():
    import argparse
    import sys
    import tempfile
    sys.dont_write_bytecode = True
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tools"))
    import write_mcap
    import write_rosbag2
    topics = {1: ("/imu", write_rosbag2.IMU_TYPE), 2: ("/temperature", write_rosbag2.TEMPERATURE_TYPE)}
    rows = [(1000 + k * 5_000_000, 1, write_rosbag2.imu_message(
        1_700_000_000_000_000_000 + k * 5_000_000, "imu", [0.01 * k, -0.02, 0.003],
        [0.1, -0.2 * k, 9.81])) for k in range(3)]
    rows.append((2000, 2, write_rosbag2.temperature_message(1_700_000_000_000_000_000, "imu",
                                                            31.5)))
    rows.sort()
    layouts = [("none", False, False), ("none", True, False), ("zstd", False, False),
               ("lz4", True, False), ("none", False, True)]
    for compression, no_summary, no_chunks in layouts:
        args = argparse.Namespace(compression=compression, no_summary=no_summary,
                                  no_chunks=no_chunks, chunk_bytes=1200)
        with tempfile.TemporaryDirectory() as d:
            path = os.path.join(d, "seed.mcap")
            write_mcap.write_mcap(path, args, topics, rows)
            with open(path, "rb") as f:
                data = f.read()
        name = "%s%s%s.mcap" % (compression, "_no_summary" if no_summary else "",
                                "_unchunked" if no_chunks else "")
        write("mcap", name, data)


mcap_seeds()
