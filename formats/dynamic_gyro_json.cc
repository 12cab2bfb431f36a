#include "formats/dynamic_gyro_json.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "formats/json_fields.h"
#include "util/status.h"
#include "util/units.h"

namespace imucal::formats {
namespace {

using json_fields::Child;
using json_fields::Element;
using json_fields::kOptional;
using json_fields::kRequired;
using json_fields::Member;
using json_fields::Null;
using json_fields::Number;
using json_fields::Numbers;
using json_fields::PathError;
using json_fields::ReadDouble;
using json_fields::ReadInt;
using json_fields::ReadString;
using json_fields::Vec;
using Json = json_fields::Json;
// 3 output axes x 6 input channels per tap.
constexpr int kWeightsPerTap = 18;

// ---------------------------------------------------------------------------------------------
// Writing

Json RecordingToJson(const core::DynamicGyroRecording& r) {
  Json out = Json::object();
  out["name"] = r.name;
  out["sha256"] = r.sha256;
  out["duration_s"] = Number(r.duration_s);
  out["aoe_static_deg"] = Number(r.aoe_static_deg);
  out["aoe_learnt_deg"] = Number(r.aoe_learnt_deg);
  return out;
}

// ---------------------------------------------------------------------------------------------
// Reading: every reader names the JSON path it reads in its error.

absl::Status ReadWeights(const Json& j, const std::string& path, std::vector<double>* out) {
  if (!j.is_array()) return PathError(path, "expected an array of numbers");
  out->assign(j.size(), 0.0);
  for (size_t i = 0; i < j.size(); ++i) {
    IMUCAL_RETURN_IF_ERROR(ReadDouble(j[i], Element(path, i), Null::kReject, &(*out)[i]));
  }
  return absl::OkStatus();
}

absl::Status ReadEnvelope(const Json& j, const std::string& path, core::DynamicGyroEnvelope* out) {
  if (!j.is_object()) return PathError(path, "expected an object");
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "max_abs_rate_rad_s", kRequired, Numbers(Null::kReject),
                                &out->max_abs_rate_rad_s));
  return Member(j, path, "max_abs_accel_m_s2", kRequired, Numbers(Null::kReject),
                &out->max_abs_accel_m_s2);
}

absl::Status ReadRecording(const Json& j, const std::string& path,
                           core::DynamicGyroRecording* out) {
  if (!j.is_object()) return PathError(path, "expected an object");
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "name", kRequired, ReadString, &out->name));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "sha256", kOptional, ReadString, &out->sha256));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "duration_s", kOptional, Numbers(Null::kAsNan), &out->duration_s));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "aoe_static_deg", kOptional, Numbers(Null::kAsNan), &out->aoe_static_deg));
  return Member(j, path, "aoe_learnt_deg", kOptional, Numbers(Null::kAsNan), &out->aoe_learnt_deg);
}

absl::Status ReadTraining(const Json& j, const std::string& path,
                          std::vector<core::DynamicGyroRecording>* out) {
  if (!j.is_array()) return PathError(path, "expected an array");
  out->assign(j.size(), core::DynamicGyroRecording());
  for (size_t i = 0; i < j.size(); ++i) {
    IMUCAL_RETURN_IF_ERROR(ReadRecording(j[i], Element(path, i), &(*out)[i]));
  }
  return absl::OkStatus();
}

absl::Status AllFinite(const Eigen::Vector3d& v, const std::string& path) {
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(v(i))) return PathError(Element(path, i), "not finite");
  }
  return absl::OkStatus();
}

absl::Status FiniteNonNegative(const Eigen::Vector3d& v, const std::string& path) {
  IMUCAL_RETURN_IF_ERROR(AllFinite(v, path));
  for (int i = 0; i < 3; ++i) {
    if (v(i) < 0) return PathError(Element(path, i), "negative (a bound on |value|)");
  }
  return absl::OkStatus();
}

// taps, dilation and the window they make; the weights' count against taps.
absl::Status ShapeIsValid(const core::DynamicGyro& b, const std::string& path) {
  if (b.taps < 0) return PathError(Child(path, "taps"), "negative (0: no filter)");
  if (b.dilation < 1) return PathError(Child(path, "dilation"), "must be 1 or more");
  const int64_t window = b.taps > 0 ? int64_t{b.taps - 1} * b.dilation + 1 : 2;
  if (window > kMaxDynamicGyroWindowSamples) {
    return PathError(Child(path, "dilation"),
                     "window (taps-1)*dilation+1 = " + std::to_string(window) +
                         " samples, at most " + std::to_string(kMaxDynamicGyroWindowSamples));
  }
  const int64_t expected = int64_t{b.taps} * kWeightsPerTap;
  if (static_cast<int64_t>(b.weights.size()) != expected) {
    return PathError(Child(path, "weights"),
                     std::to_string(b.weights.size()) +
                         " values but taps*18 = " + std::to_string(expected) + " expected");
  }
  for (size_t i = 0; i < b.weights.size(); ++i) {
    if (!std::isfinite(b.weights[i])) {
      return PathError(Element(Child(path, "weights"), i), "not finite");
    }
  }
  return absl::OkStatus();
}

}  // namespace

