#include "core/gyro_unit.h"

#include <algorithm>
#include <cmath>

#include "Eigen/Geometry"
#include "absl/strings/str_format.h"
#include "core/so3.h"
#include "util/units.h"

namespace imucal::core {
namespace {

// An uncalibrated gyro's scale error (a few %) over a 90-degree move leaves a few degrees; the
// wrong unit, tens.
constexpr double kUnitAgreeDeg = 10.0;
constexpr double kUnitErrorRatio = 3.0;
// A time gap: an interval between samples over this many median intervals (as the importers).
constexpr double kGapFactor = 3.0;

// The error (degrees) of the gravity direction at rest `b` predicted from rest `a` by the rates
// between them read with `to_rad_s` (rad/s per input unit), the rests' mean rate removed as the
// bias: R = prod Exp(w dt) over the samples between, and the specific force seen in the body
// turns by R^T.
double PredictionErrorDeg(const Capture& cap, const StaticInterval& a, const StaticInterval& b,
                          double to_rad_s) {
  const Eigen::Vector3d bias = 0.5 * (a.gyro_mean + b.gyro_mean);
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  for (size_t k = a.end - 1; k + 1 <= b.begin; ++k) {
    const Eigen::Vector3d w = to_rad_s * (0.5 * (cap.gyro[k] + cap.gyro[k + 1]) - bias);
    r = r * ExpAndRightJacobian(w * (cap.t_s[k + 1] - cap.t_s[k]), nullptr);
  }
  return AngleBetweenDeg(r.transpose() * a.accel_mean, b.accel_mean);
}

// Whether rests a and b bound one recorded move: the same file, no time gap between them.
bool OneMove(const Capture& cap, const StaticInterval& a, const StaticInterval& b) {
  if (b.begin <= a.end || a.end == 0 || cap.FileOf(a.begin) != cap.FileOf(b.end - 1)) return false;
  const double gap_s = kGapFactor * cap.MedianDt();
  for (size_t k = a.end - 1; k + 1 <= b.begin; ++k) {
    const double dt = cap.t_s[k + 1] - cap.t_s[k];
    if (!(dt > 0) || dt > gap_s) return false;
  }
  return true;
}

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

}  // namespace

std::string GyroUnitEvidence::Describe() const {
  if (moves == 0) {
    return absl::StrFormat("no move between two rests tilts gravity by %g degrees",
                           kMinTiltForUnitDeg);
  }
  return absl::StrFormat(
      "the rates integrated over %d moves between rests turn gravity as the accelerometer sees "
      "it to a median %.3g degrees read as deg/s, %.3g degrees read as rad/s",
      moves, error_as_deg_s_deg, error_as_rad_s_deg);
}

GyroUnitEvidence GyroUnitFromMoves(const Capture& capture,
                                   const std::vector<StaticInterval>& rests) {
  GyroUnitEvidence out;
  std::vector<double> as_rad, as_deg;
  for (size_t i = 0; i + 1 < rests.size(); ++i) {
    const StaticInterval& a = rests[i];
    const StaticInterval& b = rests[i + 1];
    if (AngleBetweenDeg(a.accel_mean, b.accel_mean) < kMinTiltForUnitDeg || !OneMove(capture, a, b))
      continue;
    as_rad.push_back(PredictionErrorDeg(capture, a, b, 1.0));
    as_deg.push_back(PredictionErrorDeg(capture, a, b, kDegToRad));
  }
  out.moves = static_cast<int>(as_rad.size());
  if (as_rad.empty()) return out;
  out.error_as_rad_s_deg = Median(as_rad);
  out.error_as_deg_s_deg = Median(as_deg);
  const double r = out.error_as_rad_s_deg, d = out.error_as_deg_s_deg;
  if (d < kUnitAgreeDeg && r > kUnitErrorRatio * d) out.unit = GyroUnit::kDegPerSecond;
  if (r < kUnitAgreeDeg && d > kUnitErrorRatio * r) out.unit = GyroUnit::kRadPerSecond;
  return out;
}

}  // namespace imucal::core
