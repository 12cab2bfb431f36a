// The undeclared-effect scenarios shared by tests/core/effects_test.cc and
// bench/effects_bench.cc: the simulated captures, the effects with datasheet magnitudes
// (../shared/notes/field-notes.md, section 7), and the validation error of a parameter set on a
// fresh capture through the robot SDK's Corrector (the code robots run).
#ifndef IMUCAL_TESTS_CORE_EFFECT_SCENARIOS_H_
#define IMUCAL_TESTS_CORE_EFFECT_SCENARIOS_H_

#include <cmath>
#include <cstdio>
#include <optional>
#include <ostream>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "client/sdk/corrector.h"
#include "core/params.h"
#include "core/simulator.h"

namespace imucal::core {

constexpr double kMg = 1e-3 * kStandardGravity;  // m/s^2
constexpr double kDegS = M_PI / 180.0;           // rad/s

// Six-face + 24 extra poses at 200 Hz, 2 mg accel noise, a warm-up of 8 degC. `move_s`: each
// move's duration (the simulator's 2.5 s by default: up to 135 deg/s; 1 s is a hand's pace, up
// to 340 deg/s, what a rate-dependent term needs to show). The unit's second-order terms come
// from the wide prior of real MEMS units (1e-5..3e-4 per m/s^2 on every axis,
// SimOptions::wide_second_order): an effect is searched beside a model that has them (issue 25).
inline SimOptions EffectScenario(uint64_t seed, std::vector<SimEffect> effects,
                                 bool temperature = true, double move_s = 2.5) {
  SimOptions o;
  o.wide_second_order = true;
  o.move_s = move_s;
  o.protocol = SimProtocol::kSixFace;
  o.seed = seed;
  o.extra_poses = 24;
  o.accel_noise_m_s2 = 2 * kMg;
  o.temperature = temperature;
  o.effects = std::move(effects);
  return o;
}

// Error of a parameter set on the static holds of a capture, through the SDK's Corrector:
// RMS over holds of |mean a| - g (m/s^2) and of |mean w| (rad/s).
struct HoldError {
  double accel_m_s2 = 0, gyro_rad_s = 0;
};
inline HoldError ErrorOn(const SimResult& sim, const ParamSet& params) {
  absl::StatusOr<sdk::Corrector> c = sdk::Corrector::Create(params, sim.capture.t_s.front());
  if (!c.ok()) return {NAN, NAN};  // a parameter set the SDK refuses: no error to measure
  const Capture& cap = sim.capture;
  double sa = 0, sg = 0;
  for (const SimPose& pose : sim.poses) {
    Eigen::Vector3d a = Eigen::Vector3d::Zero(), w = Eigen::Vector3d::Zero();
    int n = 0;
    for (size_t k = 0; k < cap.size(); ++k) {
      // The middle of the hold, clear of the moves on either side.
      if (cap.t_s[k] < pose.t_start_s + 0.3 || cap.t_s[k] > pose.t_end_s - 0.3) continue;
      sdk::RawSample in;
      in.t_s = cap.t_s[k];
      for (int j = 0; j < 3; ++j) in.accel[j] = cap.accel[k](j), in.gyro[j] = cap.gyro[k](j);
      if (cap.has_temp()) in.temp_c = cap.temp[k];
      sdk::CalibratedSample out;
      c->Apply(in, &out);
      a += Eigen::Vector3d(out.accel_m_s2[0], out.accel_m_s2[1], out.accel_m_s2[2]);
      w += Eigen::Vector3d(out.gyro_rad_s[0], out.gyro_rad_s[1], out.gyro_rad_s[2]);
      ++n;
    }
    sa += std::pow((a / n).norm() - cap.gravity_m_s2, 2);
    sg += (w / n).squaredNorm();
  }
  const auto holds = static_cast<double>(sim.poses.size());
  return {std::sqrt(sa / holds), std::sqrt(sg / holds)};
}

// The gravity-direction error after the moves of a capture, through the SDK's Corrector (what a
// rate-dependent gyroscope term changes; the holds cannot show it): each move's corrected rates
// integrated with the midpoint rule from the last sample of one hold to the first of the next,
// the true up direction before it carried over and compared with the true one after it. RMS
// over the moves, rad.
inline double MoveErrorOn(const SimResult& sim, const ParamSet& params) {
  absl::StatusOr<sdk::Corrector> c = sdk::Corrector::Create(params, sim.capture.t_s.front());
  if (!c.ok()) return NAN;
  const Capture& cap = sim.capture;
  const auto rate = [&](size_t k) {
    sdk::RawSample in;
    in.t_s = cap.t_s[k];
    for (int j = 0; j < 3; ++j) in.accel[j] = cap.accel[k](j), in.gyro[j] = cap.gyro[k](j);
    if (cap.has_temp()) in.temp_c = cap.temp[k];
    sdk::CalibratedSample out;
    c->Apply(in, &out);
    return Eigen::Vector3d(out.gyro_rad_s[0], out.gyro_rad_s[1], out.gyro_rad_s[2]);
  };
  double ss = 0;
  int moves = 0;
  for (size_t i = 0; i + 1 < sim.poses.size(); ++i) {
    size_t k0 = 0, k1 = 0;
    while (k0 + 1 < cap.size() && cap.t_s[k0 + 1] <= sim.poses[i].t_end_s) ++k0;
    k1 = k0;
    while (k1 + 1 < cap.size() && cap.t_s[k1] < sim.poses[i + 1].t_start_s) ++k1;
    Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
    Eigen::Vector3d w0 = rate(k0);
    for (size_t k = k0; k < k1; ++k) {
      const Eigen::Vector3d w1 = rate(k + 1);
      r = r * ExpSo3<double>(0.5 * (w0 + w1) * (cap.t_s[k + 1] - cap.t_s[k]));
      w0 = w1;
    }
    const Eigen::Vector3d up0 = sim.poses[i].R_world_body.transpose() * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d up1 =
        sim.poses[i + 1].R_world_body.transpose() * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d predicted = r.transpose() * up0;
    const double e = std::atan2(predicted.cross(up1).norm(), predicted.dot(up1));
    ss += e * e;
    ++moves;
  }
  return moves > 0 ? std::sqrt(ss / moves) : NAN;
}

// The oracle: the simulated truth with its effects, the validation capture's noise floor.
inline ParamSet TruthParams(const SimResult& sim) {
  ParamSet p;
  // A truth written about its own turnover, `(temperature-17.3)^2`, states that reference.
  for (const SimEffect& e : sim.effects) {
    const std::optional<Regressor> r = ParseRegressor(e.regressor);
    if (!r) continue;
    const double t = r->centre[static_cast<size_t>(Signal::kTemperature)];
    const double s = r->centre[static_cast<size_t>(Signal::kTime)];
    if (t != 0) p.effect_reference.temperature_c = t;
    if (s != 0) p.effect_reference.time_s = s;
  }
  p.accel = sim.truth.accel;
  p.gyro = sim.truth.gyro;
  p.gyro_calibrated = true;
  for (const SimEffect& e : sim.effects) {
    Effect fx;
    fx.sensor = e.sensor;
    fx.axis = e.axis;
    fx.regressor = e.regressor;
    fx.coefficient = e.coefficient;
    fx.applied = true;
    p.effects.push_back(fx);
  }
  return p;
}

// True when two regressor names are the same form up to the references their temperature and
// time factors are centred on (`(temperature-31.2)^2` and `temperature^2`): the coefficient of
// a polynomial's highest power, the one the truth's form names, does not depend on the centre.
inline bool SameForm(const std::string& a, const std::string& b) {
  const std::optional<Regressor> x = ParseRegressor(a);
  const std::optional<Regressor> y = ParseRegressor(b);
  return x && y && x->factors == y->factors && x->absolute == y->absolute &&
         x->num_factors == y->num_factors;
}

// True when `e` is a lower power that entered with a higher one in `all` (the search adds
// `(temperature-31.2)` with `(temperature-31.2)^2`, core/effects.h POLYNOMIALS): the same
// sensor, axis and form but one temperature or time factor fewer.
inline bool IsLowerPower(const Effect& e, const std::vector<Effect>& all) {
  const std::optional<Regressor> r = ParseRegressor(e.regressor);
  if (!r) return false;
  for (const Effect& h : all) {
    if (&h == &e || h.sensor != e.sensor || h.axis != e.axis) continue;
    const std::optional<Regressor> hr = ParseRegressor(h.regressor);
    if (!hr || hr->num_factors != r->num_factors + 1) continue;
    for (int i = 0; i < hr->num_factors; ++i) {
      const int f = hr->factors[i];
      if (f != static_cast<int>(Signal::kTemperature) && f != static_cast<int>(Signal::kTime))
        continue;
      Regressor lower;
      for (int k = 0; k < hr->num_factors; ++k)
        if (k != i) lower.factors[lower.num_factors++] = hr->factors[k];
      if (lower.factors == r->factors && lower.num_factors == r->num_factors) return true;
    }
  }
  return false;
}

// The effects that are not lower powers of another (one per physical effect).
inline int CountMainEffects(const std::vector<Effect>& all) {
  int n = 0;
  for (const Effect& e : all) n += !IsLowerPower(e, all);
  return n;
}

struct EffectCase {
  std::string name;
  std::vector<SimEffect> effects;
};

// Test names carry the case; this keeps gtest from printing the struct's bytes.
inline void PrintTo(const EffectCase& c, std::ostream* os) { *os << c.name; }

inline SimEffect Fx(Sensor s, int axis, const char* regressor, double c) {
  return SimEffect{s, axis, regressor, c};
}

// Magnitudes from the field notes' datasheet table.
inline const EffectCase kEffectCases[] = {
    {"AccelBiasTemperature", {Fx(Sensor::kAccel, 0, "temperature", 0.5 * kMg)}},   // /degC
    {"GyroBiasTemperature", {Fx(Sensor::kGyro, 2, "temperature", 0.02 * kDegS)}},  // /degC
    {"GyroBiasTemperatureNonlinear", {Fx(Sensor::kGyro, 0, "temperature^2", 0.002 * kDegS)}},
    {"AccelScaleTemperature", {Fx(Sensor::kAccel, 1, "temperature*ay", 2e-4)}},  // 0.02 %/degC
    {"GyroGSensitivity", {Fx(Sensor::kGyro, 1, "ax", 0.05 * kDegS / kStandardGravity)}},  // /g
    {"GyroBiasDrift", {Fx(Sensor::kGyro, 0, "time", 0.01 * kDegS / 60)}},                 // /min
    {"AccelCrossQuadratic", {Fx(Sensor::kAccel, 0, "ax*az", 3e-4)}},  // /(m/s^2)
};

// Harder shapes, run by bench/effects_bench only (with validation on other temperature
// histories). `T0` in a regressor is a turnover drawn per seed (TurnoverFor).
//   - a temperature quadratic whose turnover lies anywhere in 0-50 degC, on the gyroscope (0.002
//     deg/s/degC^2, the size an independent simulator used) and on the accelerometer (0.05
//     mg/degC^2: 3 mg at 8 degC off the turnover);
//   - two effects on different sensors at once.
inline const EffectCase kHarderCases[] = {
    {"GyroTemperatureTurnover", {Fx(Sensor::kGyro, 0, "(temperature-T0)^2", 0.002 * kDegS)}},
    {"AccelTemperatureTurnover", {Fx(Sensor::kAccel, 2, "(temperature-T0)^2", 0.05 * kMg)}},
    {"AccelTempGyroGSensitivity",
     {Fx(Sensor::kAccel, 1, "temperature", 0.5 * kMg),
      Fx(Sensor::kGyro, 2, "ax", 0.05 * kDegS / kStandardGravity)}},
};

// The case's effects for one seed: `T0` becomes a turnover uniform in 0-50 degC (0.1 degC steps),
// drawn from the seed.
inline std::vector<SimEffect> EffectsFor(const EffectCase& c, uint64_t seed) {
  std::vector<SimEffect> out = c.effects;
  std::mt19937_64 rng(seed * 0x9E3779B97F4A7C15ull + 17);
  const double t0 = std::round(std::uniform_real_distribution<double>(0, 50)(rng) * 10) / 10;
  char text[32];
  std::snprintf(text, sizeof(text), "%.1f", t0);
  for (SimEffect& e : out) {
    const size_t at = e.regressor.find("T0");
    if (at != std::string::npos) e.regressor.replace(at, 2, text);
  }
  return out;
}

// Temperature histories of a unit: EffectScenario's warm-up (25 -> 33 degC, 120 s time
// constant) and three others, for calibration and for validation: what a correction must also
// hold on.
enum class History { kWarmUp, kRamp, kCoolDown, kPlateau };
inline constexpr History kHistories[] = {History::kWarmUp, History::kRamp, History::kCoolDown,
                                         History::kPlateau};
inline const char* HistoryName(History h) {
  return h == History::kWarmUp     ? "warm-up"
         : h == History::kRamp     ? "ramp"
         : h == History::kCoolDown ? "cool-down"
                                   : "plateau";
}
inline SimOptions HistoryScenario(uint64_t seed, std::vector<SimEffect> effects, History h,
                                  double move_s = 2.5) {
  SimOptions o = EffectScenario(seed, std::move(effects), /*temperature=*/true, move_s);
  switch (h) {
    case History::kWarmUp:
      break;
    case History::kRamp:  // 25 -> 33 degC nearly linearly over the ~240 s capture
      o.temp_tau_s = 2400;
      o.temp_rise_c = 8 / (1 - std::exp(-0.1));
      break;
    case History::kCoolDown:  // 33 -> 25 degC
      o.temp_start_c = 33;
      o.temp_rise_c = -8;
      break;
    case History::kPlateau:  // steady, 2 degC above the calibration's range
      o.temp_start_c = 35;
      o.temp_rise_c = 0;
      break;
  }
  return o;
}

// True when the regressor reads a rate (gx, gy, gz, |gx|, ...): a term only the moves show.
inline bool ReadsRate(const std::string& regressor) {
  const std::optional<Regressor> r = ParseRegressor(regressor);
  if (!r) return false;
  for (int i = 0; i < r->num_factors; ++i)
    if (r->factors[static_cast<size_t>(i)] >= static_cast<int>(Signal::kGx)) return true;
  return false;
}

// Rate-dependent gyroscope terms, run by bench/effects_bench (and tests/core/move_effects_test):
// a scale 0.1 % higher per 100 deg/s of rate on z. Simulated with moves at a hand's pace
// (CaseMoveSeconds): the simulator's default 2.5 s moves stay under 135 deg/s. On a +-2000
// deg/s gyroscope this is about 0.3 % of full scale from the best straight line (the form's
// largest deviation is 0.17 s FS^2 for s per rad/s), beside datasheets' 0.1-0.2 % FS. Then
// smaller ones, down to and below what such a capture can detect (its detection bound on z is
// about 10 ppm/(deg/s), i.e. 0.1 % per 100 deg/s: core/move_effects.h DetectionBound).
inline const EffectCase kRateCases[] = {
    {"GyroRateScale", {Fx(Sensor::kGyro, 2, "gz*|gz|", 0.001 / (100 * kDegS))}},
    {"GyroRateScaleHalf", {Fx(Sensor::kGyro, 2, "gz*|gz|", 0.0005 / (100 * kDegS))}},
    {"GyroRateScaleFifth", {Fx(Sensor::kGyro, 2, "gz*|gz|", 0.0002 / (100 * kDegS))}},
    {"GyroRateScaleX", {Fx(Sensor::kGyro, 0, "gx*|gx|", 0.001 / (100 * kDegS))}},
};

// The moves' duration a case is simulated with: 1 s (a hand's pace, up to 340 deg/s) when an
// effect reads a rate, else the scenarios' 2.5 s.
inline double CaseMoveSeconds(const EffectCase& c) {
  for (const SimEffect& e : c.effects)
    if (ReadsRate(e.regressor)) return 1.0;
  return 2.5;
}

// True when some effect of the case reads `temperature` (it needs a temperature channel).
inline bool UsesTemperature(const EffectCase& c) {
  for (const SimEffect& e : c.effects)
    if (e.regressor.find("temperature") != std::string::npos) return true;
  return false;
}

// Two undeclared effects at once, on different sensors, axes and regressors: an accelerometer
// y bias that follows temperature and a gyroscope z g-sensitivity to the x specific force.
// Datasheet magnitudes (field notes, section 7): 0.5 mg/degC, 0.05 deg/s/g.
inline std::vector<SimEffect> TwoEffects() {
  return {Fx(Sensor::kAccel, 1, "temperature", 0.5 * kMg),
          Fx(Sensor::kGyro, 2, "ax", 0.05 * kDegS / kStandardGravity)};
}

// A slow warm-up that temperature follows almost linearly in time: EffectScenario's capture
// (about 240 s) covers a fifth of a 1200 s time constant, 25 -> 33 degC, so only the slight
// curvature of T(t) tells a temperature effect from a drift over time.
inline SimOptions SlowWarmUpScenario(uint64_t seed, std::vector<SimEffect> effects) {
  SimOptions o = EffectScenario(seed, std::move(effects));
  o.temp_tau_s = 1200.0;
  o.temp_rise_c = 45.0;
  return o;
}

}  // namespace imucal::core

#endif  // IMUCAL_TESTS_CORE_EFFECT_SCENARIOS_H_
