#include "core/health/drift.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <string>
#include <vector>

#include "Eigen/LU"
#include "absl/strings/str_format.h"
#include "boost/math/distributions/normal.hpp"
#include "boost/math/distributions/students_t.hpp"
#include "util/units.h"

namespace imucal::core::health {
namespace {

constexpr double kMaxScore = 8.0;  // normal scores are clamped here: one wild check adds <= 8 - k
// The MAD's asymptotic efficiency for normal data (0.37): n differences weigh as 0.37 n checks.
constexpr double kMadEfficiency = 0.37;

struct Series {
  std::vector<double> x, se, t_s, temp_c;
};

double MedianOrZero(std::vector<double> v) {
  if (v.empty()) return 0;
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(mid), v.end());
  double m = v[mid];
  if (v.size() % 2 == 0)
    m = (m + *std::max_element(v.begin(), v.begin() + static_cast<long>(mid))) / 2;
  return m;
}

// Two unit vectors across u0 (a fixed, deterministic choice: the axis least along u0 first).
void Across(const Eigen::Vector3d& u0, Eigen::Vector3d* ea, Eigen::Vector3d* eb) {
  int least = 0;
  u0.cwiseAbs().minCoeff(&least);
  *ea = u0.cross(Eigen::Vector3d::Unit(least)).normalized();
  *eb = u0.cross(*ea).normalized();
}

// fixed: the checks share one orientation (a dock); else along gravity is |f| - g (u0 would mix
// orientations).
Series SeriesOf(const std::vector<HealthCheck>& c, Quantity q, const Eigen::Vector3d& u0,
                bool fixed) {
  Eigen::Vector3d ea, eb;
  Across(u0, &ea, &eb);
  Series s;
  for (const HealthCheck& h : c) {
    double x = 0, se = 0;
    const int gyro_axis = static_cast<int>(q) - static_cast<int>(Quantity::kGyroX);
    if (q == Quantity::kAlongGravity && !fixed) {
      x = h.norm_minus_g_m_s2;
      se = h.norm_minus_g_se_m_s2;
    } else if (q == Quantity::kAlongGravity) {
      x = h.specific_force_m_s2.dot(u0) - h.gravity_m_s2;
      se = std::sqrt(
          u0.array().square().matrix().dot(h.specific_force_se_m_s2.array().square().matrix()));
    } else if (q == Quantity::kTiltA || q == Quantity::kTiltB) {
      x = h.gravity_dir_body.dot(q == Quantity::kTiltA ? ea : eb);
      se = h.gravity_dir_se_rad;
    } else {
      x = h.gyro_bias_rad_s(gyro_axis);
      se = h.gyro_bias_se_rad_s(gyro_axis);
    }
    s.x.push_back(x);
    s.se.push_back(se);
    s.t_s.push_back(h.t_start_s);
    s.temp_c.push_back(h.temp_mean_c);
  }
  return s;
}

struct Learnt {
  double baseline = 0, sigma = 0, nu = 0;
};

Learnt Learn(const Series& s, int learning, double prior_sigma, double prior_checks) {
  Learnt l;
  l.baseline = MedianOrZero(std::vector<double>(s.x.begin(), s.x.begin() + learning));
  // The spread from every check's successive difference: a step or a wild check spoils one or
  // two differences (the MAD ignores them), a ramp or a season hardly moves them.
  std::vector<double> diff;
  for (size_t i = 1; i < s.x.size(); ++i) diff.push_back(s.x[i] - s.x[i - 1]);
  const double md = MedianOrZero(diff);
  std::vector<double> dev;
  for (double v : diff) dev.push_back(std::abs(v - md));
  const double mad = 1.4826 * MedianOrZero(dev) / std::sqrt(2.0);
  const double se_median = MedianOrZero(std::vector<double>(s.se.begin(), s.se.begin() + learning));
  const double prior = std::max(prior_sigma, se_median);
  const double learnt = kMadEfficiency * static_cast<double>(diff.size());
  l.nu = prior_checks + learnt;
  l.sigma = std::sqrt((prior_checks * prior * prior + learnt * mad * mad) / l.nu);
  l.sigma = std::max(l.sigma, se_median);
  return l;
}

// The self-starting scores (Hawkins 1987) from check `from` on: check n is standardised by the
// mean m and spread of the checks before it, the spread with the prior's nu0 pseudo-checks:
//   sigma^2 = (nu0 s0^2 + sum (x_i - m)^2) / (nu0 + n - 1),   r = (x_n - m) / (sigma sqrt(1 + 1/n))
// Student-t with nu0 + n - 1 degrees of freedom when nothing changed (the conjugate predictive),
// and, unlike residuals from one fixed baseline, independent from check to check: an error of a
// fixed baseline is in every later residual and a CUSUM adds it up. r is mapped to the normal
// score with the same tail probability. Never under the check's own SE.
std::vector<double> SelfStartingScores(const Series& s, int from, double prior_sigma,
                                       double prior_checks) {
  const boost::math::normal normal;
  std::vector<double> z(s.x.size(), 0.0);
  double sum = 0, sum_sq = 0;
  const double shift = s.x.front();  // sums about the first value: no cancellation
  for (int n = 0; n < static_cast<int>(s.x.size()); ++n) {
    const double v = s.x[n] - shift;
    if (n >= std::max(from, 2)) {
      const double m = sum / n;
      const double nu = prior_checks + n - 1;
      const double var = (prior_checks * prior_sigma * prior_sigma + sum_sq - n * m * m) / nu;
      const double sigma = std::max(std::sqrt(std::max(var, 0.0)), s.se[n]);
      const double r = (v - m) / (sigma * std::sqrt(1.0 + 1.0 / n));
      const boost::math::students_t t(nu);
      const double tail = boost::math::cdf(boost::math::complement(t, std::abs(r)));
      double g =
          tail > 1e-15 ? boost::math::quantile(boost::math::complement(normal, tail)) : kMaxScore;
      g = std::min(g, kMaxScore);
      z[n] = r < 0 ? -g : g;
    }
    sum += v;
    sum_sq += v * v;
  }
  return z;
}

struct CusumRun {
  std::vector<double> stat;
  int alarm = -1;
  int onset = -1;  // the check after the statistic's last zero before the alarm
};

CusumRun RunCusum(const std::vector<double>& z, int from, double k, double h) {
  CusumRun r;
  r.stat.assign(z.size(), 0.0);
  double up = 0, down = 0;
  int last_zero_up = from, last_zero_down = from;
  for (int i = from; i < static_cast<int>(z.size()); ++i) {
    up = std::max(0.0, up + z[i] - k);
    down = std::max(0.0, down - z[i] - k);
    if (up == 0) last_zero_up = i + 1;
    if (down == 0) last_zero_down = i + 1;
    r.stat[i] = std::max(up, down);
    if (r.alarm < 0 && r.stat[i] >= h) {
      r.alarm = i;
      r.onset = up >= h ? last_zero_up : last_zero_down;
    }
  }
  return r;
}

// Step against ramp (module header): both with a level a of their own before change point j
// (so the first checks' baseline error does not choose j), a + m after it (step) or
// a + beta (t - t_(j-1)) after it (ramp), least squares, j from `from` on; fills kind, onset,
// size, slope.
void ClassifyChange(const Series& s, const std::vector<double>& d, int from, double sigma,
                    QuantityEvidence* e) {
  const int n = static_cast<int>(d.size());
  double best_step = INFINITY, best_ramp = INFINITY, step = 0, slope = 0;
  int step_at = e->onset_check, ramp_at = e->onset_check;
  for (int j = std::max(from, 2); j < n; ++j) {
    double a = 0, pre = 0, m = 0;
    for (int i = 0; i < j; ++i) a += d[i] / j;
    for (int i = 0; i < j; ++i) pre += (d[i] - a) * (d[i] - a);
    for (int i = j; i < n; ++i) m += (d[i] - a) / (n - j);
    const double t0 = s.t_s[j - 1];
    double stt = 0, sdt = 0, rss_step = pre, rss_ramp = pre;
    for (int i = j; i < n; ++i) {
      const double dt = (s.t_s[i] - t0) / kDay_s;
      stt += dt * dt;
      sdt += (d[i] - a) * dt;
    }
    const double beta = stt > 0 ? sdt / stt : 0;
    for (int i = j; i < n; ++i) {
      rss_step += (d[i] - a - m) * (d[i] - a - m);
      const double r = d[i] - a - beta * (s.t_s[i] - t0) / kDay_s;
      rss_ramp += r * r;
    }
    if (rss_step < best_step) best_step = rss_step, step = m, step_at = j;
    if (n - j >= 3 && rss_ramp < best_ramp) best_ramp = rss_ramp, slope = beta, ramp_at = j;
  }
  const double margin = 2 * std::log(std::max(2, n - from)) * sigma * sigma;
  if (best_ramp < best_step - margin) {
    e->kind = ChangeKind::kDrift;
    e->onset_check = ramp_at;
    e->drift_per_day = slope;
  } else {
    e->kind = ChangeKind::kStep;
    e->onset_check = step_at;
    e->step_size = step;
  }
  e->onset_t_s = s.t_s[e->onset_check];
}

// x = a + c (T - Tmean) over every check with a temperature; false when the checks do not span
// min_temp_span_c. Fills the residuals (NaN temperature: the check's own deviation from a).
bool RegressOnTemperature(const Series& s, double min_span_c, std::vector<double>* residual,
                          double* coefficient, double* coefficient_se) {
  std::vector<int> idx;
  for (int i = 0; i < static_cast<int>(s.x.size()); ++i)
    if (!std::isnan(s.temp_c[i])) idx.push_back(i);
  if (idx.size() < 6) return false;
  double lo = INFINITY, hi = -INFINITY, tm = 0, xm = 0;
  for (int i : idx) lo = std::min(lo, s.temp_c[i]), hi = std::max(hi, s.temp_c[i]);
  if (hi - lo < min_span_c) return false;
  for (int i : idx) tm += s.temp_c[i], xm += s.x[i];
  tm /= idx.size();
  xm /= idx.size();
  double stt = 0, stx = 0;
  for (int i : idx)
    stt += (s.temp_c[i] - tm) * (s.temp_c[i] - tm), stx += (s.temp_c[i] - tm) * (s.x[i] - xm);
  *coefficient = stx / stt;
  double rss = 0;
  residual->assign(s.x.size(), 0.0);
  for (size_t i = 0; i < s.x.size(); ++i) {
    const double dt = std::isnan(s.temp_c[i]) ? 0.0 : s.temp_c[i] - tm;
    (*residual)[i] = s.x[i] - xm - *coefficient * dt;
    if (!std::isnan(s.temp_c[i])) rss += (*residual)[i] * (*residual)[i];
  }
  *coefficient_se = std::sqrt(rss / (idx.size() - 2) / stt);
  return true;
}

}  // namespace

