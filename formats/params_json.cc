#include "formats/params_json.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/regressor.h"
#include "formats/dynamic_gyro_json.h"
#include "formats/json_fields.h"
#include "nlohmann/json.hpp"
#include "util/status.h"
#include "util/units.h"

namespace imucal::formats {
namespace {

using json_fields::Child;
using json_fields::Element;
using json_fields::ExpectObject;
using json_fields::kOptional;
using json_fields::kRequired;
using json_fields::Mat;
using json_fields::Member;
using json_fields::Null;
using json_fields::Number;
using json_fields::Numbers;
using json_fields::PathError;
using json_fields::ReadBool;
using json_fields::ReadDouble;
using json_fields::ReadInt;
using json_fields::ReadString;
using json_fields::ReadVec3;
using json_fields::Vec;
using Json = json_fields::Json;
using OrderedJson = json_fields::Json;
constexpr const char* kAxisNames[3] = {"x", "y", "z"};

// ---------------------------------------------------------------------------------------------
// Writing

OrderedJson AccelModelFields(const core::AccelParams& a) {
  OrderedJson out = OrderedJson::object();
  out["bias"] = Vec(a.bias);
  out["scale"] = Vec(a.scale);
  out["tri_angles"] = Vec(a.tri_angles);
  out["frame_angles"] = Vec(a.frame_angles);
  out["quadratic"] = Vec(a.quadratic);
  return out;
}

// Evidence is a free string in core::Effect; report.md shows an object. A string that holds a
// JSON object is written as that object, anything else as {"what": text}.
OrderedJson EvidenceToJson(const std::string& evidence) {
  OrderedJson parsed = OrderedJson::parse(evidence, nullptr, /*allow_exceptions=*/false);
  if (parsed.is_object()) return parsed;
  OrderedJson out = OrderedJson::object();
  out["what"] = evidence;
  return out;
}

OrderedJson EffectToJson(const core::Effect& e) {
  OrderedJson out = OrderedJson::object();
  out["sensor"] = e.sensor == core::Sensor::kGyro ? "gyro" : "accel";
  out["axis"] = e.axis >= 0 && e.axis < 3 ? kAxisNames[e.axis] : "?";
  out["regressor"] = e.regressor;
  out["coefficient"] = Number(e.coefficient);
  out["stderr"] = Number(e.std_error);
  out["error_before"] = Number(e.error_before);
  out["error_after"] = Number(e.error_after);
  out["applied"] = e.applied;
  out["evidence"] = EvidenceToJson(e.evidence);
  return out;
}

// The noise block (core/params.h NoiseFigures): units spelled out, NaN (not reached) as null.
OrderedJson SensorNoiseToJson(const core::SensorNoise& s, double rate_hz) {
  OrderedJson out = OrderedJson::object();
  out["noise_density"] = Vec(s.noise_density);
  out["bias_instability"] = Vec(s.bias_instability);
  out["random_walk"] = Vec(s.random_walk);
  out["random_walk_bound"] = Vec(s.random_walk_bound);
  out["noise_std_per_sample"] = Vec(s.noise_density * std::sqrt(rate_hz));  // informational
  return out;
}

// Without a gyroscope (has_gyro false) the gyro figures and their units are left out.
OrderedJson NoiseToJson(const core::NoiseFigures& n, bool has_gyro) {
  OrderedJson out = OrderedJson::object();
  out["method"] =
      "overlapping Allan deviation of the calibrated body-frame signal over the longest static "
      "interval; noise_density N read at tau = 1 s on the slope -1/2 line, bias_instability B = "
      "flat minimum / 0.664, random_walk K read at tau = 3 s on the slope +1/2 line; null where "
      "the data did not reach the figure (see notes)";
  OrderedJson interval = OrderedJson::object();
  interval["t_start"] = Number(n.t_start_s);
  interval["t_end"] = Number(n.t_end_s);
  interval["samples"] = n.samples;
  interval["rate_hz"] = Number(n.rate_hz);
  out["interval"] = std::move(interval);
  OrderedJson units = OrderedJson::object();
  units["accel.noise_density"] = "m/s^2/sqrt(Hz) (continuous-time)";
  units["accel.bias_instability"] = "m/s^2";
  units["accel.random_walk"] = "m/s^3/sqrt(Hz)";
  units["accel.noise_std_per_sample"] = "m/s^2 (discrete: noise_density * sqrt(rate_hz))";
  if (has_gyro) {
    units["gyro.noise_density"] = "rad/s/sqrt(Hz) (continuous-time)";
    units["gyro.bias_instability"] = "rad/s";
    units["gyro.random_walk"] = "rad/s^2/sqrt(Hz)";
    units["gyro.noise_std_per_sample"] = "rad/s (discrete: noise_density * sqrt(rate_hz))";
  }
  out["units"] = std::move(units);
  out["accel"] = SensorNoiseToJson(n.accel, n.rate_hz);
  if (has_gyro) out["gyro"] = SensorNoiseToJson(n.gyro, n.rate_hz);
  out["notes"] = n.notes;
  return out;
}

// ---------------------------------------------------------------------------------------------
// Reading. Every reader takes the JSON path of the value it reads and names it in its error.

std::optional<core::AccelUnit> AccelUnitFromName(std::string_view name) {
  for (core::AccelUnit u :
       {core::AccelUnit::kMetersPerSecond2, core::AccelUnit::kG, core::AccelUnit::kCounts}) {
    if (UnitName(u) == name) return u;
  }
  return std::nullopt;
}

std::optional<core::GyroUnit> GyroUnitFromName(std::string_view name) {
  for (core::GyroUnit u :
       {core::GyroUnit::kRadPerSecond, core::GyroUnit::kDegPerSecond, core::GyroUnit::kCounts}) {
    if (UnitName(u) == name) return u;
  }
  return std::nullopt;
}

absl::Status ReadAccelUnit(const Json& j, const std::string& path, core::AccelUnit* out) {
  std::string name;
  IMUCAL_RETURN_IF_ERROR(ReadString(j, path, &name));
  const std::optional<core::AccelUnit> unit = AccelUnitFromName(name);
  if (!unit) return PathError(path, "unknown accel unit \"" + name + "\" (m/s^2, g or counts)");
  *out = *unit;
  return absl::OkStatus();
}

absl::Status ReadGyroUnit(const Json& j, const std::string& path, core::GyroUnit* out) {
  std::string name;
  IMUCAL_RETURN_IF_ERROR(ReadString(j, path, &name));
  const std::optional<core::GyroUnit> unit = GyroUnitFromName(name);
  if (!unit) return PathError(path, "unknown gyro unit \"" + name + "\" (rad/s, deg/s or counts)");
  *out = *unit;
  return absl::OkStatus();
}

// The five accel parameter vectors, all required (values) or all optional (standard errors).
absl::Status ReadAccelModelFields(const Json& obj, const std::string& path, bool required,
                                  Null null, core::AccelParams* out) {
  IMUCAL_RETURN_IF_ERROR(Member(obj, path, "bias", required, Numbers(null), &out->bias));
  IMUCAL_RETURN_IF_ERROR(Member(obj, path, "scale", required, Numbers(null), &out->scale));
  IMUCAL_RETURN_IF_ERROR(
      Member(obj, path, "tri_angles", required, Numbers(null), &out->tri_angles));
  IMUCAL_RETURN_IF_ERROR(
      Member(obj, path, "frame_angles", required, Numbers(null), &out->frame_angles));
  return Member(obj, path, "quadratic", required, Numbers(null), &out->quadratic);
}

absl::Status ReadAccel(const Json& j, const std::string& path, core::ParamSet* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  IMUCAL_RETURN_IF_ERROR(ReadAccelModelFields(j, path, kRequired, Null::kReject, &out->accel));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "input_unit", kRequired, ReadAccelUnit, &out->accel_unit));
  // Standard errors: unknown (NaN) unless stated.
  core::AccelParams& se = out->stderrs.accel;
  se.bias = se.scale = se.tri_angles = se.frame_angles = se.quadratic =
      Eigen::Vector3d::Constant(kNaN);
  const std::string se_path = Child(path, "stderr");
  const auto it = j.find("stderr");
  if (it == j.end()) return absl::OkStatus();
  IMUCAL_RETURN_IF_ERROR(ExpectObject(*it, se_path));
  return ReadAccelModelFields(*it, se_path, kOptional, Null::kAsNan, &se);
}

