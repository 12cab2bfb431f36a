#include "formats/params_check.h"

#include <cmath>
#include <string>
#include <utility>

#include "Eigen/Core"
#include "Eigen/SVD"
#include "formats/dynamic_gyro_json.h"
#include "formats/json_fields.h"

namespace imucal::formats {
namespace {

using json_fields::Element;
using json_fields::PathError;

// Beyond this condition number the gyro matrix is singular for practical purposes: inverting
// it (the model's Invert, or a reader of the export) would lose all precision.
constexpr double kMaxConditionNumber = 1e12;

absl::Status AllEntriesFinite(const Eigen::Vector3d& v, const std::string& path) {
  for (int i = 0; i < 3; ++i) {
    if (!std::isfinite(v(i))) return PathError(Element(path, static_cast<size_t>(i)), "not finite");
  }
  return absl::OkStatus();
}

absl::Status AllEntriesFinite(const Eigen::Matrix3d& m, const std::string& path) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      if (!std::isfinite(m(r, c)))
        return PathError(Element(Element(path, static_cast<size_t>(r)), static_cast<size_t>(c)),
                         "not finite");
    }
  }
  return absl::OkStatus();
}

// The misalignment R(frame_angles) L(tri_angles) is a rotation times a unit lower-triangular
// matrix (determinant 1), so finite angles always make it invertible; only the scales can
// make the accel model singular.
absl::Status AccelParamsAreValid(const core::AccelParams& a) {
  for (const auto& [v, path] : {std::pair{&a.bias, "accel.bias"},
                                {&a.scale, "accel.scale"},
                                {&a.tri_angles, "accel.tri_angles"},
                                {&a.frame_angles, "accel.frame_angles"},
                                {&a.quadratic, "accel.quadratic"}}) {
    if (absl::Status s = AllEntriesFinite(*v, path); !s.ok()) return s;
  }
  for (int i = 0; i < 3; ++i) {
    if (a.scale(i) == 0.0)
      return PathError(Element("accel.scale", static_cast<size_t>(i)), "zero (not invertible)");
  }
  return absl::OkStatus();
}

absl::Status GyroParamsAreValid(const core::GyroParams& g) {
  if (absl::Status s = AllEntriesFinite(g.bias, "gyro.bias"); !s.ok()) return s;
  if (absl::Status s = AllEntriesFinite(g.matrix, "gyro.matrix"); !s.ok()) return s;
  if (absl::Status s = AllEntriesFinite(g.accel_coupling, "gyro.accel_coupling"); !s.ok()) return s;
  const Eigen::Vector3d sv = Eigen::JacobiSVD<Eigen::Matrix3d>(g.matrix).singularValues();
  if (!(sv(2) > 0.0) || sv(0) / sv(2) > kMaxConditionNumber) {
    return PathError("gyro.matrix",
                     "not invertible (condition number " + std::to_string(sv(0) / sv(2)) + ")");
  }
  return absl::OkStatus();
}

// The block's own checks are formats' (the reader's, shared), under the JSON path it has.
absl::Status BlockIsApplicable(const core::ParamSet& params) {
  if (!params.dynamic_gyro) return absl::OkStatus();
  if (!params.has_gyro) {
    return PathError("dynamic_gyro", "a dynamic gyro block in a parameter set without a gyroscope");
  }
  return formats::DynamicGyroIsValid(*params.dynamic_gyro, "dynamic_gyro");
}

}  // namespace

absl::Status ModelIsApplicable(const core::ParamSet& params) {
  if (absl::Status s = AccelParamsAreValid(params.accel); !s.ok()) return s;
  if (params.has_gyro) {
    if (absl::Status s = GyroParamsAreValid(params.gyro); !s.ok()) return s;
  }
  return BlockIsApplicable(params);
}

}  // namespace imucal::formats