const char* HealthStateName(HealthState state) {
  switch (state) {
    case HealthState::kOk:
      return "ok";
    case HealthState::kWatch:
      return "watch";
    case HealthState::kRecalibrate:
      return "recalibrate";
  }
  return "?";
}

const char* QuantityName(Quantity q) {
  static constexpr const char* kNames[kNumQuantities] = {"specific force along gravity",
                                                         "gravity direction (tilt a)",
                                                         "gravity direction (tilt b)",
                                                         "gyro bias x",
                                                         "gyro bias y",
                                                         "gyro bias z"};
  return kNames[static_cast<int>(q)];
}

const char* ChangeKindName(ChangeKind kind) {
  switch (kind) {
    case ChangeKind::kNone:
      return "";
    case ChangeKind::kStep:
      return "step";
    case ChangeKind::kDrift:
      return "drift";
    case ChangeKind::kTemperature:
      return "temperature";
  }
  return "?";
}

double SiegmundArl0(double k, double h) {
  const double b = h + 1.166;
  const double a = 2 * k * b;
  return (std::exp(a) - a - 1) / (2 * k * k);
}

double CusumArl0(double k, double h) {
  // Brook and Evans: the statistic on an atom at 0 and kBins cells of [0, h); from state s the
  // next is max(0, s + z - k), z ~ N(0, 1). ARL = (I - P)^-1 1, read at the atom.
  constexpr int kBins = 60;
  const auto phi = [](double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); };
  const double w = h / kBins;
  Eigen::MatrixXd a = Eigen::MatrixXd::Identity(kBins + 1, kBins + 1);
  for (int i = 0; i <= kBins; ++i) {
    const double s = i == 0 ? 0.0 : (i - 0.5) * w;
    a(i, 0) -= phi(k - s);
    for (int j = 1; j <= kBins; ++j) a(i, j) -= phi(j * w - s + k) - phi((j - 1) * w - s + k);
  }
  const Eigen::VectorXd arl = a.partialPivLu().solve(Eigen::VectorXd::Ones(kBins + 1));
  return arl(0);
}