absl::Status ReadGyro(const Json& j, const std::string& path, core::ParamSet* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "bias", kRequired, Numbers(Null::kReject), &out->gyro.bias));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "matrix", kRequired, Numbers(Null::kReject), &out->gyro.matrix));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "accel_coupling", kOptional, Numbers(Null::kReject),
                                &out->gyro.accel_coupling));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "input_unit", kRequired, ReadGyroUnit, &out->gyro_unit));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "calibrated", kOptional, ReadBool, &out->gyro_calibrated));
  out->stderrs.gyro_bias = Eigen::Vector3d::Constant(kNaN);
  out->stderrs.gyro_matrix = Eigen::Matrix3d::Constant(kNaN);
  const std::string se_path = Child(path, "stderr");
  const auto it = j.find("stderr");
  if (it == j.end()) return absl::OkStatus();
  IMUCAL_RETURN_IF_ERROR(ExpectObject(*it, se_path));
  IMUCAL_RETURN_IF_ERROR(
      Member(*it, se_path, "bias", kOptional, Numbers(Null::kAsNan), &out->stderrs.gyro_bias));
  return Member(*it, se_path, "matrix", kOptional, Numbers(Null::kAsNan),
                &out->stderrs.gyro_matrix);
}

absl::Status ReadSensor(const Json& j, const std::string& path, core::Sensor* out) {
  std::string name;
  IMUCAL_RETURN_IF_ERROR(ReadString(j, path, &name));
  if (name == "accel") {
    *out = core::Sensor::kAccel;
  } else if (name == "gyro") {
    *out = core::Sensor::kGyro;
  } else {
    return PathError(path, "expected \"accel\" or \"gyro\", got \"" + name + "\"");
  }
  return absl::OkStatus();
}

