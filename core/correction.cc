#include "core/correction.h"

#include <algorithm>
#include <cmath>
#include <optional>

namespace imucal::core {

SampleCorrection::SampleCorrection(const AccelParams& accel, const GyroParams& gyro,
                                   const std::vector<Effect>& effects, double time_origin_s)
    : accel_(accel),
      accel_misalignment_(accel.Misalignment()),
      gyro_(gyro),
      time_origin_s_(time_origin_s) {
  for (const Effect& e : effects) {
    const std::optional<Regressor> r = ParseRegressor(e.regressor);
    if (!e.applied || !r || e.axis < 0 || e.axis > 2) continue;
    Term t;
    t.output = (e.sensor == Sensor::kAccel ? 0 : 3) + e.axis;
    t.coefficient = e.coefficient;
    t.regressor = *r;
    const int temperature = static_cast<int>(Signal::kTemperature);
    t.uses_temperature = std::find(r->factors.begin(), r->factors.begin() + r->num_factors,
                                   temperature) != r->factors.begin() + r->num_factors;
    terms_.push_back(t);
  }
}

void SampleCorrection::LeaveGyroAsRead() {
  corrects_gyro_ = false;
  std::erase_if(terms_, [](const Term& t) { return t.output >= 3; });
}

CorrectedSample SampleCorrection::Apply(const Eigen::Vector3d& accel_raw,
                                        const Eigen::Vector3d& gyro_raw, double temp_c,
                                        double t_s) const {
  CorrectedSample out;
  out.accel_m_s2 = accel_misalignment_ * accel_.PerAxis(accel_raw);  // accel_.Apply(accel_raw)
  out.gyro_rad_s = corrects_gyro_ ? gyro_.Apply(gyro_raw, out.accel_m_s2) : gyro_raw;
  if (terms_.empty()) return out;
  const Eigen::Vector3d& a = out.accel_m_s2;
  const Eigen::Vector3d& w = out.gyro_rad_s;
  const SignalArray signals = {temp_c, t_s - time_origin_s_, a(0), a(1), a(2), w(0), w(1), w(2)};
  double values[6] = {a(0), a(1), a(2), w(0), w(1), w(2)};
  for (const Term& t : terms_) {
    if (t.uses_temperature && std::isnan(temp_c)) continue;
    values[t.output] -= t.coefficient * t.regressor.Evaluate(signals);
  }
  out.accel_m_s2 = Eigen::Vector3d(values[0], values[1], values[2]);
  out.gyro_rad_s = Eigen::Vector3d(values[3], values[4], values[5]);
  return out;
}

}  // namespace imucal::core
