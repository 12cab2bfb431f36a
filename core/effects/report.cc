// Stage "report" of the effect search (search.h): what the search says of itself. The evidence of
// each effect that entered and the ambiguities it leaves; the rows per pose, the noise floors, the
// covariance; the notes on what remains and what could not be tested; the DETECTION BOUNDS of
// core/effects.h; the rotation residuals examined for trends; the coefficients in the units an
// engineer reads.
#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "Eigen/Dense"
#include "absl/strings/str_format.h"
#include "core/effects/search.h"
#include "util/str_util.h"
#include "util/units.h"

namespace imucal::core::effects {

// What would tell two regressors apart.
std::string Separator(const Regressor& a, const Regressor& b) {
  const bool temp = UsesSignal(a, Signal::kTemperature) || UsesSignal(b, Signal::kTemperature);
  const bool time = UsesSignal(a, Signal::kTime) || UsesSignal(b, Signal::kTime);
  if (temp && time) {
    return "temperature and time rose together in this capture; a capture at a steady "
           "temperature (or one that warms and cools) would tell them apart";
  }
  return "poses that vary one of them without the other, or per-axis references (known "
         "orientations), would tell them apart";
}

namespace {

std::string TermName(const Term& t) { return Describe(t.sensor, t.axis, t.regressor); }

// The detection bounds' note: per sensor and kind of form, the range of the bounds over the axes
// ("; accel bias slope 0.021 to 0.03 mg/degC (xyz)..."); empty without bounds.
std::string BoundsText(const std::vector<DetectionBound>& bounds) {
  std::string text;
  // 0: a bias slope, 1: a curvature (temperature alone, one or two factors), 2: a scale slope.
  const auto kind_of = [](const std::string& name) {
    const std::optional<Regressor> r = ParseRegressor(name);
    if (!r) return -1;
    for (int i = 0; i < r->num_factors; ++i)
      if (r->factors[i] != static_cast<int>(Signal::kTemperature)) return 2;
    return r->num_factors - 1;
  };
  const char* const kKinds[] = {"bias slope", "curvature", "scale slope"};
  for (int sensor = 0; sensor < 2; ++sensor) {
    for (int kind = 0; kind < 3; ++kind) {
      std::vector<const DetectionBound*> same;
      for (const DetectionBound& b : bounds)
        if (static_cast<int>(b.sensor) == sensor && kind_of(b.regressor) == kind)
          same.push_back(&b);
      if (same.empty()) continue;
      const DetectionBound* low = same.front();
      const DetectionBound* high = same.front();
      std::string axes;
      for (const DetectionBound* b : same) {
        if (b->coefficient < low->coefficient) low = b;
        if (b->coefficient > high->coefficient) high = b;
        axes += AxisName(b->axis);
      }
      const auto sn = static_cast<Sensor>(sensor);
      const std::string lo_text = HumanValue(sn, low->regressor, low->coefficient);
      const std::string hi_text = HumanValue(sn, high->regressor, high->coefficient);
      const std::string range =
          !std::isfinite(high->coefficient)
              ? absl::StrFormat("none (%s: the temperature does not vary)", axes)
          : lo_text == hi_text ? absl::StrFormat("%s (%s)", hi_text, axes)
                               : absl::StrFormat("%s to %s (%s)", lo_text, hi_text, axes);
      absl::StrAppendFormat(&text, "%s %s %s %s", text.empty() ? "" : ";", SensorName(sn),
                            kKinds[kind], range);
    }
  }
  return text;
}
}  // namespace

double RmsOf(const std::vector<double>& v) {
  double s = 0;
  int n = 0;
  for (double x : v)
    if (std::isfinite(x)) s += x * x, ++n;
  return n > 0 ? std::sqrt(s / n) : kNaN;
}

double GyroRms(const std::vector<Eigen::Vector3d>& v) {
  double s = 0;
  for (const auto& x : v) s += x.squaredNorm();
  return v.empty() ? kNaN : std::sqrt(s / static_cast<double>(v.size()));
}

void KeepTop(std::vector<RoundCandidate> cands, EffectDiagnostics* diag) {
  std::sort(cands.begin(), cands.end(),
            [](const RoundCandidate& a, const RoundCandidate& b) { return a.score.f > b.score.f; });
  for (size_t k = 0; k < cands.size() && k < 8; ++k) diag->top.push_back(cands[k].score);
}

void FillAccelCovariance(const AccelMask& free, const Fit& fit, EffectSearchResult* out) {
  std::vector<int> idx;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)]) idx.push_back(c);
  for (size_t a = 0; a < idx.size(); ++a)
    for (size_t b = 0; b < idx.size(); ++b)
      out->accel_covariance(idx[a], idx[b]) =
          fit.accel_cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b));
}