absl::Status ReadAxis(const Json& j, const std::string& path, int* out) {
  std::string name;
  IMUCAL_RETURN_IF_ERROR(ReadString(j, path, &name));
  for (int i = 0; i < 3; ++i) {
    if (name == kAxisNames[i]) {
      *out = i;
      return absl::OkStatus();
    }
  }
  return PathError(path, "expected \"x\", \"y\" or \"z\", got \"" + name + "\"");
}

absl::Status ReadRegressor(const Json& j, const std::string& path, std::string* out) {
  IMUCAL_RETURN_IF_ERROR(ReadString(j, path, out));
  if (!core::ParseRegressor(*out).has_value()) {
    return PathError(path, "unknown regressor \"" + *out +
                               "\" (signals temperature, time, ax, ay, az, gx, gy, gz joined by "
                               "'*', each optionally '^2'; a sensor signal's magnitude as |gx|)");
  }
  return absl::OkStatus();
}

absl::Status ReadEvidence(const Json& j, const std::string& path, std::string* out) {
  if (j.is_string()) {
    *out = j.get<std::string>();
  } else if (j.is_object()) {
    const auto what = j.find("what");
    if (j.size() == 1 && what != j.end() && what->is_string()) {
      *out = what->get<std::string>();
    } else {
      *out = j.dump(-1, ' ', false, Json::error_handler_t::replace);
    }
  } else {
    return PathError(path, "expected a string or an object");
  }
  return absl::OkStatus();
}

absl::Status ReadEffect(const Json& j, const std::string& path, core::Effect* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "sensor", kRequired, ReadSensor, &out->sensor));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "axis", kRequired, ReadAxis, &out->axis));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "regressor", kRequired, ReadRegressor, &out->regressor));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "coefficient", kRequired, Numbers(Null::kReject), &out->coefficient));
  out->std_error = kNaN;
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "stderr", kOptional, Numbers(Null::kAsNan), &out->std_error));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "error_before", kOptional, Numbers(Null::kAsNan), &out->error_before));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "error_after", kOptional, Numbers(Null::kAsNan), &out->error_after));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "applied", kOptional, ReadBool, &out->applied));
  return Member(j, path, "evidence", kOptional, ReadEvidence, &out->evidence);
}

absl::Status ReadEffects(const Json& j, const std::string& path, std::vector<core::Effect>* out) {
  if (!j.is_array()) return PathError(path, "expected an array");
  out->assign(j.size(), core::Effect());
  for (size_t i = 0; i < j.size(); ++i) {
    IMUCAL_RETURN_IF_ERROR(ReadEffect(j[i], Element(path, i), &(*out)[i]));
  }
  return absl::OkStatus();
}

