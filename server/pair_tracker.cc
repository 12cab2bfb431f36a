#include "server/pair_tracker.h"

#include <cmath>

#include "core/capture.h"

namespace imucal::server {

PairTracker::PairTracker(bool enabled, std::string_view accel_unit, std::string_view gyro_unit) {
  auto accel = core::ParseAccelUnit(accel_unit);
  auto gyro = core::ParseGyroUnit(gyro_unit);
  enabled_ = enabled && accel.ok() && gyro.ok() && *accel != core::AccelUnit::kCounts &&
             *gyro != core::GyroUnit::kCounts;
  if (enabled_) gyro_to_rad_s_ = core::NominalGyroToSi(*gyro);
}

void PairTracker::AddGyro(double t_s, const Eigen::Vector3d& gyro) {
  if (!integrating_) return;
  if (have_previous_) {
    // Trapezoid rate over the interval, exact rotation of that constant rate.
    const Eigen::Vector3d w = gyro_to_rad_s_ * (0.5 * (gyro + previous_gyro_) - bias_);
    const Eigen::Vector3d phi = w * (t_s - previous_t_s_);
    const double angle = phi.norm();
    if (angle > 0)
      rotation_ = rotation_ * Eigen::Quaterniond(Eigen::AngleAxisd(angle, phi / angle));
  }
  have_previous_ = true;
  previous_t_s_ = t_s;
  previous_gyro_ = gyro;
}

std::vector<core::PairCheck> PairTracker::OnPoseAccepted(const core::PoseUpdate& pose) {
  std::vector<core::PairCheck> out;
  if (!enabled_ || pose.accel_mean.norm() == 0 || poses_.size() >= kMaxPoses) return out;
  core::FacePose fp;
  fp.index = pose.index;
  fp.up = pose.accel_mean.normalized();
  if (!poses_.empty()) {
    const Eigen::AngleAxisd aa(rotation_.normalized());
    fp.rotation_from_previous = aa.angle() * aa.axis();
  }
  poses_.push_back(fp);
  // Restart the integration at this pose, with its own bias estimate.
  integrating_ = true;
  bias_ = pose.gyro_mean;
  rotation_ = Eigen::Quaterniond::Identity();
  // The whole list is re-checked (a few dozen poses at most): the verdicts are exactly those
  // of the offline check, including its re-done placements; only new pairs are reported.
  const core::SixFaceCheck check = core::CheckSixFacePairs(poses_);
  for (const core::PairCheck& p : check.pairs) {
    if (reported_.insert({p.pose_a, p.pose_b}).second) out.push_back(p);
  }
  return out;
}

}  // namespace imucal::server