// The entering effect's evidence, and notes on the candidates it was weighed against:
// `static_best` is the static choice (it differs from `win` when the moves overruled it).
std::string Search::Evidence(const RoundCandidate& win, const RoundCandidate& static_best,
                             const std::vector<RoundCandidate>& cands, int tests,
                             EffectDiagnostics* diag) const {
  const std::string win_name = Describe(win);
  const auto judged = static_cast<int>(
      std::count_if(cands.begin(), cands.end(), [](const auto& c) { return c.Judged(); }));
  const double t_crit = MoveTThreshold(judged - 1, win.move_error_rad.size());
  const auto by_moves = [&](const RoundCandidate& lost, const char* why) {
    diag->notes.push_back(absl::StrFormat(
        "resolved by the rotations between poses: %s rather than %s, %s (BIC %+.1f vs %+.1f); "
        "the gyroscope, refitted to each one's pose directions, leaves %.4f vs %.4f deg RMS "
        "after the %d moves (paired t %.1f > %.1f)",
        win_name, Describe(lost), why, win.score.delta_bic, lost.score.delta_bic,
        win.MoveRms() * kRadToDeg, lost.MoveRms() * kRadToDeg,
        static_cast<int>(win.move_error_rad.size()), MovePairedT(lost, win), t_crit));
  };
  if (&win != &static_best) by_moves(static_best, "which |a| - g preferred");
  std::string rivals;
  for (const RoundCandidate& c : cands) {
    if (&c == &win || &c == &static_best || !Ambiguous(win, c, kWeakEvidenceBic)) continue;
    // A polynomial and its own lower power are not rival explanations: the higher one is
    // tested again next round, with the lower one in.
    if (Nested(win, c) || Nested(c, win)) continue;
    // |a| - g does not tell them apart; the moves may, unless they differ in temperature or
    // time only.
    const double t = SameGeometry(win, c) ? kNaN : MovePairedT(c, win);
    if (t > t_crit) {
      by_moves(c, "which explains |a| - g as well");
      continue;
    }
    const std::string name = Describe(c);
    rivals += Cat(rivals.empty() ? "" : ", ", name);
    const double gap = std::abs(win.score.delta_bic - c.score.delta_bic);
    const std::string favoured = win.score.delta_bic <= c.score.delta_bic ? win_name : name;
    diag->notes.push_back(
        Cat("ambiguous: ", win_name,
            gap < kAmbiguousBic ? Cat(" explains the residual about as well as ", name)
                                : Cat(" and ", name, " both explain the residual; the data favour ",
                                      favoured, " but not strongly"),
            absl::StrFormat(" (BIC %+.1f vs %+.1f", win.score.delta_bic, c.score.delta_bic),
            gap < kAmbiguousBic ? "); " : ", a difference under 6 is not strong evidence); ",
            std::isfinite(t)
                ? absl::StrFormat("the rotations between poses do not decide between them either "
                                  "(%.4f vs %.4f deg RMS after the moves, paired t %.1f against "
                                  "%.1f); ",
                                  win.MoveRms() * kRadToDeg, c.MoveRms() * kRadToDeg, t, t_crit)
                : "",
            Separator(win.regressor, c.regressor)));
  }
  return absl::StrFormat(
      "F %.1f > %.1f (F(1,dof) at %.2g/%d candidates, Bonferroni); BIC %+.1f; held-out sum of "
      "squares -%.1f (noise units)%s%s",
      win.score.f, win.score.f_threshold, opt_.family_alpha, tests, win.score.delta_bic,
      win.score.press_gain,
      &win != &static_best ? "; chosen over the static choice by the rotations between poses" : "",
      rivals.empty() ? "" : Cat("; ambiguous with ", rivals));
}

