// ROS 2 bag importer: a bag directory (metadata.yaml beside its files, read in the order of
// relative_file_paths, else of their split index) in either of rosbag2's storages, sqlite3
// (*.db3) or mcap (*.mcap, read by importers/mcap.h), or one .db3 file. Messages of type
// sensor_msgs/msg/Imu in CDR (importers/ros_imu.h: the decoding, the topic choice, time and
// units).
//
// A .db3 holds the tables
//   topics(id, name, type, serialization_format, ...) and messages(id, topic_id, timestamp, data),
// read in (timestamp, id) order.
// The topic is ImportOptions::topic, else the bag's only sensor_msgs/msg/Imu topic; otherwise the
// error lists the Imu topics.
// Errors name the file, the message (0-based index in time order, its bag timestamp) and the
// field: "bag_0.db3: message 17 (t=1700000000123456789 ns) on /imu: truncated in
// angular_velocity.y (needs 8 bytes at offset 316, message has 300)".
#ifndef IMUCAL_IMPORTERS_ROSBAG2_H_
#define IMUCAL_IMPORTERS_ROSBAG2_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "importers/registry.h"
#include "importers/ros_imu.h"

namespace imucal::importers {

// Reads the bag at `path` (directory, .db3 or .mcap) into a capture.
absl::StatusOr<core::Capture> ReadRosbag2Imu(const std::string& path, const ImportOptions& options,
                                             std::vector<std::string>* notes);

// The "rosbag2" importer for the registry (a directory with metadata.yaml, or a file that starts
// with the SQLite header).
const CaptureImporter* Rosbag2Importer();

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_ROSBAG2_H_
