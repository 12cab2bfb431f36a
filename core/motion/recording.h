// A recording with a reference orientation (issue 27): an IMU stream and the orientation of a
// body rigidly attached to it, measured by something else (motion capture, a VIO run), on
// clocks that may differ by an offset. What importers/reference.h reads and core/motion/align.h,
// learn.h consume. Header-only data.
//
// Frames: `q_world_ref[j]` rotates vectors from the reference body frame into the reference's
// world frame (Hamilton, x y z w as TUM and EuRoC write them). The reference body frame may be
// rotated against the IMU frame; align.h estimates R_imu_ref. Time: `t_s` and `ref_t_s` count
// from one origin (the IMU's first time stamp), each on its own clock as written.
#ifndef IMUCAL_CORE_MOTION_RECORDING_H_
#define IMUCAL_CORE_MOTION_RECORDING_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"

namespace imucal::core::motion {

struct MotionRecording {
  std::string name;            // as given (IMU_FILE:REFERENCE_FILE or a directory)
  std::string imu_path;        // the files read, for provenance
  std::string reference_path;  //
  std::vector<double> t_s;     // IMU time stamps, strictly increasing
  std::vector<Eigen::Vector3d> gyro_rad_s;
  std::vector<Eigen::Vector3d> accel_m_s2;
  std::vector<double> ref_t_s;  // reference time stamps, strictly increasing
  std::vector<Eigen::Quaterniond> q_world_ref;
  std::vector<int> ref_line;  // 1-based line of each reference sample in its file
  std::string sha256;  // of the IMU file then the reference file (set by the reader's caller)

  double DurationS() const { return t_s.empty() ? 0.0 : t_s.back() - t_s.front(); }
};

}  // namespace imucal::core::motion

#endif  // IMUCAL_CORE_MOTION_RECORDING_H_