void Search::NoiseFloors(EffectDiagnostics* diag) const {
  std::vector<AccelPose> bare = AccelPoses(poses_);
  for (AccelPose& p : bare) p.model_sigma_m_s2 = 0, p.offset_m_s2.setZero();
  diag->accel_noise_floor_m_s2 = RmsOf(MagnitudeSigmas(in_.accel, bare));
  double s = 0;
  for (const auto& g : gyro_sigma_) s += g.squaredNorm();
  diag->gyro_noise_floor_rad_s = std::sqrt(s / static_cast<double>(gyro_sigma_.size()));
}

void Search::Rows(const Fit& before, const Fit& after, const Fit& all,
                  EffectDiagnostics* diag) const {
  for (size_t i = 0; i < poses_.size(); ++i) {
    EffectPoseRow row;
    row.pose_index = poses_[i].pose_index;
    row.signals = signals_[i];
    row.accel_before_m_s2 = before.accel_residual[i];
    row.accel_after_m_s2 = after.accel_residual[i];
    row.gyro_before_rad_s = before.gyro_residual[i];
    row.gyro_after_rad_s = after.gyro_residual[i];
    row.accel_all_m_s2 = all.accel_residual[i];
    row.gyro_all_rad_s = all.gyro_residual[i];
    diag->rows.push_back(row);
  }
}

void Search::FinalNotes(const State& st, const Fit& fit, EffectDiagnostics* diag) const {
  bool has_temp = true;
  for (const EffectPose& p : poses_) has_temp &= std::isfinite(p.temp_c);
  for (const Term& t : st.terms) {
    if (UsesSignal(t.regressor, Signal::kTime)) {
      diag->notes.push_back(
          Cat(TermName(t), ": a dependence on time since the capture started",
              t.applied ? " (applied: the user opted in)"
                        : " is reported, not applied (opt in to apply it at run time)",
              has_temp ? ""
                       : "; the capture has no temperature channel, so a warm-up would look the "
                         "same: record temperature to tell them apart"));
    }
  }
  const double accel_rms = RmsOf(fit.accel_residual);
  const auto unpredictable = std::count_if(fit.accel_heldout.begin(), fit.accel_heldout.end(),
                                           [](double v) { return !std::isfinite(v); });
  if (unpredictable > 0) {
    diag->notes.push_back(absl::StrFormat(
        "%d of %d poses are each the only one to fix part of the accelerometer model (a face "
        "placed once): the others cannot predict them, so the held-out figures leave them out%s",
        static_cast<int>(unpredictable), static_cast<int>(fit.accel_heldout.size()),
        unpredictable == static_cast<long>(fit.accel_heldout.size())
            ? "; none is left, so accelerometer effects could not be judged held out. Place "
              "each face twice (the six-face protocol) or add poses between the faces"
            : ""));
  }
  diag->notes.push_back(absl::StrFormat(
      "remaining accelerometer residual %.3f mg RMS (held out %.3f mg) against a noise floor "
      "of %.3f mg",
      accel_rms / kStandardGravity * 1e3, RmsOf(fit.accel_heldout) / kStandardGravity * 1e3,
      diag->accel_noise_floor_m_s2 / kStandardGravity * 1e3));
  diag->notes.push_back(absl::StrFormat(
      "remaining gyroscope static residual %.4f deg/s RMS (held out %.4f deg/s) against a "
      "noise floor of %.4f deg/s",
      GyroRms(fit.gyro_residual) * kRadToDeg, GyroRms(fit.gyro_heldout) * kRadToDeg,
      diag->gyro_noise_floor_rad_s * kRadToDeg));
  if (!has_temp) {
    diag->notes.push_back("no temperature channel: temperature effects could not be tested");
  }
  if (!in_.gyro_output_si) {
    diag->notes.push_back(
        "gyroscope effects not searched: its output stays in raw counts (scale not calibrated)");
  }
  if (diag->not_excited > 0) {
    diag->notes.push_back(absl::StrFormat(
        "%d candidates not testable on static poses: their signals (rates) do not vary at "
        "rest",
        diag->not_excited));
  }
}

