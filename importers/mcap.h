// MCAP reader (https://mcap.dev/spec, major version 0), for ROS 2 bags recorded with rosbag2's
// mcap storage (the default since Iron): a bare .mcap file, or a bag directory whose
// metadata.yaml says storage_identifier: mcap (read through the rosbag2 importer,
// importers/rosbag2.h). Messages are sensor_msgs/msg/Imu in CDR (importers/ros_imu.h), the
// channel's schema naming the type and its message_encoding the serialisation.
//
// File: magic "\x89MCAP0\r\n", then records <opcode u8><content length u64><content>, ending
// with a Footer (summary_start u64, summary_offset_start u64, summary_crc u32) and the magic.
// Integers are little-endian; a string is u32 length + bytes; a map is u32 byte length + pairs.
//   Schema  0x03  id u16, name, encoding, data (u32 length)   name = the ROS type
//   Channel 0x04  id u16, schema_id u16, topic, message_encoding, metadata map
//   Message 0x05  channel_id u16, sequence u32, log_time u64, publish_time u64, data (the rest)
//   Chunk   0x06  message_start_time u64, message_end_time u64, uncompressed_size u64,
//                 uncompressed_crc u32 (CRC-32, 0 = none), compression ("", "zstd", "lz4": the
//                 LZ4 frame format), records (u64 length): Schema, Channel and Message records
//   Chunk Index 0x08 (summary)  message_start_time, message_end_time, chunk_start_offset,
//                 chunk_length, message_index_offsets map<u16, u64>, message_index_length,
//                 compression, compressed_size, uncompressed_size
// Other records (Header, Message Index, Attachment, Metadata, Statistics, Data End, ...) are
// skipped; records may grow new fields at their end, which are ignored.
//
// With a summary section (Footer summary_start != 0) the topics come from its Schema and
// Channel records and the messages from the chunks its Chunk Index records point to (only the
// chunks whose message index names one of the topic's channels, when the index says). Without
// one (a recording cut short, or a writer that writes none) the data section is scanned from
// the start, decompressing every chunk. A file that ends inside a record is an error naming
// the offset: nothing is half-imported.
//
// Errors are InvalidArgument "FILE: byte OFFSET: what", e.g.
//   "imu.mcap: byte 4120: chunk of 31000 bytes: its records fail their CRC-32 (...)".
#ifndef IMUCAL_IMPORTERS_MCAP_H_
#define IMUCAL_IMPORTERS_MCAP_H_

#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "importers/registry.h"
#include "importers/ros_imu.h"

namespace imucal::importers {

inline constexpr std::string_view kMcapMagic = std::string_view("\x89MCAP0\r\n", 8);

class McapReader {
 public:
  // Maps `path` into memory and reads its footer and summary (when there is one).
  static absl::StatusOr<std::unique_ptr<McapReader>> Open(const std::string& path);
  // The same over `bytes`, which must outlive the reader (the fuzzer); `name` names it in errors.
  static absl::StatusOr<std::unique_ptr<McapReader>> FromBytes(std::string_view bytes,
                                                               std::string name);
  ~McapReader();
  McapReader(const McapReader&) = delete;
  McapReader& operator=(const McapReader&) = delete;

  // The file's topics (one per topic name), from the summary or a scan of the data section.
  absl::StatusOr<std::vector<BagTopic>> Topics();
  // Adds the messages of every channel on `topic` to `out`, in the file's order.
  absl::Status ReadTopic(std::string_view topic, ImuMessages* out);
  // Whether the messages are found through the summary's chunk index (else: a linear scan).
  bool indexed() const;

  struct Impl;

 private:
  explicit McapReader(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Reads the Imu topic (ImportOptions::topic, else the only one) of the MCAP files `files`
// (a bag's splits, in order) into a capture; `path` names the bag in errors and notes.
absl::StatusOr<core::Capture> ReadMcapImu(const std::string& path,
                                          const std::vector<std::string>& files,
                                          const ImportOptions& options,
                                          std::vector<std::string>* notes);

// The "mcap" importer for the registry: one bare .mcap file (by its magic).
const CaptureImporter* McapImporter();

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_MCAP_H_
