#!/usr/bin/env python3
"""Writes a simulated six-face capture as a ROS 2 MCAP file, independently of imucal's reader:
the same messages as write_rosbag2.py (tests/tools/imu_sim.py says what is simulated), stored
as rosbag2's mcap storage plugin stores them. OUT is a bare .mcap file, or with --bag-dir a
bag directory (OUT/metadata.yaml with storage_identifier: mcap, OUT/OUT_0.mcap).

Written from the MCAP specification (https://mcap.dev/spec, major version 0): the magic
89 4D 43 41 50 30 0D 0A, then records <opcode u8><content length u64 LE><content>; strings are a
u32 length then UTF-8, byte fields a u32 (u64 for a chunk's records) length then the bytes, maps
a u32 byte length then the pairs. The ros2 profile: schema encoding "ros2msg" named by the ROS
type, channel message_encoding "cdr", channel metadata offered_qos_profiles.

  Header(0x01) [Chunk(0x06) MessageIndex(0x07)...]... DataEnd(0x0F)
  [summary: Schema(0x03)... Channel(0x04)... Statistics(0x0B) ChunkIndex(0x08)...
   SummaryOffset(0x0E)...] Footer(0x02) magic

Schemas and channels are written inside the first chunk that holds a message of theirs (so a
reader without the summary must find them there), and again in the summary. Chunks are
compressed with the `zstd` and `lz4` command-line tools (the LZ4 frame format), whichever
--compression names. Usage: write_mcap.py OUT [--bag-dir] [--compression none|zstd|lz4]
[--no-summary] [--no-chunks] [--chunk-bytes N] [imu_sim and write_rosbag2 options]

With --from-db3 FILE, the messages are not simulated: every message of a recorded rosbag2
sqlite3 file (its `topics` and `messages` tables) is carried over byte for byte, in timestamp
order, as `ros2 bag convert` would carry it into the mcap storage.
"""
import argparse
import os
import sqlite3
import struct
import subprocess
import sys
import zlib

sys.dont_write_bytecode = True  # no __pycache__ in the source tree when ctest runs this
import imu_sim  # noqa: E402 (after the line above)
import write_rosbag2  # noqa: E402

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
OP_CHUNK, OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS = 0x06, 0x07, 0x08, 0x0B
OP_SUMMARY_OFFSET, OP_DATA_END = 0x0E, 0x0F
# The message definitions the schema records carry (ros2msg: the .msg text).
DEFINITIONS = {
    write_rosbag2.IMU_TYPE: "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\n"
    "float64[9] orientation_covariance\ngeometry_msgs/Vector3 angular_velocity\n"
    "float64[9] angular_velocity_covariance\ngeometry_msgs/Vector3 linear_acceleration\n"
    "float64[9] linear_acceleration_covariance\n",
    write_rosbag2.TEMPERATURE_TYPE: "std_msgs/Header header\nfloat64 temperature\n"
    "float64 variance\n",
}


def u8(v):
    return struct.pack("<B", v)


def u16(v):
    return struct.pack("<H", v)


def u32(v):
    return struct.pack("<I", v)


def u64(v):
    return struct.pack("<Q", v)


def string(s):
    raw = s.encode("utf-8")
    return u32(len(raw)) + raw


def record(op, content):
    return u8(op) + u64(len(content)) + content


def schema_record(schema_id, type_name):
    # A type this file has no .msg text for (from a recorded bag) gets an empty definition.
    return record(OP_SCHEMA, u16(schema_id) + string(type_name) + string("ros2msg") +
                  string(DEFINITIONS.get(type_name, "")))


def channel_record(channel_id, schema_id, topic):
    metadata = string("offered_qos_profiles") + string(write_rosbag2.QOS_YAML)
    return record(OP_CHANNEL, u16(channel_id) + u16(schema_id) + string(topic) + string("cdr") +
                  u32(len(metadata)) + metadata)


def message_record(channel_id, sequence, log_time_ns, data):
    return record(OP_MESSAGE, u16(channel_id) + u32(sequence) + u64(log_time_ns) +
                  u64(log_time_ns) + data)


def compress(data, compression):
    if compression == "none":
        return data
    tool = {"zstd": ["zstd", "-q", "-c"], "lz4": ["lz4", "-q", "-c"]}[compression]
    return subprocess.run(tool, input=data, stdout=subprocess.PIPE, check=True).stdout