// Optional, and each field in it: a missing reference is 0 (parameter sets written before
// centred factors existed use plain `temperature`, i.e. about 0 degC).
absl::Status ReadEffectReference(const Json& j, const std::string& path,
                                 core::EffectReference* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "temperature", kOptional, Numbers(Null::kReject), &out->temperature_c));
  return Member(j, path, "time", kOptional, Numbers(Null::kReject), &out->time_s);
}

absl::Status ReadQuality(const Json& j, const std::string& path, core::ParamSet* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "accel_rms", kOptional, Numbers(Null::kAsNan), &out->quality_accel_rms_m_s2));
  return Member(j, path, "gyro_static_rms", kOptional, Numbers(Null::kAsNan),
                &out->quality_gyro_static_rms_rad_s);
}

absl::Status ReadInt64(const Json& j, const std::string& path, int64_t* out) {
  if (!j.is_number_integer()) return PathError(path, "expected an integer");
  *out = j.get<int64_t>();
  return absl::OkStatus();
}

absl::Status ReadStrings(const Json& j, const std::string& path, std::vector<std::string>* out) {
  if (!j.is_array()) return PathError(path, "expected an array of strings");
  out->clear();
  for (size_t i = 0; i < j.size(); ++i) {
    out->emplace_back();
    IMUCAL_RETURN_IF_ERROR(ReadString(j[i], Element(path, i), &out->back()));
  }
  return absl::OkStatus();
}

// noise_density is required in a noise block; the other figures may be missing or null (NaN).
absl::Status ReadSensorNoise(const Json& j, const std::string& path, core::SensorNoise* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "noise_density", kRequired, Numbers(Null::kAsNan), &out->noise_density));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "bias_instability", kOptional, Numbers(Null::kAsNan),
                                &out->bias_instability));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "random_walk", kOptional, Numbers(Null::kAsNan), &out->random_walk));
  return Member(j, path, "random_walk_bound", kOptional, Numbers(Null::kAsNan),
                &out->random_walk_bound);
}

absl::Status ReadNoiseInterval(const Json& j, const std::string& path, core::NoiseFigures* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "t_start", kOptional, Numbers(Null::kAsNan), &out->t_start_s));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "t_end", kOptional, Numbers(Null::kAsNan), &out->t_end_s));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "samples", kOptional, ReadInt64, &out->samples));
  return Member(j, path, "rate_hz", kRequired, Numbers(Null::kReject), &out->rate_hz);
}

// Optional as a whole: parameter sets written before it existed have none.
absl::Status ReadNoise(const Json& j, const std::string& path,
                       std::optional<core::NoiseFigures>* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  core::NoiseFigures n;
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "interval", kRequired, ReadNoiseInterval, &n));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "accel", kRequired, ReadSensorNoise, &n.accel));
  // Optional here; ReadParamSet requires it of a parameter set that has a gyroscope.
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "gyro", kOptional, ReadSensorNoise, &n.gyro));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "notes", kOptional, ReadStrings, &n.notes));
  *out = std::move(n);
  return absl::OkStatus();
}

// Optional as a whole: parameter sets written before issue 25 have none. Widths must be > 0.
absl::Status ReadTermPriors(const Json& j, const std::string& path,
                            std::optional<core::TermPriors>* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  core::TermPriors p;
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "sensor_class", kRequired, ReadString, &p.sensor_class));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "accel_quadratic_sigma", kRequired,
                                Numbers(Null::kReject), &p.accel_quadratic_per_m_s2));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "accel_angle_sigma", kRequired, Numbers(Null::kReject),
                                &p.accel_angle_rad));
  if (!(p.accel_quadratic_per_m_s2 > 0))
    return PathError(Child(path, "accel_quadratic_sigma"), "must be > 0");
  if (!(p.accel_angle_rad > 0)) return PathError(Child(path, "accel_angle_sigma"), "must be > 0");
  *out = std::move(p);
  return absl::OkStatus();
}

// Optional as a whole: only a parameter set with a learnt block has one (issue 27).
absl::Status ReadDynamicGyro(const Json& j, const std::string& path,
                             std::optional<core::DynamicGyro>* out) {
  core::DynamicGyro block;
  IMUCAL_RETURN_IF_ERROR(DynamicGyroFromJson(j, path, &block));
  *out = std::move(block);
  return absl::OkStatus();
}

absl::Status ReadSource(const Json& j, const std::string& path, core::ParamSet* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "session", kOptional, ReadString, &out->source_session));
  return Member(j, path, "software", kOptional, ReadString, &out->software);
}

