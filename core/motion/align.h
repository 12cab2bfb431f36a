// Aligning a recording's reference orientation with its IMU (issue 27): the offset between the
// two clocks and the rotation from the reference body frame to the IMU frame, each with its
// standard error, and the reference at the IMU's time stamps.
//
// Time: |rate| of the gyro is cross-correlated with |rate| differentiated from the reference
// (both resampled at the IMU's rate; whole samples), the peak refined by a parabola, then the
// offset, the rotation and a rate bias are refined together by Gauss-Newton on
//   w_gyro(t - offset_s) = R_imu_ref w_ref(t) + b
// over intervals of about 50 ms of the reference (w_ref = Log(q_j^-1 q_j+m) / dt, w_gyro the
// gyro's mean over the same interval).
// Rotation: the Kabsch solution of the same equation (centred, so b drops out).
// `offset_s` is the reference clock minus the IMU clock: a reference stamped t was taken at IMU
// time t - offset_s. Standard errors are those of white residuals (a lower bound when the
// residual is coloured).
//
// What is applied: clocks that agree within `shared_clock_s` are taken as one clock, so the
// stamps are kept and what remains (the gyro's own delay) is learnt by the dynamic block
// (core/dynamic_gyro.h delay_s); a larger offset is removed. A reference frame within
// `frame_identity_deg` of the IMU's is taken as the IMU's frame (the reference already states
// the IMU's orientation, as TUM-VI's and EuRoC's estimate do; what remains is the gyro's own
// misalignment, which the calibration fits), a larger rotation is removed.
#ifndef IMUCAL_CORE_MOTION_ALIGN_H_
#define IMUCAL_CORE_MOTION_ALIGN_H_

#include <cstdint>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/statusor.h"
#include "core/motion/recording.h"

namespace imucal::core::motion {

struct AlignOptions {
  double max_offset_s = 1.0;        // the clock offsets searched: +-max_offset_s
  double shared_clock_s = 0.010;    // |offset| below this: one clock (see above)
  double frame_identity_deg = 2.0;  // a rotation below this: the reference is the IMU frame
  double min_correlation = 0.5;     // the |rate| correlation peak below this: no match
  // The rotation fit's residual RMS over the rate RMS above this: the reference's frame does
  // not follow the IMU (another body, or the inverse orientation).
  double max_frame_residual = 0.3;
  int min_reference_intervals = 100;  // usable 50 ms reference intervals (rates) needed
  double min_rate_rms_rad_s = 0.05;   // a recording still throughout cannot be aligned
  double gap_factor = 2.5;            // reference intervals longer than this x the median are gaps
};

struct Alignment {
  double offset_s = 0.0;
  double offset_std_error_s = 0.0;
  bool offset_applied = false;
  Eigen::Quaterniond q_imu_ref = Eigen::Quaterniond::Identity();
  double rotation_deg = 0.0;
  double rotation_std_error_deg = 0.0;
  bool rotation_applied = false;
  double correlation = 0.0;     // the normalised |rate| cross-correlation at its peak
  double frame_residual = 0.0;  // rotation fit residual RMS / rate RMS
  int intervals_used = 0;
  double gap_s = 0.0;  // reference intervals longer than this are gaps
  std::string summary;
};

absl::StatusOr<Alignment> EstimateAlignment(const MotionRecording& recording,
                                            const AlignOptions& options = {});

// The IMU frame's orientation in the reference world frame at each IMU time stamp, slerped
// between reference samples; `valid` is 0 in a reference gap and outside the reference.
struct AlignedReference {
  std::vector<Eigen::Quaterniond> q_world_imu;
  std::vector<uint8_t> valid;
  Eigen::Vector3d up_world = Eigen::Vector3d::UnitZ();  // against gravity, reference world
  int valid_count = 0;
};

AlignedReference AlignReference(const MotionRecording& recording, const Alignment& alignment);

// Log of a unit quaternion (rotation vector, rad, angle in [0, pi]).
Eigen::Vector3d LogQuaternion(const Eigen::Quaterniond& q);

}  // namespace imucal::core::motion

#endif  // IMUCAL_CORE_MOTION_ALIGN_H_