double CusumThreshold(double k, double arl0) {
  // Siegmund's h to start, then the secant on log ARL(h) (nearly linear in h) to the chain's.
  double h0 = 0, hi = 100;
  for (int i = 0; i < 200; ++i) {
    const double mid = (h0 + hi) / 2;
    (SiegmundArl0(k, mid) < arl0 ? h0 : hi) = mid;
  }
  double h1 = h0 + 0.2;
  double f0 = std::log(CusumArl0(k, h0) / arl0), f1 = std::log(CusumArl0(k, h1) / arl0);
  for (int i = 0; i < 8 && std::abs(f1) > 1e-4 && f1 != f0; ++i) {
    const double h2 = std::max(0.01, h1 - f1 * (h1 - h0) / (f1 - f0));
    h0 = h1, f0 = f1, h1 = h2;
    f1 = std::log(CusumArl0(k, h1) / arl0);
  }
  return h1;
}

DriftReference ReferenceFromParams(const ParamSet& params, double activated_s) {
  DriftReference r;
  r.version = params.version;
  r.activated_s = activated_s;
  // The accel bias SE (input units) in m/s^2 through the scale; its RMS over the axes stands for
  // the direction a check reads along when the dock's is not known.
  const Eigen::Vector3d b = params.stderrs.accel.bias.cwiseProduct(params.accel.scale.cwiseAbs());
  r.along_gravity_se_m_s2 = b.allFinite() ? b.norm() / std::sqrt(3.0) : 0.0;
  if (params.has_gyro && params.stderrs.gyro_bias.allFinite())
    r.gyro_bias_se_rad_s =
        (params.gyro.matrix * params.stderrs.gyro_bias.asDiagonal()).rowwise().norm();
  return r;
}