// A parameter set without a gyroscope cannot correct the gyroscope.
absl::Status CheckNoGyroEffects(const core::ParamSet& params, const std::string& path) {
  if (params.has_gyro) return absl::OkStatus();
  for (size_t i = 0; i < params.effects.size(); ++i) {
    if (params.effects[i].sensor == core::Sensor::kGyro) {
      return PathError(Child(Element(Child(path, "effects"), i), "sensor"),
                       "a gyro effect in a parameter set without a \"gyro\" block");
    }
  }
  return absl::OkStatus();
}

// An "imucal-params v1" object at `path` ("" at top level, "parameters" inside a report).
absl::Status ReadParamSet(const Json& j, const std::string& path, core::ParamSet* out) {
  IMUCAL_RETURN_IF_ERROR(ExpectObject(j, path.empty() ? "(top level)" : path));
  std::string format;
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "format", kRequired, ReadString, &format));
  if (format != kParamsFormat) {
    return PathError(Child(path, "format"),
                     "expected \"" + std::string(kParamsFormat) + "\", got \"" + format + "\"");
  }
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "device", kOptional, ReadString, &out->device));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "version", kOptional, ReadInt, &out->version));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "created_at", kOptional, ReadString, &out->created_at));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "gravity", kOptional, Numbers(Null::kReject), &out->gravity_m_s2));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "accel", kRequired, ReadAccel, out));
  // No "gyro" member: a parameter set fitted without a gyroscope (ParamSet::has_gyro).
  out->has_gyro = j.contains("gyro");
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "gyro", kOptional, ReadGyro, out));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "effects", kOptional, ReadEffects, &out->effects));
  IMUCAL_RETURN_IF_ERROR(CheckNoGyroEffects(*out, path));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "effect_reference", kOptional, ReadEffectReference, &out->effect_reference));
  for (size_t i = 0; i < out->effects.size(); ++i) {
    const std::string mismatch = core::CentreMismatch(
        *core::ParseRegressor(out->effects[i].regressor), out->effect_reference);
    if (!mismatch.empty())
      return PathError(Child(Element(Child(path, "effects"), i), "regressor"), mismatch);
  }
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "quality", kOptional, ReadQuality, out));
  IMUCAL_RETURN_IF_ERROR(Member(j, path, "noise", kOptional, ReadNoise, &out->noise));
  if (out->noise && out->has_gyro && !j.at("noise").contains("gyro")) {
    return PathError(Child(Child(path, "noise"), "gyro"), "missing");
  }
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "term_priors", kOptional, ReadTermPriors, &out->term_priors));
  IMUCAL_RETURN_IF_ERROR(
      Member(j, path, "dynamic_gyro", kOptional, ReadDynamicGyro, &out->dynamic_gyro));
  if (out->dynamic_gyro && !out->has_gyro) {
    return PathError(Child(path, "dynamic_gyro"),
                     "a dynamic gyro block in a parameter set without a \"gyro\" block");
  }
  return Member(j, path, "source", kOptional, ReadSource, out);
}

}  // namespace

std::string_view UnitName(core::AccelUnit unit) {
  switch (unit) {
    case core::AccelUnit::kMetersPerSecond2:
      return "m/s^2";
    case core::AccelUnit::kG:
      return "g";
    case core::AccelUnit::kCounts:
      return "counts";
  }
  return "unknown";
}

std::string_view UnitName(core::GyroUnit unit) {
  switch (unit) {
    case core::GyroUnit::kRadPerSecond:
      return "rad/s";
    case core::GyroUnit::kDegPerSecond:
      return "deg/s";
    case core::GyroUnit::kCounts:
      return "counts";
  }
  return "unknown";
}

OrderedJson GyroToJson(const core::ParamSet& params) {
  OrderedJson gyro = OrderedJson::object();
  gyro["bias"] = Vec(params.gyro.bias);
  gyro["matrix"] = Mat(params.gyro.matrix);
  gyro["scale"] = Vec(params.gyro.matrix.diagonal());
  gyro["accel_coupling"] = Mat(params.gyro.accel_coupling);
  gyro["input_unit"] = std::string(UnitName(params.gyro_unit));
  gyro["calibrated"] = params.gyro_calibrated;
  OrderedJson gyro_se = OrderedJson::object();
  gyro_se["bias"] = Vec(params.stderrs.gyro_bias);
  gyro_se["matrix"] = Mat(params.stderrs.gyro_matrix);
  gyro["stderr"] = std::move(gyro_se);
  return gyro;
}

