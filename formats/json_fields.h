// The field readers and writers that the parameter-set document (params_json.cc) and its dynamic
// gyro block (dynamic_gyro_json.cc) share: numbers with NaN as null, 3-vectors and row-major
// 3x3 matrices, and readers that name the JSON path of what they read in their error
// ("gyro.matrix[1][2]: expected a number"). Internal to imucal::params_format (not installed).
#ifndef IMUCAL_FORMATS_JSON_FIELDS_H_
#define IMUCAL_FORMATS_JSON_FIELDS_H_

#include <cstddef>
#include <string>
#include <type_traits>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "nlohmann/json.hpp"

namespace imucal::formats::json_fields {

// Ordered both ways: the output keeps the spec's key order, and an object read back keeps its
// keys in the order written.
using Json = nlohmann::ordered_json;

// Writing. NaN (a figure not determined) is written as null.
Json Number(double v);
Json Vec(const Eigen::Vector3d& v);
Json Mat(const Eigen::Matrix3d& m);  // row-major nested arrays: m[row][column]

// Reading.
absl::Status PathError(const std::string& path, const std::string& what);
std::string Child(const std::string& path, const char* key);  // "a.b"; "b" under the root
std::string Element(const std::string& path, size_t index);   // "a[3]"

// Whether null is read as NaN (standard errors, figures not reached) or rejected.
enum class Null { kReject, kAsNan };

absl::Status ReadDouble(const Json& j, const std::string& path, Null null, double* out);
absl::Status ReadVec3(const Json& j, const std::string& path, Null null, Eigen::Vector3d* out);
absl::Status ReadMat3(const Json& j, const std::string& path, Null null, Eigen::Matrix3d* out);
absl::Status ReadString(const Json& j, const std::string& path, std::string* out);
absl::Status ReadBool(const Json& j, const std::string& path, bool* out);
absl::Status ReadInt(const Json& j, const std::string& path, int* out);
absl::Status ExpectObject(const Json& j, const std::string& path);

// Reads obj[key] with `read` if present. A missing required member is an error; a missing
// optional one leaves *out as it is.
inline constexpr bool kRequired = true;
inline constexpr bool kOptional = false;
template <typename T, typename ReadFn>
absl::Status Member(const Json& obj, const std::string& obj_path, const char* key, bool required,
                    ReadFn read, T* out) {
  const std::string path = Child(obj_path, key);
  const auto it = obj.find(key);
  if (it == obj.end()) return required ? PathError(path, "missing") : absl::OkStatus();
  return read(*it, path, out);
}

// Binds the null policy so that the numeric readers fit Member().
inline auto Numbers(Null null) {
  return [null](const Json& j, const std::string& path, auto* out) -> absl::Status {
    using T = std::remove_pointer_t<decltype(out)>;
    if constexpr (std::is_same_v<T, double>) {
      return ReadDouble(j, path, null, out);
    } else if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
      return ReadVec3(j, path, null, out);
    } else {
      static_assert(std::is_same_v<T, Eigen::Matrix3d>);
      return ReadMat3(j, path, null, out);
    }
  };
}

}  // namespace imucal::formats::json_fields

#endif  // IMUCAL_FORMATS_JSON_FIELDS_H_