namespace {

struct Design {
  double k = 2.5, h_alarm = 0, h_watch = 0;
  int learning = 8;
};

QuantityEvidence Evaluate(const Series& s, Quantity q, double prior_sigma, double version_se,
                          const Design& dz, const DriftOptions& opt) {
  QuantityEvidence e;
  e.quantity = q;
  e.tested = true;
  const int L = dz.learning;
  const Learnt l = Learn(s, L, prior_sigma, opt.prior_checks);
  e.baseline = l.baseline;
  e.spread = l.sigma;
  e.dof = l.nu;
  for (double v : s.x) e.residual.push_back(v - l.baseline);
  e.latest_change = e.residual.back();
  const CusumRun run =
      RunCusum(SelfStartingScores(s, L, prior_sigma, opt.prior_checks), L, dz.k, dz.h_alarm);
  e.cusum = run.stat;
  e.statistic = run.stat.back();
  e.alarm_check = run.alarm;
  e.onset_check = run.onset;
  if (version_se > 0) {
    const double sd =
        std::sqrt(version_se * version_se + l.sigma * l.sigma * (1 + kPi / (2.0 * L)));
    e.version_disagrees = std::abs(l.baseline) > opt.version_disagreement_sigmas * sd;
  }
  if (run.alarm < 0) return e;
  ClassifyChange(s, e.residual, L, l.sigma, &e);
  std::vector<double> r;
  double c = 0, c_se = 0;
  if (!RegressOnTemperature(s, opt.min_temp_span_c, &r, &c, &c_se)) return e;
  Series adjusted = s;
  adjusted.x = r;
  const Learnt la = Learn(adjusted, L, prior_sigma, opt.prior_checks);
  std::vector<double> d;
  for (double v : r) d.push_back(v - la.baseline);
  const CusumRun adj =
      RunCusum(SelfStartingScores(adjusted, L, prior_sigma, opt.prior_checks), L, dz.k, dz.h_alarm);
  e.temp_coefficient_per_c = c;
  e.temp_coefficient_se_per_c = c_se;
  if (adj.alarm < 0 && std::abs(c) > 3 * c_se) {
    e.kind = ChangeKind::kTemperature;
    e.alarm_check = -1;
    e.cusum = adj.stat;
    e.statistic = adj.stat.back();
    e.residual = d;
  }
  return e;
}

// A quantity's value as a technician reads it.
std::string Display(Quantity q, double v) {
  if (q == Quantity::kAlongGravity) return absl::StrFormat("%.2f mg", v / kStandardGravity * 1e3);
  if (q == Quantity::kTiltA || q == Quantity::kTiltB)
    return absl::StrFormat("%.3f deg", v * kRadToDeg);
  return absl::StrFormat("%.4f deg/s", v * kRadToDeg);
}

std::string Summarise(const DriftAssessment& a, const std::vector<HealthCheck>& c,
                      const DriftReference& ref) {
  if (a.checks < a.learning || a.worst < 0) {
    return absl::StrFormat("learning: %d of %d checks since version %d", a.checks, a.learning,
                           ref.version);
  }
  const QuantityEvidence& e = a.quantities[a.worst];
  const double t0 = ref.activated_s > 0 ? ref.activated_s : c.front().t_start_s;
  std::string what;
  if (e.kind == ChangeKind::kStep) {
    what = absl::StrFormat("stepped %s at check %d (day %.1f since version %d)",
                           Display(e.quantity, e.step_size), e.onset_check + 1,
                           (e.onset_t_s - t0) / kDay_s, ref.version);
  } else if (e.kind == ChangeKind::kDrift) {
    what = absl::StrFormat("drifts %s a day since check %d (day %.1f since version %d)",
                           Display(e.quantity, e.drift_per_day), e.onset_check + 1,
                           (e.onset_t_s - t0) / kDay_s, ref.version);
  } else if (e.kind == ChangeKind::kTemperature) {
    what = absl::StrFormat("follows temperature by %s per degC, which the stored effects miss",
                           Display(e.quantity, e.temp_coefficient_per_c));
  } else if (e.version_disagrees) {
    what = absl::StrFormat("reads %s from version %d's own figure since its first checks",
                           Display(e.quantity, e.baseline), ref.version);
  } else if (a.state == HealthState::kOk) {
    return absl::StrFormat(
        "ok: %d checks since version %d, the largest statistic %.1f of %.1f (%s)", a.checks,
        ref.version, e.statistic, a.threshold_alarm, QuantityName(e.quantity));
  } else {
    what = absl::StrFormat("moved %s (statistic %.1f of %.1f)",
                           Display(e.quantity, e.latest_change), e.statistic, a.threshold_alarm);
  }
  return std::string(QuantityName(e.quantity)) + ": " + what + ": " + HealthStateName(a.state);
}

}  // namespace