std::string ParamSetToJson(const core::ParamSet& params) {
  OrderedJson j = OrderedJson::object();
  j["format"] = std::string(kParamsFormat);
  j["device"] = params.device;
  j["version"] = params.version;
  j["created_at"] = params.created_at;
  j["model"] = core::ModelTextOf(params);
  j["gravity"] = Number(params.gravity_m_s2);

  OrderedJson accel = AccelModelFields(params.accel);
  accel["misalignment"] = Mat(params.accel.Misalignment());
  accel["input_unit"] = std::string(UnitName(params.accel_unit));
  accel["stderr"] = AccelModelFields(params.stderrs.accel);
  j["accel"] = std::move(accel);

  if (params.has_gyro) j["gyro"] = GyroToJson(params);

  OrderedJson effects = OrderedJson::array();
  for (const core::Effect& e : params.effects) effects.push_back(EffectToJson(e));
  j["effects"] = std::move(effects);
  // Written whenever it is not the default, so an older reader that ignores it still sees the
  // references spelled in each centred name.
  if (params.effect_reference != core::EffectReference()) {
    OrderedJson reference = OrderedJson::object();
    reference["temperature"] = Number(params.effect_reference.temperature_c);
    reference["time"] = Number(params.effect_reference.time_s);
    j["effect_reference"] = std::move(reference);
  }

  OrderedJson quality = OrderedJson::object();
  quality["accel_rms"] = Number(params.quality_accel_rms_m_s2);
  if (params.has_gyro) quality["gyro_static_rms"] = Number(params.quality_gyro_static_rms_rad_s);
  j["quality"] = std::move(quality);
  if (params.noise) j["noise"] = NoiseToJson(*params.noise, params.has_gyro);
  if (params.term_priors) {
    // The one-sigma widths the terms were estimated with (core/params.h TermPriors):
    // accel_quadratic_sigma in 1/(m/s^2), accel_angle_sigma in rad.
    OrderedJson priors = OrderedJson::object();
    priors["sensor_class"] = params.term_priors->sensor_class;
    priors["accel_quadratic_sigma"] = Number(params.term_priors->accel_quadratic_per_m_s2);
    priors["accel_angle_sigma"] = Number(params.term_priors->accel_angle_rad);
    j["term_priors"] = std::move(priors);
  }
  // Only when there is one: a parameter set without a block keeps its bytes.
  if (params.dynamic_gyro) j["dynamic_gyro"] = DynamicGyroToJson(*params.dynamic_gyro);
  OrderedJson source = OrderedJson::object();
  source["session"] = params.source_session;
  source["software"] = params.software;
  j["source"] = std::move(source);
  // Strings from a device are not guaranteed UTF-8: replace bad bytes rather than throw.
  return j.dump(2, ' ', false, OrderedJson::error_handler_t::replace);
}

absl::StatusOr<core::ParamSet> ParamSetFromJson(std::string_view json) {
  Json j;
  try {
    j = Json::parse(json.begin(), json.end());
  } catch (const Json::parse_error& e) {
    return absl::InvalidArgumentError(std::string("invalid JSON: ") + e.what());
  }
  core::ParamSet params;
  if (!j.is_object()) return PathError("(top level)", "expected an object");
  // A whole report carries the parameter set as its `parameters` member.
  const auto format = j.find("format");
  const std::string format_name =
      format != j.end() && format->is_string() ? format->get<std::string>() : std::string();
  if (format_name == kReportFormat) {
    const auto inner = j.find("parameters");
    if (inner == j.end()) return PathError("parameters", "missing (a report without parameters)");
    if (absl::Status s = ReadParamSet(*inner, "parameters", &params); !s.ok()) return s;
    return params;
  }
  if (!format_name.empty() && format_name != kParamsFormat) {
    return PathError("format", "expected \"" + std::string(kParamsFormat) + "\" or \"" +
                                   std::string(kReportFormat) + "\", got \"" + format_name + "\"");
  }
  if (absl::Status s = ReadParamSet(j, "", &params); !s.ok()) return s;
  return params;
}

}  // namespace imucal::formats
