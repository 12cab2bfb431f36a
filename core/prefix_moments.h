// Prefix sums of a vector series' first and second moments, for the mean and variance of any
// window in constant time (core/static_detector.cc's motion signal, core/noise_estimate.cc's
// noise). Internal to core.
#ifndef IMUCAL_CORE_PREFIX_MOMENTS_H_
#define IMUCAL_CORE_PREFIX_MOMENTS_H_

#include <cstddef>
#include <vector>

#include "Eigen/Core"

namespace imucal::core {

// Prefix sums of x - x0 and (x - x0)^2 per axis. The offset x0 (the first sample) keeps the
// sums well conditioned for raw counts around 32768.
struct PrefixMoments {
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> s1, s2;

  explicit PrefixMoments(const std::vector<Eigen::Vector3d>& x) {
    if (!x.empty()) offset = x.front();
    s1.assign(x.size() + 1, Eigen::Vector3d::Zero());
    s2.assign(x.size() + 1, Eigen::Vector3d::Zero());
    for (size_t i = 0; i < x.size(); ++i) {
      const Eigen::Vector3d d = x[i] - offset;
      s1[i + 1] = s1[i] + d;
      s2[i + 1] = s2[i] + d.cwiseProduct(d);
    }
  }
  // Per-axis mean over [b, e) (b < e).
  Eigen::Vector3d Mean(size_t b, size_t e) const {
    return offset + (s1[e] - s1[b]) / static_cast<double>(e - b);
  }
  // Unbiased per-axis variance over [b, e).
  Eigen::Vector3d Variance(size_t b, size_t e) const {
    const double n = static_cast<double>(e - b);
    if (n < 2) return Eigen::Vector3d::Zero();
    const Eigen::Vector3d m1 = s1[e] - s1[b];
    const Eigen::Vector3d m2 = s2[e] - s2[b];
    return ((m2 - m1.cwiseProduct(m1) / n) / (n - 1)).cwiseMax(0.0);
  }
};

}  // namespace imucal::core

#endif  // IMUCAL_CORE_PREFIX_MOMENTS_H_
