// A parameter set applied to one sample: the one implementation, header-only, that the report's
// figures are computed with and that the robot SDK wraps (client/sdk/corrector.h adds the
// validation of a received parameter set around it), so that a report describes exactly the
// parameter set a robot applies, effects included.
//
// For a raw sample (u_a accel, u_g gyro, in the parameter set's input units; t_s; temp_c):
//   a  = AccelModel::Apply(u_a)      = R(frame_angles) L(tri_angles) z,
//        z_i = y_i + quadratic_i y_i^2,  y = diag(scale) (u_a - bias)           [m/s^2]
//   w  = GyroModel::Apply(u_g, a)    = matrix (u_g - bias) - accel_coupling a   [rad/s]
//   signals = (temperature = temp_c, time = t_s - time_origin_s, ax, ay, az = a, gx, gy, gz = w)
//   for every applied effect:  out[sensor][axis] -= coefficient * regressor(signals)
// (core/model.h; report.md, "effects"). All effects read the same signals, computed from the
// model output before any effect, so their order does not matter; the gyro's accel_coupling
// uses `a` before the accelerometer's effects. An applied effect whose regressor uses
// temperature is skipped on a sample without temperature (temp_c NaN) and counted.
//
// Thread safety: immutable after construction; Apply is const, allocation-free and noexcept.
#ifndef IMUCAL_CORE_CORRECTION_H_
#define IMUCAL_CORE_CORRECTION_H_

#include <algorithm>
#include <cmath>
#include <optional>
#include <vector>

#include "Eigen/Core"
#include "core/params.h"
#include "core/regressor.h"

namespace imucal::core {

struct CorrectedSample {
  Eigen::Vector3d accel_m_s2 = Eigen::Vector3d::Zero();  // body frame
  Eigen::Vector3d gyro_rad_s = Eigen::Vector3d::Zero();  // body frame
  int effects_skipped = 0;  // applied temperature effects skipped: the sample had no temp_c
};

class SampleCorrection {
 public:
  // `time_origin_s`: the time stamp effects on `time` count from (the capture's first). Effects
  // that are not applied, or whose axis or regressor is not valid, are left out (a parameter
  // set that holds an invalid one is refused where it is read: formats/params_json, the SDK).
  SampleCorrection(const AccelParams& accel, const GyroParams& gyro,
                   const std::vector<Effect>& effects, double time_origin_s)
      : accel_misalignment_(accel.Misalignment()),
        accel_linear_(accel_misalignment_ * accel.scale.asDiagonal()),
        accel_bias_(accel.bias),
        accel_scale_(accel.scale),
        accel_quadratic_(accel.quadratic),
        accel_has_quadratic_(!accel.quadratic.isZero(0.0)),
        gyro_matrix_(gyro.matrix),
        gyro_bias_(gyro.bias),
        gyro_accel_coupling_(gyro.accel_coupling),
        time_origin_s_(time_origin_s) {
    for (const Effect& e : effects) {
      const std::optional<Regressor> r = ParseRegressor(e.regressor);
      if (!e.applied || !r || e.axis < 0 || e.axis > 2) continue;
      terms_.push_back({(e.sensor == Sensor::kAccel ? 0 : 3) + e.axis, e.coefficient, *r,
                        Uses(*r, Signal::kTemperature)});
    }
  }
  // A parameter set without a gyroscope (ParamSet::has_gyro false) corrects the accelerometer
  // only: Apply then returns the gyro reading as read (input units, not rad/s), bit for bit.
  SampleCorrection(const ParamSet& params, double time_origin_s)
      : SampleCorrection(params.accel, params.has_gyro ? params.gyro : GyroParams(), params.effects,
                         time_origin_s) {
    if (!params.has_gyro) {
      corrects_gyro_ = false;
      std::erase_if(terms_, [](const Term& t) { return t.output >= 3; });
    }
  }

  bool corrects_gyro() const { return corrects_gyro_; }
  double time_origin_s() const { return time_origin_s_; }
  void set_time_origin_s(double t_s) { time_origin_s_ = t_s; }
  int num_terms() const { return static_cast<int>(terms_.size()); }

  // Raw readings (the parameter set's input units), temperature in degC (NaN when absent) and
  // time stamp in s -> the calibrated sample.
  CorrectedSample Apply(const Eigen::Vector3d& accel_raw, const Eigen::Vector3d& gyro_raw,
                        double temp_c, double t_s) const noexcept {
    CorrectedSample out;
    Eigen::Vector3d& a = out.accel_m_s2;
    if (accel_has_quadratic_) {
      const Eigen::Vector3d y = accel_scale_.cwiseProduct(accel_raw - accel_bias_);
      a = accel_misalignment_ * (y + accel_quadratic_.cwiseProduct(y.cwiseProduct(y)));
    } else {
      a.noalias() = accel_linear_ * (accel_raw - accel_bias_);
    }
    // Without a gyroscope the defaults (identity, zero bias, no coupling) pass the reading
    // through bit for bit: 1*u + 0*v + 0*w == u for finite values.
    Eigen::Vector3d& w = out.gyro_rad_s;
    w.noalias() = gyro_matrix_ * (gyro_raw - gyro_bias_);
    w.noalias() -= gyro_accel_coupling_ * a;
    if (terms_.empty()) return out;
    const SignalArray signals = {temp_c, t_s - time_origin_s_, a(0), a(1), a(2), w(0), w(1), w(2)};
    double values[6] = {a(0), a(1), a(2), w(0), w(1), w(2)};
    const bool no_temperature = std::isnan(temp_c);
    for (const Term& t : terms_) {
      if (t.uses_temperature && no_temperature) {
        ++out.effects_skipped;
        continue;
      }
      values[t.output] -= t.coefficient * t.regressor.Evaluate(signals);
    }
    a = Eigen::Vector3d(values[0], values[1], values[2]);
    w = Eigen::Vector3d(values[3], values[4], values[5]);
    return out;
  }

  static bool Uses(const Regressor& r, Signal signal) {
    return std::find(r.factors.begin(), r.factors.begin() + r.num_factors,
                     static_cast<int>(signal)) != r.factors.begin() + r.num_factors;
  }

 private:
  struct Term {
    int output = 0;  // 0-2 accel x-z, 3-5 gyro x-z
    double coefficient = 0;
    Regressor regressor;
    bool uses_temperature = false;
  };
  // Accel: a = accel_linear_ (u - bias) when there is no quadratic term (the common case);
  // otherwise misalignment (y + quadratic .* y.^2), y = diag(scale) (u - bias).
  Eigen::Matrix3d accel_misalignment_;  // accel.Misalignment(), once: it costs an exp map
  Eigen::Matrix3d accel_linear_;        // misalignment * diag(scale)
  Eigen::Vector3d accel_bias_;
  Eigen::Vector3d accel_scale_;
  Eigen::Vector3d accel_quadratic_;
  bool accel_has_quadratic_ = false;
  Eigen::Matrix3d gyro_matrix_;
  Eigen::Vector3d gyro_bias_;
  Eigen::Matrix3d gyro_accel_coupling_;
  std::vector<Term> terms_;
  double time_origin_s_ = 0;
  bool corrects_gyro_ = true;
};

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CORRECTION_H_