// DETECTION BOUNDS (core/move_effects.h DetectionBound): on each output where the search did
// not put it, the smallest bias slope `(temperature-T)`, curvature `(temperature-T)^2` and (on
// the accelerometer) scale slope `(temperature-T)*a` this capture would have found, at the final
// model and the last round's threshold. Each form is tested as the search tests it: with the
// lower powers it lacks on that output (a curvature with its slope: the bound is the one for a
// turnover at the capture's reference temperature, the hardest place for it).
void Search::TemperatureBounds(const State& st, const Excitation& excited,
                               EffectDiagnostics* diag) {
  const auto temp = static_cast<size_t>(Signal::kTemperature);
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const SignalArray& a : signals_)
    if (std::isfinite(a[temp])) lo = std::min(lo, a[temp]), hi = std::max(hi, a[temp]);
  if (!(hi >= lo)) return;  // no temperature channel: the notes say so
  const std::string from =
      absl::StrFormat("%d poses at %.1f-%.1f degC", static_cast<int>(poses_.size()), lo, hi);
  const int tests = std::max(1, last_tests_);
  const RoundDesigns designs = DesignsAt(st);
  for (int sensor = 0; sensor < (in_.gyro_output_si ? 2 : 1); ++sensor) {
    const auto sn = static_cast<Sensor>(sensor);
    for (int axis = 0; axis < 3; ++axis) {
      std::vector<std::string> forms = {"temperature", "temperature^2"};
      if (sn == Sensor::kAccel) forms.push_back(absl::StrFormat("temperature*a%c", "xyz"[axis]));
      const Scorer& scorer = designs.For(sn, axis);
      for (const std::string& name : forms) {
        const Regressor form = ParseRegressor(name)->CentredOn(centre_);
        if (InModel(st, sn, axis, form)) continue;  // found: its coefficient says the rest
        const std::optional<std::vector<Regressor>> lower = LowerPowers(st, sn, axis, form);
        if (!lower) continue;
        std::vector<Regressor> group = *lower;
        group.push_back(form);
        const auto k = static_cast<Eigen::Index>(group.size());
        const Eigen::MatrixXd cols = CandidateColumns(designs, st, sn, axis, group);
        DetectionBound b;
        b.sensor = sn;
        b.axis = axis;
        b.regressor = form.Name();
        b.from = from;
        b.coefficient = std::numeric_limits<double>::infinity();
        const double beyond = excited[temp] ? scorer.LastBeyond(cols) : 0.0;
        const double f_star = FThreshold(opt_.family_alpha, tests, DofAfter(st, sn, axis) - (k - 1),
                                         static_cast<int>(k));
        if (beyond > 0) {
          const double lambda =
              DetectableNoncentrality(static_cast<int>(k), static_cast<double>(k) * f_star);
          b.coefficient = std::sqrt(lambda * scorer.variance()) / beyond;
        }
        diag->detection_bounds.push_back(std::move(b));
      }
    }
  }
  const std::string text = BoundsText(diag->detection_bounds);
  if (!text.empty())
    diag->notes.push_back(
        Cat("temperature: where none was found, this capture (", from,
            ") would have found one 9 times in 10 at:", text,
            ". A smaller one may be there; a capture over a wider temperature span sees smaller "
            "ones"));
}

}  // namespace imucal::core::effects

