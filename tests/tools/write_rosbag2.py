#!/usr/bin/env python3
"""Writes a simulated six-face capture as a ROS 2 bag (rosbag2, sqlite3 storage), independently
of imucal's importer: OUT/metadata.yaml, OUT/OUT_0.db3 and OUT/../truth.json (tests/tools/
imu_sim.py says what is simulated).

The bag is what `ros2 bag record` writes with rosbag2_storage_default_plugins' sqlite3 plugin:
tables `topics` and `messages` (plus `schema`, and `metadata` for --distro jazzy), each message
the CDR serialisation of its type. Topics:
  /imu/data     sensor_msgs/msg/Imu          the capture, one message per sample
  /temperature  sensor_msgs/msg/Temperature  1 Hz, another type (the importer must skip it)
  --decoy-imu TOPIC adds a second sensor_msgs/msg/Imu topic (the board's other IMU, lying flat),
  so that choosing the capture needs --topic.

CDR (OMG CDR as in XCDR version 1, ROS 2's `cdr` serialization format): a 4-byte encapsulation
header (00 01 = CDR little-endian, then 2 option bytes 00 00); after it each primitive is aligned
to its own size, counted from the first byte after the header; a string is a uint32 length that
counts the terminating NUL, the bytes, the NUL; fixed arrays (double[9]) are their elements.

Standard library only. Usage: write_rosbag2.py BAG_DIR [--truth FILE] [--distro humble|jazzy]
"""
import argparse
import json
import math
import os
import sqlite3
import struct
import sys

sys.dont_write_bytecode = True  # no __pycache__ in the source tree when ctest runs this
import imu_sim  # noqa: E402 (after the line above)

IMU_TYPE = "sensor_msgs/msg/Imu"
TEMPERATURE_TYPE = "sensor_msgs/msg/Temperature"
# Recording starts at a Unix time, as a robot's clock does (2023-11-14T22:13:20Z).
T0_NS = 1_700_000_000_000_000_000
# What `ros2 bag record` stores for a sensor-data publisher (best effort, volatile; history and
# depth unknown): the offered QoS profiles as a YAML list inside a string.
QOS_YAML = (
    "- history: 3\n  depth: 0\n  reliability: 2\n  durability: 2\n"
    "  deadline:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  lifespan:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  liveliness: 1\n"
    "  liveliness_lease_duration:\n    sec: 9223372036\n    nsec: 854775807\n"
    "  avoid_ros_namespace_conventions: false")


class CdrLittleEndian:
    """XCDR1 little-endian serialiser: alignment relative to the end of the encapsulation."""

    def __init__(self):
        self.body = bytearray()

    def _align(self, size):
        self.body.extend(b"\0" * (-len(self.body) % size))

    def int32(self, v):
        self._align(4)
        self.body += struct.pack("<i", v)

    def uint32(self, v):
        self._align(4)
        self.body += struct.pack("<I", v)

    def float64(self, v):
        self._align(8)
        self.body += struct.pack("<d", v)

    def string(self, s):
        raw = s.encode("utf-8")
        self.uint32(len(raw) + 1)
        self.body += raw + b"\0"

    def bytes(self):
        return b"\x00\x01\x00\x00" + bytes(self.body)


