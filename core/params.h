// A calibration parameter set: what a solve produces, the server stores per version and the SDK
// applies to every sample. Serialised as "imucal-params v1" (../shared/spec/report.md).
// Header-only (Eigen and the standard library only) so the SDK needs no solver.
#ifndef IMUCAL_CORE_PARAMS_H_
#define IMUCAL_CORE_PARAMS_H_

#include <string>
#include <vector>

#include "core/capture.h"
#include "core/model.h"

namespace imucal::core {

enum class Sensor { kAccel, kGyro };

// An extra error effect found in the residual (issue: close the loop). It acts on one output
// axis of one sensor, additively on the calibrated value:
//   out[axis] -= coefficient * regressor(signals)
// so `coefficient` is what the sensor adds per regressor unit, in the sensor's SI unit
// (m/s^2 or rad/s). Regressor names follow report.md: temperature, time, ax..gz, `*`, `^2`.
struct Effect {
  Sensor sensor = Sensor::kAccel;
  int axis = 0;  // 0 = x, 1 = y, 2 = z
  std::string regressor;
  double coefficient = 0.0;
  double std_error = 0.0;  // one-sigma standard error of coefficient
  double error_before = 0.0;  // held-out RMS without the effect, SI
  double error_after = 0.0;   // held-out RMS with the effect, SI
  bool applied = true;        // time effects are reported but applied only if the user opts in
  std::string evidence;
};

// One-sigma standard errors of the parameters, in the parameters' own units. NaN where the
// data did not determine the parameter (see CalibrationReport::observability).
struct ParamStdErrors {
  AccelModel<double> accel;
  Eigen::Matrix3d gyro_matrix = Eigen::Matrix3d::Zero();
  Eigen::Vector3d gyro_bias = Eigen::Vector3d::Zero();
};

struct ParamSet {
  std::string device;
  int version = 0;         // assigned by the server; 0 offline
  std::string created_at;  // RFC 3339, UTC
  // The input units the parameters expect; the SDK refuses samples of any other unit.
  AccelUnit accel_unit = AccelUnit::kMetersPerSecond2;
  GyroUnit gyro_unit = GyroUnit::kRadPerSecond;
  double gravity_m_s2 = kStandardGravity;
  AccelParams accel;
  GyroParams gyro;
  bool gyro_calibrated = false;  // false: only the gyro bias was determined (matrix nominal)
  std::vector<Effect> effects;
  ParamStdErrors stderrs;
  double quality_accel_rms_m_s2 = 0.0;
  double quality_gyro_static_rms_rad_s = 0.0;
  std::string source_session;
  std::string software;
};

// The model text stored in every parameter set and export, so a reader never guesses.
inline constexpr const char* kModelText =
    "inverse model, raw -> calibrated, body frame = accelerometer frame rotated by "
    "frame_angles. accel: y = diag(scale)*(u - bias); z_i = y_i + quadratic_i*y_i^2; "
    "a[m/s^2] = R(frame_angles)*L(tri_angles)*z, L unit lower-triangular "
    "[[1,0,0],[t_yx,1,0],[t_zx,t_zy,1]], R = exp([frame_angles]x). "
    "gyro: w[rad/s] = matrix*(u - bias) - accel_coupling*a. "
    "effects: out[axis] -= coefficient*regressor. u in the stated input units.";

}  // namespace imucal::core

#endif  // IMUCAL_CORE_PARAMS_H_
