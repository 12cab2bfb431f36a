// Recordings with a reference orientation (issue 27, `imucal learn`): an IMU stream and the
// orientation of a body rigidly attached to it (core/motion/recording.h). A recording is named
// either `IMU_FILE:REFERENCE_FILE` or an EuRoC/ASL directory.
//
// IMU files:
//   - the TUM-VI / ROS CSV export: a header naming `Time` (s) and columns ending in
//     angular_velocity.x/y/z (rad/s) and linear_acceleration.x/y/z (m/s^2), any order;
//   - EuRoC/ASL imu0/data.csv (importers/euroc.h, nanoseconds).
// Reference files:
//   - the TUM-VI / ROS CSV export: `Time` (s) and columns ending in rotation.x/y/z/w (a
//     geometry_msgs Transform) or orientation.x/y/z/w (a Pose);
//   - EuRoC/ASL mocap0/data.csv or state_groundtruth_estimate0/data.csv: `#timestamp` (ns) and
//     q_RS_w, q_RS_x, q_RS_y, q_RS_z;
//   - the TUM trajectory format: `t tx ty tz qx qy qz qw` separated by spaces, t in s, lines
//     starting with '#' are comments.
// Quaternions must be unit within 1 % (they are normalised); time stamps must increase. A
// directory DIR reads DIR/mav0/imu0/data.csv (or DIR/imu0/data.csv) with mocap0 (the measured
// orientation) or else state_groundtruth_estimate0. Times in seconds are read as exact integer
// nanoseconds, so a Unix-epoch origin costs no precision; both streams then count from the IMU's
// first stamp. Every error names the file and line ("FILE:LINE: ...").
#ifndef IMUCAL_IMPORTERS_REFERENCE_H_
#define IMUCAL_IMPORTERS_REFERENCE_H_

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/statusor.h"
#include "core/motion/recording.h"

namespace imucal::importers {

// A stream's times as read: t_s counts from origin_ns (the first stamp).
struct ImuStream {
  int64_t origin_ns = 0;
  std::vector<double> t_s;
  std::vector<Eigen::Vector3d> gyro_rad_s, accel_m_s2;
};
struct ReferenceStream {
  int64_t origin_ns = 0;
  std::vector<double> t_s;
  std::vector<Eigen::Quaterniond> q_world_ref;
  std::vector<int> line;
};

absl::StatusOr<ImuStream> ParseImuStream(std::string_view text, std::string_view source);
absl::StatusOr<ReferenceStream> ParseReferenceStream(std::string_view text,
                                                     std::string_view source);

// The two streams on one time base (the IMU's first stamp).
core::motion::MotionRecording JoinStreams(const ImuStream& imu, const ReferenceStream& reference);

// `spec`: IMU_FILE:REFERENCE_FILE or an EuRoC/ASL directory.
absl::StatusOr<core::motion::MotionRecording> ReadMotionRecording(const std::string& spec);

}  // namespace imucal::importers

#endif  // IMUCAL_IMPORTERS_REFERENCE_H_
