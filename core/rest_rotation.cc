#include "core/rest_rotation.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <utility>

namespace imucal::core {
namespace {

// The moves that tell the gyroscope's scale from the gravity direction: a tilt of at least this.
constexpr double kMinTiltRad = 30.0 * std::numbers::pi / 180.0;

double WeightedMedian(std::vector<std::pair<double, double>> value_weight) {
  std::sort(value_weight.begin(), value_weight.end());
  double total = 0;
  for (const auto& [v, w] : value_weight) total += w;
  double sum = 0;
  for (const auto& [v, w] : value_weight) {
    sum += w;
    if (sum >= 0.5 * total) return v;
  }
  return value_weight.empty() ? 0.0 : value_weight.back().first;
}

Eigen::Vector3d MeanOf(const std::vector<Eigen::Vector3d>& x, size_t b, size_t e) {
  Eigen::Vector3d s = Eigen::Vector3d::Zero();
  for (size_t i = b; i < e; ++i) s += x[i];
  return s / static_cast<double>(std::max<size_t>(1, e - b));
}

}  // namespace

GyroIntegral::GyroIntegral(const Capture& capture, double median_dt) : median_dt_s(median_dt) {
  const size_t n = capture.size();
  angle.assign(n + 1, Eigen::Vector3d::Zero());
  time_s.assign(n + 1, 0.0);
  for (size_t i = 0; i < n; ++i) {
    double dt = i + 1 < n ? capture.t_s[i + 1] - capture.t_s[i] : median_dt_s;
    dt = std::min(dt, 3 * median_dt_s);
    angle[i + 1] = angle[i] + capture.gyro[i] * dt;
    time_s[i + 1] = time_s[i] + dt;
  }
}

double GyroIntegral::Excursion(size_t b, size_t e, const Eigen::Vector3d& rate) const {
  double worst = 0;
  for (size_t i = b + 1; i <= e; ++i) {
    const Eigen::Vector3d v = (angle[i] - angle[b]) - rate * (time_s[i] - time_s[b]);
    worst = std::max(worst, v.squaredNorm());
  }
  return std::sqrt(worst);
}

RestRate DenseRestRate(const std::vector<RateSample>& runs, double bound) {
  RestRate out;
  if (runs.empty()) return out;
  size_t best = 0;
  double best_weight = -1;
  for (size_t i = 0; i < runs.size(); ++i) {
    double w = 0;
    for (const RateSample& r : runs)
      if ((r.mean - runs[i].mean).cwiseAbs().maxCoeff() <= bound) w += r.weight;
    if (w > best_weight) best_weight = w, best = i;
  }
  for (int j = 0; j < 3; ++j) {
    std::vector<std::pair<double, double>> vw;
    for (const RateSample& r : runs)
      if ((r.mean - runs[best].mean).cwiseAbs().maxCoeff() <= bound)
        vw.emplace_back(r.mean(j), r.weight);
    out.members = static_cast<int>(vw.size());
    out.rate(j) = WeightedMedian(std::move(vw));
  }
  return out;
}

double RoughRadPerGyroUnit(const Capture& capture, const GyroIntegral& integral,
                           const std::vector<std::pair<size_t, size_t>>& rests,
                           const Eigen::Vector3d& rest_rate) {
  if (rests.size() < 2) return 0;
  std::vector<Eigen::Vector3d> means;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(INFINITY), hi = -lo;
  for (const auto& [b, e] : rests) {
    means.push_back(MeanOf(capture.accel, b, e));
    lo = lo.cwiseMin(means.back());
    hi = hi.cwiseMax(means.back());
  }
  // Raw counts carry an offset (the middle of the extremes, near enough for a rough figure);
  // m/s^2 and g read zero at zero.
  const Eigen::Vector3d offset =
      capture.accel_unit == AccelUnit::kCounts ? Eigen::Vector3d(0.5 * (lo + hi))
                                               : Eigen::Vector3d::Zero();
  double best = 0;
  for (size_t k = 1; k < rests.size(); ++k) {
    const size_t from = rests[k - 1].second, to = rests[k].first;
    if (to <= from || capture.FileOf(from) != capture.FileOf(to)) continue;
    const Eigen::Vector3d u1 = (means[k - 1] - offset).normalized();
    const Eigen::Vector3d u2 = (means[k] - offset).normalized();
    const double tilt = std::acos(std::clamp(u1.dot(u2), -1.0, 1.0));
    const double turned =
        ((integral.angle[to] - integral.angle[from]) -
         rest_rate * (integral.time_s[to] - integral.time_s[from])).norm();
    if (tilt >= kMinTiltRad && turned > 0) best = std::max(best, tilt / turned);
  }
  return best;
}

double RestRotationBound(const Eigen::Vector3d& gyro_noise_rad_s, size_t samples, double dt_s,
                         double duration_s, double bias_bound_rad_s, double sigmas) {
  return sigmas * gyro_noise_rad_s.norm() * std::sqrt(static_cast<double>(samples)) * dt_s +
         bias_bound_rad_s * duration_s;
}

}  // namespace imucal::core
