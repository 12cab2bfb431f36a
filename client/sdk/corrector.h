// The robot SDK's per-sample correction: applies a calibration parameter set (core/params.h) to
// raw IMU samples. Links no solver: the equations are core/model.h's, shared header-only.
//
// For a raw sample (u_a accel, u_g gyro, in the parameter set's input units; t_s; temp_c):
//   a  = AccelModel::Apply(u_a)      = R(frame_angles) L(tri_angles) z,
//        z_i = y_i + quadratic_i y_i^2,  y = diag(scale) (u_a - bias)           [m/s^2]
//   w  = GyroModel::Apply(u_g, a)    = matrix (u_g - bias) - accel_coupling a   [rad/s]
//   signals = (temperature = temp_c, time = t_s - time_origin_s, ax, ay, az = a, gx, gy, gz = w)
//   for every applied effect:  out[sensor][axis] -= coefficient * regressor(signals)
// All effects read the same signals, computed from the model output before any effect, so the
// order of the effects does not matter; the gyro's accel_coupling uses a before accel effects.
// Effects with `applied == false` (time effects unless the user opts in) are not applied. An
// applied effect whose regressor uses temperature is skipped on a sample without temperature
// (temp_c NaN) and counted in CalibratedSample::effects_skipped.
//
// A parameter set without a gyroscope (core::ParamSet::has_gyro false, fitted on an
// accelerometer-only capture) corrects the accelerometer only: gyro_rad_s is then the gyro
// reading exactly as given (its own unit, not rad/s), and any gyro unit is accepted.
//
// Thread safety: a Corrector is immutable after Create; Apply is const, allocation-free and
// noexcept, so any number of threads may share one Corrector.
#ifndef IMUCAL_CLIENT_SDK_CORRECTOR_H_
#define IMUCAL_CLIENT_SDK_CORRECTOR_H_

#include <limits>
#include <optional>
#include <span>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/capture.h"
#include "core/params.h"
#include "core/regressor.h"

namespace imucal::sdk {

struct RawSample {
  double t_s = 0.0;      // seconds, any origin (see Corrector time origin)
  double accel[3] = {};  // in the parameter set's accel input unit
  double gyro[3] = {};   // in the parameter set's gyro input unit
  double temp_c = std::numeric_limits<double>::quiet_NaN();  // degC; NaN when not measured
};

struct CalibratedSample {
  double accel_m_s2[3] = {};
  double gyro_rad_s[3] = {};
  int effects_skipped = 0;  // applied temperature effects skipped: this sample had no temp_c
};

class Corrector {
 public:
  // Validates `params` and precomputes everything Apply needs. InvalidArgument naming the
  // parameter (JSON path spelling, e.g. `gyro.matrix: not invertible`, `effects[1].regressor:
  // unknown regressor "ax*bz"`) when a value is not finite, an accel scale is zero, the gyro
  // matrix is singular or ill-conditioned (condition number > 1e12), an effect has a bad axis or
  // regressor, or an applied effect uses `time` but no time origin is given.
  //
  // time_origin_s: the t_s from which the `time` signal counts (the capture start when the
  // effect was fitted; e.g. the first sample's t_s). Needed only by applied time effects.
  static absl::StatusOr<Corrector> Create(const core::ParamSet& params,
                                          std::optional<double> time_origin_s = std::nullopt);

  // The same corrector counting `time` from time_origin_s (must be finite).
  absl::StatusOr<Corrector> WithTimeOrigin(double time_origin_s) const;

  // Corrects one sample. Allocation-free, noexcept, no shared mutable state.
  void Apply(const RawSample& in, CalibratedSample* out) const noexcept;

  // Applies to in[i] -> out[i]. InvalidArgument (nothing written) if the sizes differ.
  absl::Status ApplyBatch(std::span<const RawSample> in, std::span<CalibratedSample> out) const;

  // True if some applied effect reads temperature: samples then need temp_c.
  bool NeedsTemperature() const { return needs_temperature_; }
  // True if some applied effect reads time (a time origin was then required by Create).
  bool NeedsTime() const { return needs_time_; }
  int num_applied_effects() const { return static_cast<int>(effects_.size()); }
  std::optional<double> time_origin_s() const { return time_origin_s_; }

  // The input units the parameters expect. Samples in any other unit must be refused:
  // CheckInputUnits says which one differs.
  core::AccelUnit accel_unit() const { return accel_unit_; }
  core::GyroUnit gyro_unit() const { return gyro_unit_; }
  // False: the parameter set has no gyroscope part; Apply leaves the gyro as read.
  bool has_gyro() const { return has_gyro_; }
  absl::Status CheckInputUnits(core::AccelUnit accel, core::GyroUnit gyro) const;

 private:
  // An applied effect, parsed once.
  struct CompiledEffect {
    core::Regressor regressor;
    int output = 0;  // 0..2 accel x..z, 3..5 gyro x..z
    double coefficient = 0.0;
    bool uses_temperature = false;
  };

  Corrector() = default;

  // Accel: a = accel_linear_ (u - bias) when there is no quadratic term (the common case);
  // otherwise misalignment (y + quadratic .* y.^2), y = diag(scale) (u - bias).
  Eigen::Matrix3d accel_linear_ = Eigen::Matrix3d::Identity();  // misalignment * diag(scale)
  Eigen::Matrix3d accel_misalignment_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d accel_bias_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d accel_scale_ = Eigen::Vector3d::Ones();
  Eigen::Vector3d accel_quadratic_ = Eigen::Vector3d::Zero();
  bool accel_has_quadratic_ = false;
  Eigen::Matrix3d gyro_matrix_ = Eigen::Matrix3d::Identity();
  Eigen::Vector3d gyro_bias_ = Eigen::Vector3d::Zero();
  Eigen::Matrix3d gyro_accel_coupling_ = Eigen::Matrix3d::Zero();
  bool has_gyro_ = true;

  std::vector<CompiledEffect> effects_;
  bool needs_temperature_ = false;
  bool needs_time_ = false;
  std::optional<double> time_origin_s_;
  double time_origin_or_zero_s_ = 0.0;
  core::AccelUnit accel_unit_ = core::AccelUnit::kMetersPerSecond2;
  core::GyroUnit gyro_unit_ = core::GyroUnit::kRadPerSecond;
};

}  // namespace imucal::sdk

#endif  // IMUCAL_CLIENT_SDK_CORRECTOR_H_
