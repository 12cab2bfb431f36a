#include "core/motion/evaluate.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/correction.h"
#include "core/dynamic_gyro.h"
#include "core/dynamic_gyro_state.h"
#include "core/so3.h"
#include "util/units.h"

namespace imucal::core::motion {
namespace {

// A still interval: the gyro's spread about its mean below this (rad/s RMS, about 1 deg/s, well
// above a MEMS gyro's noise at 200 Hz and well below hand-held motion) and its mean below
// kRestMeanRadS (a bias, not a turn).
constexpr double kRestSpreadRadS = 0.015;
constexpr double kRestMeanRadS = 0.1;

}  // namespace

double MedianStepS(const std::vector<double>& t) {
  std::vector<double> d;
  for (size_t k = 0; k + 1 < t.size(); ++k) d.push_back(t[k + 1] - t[k]);
  if (d.empty()) return 0.0;
  std::nth_element(d.begin(), d.begin() + d.size() / 2, d.end());
  return d[d.size() / 2];
}

void StaticOutputs(const MotionRecording& r, const ParamSet& params,
                   std::vector<Eigen::Vector3d>* w_s, std::vector<Eigen::Vector3d>* accel) {
  const SampleCorrection correction(params, r.t_s.empty() ? 0.0 : r.t_s.front());
  w_s->resize(r.t_s.size());
  accel->resize(r.t_s.size());
  for (size_t k = 0; k < r.t_s.size(); ++k) {
    const CorrectedSample c =
        correction.Apply(r.accel_m_s2[k], r.gyro_rad_s[k], std::nan(""), r.t_s[k]);
    (*w_s)[k] = c.gyro_rad_s;
    (*accel)[k] = c.accel_m_s2;
  }
}

std::vector<Eigen::Vector3d> CorrectedRates(const MotionRecording& r, const ParamSet& params,
                                            int* outside) {
  std::vector<Eigen::Vector3d> w_s, accel;
  StaticOutputs(r, params, &w_s, &accel);
  if (outside != nullptr) *outside = 0;
  if (!params.dynamic_gyro) return w_s;
  DynamicGyroState state(*params.dynamic_gyro);
  const double gap_s = kImuGapFactor * MedianStepS(r.t_s);
  std::vector<Eigen::Vector3d> out(w_s.size());
  for (size_t k = 0; k < w_s.size(); ++k) {
    if (k > 0 && r.t_s[k] - r.t_s[k - 1] > gap_s) state.Reset();
    const bool inside = state.Step(w_s[k], accel[k], &out[k]);
    if (outside != nullptr && !inside) ++*outside;
  }
  return out;
}

OrientationError CompareOrientation(const MotionRecording& r, const AlignedReference& ref,
                                    const std::vector<Eigen::Vector3d>& rate) {
  OrientationError out;
  size_t k0 = 0;
  while (k0 < ref.valid.size() && !ref.valid[k0]) ++k0;
  if (k0 == ref.valid.size()) return out;
  Eigen::Quaterniond q = ref.q_world_imu[k0];
  double sum_sq = 0.0;
  Eigen::Quaterniond last_error = Eigen::Quaterniond::Identity();
  for (size_t k = k0; k < r.t_s.size(); ++k) {
    if (k > k0) {
      const double dt = r.t_s[k] - r.t_s[k - 1];
      q = (q * ExpQuaternion(0.5 * dt * (rate[k - 1] + rate[k]))).normalized();
    }
    if (!ref.valid[k]) continue;
    const double angle = LogQuaternion(ref.q_world_imu[k].conjugate() * q).norm() * kRadToDeg;
    sum_sq += angle * angle;
    out.t_s.push_back(r.t_s[k] - r.t_s[k0]);
    out.error_deg.push_back(angle);
    last_error = q * ref.q_world_imu[k].conjugate();
  }
  out.aoe_deg = std::sqrt(sum_sq / static_cast<double>(std::max<size_t>(1, out.t_s.size())));
  // The twist of the world-frame error about up (swing-twist decomposition).
  const double along = last_error.vec().dot(ref.up_world);
  double heading = 2.0 * std::atan2(along, last_error.w()) * kRadToDeg;
  if (heading > 180.0) heading -= 360.0;
  if (heading < -180.0) heading += 360.0;
  out.final_heading_deg = heading;
  return out;
}

std::optional<Eigen::Vector3d> FirstRestBias(const MotionRecording& r, double duration_s,
                                             std::string* note) {
  const double step = MedianStepS(r.t_s);
  const size_t n = step > 0 ? static_cast<size_t>(std::lround(duration_s / step)) : 0;
  if (n < 10 || r.t_s.size() < n) {
    *note = "no first rest: the recording is too short";
    return std::nullopt;
  }
  // A sliding window's sums: the first window whose spread and mean are small.
  Eigen::Vector3d sum = Eigen::Vector3d::Zero(), sum_sq = Eigen::Vector3d::Zero();
  for (size_t k = 0; k < r.t_s.size(); ++k) {
    sum += r.gyro_rad_s[k];
    sum_sq += r.gyro_rad_s[k].cwiseAbs2();
    if (k >= n) {
      sum -= r.gyro_rad_s[k - n];
      sum_sq -= r.gyro_rad_s[k - n].cwiseAbs2();
    }
    if (k + 1 < n) continue;
    const Eigen::Vector3d mean = sum / static_cast<double>(n);
    const double spread =
        std::sqrt(std::max(0.0, (sum_sq / static_cast<double>(n) - mean.cwiseAbs2()).sum()));
    if (spread < kRestSpreadRadS && mean.norm() < kRestMeanRadS &&
        r.t_s[k] - r.t_s[k + 1 - n] < 1.5 * duration_s) {
      *note = absl::StrFormat("first rest at %.2f..%.2f s (spread %.4f rad/s)",
                              r.t_s[k + 1 - n] - r.t_s.front(), r.t_s[k] - r.t_s.front(), spread);
      return mean;
    }
  }
  *note = absl::StrFormat("no still interval of %.1f s (gyro spread < %.3f rad/s) in the recording",
                          duration_s, kRestSpreadRadS);
  return std::nullopt;
}

}  // namespace imucal::core::motion
