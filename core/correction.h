// A parameter set applied to one sample, as the robot SDK applies it (client/sdk/corrector.cc;
// tests/sdk/corrector_test.cc checks that the two agree to rounding): the model of core/model.h,
// then each applied effect subtracted from its output, its regressor evaluated on the model's
// outputs (report.md, "effects"). An effect on temperature is skipped for a sample without one,
// as the SDK skips it. What a report's figures are computed with, so that they describe the
// parameter set a robot receives, effects included.
#ifndef IMUCAL_CORE_CORRECTION_H_
#define IMUCAL_CORE_CORRECTION_H_

#include <vector>

#include "Eigen/Core"
#include "core/params.h"
#include "core/regressor.h"

namespace imucal::core {

struct CorrectedSample {
  Eigen::Vector3d accel_m_s2 = Eigen::Vector3d::Zero();  // body frame
  Eigen::Vector3d gyro_rad_s = Eigen::Vector3d::Zero();  // body frame
};

class SampleCorrection {
 public:
  // `time_origin_s`: the time stamp effects on `time` count from (the capture's first).
  // Effects whose regressor does not parse are left out (a parameter set that holds one is
  // refused where it is read: formats/params_json, the SDK).
  SampleCorrection(const AccelParams& accel, const GyroParams& gyro,
                   const std::vector<Effect>& effects, double time_origin_s);
  // A parameter set without a gyroscope (ParamSet::has_gyro false) corrects the accelerometer
  // only: Apply then returns the gyro reading as read (input units, not rad/s), untouched.
  SampleCorrection(const ParamSet& params, double time_origin_s)
      : SampleCorrection(params.accel, params.gyro, params.effects, time_origin_s) {
    if (!params.has_gyro) LeaveGyroAsRead();
  }
  bool corrects_gyro() const { return corrects_gyro_; }

  // Raw readings (the parameter set's input units), temperature in degC (NaN when absent) and
  // time stamp in s -> the calibrated sample.
  CorrectedSample Apply(const Eigen::Vector3d& accel_raw, const Eigen::Vector3d& gyro_raw,
                        double temp_c, double t_s) const;

 private:
  struct Term {
    int output = 0;  // 0-2 accel x-z, 3-5 gyro x-z
    double coefficient = 0;
    Regressor regressor;
    bool uses_temperature = false;
  };
  AccelParams accel_;
  Eigen::Matrix3d accel_misalignment_;  // accel_.Misalignment(), once: it costs an exp map
  GyroParams gyro_;
  void LeaveGyroAsRead();

  std::vector<Term> terms_;
  double time_origin_s_ = 0;
  bool corrects_gyro_ = true;
};

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CORRECTION_H_
