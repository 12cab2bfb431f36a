#include "core/calibrate/unit_check.h"

#include <cmath>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/gyro_unit.h"
#include "util/units.h"

namespace imucal::core::pipeline {
namespace {

struct Candidate {
  std::string_view name;
  double to_si;  // nominal factor to m/s^2 or rad/s
};

// How the unit was decided, as the message names it: the flag, the inference, the file.
std::string UnitPhrase(std::string_view flag, std::string_view unit, std::string_view source) {
  if (source == "declared") return absl::StrFormat("--%s %s", flag, unit);
  if (source == "inferred") return absl::StrFormat("the inferred unit %s", unit);
  if (source == "file") return absl::StrFormat("the file's unit %s", unit);
  return absl::StrFormat("its unit %s", unit);
}

// "about 9.8 times" / "about 1/57.3 of": the readings against what the unit implies.
std::string Times(double ratio) {
  return ratio >= 1 ? absl::StrFormat("about %.3g times", ratio)
                    : absl::StrFormat("about 1/%.3g of", 1 / ratio);
}

Refusal UnitRefusal(std::string message) {
  Refusal out;
  out.reason = RefusalReason::kUnitMismatch;
  out.message = std::move(message);
  return out;
}

// The refusal for one sensor whose fitted factor `fitted_si` (SI per input unit) is off the
// nominal `nominal_si` of its unit by more than the tolerance; nullopt when it is not.
std::optional<Refusal> CheckSensor(std::string_view sensor, std::string_view flag,
                                   std::string_view unit, std::string_view source,
                                   double nominal_si, double fitted_si,
                                   const std::vector<Candidate>& candidates) {
  if (!(nominal_si > 0) || !std::isfinite(fitted_si) || fitted_si <= 0) return std::nullopt;
  const double ratio = fitted_si / nominal_si;  // true reading / what the unit implies
  if (std::abs(ratio - 1) <= kUnitScaleTolerance) return std::nullopt;
  const Candidate* likely = nullptr;
  for (const Candidate& c : candidates)
    if (std::abs(fitted_si / c.to_si - 1) <= kUnitScaleTolerance) likely = &c;
  const std::string looks =
      likely != nullptr
          ? absl::StrFormat("the data look like %s; give --%s %s", likely->name, flag, likely->name)
          : absl::StrFormat("the data fit none of the units (raw counts?); give --%s counts", flag);
  return UnitRefusal(absl::StrFormat(
      "the %s reads %s what %s implies: %s. (The fit's scale is %.4g SI per input unit, %.4g "
      "times the unit's %.4g; a sensor's scale is within a few percent of its unit's, and a "
      "scale %.0f%% or more off is a wrong unit, not a calibration.)",
      sensor, Times(1 / ratio), UnitPhrase(flag, unit, source), looks, fitted_si, ratio, nominal_si,
      100 * kUnitScaleTolerance));
}

// The gyroscope's moves against its declared or inferred unit (core/gyro_unit.h): a gyro fit on
// rates 57.3 times too large can settle near a scale of 1 (the turns aliased by whole
// revolutions), so the fitted scale alone does not catch deg/s read as rad/s.
std::optional<Refusal> CheckGyroMoves(const Capture& capture,
                                      const std::vector<StaticInterval>& rests) {
  if (capture.gyro_unit == GyroUnit::kCounts || capture.accel_unit == AccelUnit::kCounts)
    return std::nullopt;
  const GyroUnitEvidence evidence = GyroUnitFromMoves(capture, rests);
  if (!evidence.unit || *evidence.unit == capture.gyro_unit) return std::nullopt;
  const double ratio =
      NominalGyroToSi(*evidence.unit) / NominalGyroToSi(capture.gyro_unit);  // reads / implies
  const std::string_view likely = GyroUnitName(*evidence.unit);
  return UnitRefusal(absl::StrFormat(
      "the gyroscope reads %s what %s implies: the data look like %s; give --gyro-unit %s. (%s.)",
      Times(1 / ratio),
      UnitPhrase("gyro-unit", GyroUnitName(capture.gyro_unit), capture.gyro_unit_source), likely,
      likely, evidence.Describe()));
}

}  // namespace

std::optional<Refusal> CheckFittedUnits(const Capture& capture, const ParamSet& params,
                                        const std::vector<StaticInterval>& rests) {
  const double g = capture.gravity_m_s2;
  if (capture.accel_unit != AccelUnit::kCounts) {
    const double fitted = params.accel.scale.cwiseAbs().mean();
    if (auto r = CheckSensor("accelerometer", "accel-unit", AccelUnitName(capture.accel_unit),
                             capture.accel_unit_source, NominalAccelToSi(capture.accel_unit, g),
                             fitted, {{"m/s^2", 1.0}, {"g", g}}))
      return r;
  }
  if (!capture.has_gyro) return std::nullopt;  // an accelerometer-only capture
  if (auto r = CheckGyroMoves(capture, rests)) return r;
  if (capture.gyro_unit != GyroUnit::kCounts && params.gyro_calibrated) {
    const double fitted = params.gyro.matrix.diagonal().cwiseAbs().mean();
    if (auto r = CheckSensor("gyroscope", "gyro-unit", GyroUnitName(capture.gyro_unit),
                             capture.gyro_unit_source, NominalGyroToSi(capture.gyro_unit), fitted,
                             {{"rad/s", 1.0}, {"deg/s", kDegToRad}}))
      return r;
  }
  return std::nullopt;
}

}  // namespace imucal::core::pipeline
