#include "formats/json_fields.h"

#include <cmath>
#include <cstdint>
#include <limits>
#include <string>

#include "util/status.h"
#include "util/units.h"

namespace imucal::formats::json_fields {

Json Number(double v) { return std::isnan(v) ? Json(nullptr) : Json(v); }

Json Vec(const Eigen::Vector3d& v) {
  Json out = Json::array();
  for (int i = 0; i < 3; ++i) out.push_back(Number(v(i)));
  return out;
}

Json Mat(const Eigen::Matrix3d& m) {
  Json out = Json::array();
  for (int r = 0; r < 3; ++r) out.push_back(Vec(m.row(r).transpose()));
  return out;
}

absl::Status PathError(const std::string& path, const std::string& what) {
  return absl::InvalidArgumentError(path + ": " + what);
}

std::string Child(const std::string& path, const char* key) {
  return path.empty() ? std::string(key) : path + "." + key;
}

std::string Element(const std::string& path, size_t index) {
  return path + "[" + std::to_string(index) + "]";
}

absl::Status ReadDouble(const Json& j, const std::string& path, Null null, double* out) {
  if (j.is_null() && null == Null::kAsNan) {
    *out = kNaN;
    return absl::OkStatus();
  }
  if (!j.is_number()) {
    return PathError(path,
                     null == Null::kAsNan ? "expected a number or null" : "expected a number");
  }
  *out = j.get<double>();
  return absl::OkStatus();
}

absl::Status ReadVec3(const Json& j, const std::string& path, Null null, Eigen::Vector3d* out) {
  if (!j.is_array() || j.size() != 3) return PathError(path, "expected an array of 3 numbers");
  for (size_t i = 0; i < 3; ++i) {
    IMUCAL_RETURN_IF_ERROR(ReadDouble(j[i], Element(path, i), null, &(*out)(i)));
  }
  return absl::OkStatus();
}

absl::Status ReadMat3(const Json& j, const std::string& path, Null null, Eigen::Matrix3d* out) {
  if (!j.is_array() || j.size() != 3) {
    return PathError(path, "expected 3 rows of 3 numbers (row-major)");
  }
  for (size_t r = 0; r < 3; ++r) {
    Eigen::Vector3d row;
    IMUCAL_RETURN_IF_ERROR(ReadVec3(j[r], Element(path, r), null, &row));
    out->row(static_cast<Eigen::Index>(r)) = row.transpose();
  }
  return absl::OkStatus();
}

absl::Status ReadString(const Json& j, const std::string& path, std::string* out) {
  if (!j.is_string()) return PathError(path, "expected a string");
  *out = j.get<std::string>();
  return absl::OkStatus();
}

absl::Status ReadBool(const Json& j, const std::string& path, bool* out) {
  if (!j.is_boolean()) return PathError(path, "expected true or false");
  *out = j.get<bool>();
  return absl::OkStatus();
}

absl::Status ReadInt(const Json& j, const std::string& path, int* out) {
  if (!j.is_number_integer()) return PathError(path, "expected an integer");
  const auto v = j.get<int64_t>();
  if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max()) {
    return PathError(path, "integer out of range");
  }
  *out = static_cast<int>(v);
  return absl::OkStatus();
}

absl::Status ExpectObject(const Json& j, const std::string& path) {
  return j.is_object() ? absl::OkStatus() : PathError(path, "expected an object");
}

}  // namespace imucal::formats::json_fields
