// A calibration parameter set: what a solve produces, the server stores per version and the SDK
// applies to every sample. Serialised as "imucal-params v1" (../shared/spec/report.md).
// Header-only (Eigen and the standard library only) so the SDK needs no solver.
#ifndef IMUCAL_CORE_PARAMS_H_
#define IMUCAL_CORE_PARAMS_H_

#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "core/capture.h"
#include "core/dynamic_gyro.h"
#include "core/model.h"
#include "core/regressor.h"

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
  double std_error = 0.0;     // one-sigma standard error of coefficient
  double error_before = 0.0;  // held-out RMS without the effect, SI
  double error_after = 0.0;   // held-out RMS with the effect, SI
  bool applied = true;        // time effects are reported but applied only if the user opts in
  std::string evidence;
};

// The references that effects' centred factors are taken about (report.md, effect_reference):
// a regressor `(temperature-31.2)^2` reads temperature_c = 31.2. The search takes the capture's
// mean pose temperature (rounded to 0.1 degC) and mean pose time (rounded to 1 s), where a
// polynomial's coefficients are least correlated. Parameter sets written before centring had
// none: a missing reference is 0, which is what their uncentred names mean.
struct EffectReference {
  double temperature_c = 0.0;  // degC
  double time_s = 0.0;         // s from the time origin (capture start)
  friend bool operator==(const EffectReference&, const EffectReference&) = default;
};

// Empty when every centred factor of `r` is taken about `reference` (a plain factor means what
// it says, about 0, whatever the reference); else what differs, e.g.
// `centred on temperature 30 but effect_reference.temperature is 31.2` (a name that the
// reference does not state would make the SDK evaluate something other than what was fitted).
inline std::string CentreMismatch(const Regressor& r, const EffectReference& reference) {
  const auto check = [&](Signal s, double stated) -> std::string {
    const double c = r.centre[static_cast<size_t>(s)];
    bool uses = false;
    for (int i = 0; i < r.num_factors; ++i) uses |= r.factors[i] == static_cast<int>(s);
    if (!uses || c == 0.0 || c == stated) return "";
    const std::string name(kSignalNames[static_cast<size_t>(s)]);
    Regressor one;  // the shortest spelling of each number, as names write them
    one.factors[0] = static_cast<int>(s);
    one.num_factors = 1;
    one.centre[static_cast<size_t>(s)] = c;
    Regressor ref = one;
    ref.centre[static_cast<size_t>(s)] = stated;
    return "written " + one.Name() + " but effect_reference." + name + " makes it " + ref.Name();
  };
  std::string out = check(Signal::kTemperature, reference.temperature_c);
  if (out.empty()) out = check(Signal::kTime, reference.time_s);
  return out;
}

// One-sigma standard errors of the parameters, in the parameters' own units. NaN where the
// data did not determine the parameter (see CalibrationReport::observability).
struct ParamStdErrors {
  AccelModel<double> accel;
  Eigen::Matrix3d gyro_matrix = Eigen::Matrix3d::Zero();
  Eigen::Vector3d gyro_bias = Eigen::Vector3d::Zero();
};

// Noise figures of one sensor, per body axis (x, y, z), from the overlapping Allan deviation of
// the calibrated signal at rest (core/allan.h). Densities are CONTINUOUS-TIME (what Kalibr,
// OpenVINS and datasheets call "noise density"), not per-sample standard deviations:
//   per-sample std = noise_density * sqrt(rate_hz)       (white noise sampled at rate_hz)
// NaN where the data did not reach the figure (see NoiseFigures::notes).
struct SensorNoise {
  static constexpr double kUnknown = std::numeric_limits<double>::quiet_NaN();
  // N: white noise density, read on the slope -1/2 line at tau = 1 s.
  //    accel [m/s^2/sqrt(Hz)] (velocity random walk), gyro [rad/s/sqrt(Hz)] (angle random walk)
  Eigen::Vector3d noise_density = Eigen::Vector3d::Constant(kUnknown);
  // B: bias instability, the flat minimum of the curve / 0.664.  accel [m/s^2], gyro [rad/s]
  Eigen::Vector3d bias_instability = Eigen::Vector3d::Constant(kUnknown);
  // K: rate random walk, read on the slope +1/2 line at tau = 3 s.
  //    accel [m/s^3/sqrt(Hz)], gyro [rad/s^2/sqrt(Hz)]  (Kalibr's *_random_walk)
  Eigen::Vector3d random_walk = Eigen::Vector3d::Constant(kUnknown);
  // When K is not reached: adev(tau_max) * sqrt(3 / tau_max), an upper bound on K (the curve
  // lies above K sqrt(tau/3) everywhere); a bound, not a measurement. Same unit as K.
  Eigen::Vector3d random_walk_bound = Eigen::Vector3d::Constant(kUnknown);
};