def write_mcap(path, args, topics, rows):
    """topics: id -> (name, type); rows: (log time ns, topic id, CDR data) in time order."""
    schema_ids = {}
    for _, type_name in topics.values():
        schema_ids.setdefault(type_name, len(schema_ids) + 1)
    out = bytearray(MAGIC)
    out += record(OP_HEADER, string("ros2") + string("imucal tests/tools/write_mcap.py"))
    chunk_indexes = []
    counts = {topic_id: 0 for topic_id in topics}
    written_schemas, written_channels = set(), set()

    def definitions_for(topic_id):
        """The schema and channel records a message on topic_id needs first, once each."""
        b = bytearray()
        type_name = topics[topic_id][1]
        if schema_ids[type_name] not in written_schemas:
            written_schemas.add(schema_ids[type_name])
            b += schema_record(schema_ids[type_name], type_name)
        if topic_id not in written_channels:
            written_channels.add(topic_id)
            b += channel_record(topic_id, schema_ids[type_name], topics[topic_id][0])
        return b

    def message(log_ns, topic_id, data):
        counts[topic_id] += 1
        return message_record(topic_id, counts[topic_id], log_ns, data)

    def flush(chunk, index, times):
        if not chunk:
            return
        records = bytes(chunk)
        compressed = compress(records, args.compression)
        start = len(out)
        content = (u64(times[0]) + u64(times[1]) + u64(len(records)) +
                   u32(zlib.crc32(records)) +
                   string("" if args.compression == "none" else args.compression) +
                   u64(len(compressed)) + compressed)
        out.extend(record(OP_CHUNK, content))
        chunk_length = len(out) - start
        index_offsets = {}
        index_start = len(out)
        for topic_id in sorted(index):
            entries = b"".join(u64(t) + u64(o) for t, o in index[topic_id])
            index_offsets[topic_id] = len(out)
            out.extend(record(OP_MESSAGE_INDEX, u16(topic_id) + u32(len(entries)) + entries))
        offsets = b"".join(u16(c) + u64(o) for c, o in sorted(index_offsets.items()))
        chunk_indexes.append(
            u64(times[0]) + u64(times[1]) + u64(start) + u64(chunk_length) +
            u32(len(offsets)) + offsets + u64(len(out) - index_start) +
            string("" if args.compression == "none" else args.compression) +
            u64(len(compressed)) + u64(len(records)))

    if args.no_chunks:
        for log_ns, topic_id, data in rows:
            out += definitions_for(topic_id) + message(log_ns, topic_id, data)
    else:
        chunk, index, times = bytearray(), {}, [0, 0]
        for log_ns, topic_id, data in rows:
            if not index:  # the chunk's first message: its start time
                times = [log_ns, log_ns]
            chunk += definitions_for(topic_id)
            index.setdefault(topic_id, []).append((log_ns, len(chunk)))
            times[1] = log_ns
            chunk += message(log_ns, topic_id, data)
            if len(chunk) >= args.chunk_bytes:
                flush(chunk, index, times)
                chunk, index, times = bytearray(), {}, [0, 0]
        flush(chunk, index, times)
    out += record(OP_DATA_END, u32(0))  # data_section_crc 0: not computed (allowed)

    summary_start = summary_offset_start = 0
    if not args.no_summary:
        summary_start = len(out)
        groups = []

        def group(op, records_bytes):
            if records_bytes:
                groups.append((op, len(out), len(records_bytes)))
                out.extend(records_bytes)

        group(OP_SCHEMA, b"".join(schema_record(i, t) for t, i in schema_ids.items()))
        group(OP_CHANNEL, b"".join(channel_record(c, schema_ids[t], n)
                                   for c, (n, t) in topics.items()))
        channel_counts = b"".join(u16(c) + u64(n) for c, n in sorted(counts.items()))
        group(OP_STATISTICS, record(OP_STATISTICS, u64(len(rows)) + u16(len(schema_ids)) +
                                    u32(len(topics)) + u32(0) + u32(0) +
                                    u32(len(chunk_indexes)) + u64(rows[0][0]) +
                                    u64(rows[-1][0]) + u32(len(channel_counts)) +
                                    channel_counts))
        group(OP_CHUNK_INDEX, b"".join(record(OP_CHUNK_INDEX, c) for c in chunk_indexes))
        summary_offset_start = len(out)
        for op, start, length in groups:
            out += record(OP_SUMMARY_OFFSET, u8(op) + u64(start) + u64(length))
    # summary_crc: CRC-32 of the summary (and offset) sections and the footer up to this field.
    footer_head = u8(OP_FOOTER) + u64(20) + u64(summary_start) + u64(summary_offset_start)
    crc = zlib.crc32(bytes(out[summary_start:]) + footer_head) if summary_start else 0
    out += footer_head + u32(crc) + MAGIC
    with open(path, "wb") as f:
        f.write(out)
    return counts


def metadata_yaml(mcap_name, topics, counts, rows):
    """rosbag2's metadata.yaml for an mcap bag (version 5 layout, as write_rosbag2.py)."""
    text = write_rosbag2.metadata_yaml("humble", mcap_name, topics, counts, rows[0][0],
                                       rows[-1][0])
    return text.replace("storage_identifier: sqlite3", "storage_identifier: mcap")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", help="the .mcap file, or with --bag-dir the bag directory")
    parser.add_argument("--bag-dir", action="store_true", help="write a bag directory")
    parser.add_argument("--compression", choices=["none", "zstd", "lz4"], default="zstd")
    parser.add_argument("--no-summary", action="store_true", help="footer without a summary")
    parser.add_argument("--no-chunks", action="store_true", help="messages outside chunks")
    parser.add_argument("--chunk-bytes", type=int, default=65536,
                        help="uncompressed size at which a chunk is closed")
    parser.add_argument("--from-db3", metavar="FILE",
                        help="carry over a recorded rosbag2 sqlite3 file instead of simulating")
    write_rosbag2.add_bag_arguments(parser)
    args = parser.parse_args()
    truth = None
    if args.from_db3:
        db = sqlite3.connect(f"file:{args.from_db3}?mode=ro", uri=True)
        topics = {topic_id: (name, type_name) for topic_id, name, type_name in
                  db.execute("SELECT id, name, type FROM topics ORDER BY id")}
        rows = list(db.execute(
            "SELECT timestamp, topic_id, data FROM messages ORDER BY timestamp, id"))
        db.close()
    else:
        samples, truth = imu_sim.simulate(args)
        topics = write_rosbag2.recorded_topics(args)
        rows = write_rosbag2.recorded_rows(args, samples)

    if args.bag_dir:
        os.makedirs(args.out)
        name = os.path.basename(os.path.normpath(args.out)) + "_0.mcap"
        counts = write_mcap(os.path.join(args.out, name), args, topics, rows)
        with open(os.path.join(args.out, "metadata.yaml"), "w") as f:
            f.write(metadata_yaml(name, topics, counts, rows))
    else:
        write_mcap(args.out, args, topics, rows)
    if truth is not None:
        write_rosbag2.write_truth(truth, args, topics, args.out)
    print(args.out)


if __name__ == "__main__":
    main()
