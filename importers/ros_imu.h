// What the ROS 2 bag readers share whatever the storage (sqlite3: importers/rosbag2.h; MCAP:
// importers/mcap.h): sensor_msgs/msg/Imu in CDR, the choice of the topic, a bag directory's
// metadata.yaml, and the capture made from one topic's messages.
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
#ifndef IMUCAL_IMPORTERS_ROS_IMU_H_
#define IMUCAL_IMPORTERS_ROS_IMU_H_

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "importers/registry.h"

namespace imucal::importers {

inline constexpr std::string_view kRosImuType = "sensor_msgs/msg/Imu";

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

// A bag directory's metadata.yaml, the two keys the readers need: rosbag2_bagfile_information's
// storage_identifier (empty when absent) and relative_file_paths (the files in split order).
// `source` names the file in errors: InvalidArgument "SOURCE:LINE: ..." for YAML that does not
// parse or keys of the wrong kind. Exposed for the fuzzer.
struct BagMetadata {
  std::string storage_identifier;
  std::vector<std::string> relative_file_paths;
};
absl::StatusOr<BagMetadata> ParseBagMetadata(std::string_view yaml,
                                             std::string_view source = "metadata.yaml");

// One topic of a bag, whatever the storage.
struct BagTopic {
  std::string name;
  std::string type;                  // "sensor_msgs/msg/Imu"
  std::string serialization_format;  // "cdr"
};

// The topic to read: `wanted` (which must exist and be an Imu topic), else the only Imu topic;
// otherwise InvalidArgument "FILE: ..." listing the topics (or the Imu topics to choose from).
// Also refuses a topic not serialised as cdr.
absl::StatusOr<BagTopic> ChooseImuTopic(const std::vector<BagTopic>& topics,
                                        std::string_view wanted, std::string_view file);

// The messages of the chosen topic, decoded, in the order the reader adds them (time order).
class ImuMessages {
 public:
  // Decodes one message; `bag_ns` is the bag's receive time. Errors name the file, the
  // message's 0-based index on the topic, its bag time and the field:
  // "bag_0.db3: message 17 (t=1700000000123456789 ns) on /imu: truncated in ...".
  absl::Status Add(std::string_view data, int64_t bag_ns, std::string_view file,
                   std::string_view topic);
  size_t size() const { return samples_.size(); }
  // Puts the messages in bag-time order (stable: equal times keep the order they came in).
  void SortByBagTime();

  // The capture of the messages (an error when there are none or time does not increase), with
  // a note on the topic, the files and the clock; `path` names the bag in errors.
  absl::StatusOr<core::Capture> ToCapture(std::string_view path, std::string_view topic,
                                          size_t file_count, const ImportOptions& options,
                                          std::vector<std::string>* notes) const;

 private:
  struct Sample {
    int64_t stamp_ns;
    int64_t bag_ns;
    Eigen::Vector3d gyro;
    Eigen::Vector3d accel;
  };
  std::vector<Sample> samples_;
  std::vector<std::string> frame_ids_;
};

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_ROS_IMU_H_