// The noise block of a parameter set: where it was measured and the figures.
struct NoiseFigures {
  double t_start_s = 0.0;  // the static interval analysed (capture time)
  double t_end_s = 0.0;
  int64_t samples = 0;
  double rate_hz = 0.0;  // sample rate of that interval (1 / median interval)
  SensorNoise accel;     // SI, calibrated body frame
  SensorNoise gyro;
  std::vector<std::string> notes;  // which figures the data did not reach, and why
};

// The prior widths of the model's own physical terms (issue 25): what a sensor class says of the
// terms the poses may not determine. They are estimated by maximum a posteriori with a zero-mean
// Gaussian prior of these one-sigma widths, never switched on or off: a weakly determined term
// is shrunk toward 0 and its uncertainty enters every other parameter's standard error.
//   accel_quadratic_per_m_s2  second-order term q_i (z_i = y_i + q_i y_i^2), 1/(m/s^2)
//   accel_angle_rad           non-orthogonality t_yx, t_zx, t_zy where no face reference
//                             measures them (with six-face or ferraris the faces give them)
// Classes (core/calibrate/term_priors.cc TermPriorsFor): "mems" (consumer and industrial MEMS:
// cross-axis sensitivity about 1 %, nonlinearity up to 0.5 % of a 2 g full scale, i.e.
// second-order terms up to 2.6e-4 per m/s^2; the width is wider, so a term the poses determine
// even loosely is theirs, not the prior's) and "tactical".
struct TermPriors {
  std::string sensor_class = "mems";
  double accel_quadratic_per_m_s2 = 5e-4;
  double accel_angle_rad = 0.01;
  bool operator==(const TermPriors&) const = default;
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
  // False for a parameter set fitted on an accelerometer-only capture: `gyro`, `gyro_unit`,
  // `gyro_calibrated`, the gyro standard errors, quality and noise mean nothing and are left out
  // of every file written (absent, not zero); whoever applies it leaves gyro readings as read.
  bool has_gyro = true;
  std::vector<Effect> effects;
  EffectReference effect_reference;
  ParamStdErrors stderrs;
  double quality_accel_rms_m_s2 = 0.0;
  double quality_gyro_static_rms_rad_s = 0.0;
  std::string source_session;
  std::string software;
  // Allan-deviation noise figures (absent in parameter sets made before they existed).
  std::optional<NoiseFigures> noise;
  // The priors the estimate was made with (absent in parameter sets made before issue 25).
  std::optional<TermPriors> term_priors;
  // The gyroscope's learnt dynamic block (core/dynamic_gyro.h, `imucal learn`); absent in a
  // parameter set from a static capture.
  std::optional<DynamicGyro> dynamic_gyro;
};

// The model text stored in every parameter set and export, so a reader never guesses (the
// accelerometer-only one: kAccelOnlyModelText).
inline constexpr const char* kModelText =
    "inverse model, raw -> calibrated, body frame = accelerometer frame rotated by "
    "frame_angles. accel: y = diag(scale)*(u - bias); z_i = y_i + quadratic_i*y_i^2; "
    "a[m/s^2] = R(frame_angles)*L(tri_angles)*z, L unit lower-triangular "
    "[[1,0,0],[t_yx,1,0],[t_zx,t_zy,1]], R = exp([frame_angles]x). "
    "gyro: w[rad/s] = matrix*(u - bias) - accel_coupling*a. "
    "effects: out[axis] -= coefficient*regressor, a centred factor (temperature-T0) read about "
    "effect_reference. u in the stated input units.";

// kModelText for a parameter set without a gyroscope (ParamSet::has_gyro false).
inline constexpr const char* kAccelOnlyModelText =
    "inverse model, raw -> calibrated, body frame = accelerometer frame rotated by "
    "frame_angles. accel: y = diag(scale)*(u - bias); z_i = y_i + quadratic_i*y_i^2; "
    "a[m/s^2] = R(frame_angles)*L(tri_angles)*z, L unit lower-triangular "
    "[[1,0,0],[t_yx,1,0],[t_zx,t_zy,1]], R = exp([frame_angles]x). "
    "accelerometer only: fitted on a capture without a gyroscope, no angular-rate model. "
    "effects: out[axis] -= coefficient*regressor, a centred factor (temperature-T0) read about "
    "effect_reference. u in the stated input units.";

inline const char* ModelTextOf(const ParamSet& params) {
  return params.has_gyro ? kModelText : kAccelOnlyModelText;
}

}  // namespace imucal::core

#endif  // IMUCAL_CORE_PARAMS_H_
