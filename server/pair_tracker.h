// Six-face pair verdicts while a session streams: as soon as both poses of a 180-degree pair
// are held, the pair is checked with core's CheckSixFacePairs, the offline engine's own check
// (same face, mirrored horizontal components, a gyro-measured half turn about the vertical).
//
// Model: the turn between two consecutive accepted poses a -> b is the body-frame rotation
//   R_a_b = prod_k Exp(s * (0.5 * (w_k + w_k+1) - b_a) * (t_k+1 - t_k))
// (right-multiplied, as core's IntegrateRotation and Compose), over the samples from a's
// acceptance to b's, with w the raw gyro reading, b_a the raw gyro mean of pose a (the bias
// estimate) and s the nominal factor of the device's gyro unit to rad/s. A pose's up direction
// is its raw accelerometer mean, normalised: a scale error of a few percent moves it far less
// than the check's tolerances. The solve repeats the check with the calibrated gyroscope.
// Counts carry an unknown offset and scale, so sessions in counts get no online verdicts.
#ifndef IMUCAL_SERVER_PAIR_TRACKER_H_
#define IMUCAL_SERVER_PAIR_TRACKER_H_

#include <set>
#include <string_view>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "core/online_segmenter.h"
#include "core/protocol.h"

namespace imucal::server {

class PairTracker {
 public:
  // Memory and the per-pose re-check stay bounded: a six-face session needs 12 poses (a few
  // more with re-dos); after kMaxPoses accepted poses no more verdicts come online (the solve
  // still checks every pair).
  static constexpr size_t kMaxPoses = 64;

  // `enabled` false (not six-face): every call is a cheap no-op.
  PairTracker(bool enabled, std::string_view accel_unit, std::string_view gyro_unit);

  bool enabled() const { return enabled_; }
  // Every sample, in time order, before the segmenter sees it.
  void AddGyro(double t_s, const Eigen::Vector3d& gyro);
  // An accepted pose (in order): the pair verdicts it completes that were not reported yet.
  std::vector<core::PairCheck> OnPoseAccepted(const core::PoseUpdate& pose);

 private:
  bool enabled_ = false;
  double gyro_to_rad_s_ = 1.0;
  std::vector<core::FacePose> poses_;
  std::set<std::pair<int, int>> reported_;
  // Since the last accepted pose.
  bool integrating_ = false;
  Eigen::Vector3d bias_ = Eigen::Vector3d::Zero();
  Eigen::Quaterniond rotation_ = Eigen::Quaterniond::Identity();
  bool have_previous_ = false;
  double previous_t_s_ = 0;
  Eigen::Vector3d previous_gyro_ = Eigen::Vector3d::Zero();
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_PAIR_TRACKER_H_