def header(cdr, stamp_ns, frame_id):
    """std_msgs/msg/Header: builtin_interfaces/msg/Time stamp {int32 sec; uint32 nanosec},
    string frame_id."""
    cdr.int32(stamp_ns // 1_000_000_000)
    cdr.uint32(stamp_ns % 1_000_000_000)
    cdr.string(frame_id)


def imu_message(stamp_ns, frame_id, gyro_rad_s, accel_m_s2):
    cdr = CdrLittleEndian()
    header(cdr, stamp_ns, frame_id)
    for q in (0.0, 0.0, 0.0, 1.0):      # orientation (x, y, z, w)
        cdr.float64(q)
    for _ in range(9):                  # orientation_covariance: -1 = no orientation estimate
        cdr.float64(-1.0)
    for v in gyro_rad_s:                # angular_velocity
        cdr.float64(v)
    for i in range(9):                  # angular_velocity_covariance
        cdr.float64(1.6e-5 if i % 4 == 0 else 0.0)
    for v in accel_m_s2:                # linear_acceleration
        cdr.float64(v)
    for i in range(9):                  # linear_acceleration_covariance
        cdr.float64(4e-4 if i % 4 == 0 else 0.0)
    return cdr.bytes()


def temperature_message(stamp_ns, frame_id, temp_c):
    cdr = CdrLittleEndian()
    header(cdr, stamp_ns, frame_id)
    cdr.float64(temp_c)  # temperature
    cdr.float64(0.01)    # variance
    return cdr.bytes()


def recorded_topics(args):
    """Topic id -> (name, type): the capture, a 1 Hz temperature, and the decoy Imu if asked."""
    topics = {1: (args.topic, IMU_TYPE), 2: ("/temperature", TEMPERATURE_TYPE)}
    if args.decoy_imu:
        topics[3] = (args.decoy_imu, IMU_TYPE)
    return topics


def recorded_rows(args, samples):
    """The messages as `ros2 bag record` receives them, in receive order: (receive time ns,
    topic id, CDR data). Shared with write_mcap.py, so both storages hold the same messages."""
    # (receive time, topic id, data): the bag's timestamp is when the recorder received the
    # message, a little after the driver stamped it; the capture's time is the header stamp.
    rows = []
    period_ns = round(1e9 / args.rate_hz)
    for k, (_, gyro, accel) in enumerate(samples):
        stamp_ns = T0_NS + k * period_ns
        rows.append((stamp_ns + 350_000 + (k * 7919) % 200_000, 1,
                     imu_message(stamp_ns, args.frame_id, gyro, accel)))
    duration_ns = len(samples) * period_ns
    for s in range(duration_ns // 1_000_000_000 + 1):
        stamp_ns = T0_NS + s * 1_000_000_000 + 2_500_000
        rows.append((stamp_ns + 400_000, 2,
                     temperature_message(stamp_ns, args.frame_id, 31.0 + 0.02 * s)))
    if args.decoy_imu:
        # The other IMU lies flat and still, read at 10 Hz: one pose, never a calibration.
        for k in range(0, len(samples), 10):
            stamp_ns = T0_NS + k * period_ns + 1_000_000
            rows.append((stamp_ns + 300_000, 3, imu_message(
                stamp_ns, "imu2_link", [0.001, -0.002, 0.0005],
                [0.05, -0.03, args.gravity + 0.1 * math.sin(k)])))
    rows.sort()
    return rows


def add_bag_arguments(parser):
    """The options both bag writers take (this one and write_mcap.py), then imu_sim's."""
    parser.add_argument("--truth", help="truth JSON (default: OUT.truth.json)")
    parser.add_argument("--topic", default="/imu/data")
    parser.add_argument("--frame-id", default="imu_link")
    parser.add_argument("--decoy-imu", metavar="TOPIC", help="a second Imu topic")
    imu_sim.add_arguments(parser)


def write_truth(truth, args, topics, out):
    """The simulation's truth with the bag's topics, to --truth or OUT.truth.json."""
    truth["topic"] = args.topic
    truth["topics"] = {name: type_name for name, type_name in topics.values()}
    truth["first_stamp_ns"] = T0_NS
    with open(args.truth or os.path.normpath(out) + ".truth.json", "w") as f:
        json.dump(truth, f, indent=1)


def create_tables(db, distro):
    """The schema of rosbag2_storage_sqlite3 (sqlite_storage.cpp): `schema` records its version
    (3 in Humble, 4 with `metadata` and type_description_hash from Iron on)."""
    if distro == "humble":
        db.execute("CREATE TABLE schema(schema_version INTEGER PRIMARY KEY,"
                   "ros_distro TEXT NOT NULL);")
        db.execute("INSERT INTO schema (schema_version, ros_distro) VALUES (3, 'humble');")
        db.execute("CREATE TABLE topics(id INTEGER PRIMARY KEY,name TEXT NOT NULL,"
                   "type TEXT NOT NULL,serialization_format TEXT NOT NULL,"
                   "offered_qos_profiles TEXT NOT NULL);")
    else:
        db.execute("CREATE TABLE schema(schema_version INTEGER PRIMARY KEY,"
                   "ros_distro TEXT NOT NULL);")
        db.execute("INSERT INTO schema (schema_version, ros_distro) VALUES (4, 'jazzy');")
        db.execute("CREATE TABLE metadata(id INTEGER PRIMARY KEY,"
                   "metadata_version INTEGER NOT NULL,metadata TEXT NOT NULL);")
        db.execute("CREATE TABLE topics(id INTEGER PRIMARY KEY,name TEXT NOT NULL,"
                   "type TEXT NOT NULL,serialization_format TEXT NOT NULL,"
                   "offered_qos_profiles TEXT NOT NULL,type_description_hash TEXT NOT NULL);")
    db.execute("CREATE TABLE messages(id INTEGER PRIMARY KEY,topic_id INTEGER NOT NULL,"
               "timestamp INTEGER NOT NULL, data BLOB NOT NULL);")
    db.execute("CREATE INDEX timestamp_idx ON messages (timestamp ASC);")


def yaml_str(s):
    """A YAML double-quoted scalar (json's escaping is a subset YAML accepts)."""
    return json.dumps(s)


def metadata_yaml(distro, db_name, topics, counts, start_ns, end_ns):
    version = 5 if distro == "humble" else 9
    total = sum(counts.values())
    lines = ["rosbag2_bagfile_information:",
             f"  version: {version}",
             "  storage_identifier: sqlite3",
             "  duration:",
             f"    nanoseconds: {end_ns - start_ns}",
             "  starting_time:",
             f"    nanoseconds_since_epoch: {start_ns}",
             f"  message_count: {total}",
             "  topics_with_message_count:"]
    for topic_id, (name, type_name) in topics.items():
        lines += ["    - topic_metadata:",
                  f"        name: {name}",
                  f"        type: {type_name}",
                  "        serialization_format: cdr",
                  f"        offered_qos_profiles: {yaml_str(QOS_YAML)}"]
        if distro != "humble":
            lines.append(f"        type_description_hash: {yaml_str('')}")
        lines.append(f"      message_count: {counts[topic_id]}")
    lines += ['  compression_format: ""',
              '  compression_mode: ""',
              "  relative_file_paths:",
              f"    - {db_name}",
              "  files:",
              f"    - path: {db_name}",
              "      starting_time:",
              f"        nanoseconds_since_epoch: {start_ns}",
              "      duration:",
              f"        nanoseconds: {end_ns - start_ns}",
              f"      message_count: {total}"]
    if distro != "humble":
        lines += ["  custom_data: ~", "  ros_distro: jazzy"]
    return "\n".join(lines) + "\n"


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("bag_dir", help="created; must not exist (as with ros2 bag record -o)")
    parser.add_argument("--distro", choices=["humble", "jazzy"], default="humble")
    add_bag_arguments(parser)
    args = parser.parse_args()
    samples, truth = imu_sim.simulate(args)

    os.makedirs(args.bag_dir)
    db_name = os.path.basename(os.path.normpath(args.bag_dir)) + "_0.db3"
    db = sqlite3.connect(os.path.join(args.bag_dir, db_name))
    create_tables(db, args.distro)
    topics = recorded_topics(args)
    for topic_id, (name, type_name) in topics.items():
        columns = [topic_id, name, type_name, "cdr", QOS_YAML]
        if args.distro != "humble":
            columns.append("")
        db.execute(f"INSERT INTO topics VALUES ({','.join('?' * len(columns))})", columns)

    rows = recorded_rows(args, samples)
    db.executemany("INSERT INTO messages (topic_id, timestamp, data) VALUES (?, ?, ?)",
                   [(topic_id, t_ns, data) for t_ns, topic_id, data in rows])
    db.commit()
    db.close()

    counts = {topic_id: sum(1 for r in rows if r[1] == topic_id) for topic_id in topics}
    with open(os.path.join(args.bag_dir, "metadata.yaml"), "w") as f:
        f.write(metadata_yaml(args.distro, db_name, topics, counts, rows[0][0], rows[-1][0]))
    write_truth(truth, args, topics, args.bag_dir)
    print(args.bag_dir)


if __name__ == "__main__":
    main()
