// Stage "candidates" of the effect search (search.h): which regressors each output may take in
// a round. Every regressor of one or two factors over the signals the capture has (the
// DICTIONARY of core/effects.h), on each output axis of either sensor, unless the signal does not
// vary over the poses (not excited), the model already holds it (its own terms: absorbed), its
// main term is missing (MARGINALITY), or it is a product of temperature and time before both main
// terms are in (POLYNOMIALS); a power comes with the lower powers it lacks. Once an effect is in,
// the parameters the model held are candidates too (RE-EXAMINATION).
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/effects/search.h"
#include "util/str_util.h"

namespace imucal::core::effects {
namespace {

// The accelerometer model's own terms: linear in the specific force (scale, misalignment) and
// the square of the output axis's own signal (its quadratic). The model's observability and
// selection decide those; the search does not re-add them as effects.
bool IsModelTerm(Sensor sensor, int axis, const Regressor& r) {
  if (sensor != Sensor::kAccel) return false;
  const auto is_accel = [](int s) {
    return s >= static_cast<int>(Signal::kAx) && s <= static_cast<int>(Signal::kAz);
  };
  if (r.num_factors == 1) return is_accel(r.factors[0]);
  return r.num_factors == 2 && r.factors[0] == r.factors[1] &&
         r.factors[0] == static_cast<int>(Signal::kAx) + axis;
}

// The marginality rule for interactions with temperature or time. `temperature*ax` on gyro y
// says that the gyroscope's sensitivity to ax changes with temperature; a coefficient can
// change only where the model has one. Without its main term the product is that main term
// scaled by an arbitrary origin (degC has no physical zero: over a 25-33 degC capture
// `temperature*ax` is nearly 29 times `ax`), and the two would trade places on noise alone.
// So a regressor that multiplies temperature or time with sensor signals is a candidate only
// when its sensor part is modelled on that output: by the model's own terms (the accelerometer's
// linear map and quadratic, the gyroscope's matrix over the rates) or by an effect already in.
// Pure temperature or time regressors are bias terms, whose main term (the bias) every model has.
bool MainTermModelled(const State& st, Sensor sensor, int axis, const Regressor& r) {
  Regressor main;  // r without its temperature and time factors (still sorted)
  for (int i = 0; i < r.num_factors; ++i) {
    const int f = r.factors[i];
    if (f != static_cast<int>(Signal::kTemperature) && f != static_cast<int>(Signal::kTime))
      main.factors[main.num_factors++] = f;
  }
  if (main.num_factors == r.num_factors || main.num_factors == 0) return true;
  if (IsModelTerm(sensor, axis, main)) return true;
  const bool rate = main.num_factors == 1 && main.factors[0] >= static_cast<int>(Signal::kGx);
  if (sensor == Sensor::kGyro && rate) return true;
  return InModel(st, sensor, axis, main);
}

// Every regressor of 1..max_factors factors over the signals.
std::vector<Regressor> Dictionary(int max_factors) {
  std::vector<Regressor> out;
  for (int a = 0; a < kNumSignals; ++a) {
    Regressor r;
    r.factors[0] = a;
    r.num_factors = 1;
    out.push_back(r);
    if (max_factors < 2) continue;
    for (int b = a; b < kNumSignals; ++b) {
      Regressor r2 = r;
      r2.factors[1] = b;
      r2.num_factors = 2;
      out.push_back(r2);
    }
  }
  return out;
}

// `r` with one factor of `signal` removed (its centre kept while a factor of it remains).
Regressor Without(const Regressor& r, int signal) {
  Regressor out;
  bool removed = false;
  for (int i = 0; i < r.num_factors; ++i) {
    if (!removed && r.factors[i] == signal) {
      removed = true;
      continue;
    }
    out.factors[out.num_factors++] = r.factors[i];
  }
  for (int i = 0; i < out.num_factors; ++i)
    out.centre[static_cast<size_t>(out.factors[i])] = r.centre[static_cast<size_t>(out.factors[i])];
  return out;
}

}  // namespace

Excitation ExcitedSignals(const std::vector<EffectPose>& poses,
                          const std::vector<SignalArray>& signals, const AccelParams& accel,
                          const GyroParams& gyro) {
  Excitation out{};
  const auto n = static_cast<double>(signals.size());
  for (int s = 0; s < kNumSignals; ++s) {
    double mean = 0, noise2 = 0;
    bool finite = true;
    for (size_t i = 0; i < signals.size(); ++i) {
      const double v = signals[i][static_cast<size_t>(s)];
      finite &= std::isfinite(v);
      mean += v / n;
      // Measurement noise of the signal at this pose (accel and rate through the model).
      if (s >= static_cast<int>(Signal::kAx) && s <= static_cast<int>(Signal::kAz)) {
        const int k = s - static_cast<int>(Signal::kAx);
        const Eigen::Matrix3d m = accel.Misalignment() * accel.scale.asDiagonal();
        noise2 += m.row(k).transpose().cwiseProduct(poses[i].accel.mean_std).squaredNorm() / n;
      } else if (s >= static_cast<int>(Signal::kGx)) {
        const int k = s - static_cast<int>(Signal::kGx);
        noise2 +=
            gyro.matrix.row(k).transpose().cwiseProduct(poses[i].gyro_mean_std).squaredNorm() / n;
      }
    }
    // At rest the true rate is zero: a measured static rate is the gyroscope's residual itself,
    // so rates are never excited on static poses (they are tested on the moves).
    if (!finite || s >= static_cast<int>(Signal::kGx)) continue;
    double var = 0;
    for (const SignalArray& a : signals) var += std::pow(a[static_cast<size_t>(s)] - mean, 2) / n;
    out[static_cast<size_t>(s)] = var > 0 && var > kExcitedRatio * kExcitedRatio * noise2;
  }
  return out;
}

bool InModel(const State& st, Sensor sensor, int axis, const Regressor& r) {
  for (const Term& t : st.terms)
    if (t.sensor == sensor && t.axis == axis && t.regressor == r) return true;
  return false;
}

// The physical forms of temperature and time (effects.h, POLYNOMIALS): the lower powers that
// must enter with `r` on this output (empty: none missing), or nullopt when `r` is not a
// candidate yet (a product of temperature and time before both its main terms are in).
std::optional<std::vector<Regressor>> Search::LowerPowers(const State& st, Sensor sensor, int axis,
                                                          const Regressor& r) const {
  int count[kNumSignals] = {};
  for (int i = 0; i < r.num_factors; ++i) ++count[r.factors[i]];
  const int temp = static_cast<int>(Signal::kTemperature);
  const int time = static_cast<int>(Signal::kTime);
  if (count[temp] > 0 && count[time] > 0) {
    if (!InModel(st, sensor, axis, Without(r, temp)) ||
        !InModel(st, sensor, axis, Without(r, time)))
      return std::nullopt;
    return std::vector<Regressor>{};
  }
  for (int s : {temp, time}) {
    if (count[s] < 2) continue;
    const Regressor below = Without(r, s);
    if (InModel(st, sensor, axis, below)) return std::vector<Regressor>{};
    return std::vector<Regressor>{below};
  }
  return std::vector<Regressor>{};
}

std::vector<RoundCandidate> Search::Candidates(const State& st, const Excitation& excited,
                                               int* absorbed, int* not_excited) const {
  std::vector<RoundCandidate> out;
  for (const Regressor& plain : Dictionary(opt_.max_factors)) {
    const Regressor r = plain.CentredOn(centre_);
    bool ok = true;
    for (int f = 0; f < r.num_factors; ++f) ok &= excited[static_cast<size_t>(r.factors[f])];
    bool has_values = true;
    for (const SignalArray& s : signals_) has_values &= std::isfinite(r.Evaluate(s));
    if (!has_values) continue;  // a signal the capture does not have (no temperature)
    for (int sensor = 0; sensor < (in_.gyro_output_si ? 2 : 1); ++sensor) {
      const auto sn = static_cast<Sensor>(sensor);
      for (int axis = 0; axis < 3; ++axis) {
        if (!ok) {
          ++*not_excited;
          continue;
        }
        if (InModel(st, sn, axis, r)) continue;
        if (IsModelTerm(sn, axis, r)) {
          ++*absorbed;
          continue;
        }
        if (!MainTermModelled(st, sn, axis, r)) continue;
        const std::optional<std::vector<Regressor>> lower = LowerPowers(st, sn, axis, r);
        if (!lower.has_value()) continue;
        RoundCandidate c;
        c.regressor = r;
        c.lower = *lower;
        c.score.sensor = sn;
        c.score.axis = axis;
        c.score.regressor = r.Name();
        out.push_back(std::move(c));
      }
    }
  }
  // RE-EXAMINATION (core/effects.h): once an effect is in, the parameters the model held.
  if (st.terms.empty()) return out;
  for (int p = 0; p < kAccelParams; ++p) {
    if (!in_.accel_held[static_cast<size_t>(p)] || st.free[static_cast<size_t>(p)]) continue;
    RoundCandidate c;
    c.model_param = p;
    c.score.sensor = Sensor::kAccel;
    c.score.axis = p % 3;
    c.score.regressor = Cat("model ", AccelParamName(p));
    out.push_back(std::move(c));
  }
  return out;
}

double RoundCandidate::MoveRms() const {
  double s = 0;
  for (double e : move_error_rad) s += e * e;
  return std::sqrt(s / static_cast<double>(std::max<size_t>(1, move_error_rad.size())));
}

std::string Describe(Sensor sensor, int axis, const Regressor& r) {
  return Cat(SensorName(sensor), " ", AxisName(axis), " ~ ", r.Name());
}

// The candidate's name, its lower powers first: "gyro x ~ (temperature-31.2) +
// (temperature-31.2)^2".
std::string Describe(const RoundCandidate& c) {
  if (c.model_param >= 0) return Cat("accel model term ", AccelParamName(c.model_param));
  std::string terms;
  for (const Regressor& l : c.lower) terms += l.Name() + " + ";
  return Cat(SensorName(c.score.sensor), " ", AxisName(c.score.axis), " ~ ", terms,
             c.regressor.Name());
}

bool UsesTime(const RoundCandidate& c) {
  bool time = UsesSignal(c.regressor, Signal::kTime);
  for (const Regressor& l : c.lower) time |= UsesSignal(l, Signal::kTime);
  return time;
}

// The terms a candidate adds to the model, lower powers first.
std::vector<Term> TermsOf(const RoundCandidate& c, bool apply_time) {
  std::vector<Term> out;
  const auto add = [&](const Regressor& r, double coefficient) {
    Term t;
    t.sensor = c.score.sensor;
    t.axis = c.score.axis;
    t.regressor = r;
    t.coefficient = coefficient;
    t.applied = !UsesSignal(r, Signal::kTime) || apply_time;
    out.push_back(t);
  };
  for (size_t k = 0; k < c.lower.size(); ++k) add(c.lower[k], c.lower_coefficients[k]);
  add(c.regressor, c.score.coefficient);
  return out;
}

Effect ToEffect(const Term& t) {
  Effect e;
  e.sensor = t.sensor;
  e.axis = t.axis;
  e.regressor = t.regressor.Name();
  e.coefficient = t.coefficient;
  e.applied = t.applied;
  return e;
}

}  // namespace imucal::core::effects