DriftAssessment AssessDrift(const std::vector<HealthCheck>& checks, const DriftReference& reference,
                            const DriftOptions& options) {
  std::vector<HealthCheck> c;
  for (const HealthCheck& h : checks)
    if (h.t_start_s >= reference.activated_s) c.push_back(h);
  std::stable_sort(c.begin(), c.end(), [](const HealthCheck& a, const HealthCheck& b) {
    return a.t_start_s < b.t_start_s;
  });
  DriftAssessment a;
  a.checks = static_cast<int>(c.size());
  a.learning = std::max(3, options.learning_checks);
  a.quantities.resize(kNumQuantities);
  for (int q = 0; q < kNumQuantities; ++q) a.quantities[q].quantity = static_cast<Quantity>(q);
  a.checks_per_day = options.checks_per_day;
  if (!(a.checks_per_day > 0)) {
    const double span_d = c.size() >= 4 ? (c.back().t_start_s - c.front().t_start_s) / kDay_s : 0;
    a.checks_per_day = span_d > 0 ? std::clamp((c.size() - 1) / span_d, 0.1, 48.0) : 1.5;
  }
  const bool gyro = !c.empty() && std::all_of(c.begin(), c.end(),
                                              [](const HealthCheck& h) { return h.has_gyro; });
  const bool tilt = options.fixed_orientation;
  const int statistics = 2 * (1 + (tilt ? 2 : 0) + (gyro ? 3 : 0));
  const double per_month = 30.0 * a.checks_per_day * statistics;
  Design dz;
  dz.learning = a.learning;
  dz.k = std::min(3.0, options.design_shift_sigmas / 2);
  dz.h_alarm = CusumThreshold(dz.k, per_month / options.false_alarms_per_device_month);
  dz.h_watch = CusumThreshold(dz.k, per_month / options.watch_alarms_per_device_month);
  a.design_k = dz.k;
  a.threshold_alarm = dz.h_alarm;
  a.threshold_watch = dz.h_watch;
  if (a.checks < a.learning) {
    a.summary = Summarise(a, c, reference);
    return a;
  }
  Eigen::Vector3d u0 = Eigen::Vector3d::Zero();
  for (int i = 0; i < a.learning; ++i) u0 += c[i].gravity_dir_body;
  u0 = reference.dock_gravity_dir_body.value_or(u0).normalized();
  for (int q = 0; q < kNumQuantities; ++q) {
    const Quantity quantity = static_cast<Quantity>(q);
    const bool is_tilt = quantity == Quantity::kTiltA || quantity == Quantity::kTiltB;
    const bool is_gyro = q >= static_cast<int>(Quantity::kGyroX);
    if ((is_tilt && !tilt) || (is_gyro && !gyro)) continue;
    double prior = options.accel_spread_prior_m_s2, version_se = reference.along_gravity_se_m_s2;
    if (is_tilt) prior = options.tilt_spread_prior_rad, version_se = 0;
    if (is_gyro) {
      prior = options.gyro_spread_prior_rad_s;
      version_se = reference.gyro_bias_se_rad_s(q - static_cast<int>(Quantity::kGyroX));
    }
    a.quantities[q] =
        Evaluate(SeriesOf(c, quantity, u0, tilt), quantity, prior, version_se, dz, options);
  }
  double worst = -1;
  for (int q = 0; q < kNumQuantities; ++q) {
    const QuantityEvidence& e = a.quantities[q];
    if (!e.tested) continue;
    HealthState s = HealthState::kOk;
    if (e.alarm_check >= 0) {
      s = HealthState::kRecalibrate;
    } else if (e.statistic >= dz.h_watch || e.version_disagrees) {
      s = HealthState::kWatch;
    }
    // The worst: the highest state, then the largest statistic over its threshold.
    const double rank = static_cast<int>(s) * 1e6 + e.statistic / dz.h_alarm +
                        (e.kind == ChangeKind::kTemperature ? 0.5 : 0.0);
    if (rank > worst) worst = rank, a.worst = q;
    a.state = std::max(a.state, s);
  }
  a.summary = Summarise(a, c, reference);
  return a;
}

}  // namespace imucal::core::health