Json DynamicGyroToJson(const core::DynamicGyro& b) {
  Json out = Json::object();
  out["model"] = kDynamicGyroModelText;
  out["rate_hz"] = Number(b.rate_hz);
  out["delay_s"] = Number(b.delay_s);
  out["delay_stderr_s"] = Number(b.delay_std_error_s);
  out["odd_rate_per_rad_s"] = Vec(b.odd_rate);
  out["odd_rate_stderr_per_rad_s"] = Vec(b.odd_rate_std_error);
  out["taps"] = b.taps;
  out["dilation"] = b.dilation;
  Json weights = Json::array();
  for (double w : b.weights) weights.push_back(Number(w));
  out["weights"] = std::move(weights);
  out["ridge_lambda"] = Number(b.ridge_lambda);
  Json envelope = Json::object();
  envelope["max_abs_rate_rad_s"] = Vec(b.envelope.max_abs_rate_rad_s);
  envelope["max_abs_accel_m_s2"] = Vec(b.envelope.max_abs_accel_m_s2);
  out["envelope"] = std::move(envelope);
  Json training = Json::array();
  for (const core::DynamicGyroRecording& r : b.training) training.push_back(RecordingToJson(r));
  out["training"] = std::move(training);
  out["gate_reason"] = b.gate_reason;
  return out;
}

absl::Status DynamicGyroFromJson(const Json& j, const std::string& path, core::DynamicGyro* out) {
  if (!j.is_object()) return PathError(path, "expected an object");
  core::DynamicGyro b;
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "rate_hz", kRequired, Numbers(Null::kReject), &b.rate_hz));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "delay_s", kOptional, Numbers(Null::kReject), &b.delay_s));
  b.delay_std_error_s = kNaN;
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "delay_stderr_s", kOptional, Numbers(Null::kAsNan), &b.delay_std_error_s));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "odd_rate_per_rad_s", kOptional, Numbers(Null::kReject), &b.odd_rate));
  b.odd_rate_std_error = Eigen::Vector3d::Constant(kNaN);
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "odd_rate_stderr_per_rad_s", kOptional,
                                Numbers(Null::kAsNan), &b.odd_rate_std_error));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "taps", kRequired, ReadInt, &b.taps));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "dilation", kRequired, ReadInt, &b.dilation));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "weights", kRequired, ReadWeights, &b.weights));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "ridge_lambda", kOptional, Numbers(Null::kReject), &b.ridge_lambda));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "envelope", kRequired, ReadEnvelope, &b.envelope));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "training", kOptional, ReadTraining, &b.training));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "gate_reason", kOptional, ReadString, &b.gate_reason));
  IMUCAL_RETURN_IF_ERROR(DynamicGyroIsValid(b, path));
  *out = std::move(b);
  return absl::OkStatus();
}

absl::Status DynamicGyroIsValid(const core::DynamicGyro& b, const std::string& path) {
  if (!(std::isfinite(b.rate_hz) && b.rate_hz > 0)) {
    return PathError(Child(path, "rate_hz"), "must be a finite number > 0");
  }
  if (!std::isfinite(b.delay_s)) return PathError(Child(path, "delay_s"), "not finite");
  IMUCAL_RETURN_IF_ERROR(AllFinite(b.odd_rate, Child(path, "odd_rate_per_rad_s")));
  IMUCAL_RETURN_IF_ERROR(ShapeIsValid(b, path));
  if (!(std::isfinite(b.ridge_lambda) && b.ridge_lambda >= 0)) {
    return PathError(Child(path, "ridge_lambda"), "must be a finite number >= 0");
  }
  IMUCAL_RETURN_IF_ERROR(FiniteNonNegative(b.envelope.max_abs_rate_rad_s,
                                           Child(Child(path, "envelope"), "max_abs_rate_rad_s")));
  return FiniteNonNegative(b.envelope.max_abs_accel_m_s2,
                           Child(Child(path, "envelope"), "max_abs_accel_m_s2"));
}

}  // namespace imucal::formats
