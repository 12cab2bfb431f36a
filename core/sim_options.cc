// The simulator's option checks (as Ceres's solver.cc checks its options): one function per
// group of options, each naming the field at fault; and the protocols' names.
#include <cmath>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "core/regressor.h"
#include "core/simulator.h"

namespace imucal::core {
namespace {

// Limits that keep a mistyped option from allocating gigabytes.
constexpr int kMaxPoses = 10000;
constexpr double kMaxSamples = 5e7;

// ---------------------------------------------------------------------------------------------
// Option checks, one per group (as Ceres's solver.cc), each naming the field at fault.

// (std::string, not std::string_view, parameters: this absl may have its own string_view.)
absl::Status Invalid(const std::string& field, const std::string& requirement, double value) {
  return absl::InvalidArgumentError(
      absl::StrCat("SimOptions.", field, " must be ", requirement, ", got ", value));
}

absl::Status CheckPositive(const std::string& field, double value) {
  if (!std::isfinite(value) || value <= 0.0) return Invalid(field, "finite and > 0", value);
  return absl::OkStatus();
}

absl::Status CheckNonNegative(const std::string& field, double value) {
  if (!std::isfinite(value) || value < 0.0) return Invalid(field, "finite and >= 0", value);
  return absl::OkStatus();
}

absl::Status CheckFinite(const std::string& field, double value) {
  if (!std::isfinite(value)) return Invalid(field, "finite", value);
  return absl::OkStatus();
}

absl::Status CheckRange(const std::string& field, double value, double lo, double hi) {
  if (!(value >= lo && value <= hi)) {
    return Invalid(field, absl::StrCat("in [", lo, ", ", hi, "]"), value);
  }
  return absl::OkStatus();
}

int ProtocolPoseCount(const SimOptions& options) {
  switch (options.protocol) {
    case SimProtocol::kSixFace:
      return 12;
    case SimProtocol::kPositions24:
      return 24;
    case SimProtocol::kPositions36:
      return 36;
    case SimProtocol::kFree:
      return options.free_poses;
  }
  return 0;
}

absl::Status PoseOptionsAreValid(const SimOptions& options) {
  switch (options.protocol) {
    case SimProtocol::kSixFace:
    case SimProtocol::kPositions24:
    case SimProtocol::kPositions36:
    case SimProtocol::kFree:
      break;
    default:
      return Invalid("protocol", "a SimProtocol value", static_cast<double>(options.protocol));
  }
  if (options.extra_poses < 0 || options.extra_poses > kMaxPoses) {
    return Invalid("extra_poses", absl::StrCat("in [0, ", kMaxPoses, "]"), options.extra_poses);
  }
  if (options.protocol == SimProtocol::kFree &&
      (options.free_poses < 1 || options.free_poses > kMaxPoses)) {
    return Invalid("free_poses", absl::StrCat("in [1, ", kMaxPoses, "]"), options.free_poses);
  }
  if (absl::Status s = CheckRange("floor_tilt_deg", options.floor_tilt_deg, 0.0, 45.0); !s.ok()) {
    return s;
  }
  if (absl::Status s = CheckRange("turn_error_deg", options.turn_error_deg, 0.0, 45.0); !s.ok()) {
    return s;
  }
  return CheckRange("tremor_rms_deg", options.tremor_rms_deg, 0.0, 10.0);
}

absl::Status TimingOptionsAreValid(const SimOptions& options) {
  if (absl::Status s = CheckPositive("rate_hz", options.rate_hz); !s.ok()) return s;
  if (absl::Status s = CheckPositive("initial_rest_s", options.initial_rest_s); !s.ok()) return s;
  if (absl::Status s = CheckPositive("hold_s", options.hold_s); !s.ok()) return s;
  if (absl::Status s = CheckPositive("move_s", options.move_s); !s.ok()) return s;
  const int poses = ProtocolPoseCount(options) + options.extra_poses;
  const double duration_s =
      options.initial_rest_s + (poses - 1) * (options.move_s + options.hold_s);
  if (duration_s * options.rate_hz > kMaxSamples) {
    return Invalid("rate_hz",
                   absl::StrCat("such that the capture has at most ", kMaxSamples,
                                " samples (duration ", duration_s, " s)"),
                   options.rate_hz);
  }
  return absl::OkStatus();
}

absl::Status NoiseOptionsAreValid(const SimOptions& options) {
  if (absl::Status s = CheckNonNegative("accel_noise_m_s2", options.accel_noise_m_s2); !s.ok()) {
    return s;
  }
  if (absl::Status s = CheckNonNegative("gyro_noise_rad_s", options.gyro_noise_rad_s); !s.ok()) {
    return s;
  }
  if (absl::Status s = CheckNonNegative("accel_step", options.accel_step); !s.ok()) return s;
  if (absl::Status s = CheckNonNegative("gyro_bias_shift_rad_s", options.gyro_bias_shift_rad_s);
      !s.ok()) {
    return s;
  }
  if (absl::Status s = CheckNonNegative("gyro_bias_walk", options.gyro_bias_walk); !s.ok()) {
    return s;
  }
  return CheckNonNegative("gyro_step", options.gyro_step);
}

absl::Status UnitOptionsAreValid(const SimOptions& options) {
  if (absl::Status s = CheckPositive("gravity_m_s2", options.gravity_m_s2); !s.ok()) return s;
  switch (options.accel_unit) {
    case AccelUnit::kMetersPerSecond2:
    case AccelUnit::kG:
      break;
    case AccelUnit::kCounts:
      if (absl::Status s = CheckPositive("accel_counts_per_g", options.accel_counts_per_g);
          !s.ok()) {
        return s;
      }
      if (absl::Status s = CheckFinite("accel_offset_counts", options.accel_offset_counts);
          !s.ok()) {
        return s;
      }
      break;
    default:
      return Invalid("accel_unit", "an AccelUnit value", static_cast<double>(options.accel_unit));
  }
  switch (options.gyro_unit) {
    case GyroUnit::kRadPerSecond:
    case GyroUnit::kDegPerSecond:
      break;
    case GyroUnit::kCounts:
      if (absl::Status s = CheckPositive("gyro_counts_per_rad_s", options.gyro_counts_per_rad_s);
          !s.ok()) {
        return s;
      }
      if (absl::Status s = CheckFinite("gyro_offset_counts", options.gyro_offset_counts); !s.ok()) {
        return s;
      }
      break;
    default:
      return Invalid("gyro_unit", "a GyroUnit value", static_cast<double>(options.gyro_unit));
  }
  return absl::OkStatus();
}

absl::Status TemperatureOptionsAreValid(const SimOptions& options) {
  if (absl::Status s = CheckFinite("temp_start_c", options.temp_start_c); !s.ok()) return s;
  if (absl::Status s = CheckFinite("temp_rise_c", options.temp_rise_c); !s.ok()) return s;
  if (absl::Status s = CheckPositive("temp_tau_s", options.temp_tau_s); !s.ok()) return s;
  return CheckNonNegative("temp_noise_c", options.temp_noise_c);
}

absl::Status EffectsAreValid(const SimOptions& options) {
  for (size_t i = 0; i < options.effects.size(); ++i) {
    const SimEffect& effect = options.effects[i];
    const std::string field = absl::StrCat("effects[", i, "]");
    if (effect.sensor != Sensor::kAccel && effect.sensor != Sensor::kGyro) {
      return Invalid(absl::StrCat(field, ".sensor"), "kAccel or kGyro",
                     static_cast<double>(effect.sensor));
    }
    if (effect.axis < 0 || effect.axis > 2) {
      return Invalid(absl::StrCat(field, ".axis"), "0, 1 or 2", effect.axis);
    }
    if (!ParseRegressor(effect.regressor).has_value()) {
      return absl::InvalidArgumentError(
          absl::StrCat("SimOptions.", field, ".regressor '", effect.regressor,
                       "' is not a regressor (signals temperature, time, ax..gz joined by '*', "
                       "squares as '^2')"));
    }
    if (absl::Status s = CheckFinite(absl::StrCat(field, ".coefficient"), effect.coefficient);
        !s.ok()) {
      return s;
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ValidateSimTruth(const SimTruth& truth) {
  const AccelParams& a = truth.accel;
  if (!a.bias.allFinite() || !a.scale.allFinite() || !a.tri_angles.allFinite() ||
      !a.frame_angles.allFinite() || !a.quadratic.allFinite()) {
    return absl::InvalidArgumentError("SimTruth.accel has a non-finite parameter");
  }
  if ((a.scale.array() == 0.0).any()) {
    return absl::InvalidArgumentError("SimTruth.accel.scale has a zero entry");
  }
  // The inverse of z = y + q y^2 exists for |z| < 1/(4|q|); 0.01 /(m/s^2) covers 25 m/s^2.
  if ((a.quadratic.array().abs() > 0.01).any()) {
    return absl::InvalidArgumentError("SimTruth.accel.quadratic must be under 0.01 /(m/s^2)");
  }
  const GyroParams& g = truth.gyro;
  if (!g.matrix.allFinite() || !g.bias.allFinite() || !g.accel_coupling.allFinite()) {
    return absl::InvalidArgumentError("SimTruth.gyro has a non-finite parameter");
  }
  const double scale = g.matrix.colwise().norm().prod();
  if (!(std::abs(g.matrix.determinant()) > 1e-6 * scale)) {
    return absl::InvalidArgumentError("SimTruth.gyro.matrix is singular");
  }
  return absl::OkStatus();
}

absl::Status ValidateSimOptions(const SimOptions& options) {
  if (absl::Status s = PoseOptionsAreValid(options); !s.ok()) return s;
  if (absl::Status s = TimingOptionsAreValid(options); !s.ok()) return s;
  if (absl::Status s = NoiseOptionsAreValid(options); !s.ok()) return s;
  if (absl::Status s = UnitOptionsAreValid(options); !s.ok()) return s;
  if (absl::Status s = TemperatureOptionsAreValid(options); !s.ok()) return s;
  return EffectsAreValid(options);
}

std::string ProtocolName(SimProtocol protocol) {
  switch (protocol) {
    case SimProtocol::kSixFace:
      return "six-face";
    case SimProtocol::kPositions24:
      return "positions24";
    case SimProtocol::kPositions36:
      return "positions36";
    case SimProtocol::kFree:
      return "free";
  }
  return "unknown";
}

absl::StatusOr<SimProtocol> ParseSimProtocol(std::string_view name) {
  for (SimProtocol protocol : {SimProtocol::kSixFace, SimProtocol::kPositions24,
                               SimProtocol::kPositions36, SimProtocol::kFree}) {
    if (name == ProtocolName(protocol)) return protocol;
  }
  return absl::InvalidArgumentError(
      absl::StrCat("unknown simulated protocol '", std::string(name),
                   "' (expected six-face, positions24, positions36 or free)"));
}

}  // namespace imucal::core
