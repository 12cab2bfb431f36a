// ROS 2 bag importer: rosbag2's default sqlite3 storage, messages of type sensor_msgs/msg/Imu.
//
// Input: a bag directory (metadata.yaml beside one or more *.db3 files, read in the order of
// their split index), or one .db3 file. Each .db3 holds the tables
//   topics(id, name, type, serialization_format, ...) and messages(id, topic_id, timestamp, data).
// The topic is ImportOptions::topic, else the bag's only sensor_msgs/msg/Imu topic; otherwise the
// error lists the Imu topics. Messages are read in (timestamp, id) order.
//
// Each message is CDR (XCDR1, as rosbag2 records with the default rmw): a 4-byte encapsulation
// header (0x00 0x01 little-endian, 0x00 0x00 big-endian; 2 option bytes), then
//   std_msgs/Header header { builtin_interfaces/Time stamp { int32 sec; uint32 nanosec; }
//                            string frame_id; }            // uint32 length incl. NUL, bytes
//   geometry_msgs/Quaternion orientation                    // 4 x float64
//   float64[9] orientation_covariance
//   geometry_msgs/Vector3 angular_velocity                  // 3 x float64, rad/s
//   float64[9] angular_velocity_covariance
//   geometry_msgs/Vector3 linear_acceleration               // 3 x float64, m/s^2
//   float64[9] linear_acceleration_covariance
// with each primitive aligned to its size relative to the first byte after the encapsulation
// header (so the float64s after a frame_id of any length start on a multiple of 8).
//
// Time: header.stamp (the sensor's time), counted from the first message's stamp (kept in the
// metadata as t0_ns); if every stamp is zero (drivers that do not stamp), the bag's receive
// timestamp instead, with a note. Units rad/s and m/s^2 (ImportOptions may override).
// Errors name the file, the message (0-based index in time order, its bag timestamp) and the
// field: "bag_0.db3: message 17 (t=1700000000123456789 ns) on /imu: truncated in
// angular_velocity.y (needs 8 bytes at offset 316, message has 300)".
#ifndef IMUCAL_IMPORTERS_ROSBAG2_H_
#define IMUCAL_IMPORTERS_ROSBAG2_H_

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "importers/registry.h"

namespace imucal::importers {

// The fields of one sensor_msgs/msg/Imu that a capture needs.
struct ImuMessage {
  int32_t stamp_sec = 0;
  uint32_t stamp_nanosec = 0;
  std::string frame_id;
  Eigen::Vector3d angular_velocity = Eigen::Vector3d::Zero();     // rad/s
  Eigen::Vector3d linear_acceleration = Eigen::Vector3d::Zero();  // m/s^2
};

// Decodes one CDR-serialised message (encapsulation header included). Errors are
// InvalidArgument naming the field and the offset; never reads out of bounds.
absl::StatusOr<ImuMessage> DecodeImuCdr(std::string_view data);

// The two keys of a bag directory's metadata.yaml the importer reads (rosbag2's flat layout;
// a full YAML parser is not needed for them): "storage_identifier: sqlite3" (empty when absent)
// and the "relative_file_paths:" list ("- bag_0.db3" lines; quotes around a value dropped).
// Never fails: anything else in the file is ignored. Exposed for the fuzzer.
struct BagMetadata {
  std::string storage_identifier;
  std::vector<std::string> relative_file_paths;
};
BagMetadata ParseBagMetadata(std::string_view yaml);

// Reads the bag at `path` (directory or .db3) into a capture.
absl::StatusOr<core::Capture> ReadRosbag2Imu(const std::string& path, const ImportOptions& options,
                                             std::vector<std::string>* notes);

// The "rosbag2" importer for the registry (a directory with metadata.yaml, or a file that starts
// with the SQLite header).
const CaptureImporter* Rosbag2Importer();

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_ROSBAG2_H_
