#include "importers/unit_inference.h"

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <span>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/capture.h"
#include "core/gyro_unit.h"
#include "core/static_detector.h"
#include "util/str_util.h"

namespace imucal::importers {
namespace {

// Element at quantile q in [0, 1] (nearest rank); `values` is reordered. NaN when empty.
double QuantileInPlace(std::vector<double>& values, double q) {
  if (values.empty()) return std::numeric_limits<double>::quiet_NaN();
  const size_t rank = static_cast<size_t>(std::ceil(q * static_cast<double>(values.size())));
  const size_t index = std::clamp<size_t>(rank, 1, values.size()) - 1;
  const auto it = values.begin() + static_cast<std::ptrdiff_t>(index);
  std::nth_element(values.begin(), it, values.end());
  return *it;
}

// Bands of the accelerometer rule (see InferAccelUnit in the header).
constexpr double kAccelBandFraction = 0.3;
// Gyro rule thresholds (see InferGyroUnit in the header).
constexpr double kGyroCountsMedianAbs = 50.0;
constexpr double kGyroDegPerSecondP99 = 20.0;
constexpr double kGyroRateQuantile = 0.99;

// Physics rule (1b): the detector's threshold for the rests (times the learnt noise variance,
// as core/noise_rest.h: a rest's windows stay well under it, a hand's move far above).
constexpr double kRestMultiplier = 8.0;

}  // namespace

std::optional<core::GyroUnit> InferGyroUnitFromMoves(const core::Capture& capture,
                                                     std::string* reason) {
  const double dt = capture.MedianDt();
  if (capture.size() < 10 || !(dt > 0)) return std::nullopt;
  core::StaticDetectorOptions options;
  options.gyro_unit_known = false;  // what this is finding out
  const core::MotionSignal motion = core::ComputeMotionSignal(capture, options);
  const core::NoiseLevel noise = core::EstimateNoise(capture, motion);
  std::vector<core::StaticInterval> rests;
  for (core::StaticInterval& iv :
       core::DetectStatic(capture, motion, noise, kRestMultiplier, options))
    if (iv.used) rests.push_back(std::move(iv));
  const core::GyroUnitEvidence evidence = core::GyroUnitFromMoves(capture, rests);
  *reason = evidence.Describe();
  if (!evidence.unit && evidence.moves > 0) absl::StrAppend(reason, ": neither agrees clearly");
  return evidence.unit;
}

core::AccelUnit InferAccelUnit(std::span<const Eigen::Vector3d> accel, double gravity_m_s2,
                               std::string* reason) {
  std::vector<double> magnitudes(accel.size());
  for (size_t i = 0; i < accel.size(); ++i) magnitudes[i] = accel[i].norm();
  const double median = QuantileInPlace(magnitudes, 0.5);
  core::AccelUnit unit = core::AccelUnit::kCounts;
  std::string why;
  if (accel.empty()) {
    unit = core::AccelUnit::kMetersPerSecond2;
    why = "no samples to go by";
  } else if (std::abs(median - gravity_m_s2) <= kAccelBandFraction * gravity_m_s2) {
    unit = core::AccelUnit::kMetersPerSecond2;
    why = absl::StrFormat("median |a| %.6g is near gravity %.6g", median, gravity_m_s2);
  } else if (std::abs(median - 1.0) <= kAccelBandFraction) {
    unit = core::AccelUnit::kG;
    why = absl::StrFormat("median |a| %.6g is near 1", median);
  } else {
    why = absl::StrFormat("median |a| %.6g is near neither %.6g (m/s^2) nor 1 (g)", median,
                          gravity_m_s2);
  }
  if (reason != nullptr) {
    *reason = Cat("accel unit inferred as ", core::AccelUnitName(unit), ": ", why);
  }
  return unit;
}

core::GyroUnit InferGyroUnit(std::span<const Eigen::Vector3d> gyro, core::AccelUnit accel_unit,
                             std::string* reason) {
  bool all_integers = true;
  std::vector<double> values;
  values.reserve(3 * gyro.size());
  for (const Eigen::Vector3d& w : gyro) {
    for (int axis = 0; axis < 3; ++axis) {
      all_integers = all_integers && std::floor(w[axis]) == w[axis];
      values.push_back(std::abs(w[axis]));
    }
  }
  const double median_abs = QuantileInPlace(values, 0.5);
  values.resize(gyro.size());
  for (size_t i = 0; i < gyro.size(); ++i) values[i] = gyro[i].norm();
  const double p99_rate = QuantileInPlace(values, kGyroRateQuantile);

  core::GyroUnit unit = core::GyroUnit::kRadPerSecond;
  std::string why;
  if (gyro.empty()) {
    why = "no samples to go by";
  } else if (accel_unit == core::AccelUnit::kCounts &&
             (all_integers || median_abs > kGyroCountsMedianAbs)) {
    unit = core::GyroUnit::kCounts;
    why = all_integers
              ? "the accelerometer is counts and every gyro value is an integer"
              : absl::StrFormat("the accelerometer is counts and the median |gyro value| %.6g > %g",
                                median_abs, kGyroCountsMedianAbs);
  } else if (p99_rate > kGyroDegPerSecondP99) {
    unit = core::GyroUnit::kDegPerSecond;
    why = absl::StrFormat("99th-percentile |rate| %.6g > %g", p99_rate, kGyroDegPerSecondP99);
  } else {
    why = absl::StrFormat(
        "99th-percentile |rate| %.6g <= %g (a capture with little rotation cannot tell deg/s "
        "from rad/s: give the unit if this is wrong)",
        p99_rate, kGyroDegPerSecondP99);
  }
  if (reason != nullptr) {
    *reason = Cat("gyro unit inferred as ", core::GyroUnitName(unit), ": ", why);
  }
  return unit;
}

void ApplyOrInferUnits(const ImportOptions& options, core::Capture* capture,
                       std::vector<std::string>* notes) {
  std::string reason;
  if (options.accel_unit.has_value()) {
    capture->accel_unit = *options.accel_unit;
    capture->accel_unit_source = "declared";
  } else {
    capture->accel_unit = InferAccelUnit(capture->accel, capture->gravity_m_s2, &reason);
    capture->accel_unit_source = "inferred";
    if (notes != nullptr) notes->push_back(reason);
  }
  if (options.gyro_unit.has_value()) {
    capture->gyro_unit = *options.gyro_unit;
    capture->gyro_unit_source = "declared";
    return;
  }
  capture->gyro_unit_source = "inferred";
  capture->gyro_unit = InferGyroUnit(capture->gyro, capture->accel_unit, &reason);
  // The physics (rule 1b) overrides the rates' size (rule 2), not a raw-counts decision.
  if (capture->gyro_unit != core::GyroUnit::kCounts &&
      capture->accel_unit != core::AccelUnit::kCounts) {
    std::string physics;
    if (std::optional<core::GyroUnit> unit = InferGyroUnitFromMoves(*capture, &physics)) {
      capture->gyro_unit = *unit;
      reason = Cat("gyro unit inferred as ", core::GyroUnitName(*unit), ": ", physics);
    } else {
      absl::StrAppend(&reason, "; the moves did not settle it (", physics, ")");
    }
  }
  if (notes != nullptr) notes->push_back(reason);
}

}  // namespace imucal::importers