namespace imucal::core {

namespace {

using effects::FThreshold;

// A coefficient's unit as an engineer reads it, and the factor from SI to it.
struct HumanUnit {
  double factor = 1;
  std::string unit;
};

HumanUnit HumanUnitOf(Sensor sensor, const std::string& regressor) {
  // Numerator: mg or deg/s. Each factor of the regressor: degC, s, g or deg/s. A factor of the
  // sensor's own kind turns the ratio into ppm (mg/g = 1000 ppm, (deg/s)/(deg/s) = 1e6 ppm).
  const std::optional<Regressor> r = ParseRegressor(regressor);
  const bool accel = sensor == Sensor::kAccel;
  double factor = accel ? 1e3 / kStandardGravity : kRadToDeg;
  std::string numerator = accel ? "mg" : "deg/s";
  std::vector<std::string> units;
  bool ppm = false;
  if (r) {
    for (int i = 0; i < r->num_factors; ++i) {
      const auto s = static_cast<Signal>(r->factors[i]);
      const bool is_accel = s >= Signal::kAx && s <= Signal::kAz;
      const bool is_rate = s >= Signal::kGx;
      if (!ppm && ((accel && is_accel) || (!accel && is_rate))) {
        // mg per g or (deg/s) per (deg/s): relative, in ppm.
        factor = 1e6;
        numerator = "ppm";
        ppm = true;
        continue;
      }
      if (s == Signal::kTemperature) units.push_back("degC");
      if (s == Signal::kTime) factor *= 3600, units.push_back("h");
      if (is_accel) factor *= kStandardGravity, units.push_back("g");
      if (is_rate) factor /= kRadToDeg, units.push_back("(deg/s)");
    }
  }
  std::string unit = numerator;
  for (size_t i = 0; i < units.size(); ++i) {
    size_t run = 1;
    while (i + run < units.size() && units[i + run] == units[i]) ++run;
    unit += "/" + units[i] + (run > 1 ? "^2" : "");
    i += run - 1;
  }
  if (units.empty() && !ppm) unit += " per regressor unit";
  return {factor, unit};
}

// A signal of the moves their gravity-direction error is regressed on.
struct MoveSignal {
  const char* name;
  const char* unit;
  double scale;  // signal unit per reported unit
  double (*get)(const EffectMoveResidual&);
};
const MoveSignal kMoveSignals[] = {
    {"the rotation angle", "per 100 deg", 100 / kRadToDeg,
     [](const EffectMoveResidual& r) { return r.rotation_rad; }},
    {"time", "per minute", 60, [](const EffectMoveResidual& r) { return r.time_s; }},
    {"temperature", "per degC", 1, [](const EffectMoveResidual& r) { return r.temp_c; }},
};

// The error's linear trend in one signal (with an intercept), its F against the flat line; nullopt
// when the signal is not finite or does not vary over the moves (not tested).
std::optional<MoveTrend> TrendOn(const MoveSignal& sig, const std::vector<EffectMoveResidual>& m) {
  const auto n = static_cast<Eigen::Index>(m.size());
  Eigen::MatrixXd x(n, 2);
  Eigen::VectorXd y(n);
  bool finite = true;
  for (Eigen::Index i = 0; i < n; ++i) {
    x(i, 0) = 1;
    x(i, 1) = sig.get(m[static_cast<size_t>(i)]);
    y(i) = m[static_cast<size_t>(i)].error_rad;
    finite &= std::isfinite(x(i, 1));
  }
  if (!finite || (x.col(1).array() - x.col(1).mean()).matrix().norm() <= 0) return std::nullopt;
  const Eigen::VectorXd b = x.colPivHouseholderQr().solve(y);
  const double rss1 = (y - x * b).squaredNorm();
  const double rss0 = (y.array() - y.mean()).matrix().squaredNorm();
  const double dof = static_cast<double>(n - 2);
  const double f = (rss0 - rss1) / std::max(1e-300, rss1 / dof);
  // The slope's standard error: sqrt(s^2 / Sxx), s^2 the residual variance about the line.
  const double sxx = (x.col(1).array() - x.col(1).mean()).matrix().squaredNorm();
  MoveTrend t;
  t.signal = sig.name;
  t.unit = Cat("deg ", sig.unit);
  t.slope_deg = b(1) * sig.scale * kRadToDeg;
  t.slope_std_error_deg = std::sqrt(rss1 / dof / sxx) * sig.scale * kRadToDeg;
  t.f = f;
  return t;
}

}  // namespace

std::string HumanCoefficient(const Effect& e) {
  const HumanUnit u = HumanUnitOf(e.sensor, e.regressor);
  return absl::StrFormat("%.4g +- %.2g %s", e.coefficient * u.factor, e.std_error * u.factor,
                         u.unit);
}

std::string HumanValue(Sensor sensor, const std::string& regressor, double value) {
  const HumanUnit u = HumanUnitOf(sensor, regressor);
  return absl::StrFormat("%.2g %s", value * u.factor, u.unit);
}

// The rotation residuals: regress the gravity-direction error after each move on each of its
// signals (with an intercept); a slope significant at 1% over the signals (Bonferroni) is
// reported with its size.
void ExamineMoveResiduals(const std::vector<EffectMoveResidual>& all, EffectDiagnostics* diag) {
  constexpr std::string_view kNote = "rotation residuals: ";
  // A move whose gravity direction turned less than this is blind to the gyroscope's error.
  constexpr double kBlindTiltRad = 5.0 / kRadToDeg;
  std::vector<MoveTrend>& trends = diag->move_trends;
  trends.clear();
  std::erase_if(diag->notes, [&](const std::string& note) { return note.starts_with(kNote); });
  std::vector<EffectMoveResidual> m;
  for (const EffectMoveResidual& r : all)
    if (!(r.tilt_rad < kBlindTiltRad)) m.push_back(r);
  const int blind = static_cast<int>(all.size() - m.size());
  const std::string left_out =
      blind == 0 ? ""
                 : absl::StrFormat(
                       "; %d that turned about the vertical left out: gravity stays "
                       "where it was whatever the gyroscope reads",
                       blind);
  if (m.size() < 6) return;
  int tested = 0;
  std::vector<std::string> found;
  const auto n = static_cast<Eigen::Index>(m.size());
  for (const MoveSignal& sig : kMoveSignals) {
    std::optional<MoveTrend> t = TrendOn(sig, m);
    if (!t) continue;
    ++tested;
    trends.push_back(std::move(*t));
  }
  const auto dof = static_cast<Eigen::Index>(n - 2);
  for (MoveTrend& r : trends) {
    r.f_threshold = FThreshold(0.01, tested, dof);
    r.significant = r.f > r.f_threshold;
    if (r.significant) {
      found.push_back(absl::StrFormat("%s (%+.3f +- %.3f %s, F %.1f)", r.signal, r.slope_deg,
                                      r.slope_std_error_deg, r.unit, r.f));
    }
  }
  double ss = 0;
  for (const auto& r : m) ss += r.error_rad * r.error_rad;
  const double rms_deg = std::sqrt(ss / static_cast<double>(m.size())) * kRadToDeg;
  if (found.empty()) {
    diag->notes.push_back(
        Cat(kNote, absl::StrFormat("the gravity-direction error after the %d moves (%.3f deg "
                                   "RMS%s) shows no trend with the rotation angle, time or "
                                   "temperature",
                                   static_cast<int>(m.size()), rms_deg, left_out)));
  } else {
    std::string list;
    for (const auto& f : found) list += (list.empty() ? "" : "; ") + f;
    diag->notes.push_back(Cat(
        kNote, absl::StrFormat("the gravity-direction error after the %d moves (%.3f deg RMS%s) "
                               "grows with %s: a rate-dependent gyroscope effect (scale "
                               "nonlinearity, or a drift during moves) that static poses cannot "
                               "test; moves of different sizes and speeds would locate it",
                               static_cast<int>(m.size()), rms_deg, left_out, list)));
  }
}

}  // namespace imucal::core
