#include "core/allan.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "boost/math/distributions/chi_squared.hpp"
#include "core/math_guard.h"
#include "util/str_util.h"

namespace imucal::core {
namespace {

constexpr double kNaN = SensorNoise::kUnknown;
constexpr size_t kMinSamples = 64;
// A figure's region: local log-log slope within this of the figure's slope (-1/2, 0, +1/2).
constexpr double kSlopeTolerance = 0.25;
// The random walk needs this many cluster times on its slope past the minimum (~0.3 decade).
constexpr int kMinRandomWalkPoints = 3;
// ... and the curve must rise above its minimum by this factor (white noise alone scatters by
// up to ~30% at the longest usable cluster time, so a smaller rise proves nothing).
constexpr double kMinRise = 1.5;
// IEEE Std 952: the flat part of the curve of flicker (bias instability) noise is
// sqrt(2 ln 2 / pi) B = 0.664 B.
constexpr double kFlickerFloor = 0.664;
// The flat minimum (B) is looked for only at cluster times with at least this many clusters:
// flicker's deviation there scatters by ~1 / sqrt(2.5 * 30) = 12% (edf ~ 1.25 x clusters, NIST
// SP 1065 Table 5), a random walk's by ~13%; with 6 clusters, by 35% and more.
constexpr double kMinClustersForFloor = 30.0;

// Least-squares slope of log(adev) over log(tau) on points [lo, hi].
double LocalSlope(const std::vector<double>& log_tau, const std::vector<double>& log_adev,
                  size_t lo, size_t hi) {
  const double n = static_cast<double>(hi - lo + 1);
  double mx = 0, my = 0;
  for (size_t i = lo; i <= hi; ++i) mx += log_tau[i], my += log_adev[i];
  mx /= n;
  my /= n;
  double sxy = 0, sxx = 0;
  for (size_t i = lo; i <= hi; ++i) {
    sxy += (log_tau[i] - mx) * (log_adev[i] - my);
    sxx += (log_tau[i] - mx) * (log_tau[i] - mx);
  }
  return sxx > 0 ? sxy / sxx : 0.0;
}

std::string AxisList(const std::vector<int>& axes) {
  static constexpr const char* kNames[3] = {"x", "y", "z"};
  std::string out;
  for (size_t i = 0; i < axes.size(); ++i) AppendTo(&out, i ? ", " : "", kNames[axes[i]]);
  return out;
}

// Notes for one sensor: which figure no axis (or only some axes) reached.
void AddNotes(const char* sensor, const SensorNoise& s, double tau_max_s,
              std::vector<std::string>* notes) {
  auto missing = [](const Eigen::Vector3d& v) {
    std::vector<int> axes;
    for (int i = 0; i < 3; ++i)
      if (std::isnan(v(i))) axes.push_back(i);
    return axes;
  };
  if (auto a = missing(s.noise_density); !a.empty()) {
    notes->push_back(Cat(sensor, " noise density not reached on ", AxisList(a),
                         ": no part of the curve has slope -1/2 (quantised or correlated "
                         "noise?)"));
  }
  if (auto a = missing(s.bias_instability); !a.empty()) {
    notes->push_back(
        Cat(sensor, " bias instability not reached on ", AxisList(a),
            ": the curve still falls at the longest cluster time with ", kMinClustersForFloor,
            " clusters (~",
            absl::StrFormat("%.3g", tau_max_s * kMinClustersForFit / kMinClustersForFloor),
            " s); a longer rest would show its flat minimum"));
  }
  if (auto a = missing(s.random_walk); !a.empty()) {
    notes->push_back(Cat(sensor, " random walk not reached on ", AxisList(a),
                         ": the curve does not rise with slope +1/2 before ",
                         absl::StrFormat("%.3g", tau_max_s),
                         " s; random_walk_bound is an upper bound, not a measurement (typical "
                         "MEMS needs a rest of an hour or more)"));
  }
}

}  // namespace

namespace {

// Adds, for each cluster size m (in samples), the sum of the squared second differences of the
// series' integral over that cluster time to sums[j] and their count to terms[j] (nothing for a
// cluster size the series is too short for). The mean is removed first so that theta stays
// small and the second differences keep their digits.
void AccumulateAllanSums(const std::vector<double>& x, double rate_hz,
                         const std::vector<size_t>& cluster_sizes, std::vector<double>* sums,
                         std::vector<double>* terms) {
  const size_t n = x.size();
  const double tau0 = 1.0 / rate_hz;
  double mean = 0;
  for (double v : x) mean += v;
  mean /= static_cast<double>(std::max<size_t>(n, 1));
  // theta: the integral of x (cumulative sum times the sample interval), n + 1 values.
  std::vector<double> theta(n + 1, 0.0);
  for (size_t i = 0; i < n; ++i) theta[i + 1] = theta[i] + (x[i] - mean) * tau0;
  for (size_t j = 0; j < cluster_sizes.size(); ++j) {
    const size_t m = cluster_sizes[j];
    if (m == 0 || 2 * m > n) continue;
    double sum = 0;
    const size_t count = n - 2 * m + 1;
    for (size_t k = 0; k < count; ++k) {
      const double d = theta[k + 2 * m] - 2.0 * theta[k + m] + theta[k];
      sum += d * d;
    }
    (*sums)[j] += sum;
    (*terms)[j] += static_cast<double>(count);
  }
}

}  // namespace

std::vector<double> OverlappingAllanDeviation(const std::vector<double>& x, double rate_hz,
                                              const std::vector<size_t>& cluster_sizes) {
  std::vector<double> sums(cluster_sizes.size(), 0.0), terms(cluster_sizes.size(), 0.0);
  AccumulateAllanSums(x, rate_hz, cluster_sizes, &sums, &terms);
  std::vector<double> out;
  out.reserve(cluster_sizes.size());
  for (size_t j = 0; j < cluster_sizes.size(); ++j) {
    const double tau = static_cast<double>(cluster_sizes[j]) * (1.0 / rate_hz);
    out.push_back(terms[j] > 0 ? std::sqrt(sums[j] / (2.0 * tau * tau * terms[j])) : kNaN);
  }
  return out;
}

std::vector<size_t> LogSpacedClusterSizes(size_t n, int per_decade) {
  std::vector<size_t> out;
  if (n < 3) return out;
  const size_t m_max = (n - 1) / 2;
  for (int k = 0;; ++k) {
    const auto m = static_cast<size_t>(std::llround(std::pow(10.0, k / double(per_decade))));
    if (m > m_max) break;
    if (out.empty() || m > out.back()) out.push_back(m);
  }
  return out;
}

namespace {

// The curve in log-log coordinates over its usable points, with each point's local slope and
// weight (~ independent clusters).
struct LogCurve {
  std::vector<double> lt, la, w, slope;
  size_t size() const { return lt.size(); }
};

bool NearSlope(double s, double target) { return std::abs(s - target) <= kSlopeTolerance; }

// N: the first run of points with slope -1/2; the line of slope -1/2 through them (weighted mean
// of log(adev sqrt(tau))), read at tau = 1 s.
void FitWhite(const LogCurve& c, AxisFigures* f) {
  const size_t n = c.size();
  size_t i = 0;
  while (i < n && !NearSlope(c.slope[i], -0.5)) ++i;
  double sw = 0, swl = 0;
  size_t nearest_1s = n;
  for (; i < n && NearSlope(c.slope[i], -0.5); ++i) {
    sw += c.w[i], swl += c.w[i] * (c.la[i] + 0.5 * c.lt[i]);
    if (nearest_1s == n || std::abs(c.lt[i]) < std::abs(c.lt[nearest_1s])) nearest_1s = i;
  }
  if (sw > 0) {
    f->noise_density = std::exp(swl / sw);
    f->noise_density_tau_s = std::exp(c.lt[nearest_1s]);
  }
}

// K: reached when, past the curve's minimum, at least kMinRandomWalkPoints cluster times have
// slope +1/2 and the curve has risen by kMinRise. Every point past the minimum then estimates
// K^2 = (avar - N^2 / tau) * 3 / tau (the white part removed, unbiased like avar); they are
// averaged with weights clusters * (share of the random walk in avar)^2, the inverse relative
// variance of each estimate, refined twice from the current K. Not reached: a bound.
void FitRandomWalk(const LogCurve& c, AxisFigures* f) {
  const size_t n = c.size();
  const auto k_min = static_cast<size_t>(std::min_element(c.la.begin(), c.la.end()) - c.la.begin());
  int rising = 0;
  double highest_after_min = c.la[k_min];
  for (size_t k = k_min + 1; k < n; ++k) {
    rising += NearSlope(c.slope[k], 0.5);
    highest_after_min = std::max(highest_after_min, c.la[k]);
  }
  if (rising >= kMinRandomWalkPoints && highest_after_min - c.la[k_min] > std::log(kMinRise)) {
    const double white = std::isnan(f->noise_density) ? 0.0 : f->noise_density * f->noise_density;
    double k2 = 0;
    size_t heaviest = k_min;  // the point of largest weight in the last pass
    for (int pass = 0; pass < 3; ++pass) {
      double sw = 0, swl = 0;
      double heaviest_weight = -1;
      for (size_t k = k_min; k < n; ++k) {
        const double tau = std::exp(c.lt[k]);
        const double avar = std::exp(2 * c.la[k]);
        const double share = pass == 0 ? 1.0 : (k2 * tau / 3) / (white / tau + k2 * tau / 3);
        sw += c.w[k] * share * share;
        swl += c.w[k] * share * share * (avar - white / tau) * 3.0 / tau;
        if (c.w[k] * share * share > heaviest_weight)
          heaviest_weight = c.w[k] * share * share, heaviest = k;
      }
      k2 = sw > 0 ? swl / sw : 0.0;
      if (!(k2 > 0)) break;
    }
    if (k2 > 0) {
      f->random_walk = std::sqrt(k2);
      f->random_walk_tau_s = std::exp(c.lt[heaviest]);
    }
  }
  if (std::isnan(f->random_walk)) {
    f->random_walk_bound = std::exp(c.la.back()) * std::sqrt(3.0 / f->tau_max_fit_s);
  }
}

// B: the minimum of the curve, if it is flat there (slope 0) after a falling part. Searched only
// where there are kMinClustersForFloor clusters: the last cluster times (6-30 clusters, a few
// degrees of freedom) scatter so much that a minimum picks their dips. Searched over the whole
// curve, pure white noise on a 30 s rest showed a "floor" on 6 of 54 simulated series
// (WhiteNoiseDensityFromSimulatedRest), and 1-hour white + flicker + random-walk rests gave B NaN
// or up to 14% low on 7 of 120 axes where the tail dipped below the floor (searched from 30
// clusters: 1 of 120 NaN, none off by more than 7%).
void FitFloor(const LogCurve& c, AxisFigures* f) {
  const size_t n = c.size();
  size_t n_floor = 0;
  while (n_floor < n && c.w[n_floor] >= kMinClustersForFloor) ++n_floor;
  if (n_floor < 3) return;
  const auto k_floor = static_cast<size_t>(
      std::min_element(c.la.begin(), c.la.begin() + static_cast<std::ptrdiff_t>(n_floor)) -
      c.la.begin());
  bool fell_before = false;
  for (size_t k = 0; k < k_floor; ++k) fell_before |= c.slope[k] < -kSlopeTolerance;
  if (fell_before && NearSlope(c.slope[k_floor], 0.0) && k_floor + 1 < n_floor) {
    f->bias_instability = std::exp(c.la[k_floor]) / kFlickerFloor;
    f->bias_instability_tau_s = std::exp(c.lt[k_floor]);
  }
}

}  // namespace

AxisFigures FitAllanFigures(const std::vector<double>& tau_s, const std::vector<double>& adev,
                            double duration_s) {
  AxisFigures f;
  // The usable points: enough independent clusters, a positive finite deviation.
  LogCurve c;
  for (size_t i = 0; i < tau_s.size(); ++i) {
    if (duration_s / tau_s[i] < kMinClustersForFit || !(adev[i] > 0) || !std::isfinite(adev[i]))
      continue;
    c.lt.push_back(std::log(tau_s[i]));
    c.la.push_back(std::log(adev[i]));
    c.w.push_back(duration_s / tau_s[i]);  // ~ independent clusters: the weight of the point
  }
  const size_t n = c.size();
  if (n < 3) return f;
  f.tau_max_fit_s = std::exp(c.lt.back());
  c.slope.resize(n);
  for (size_t i = 0; i < n; ++i)
    c.slope[i] = LocalSlope(c.lt, c.la, i < 2 ? 0 : i - 2, std::min(n - 1, i + 2));
  FitWhite(c, &f);
  FitRandomWalk(c, &f);
  FitFloor(c, &f);
  return f;
}

double AllanEdf(AllanNoise noise, size_t n, size_t m) {
  const double N = static_cast<double>(n) + 1;  // phase points
  const double M = static_cast<double>(m);
  double edf = kNaN;
  switch (noise) {
    case AllanNoise::kWhite:
      edf = (3 * (N - 1) / (2 * M) - 2 * (N - 2) / N) * 4 * M * M / (4 * M * M + 5);
      break;
    case AllanNoise::kFlicker:
      edf = m == 1 ? 2 * (N - 2) / (2.3 * N - 4.9) : 5 * N * N / (4 * M * (N + 3 * M));
      break;
    case AllanNoise::kRandomWalk:
      edf = (N - 2) / M * ((N - 1) * (N - 1) - 3 * M * (N - 1) + 4 * M * M) / ((N - 3) * (N - 3));
      break;
  }
  return edf > 0 ? edf : kNaN;
}

AxisReadings ReadAllanFigures(const std::vector<double>& tau_s, const std::vector<double>& adev,
                              size_t n, double rate_hz) {
  const double duration_s = static_cast<double>(n) / rate_hz;
  const AxisFigures f = FitAllanFigures(tau_s, adev, duration_s);
  // A figure is a fixed multiple of the deviation it was read from, so its interval is the
  // deviation's: adev^2 edf / avar is chi-squared with edf degrees of freedom.
  // The factors (low, high) that take a deviation measured at cluster time tau to its interval.
  auto interval = [&](AllanNoise noise, double tau) -> std::pair<double, double> {
    const auto m = static_cast<size_t>(std::max(1.0, std::round(tau * rate_hz)));
    const double edf = AllanEdf(noise, n, m);
    if (!(edf > 0) || !std::isfinite(edf)) return {kNaN, kNaN};
    const boost::math::chi_squared chi2(edf);
    return {std::sqrt(edf / MathOr(kNaN, [&] { return boost::math::quantile(chi2, 0.975); })),
            std::sqrt(edf / MathOr(kNaN, [&] { return boost::math::quantile(chi2, 0.025); }))};
  };
  auto read = [&](double value, double tau, double (*factor)(double), AllanNoise noise,
                  AllanReading* out) {
    if (!std::isnan(value)) {
      const auto [low, high] = interval(noise, tau);
      *out = AllanReading{value, tau, value * low, value * high, false};
      return;
    }
    // Not reached: the bound is the least 95% upper limit over the usable cluster times.
    for (size_t i = 0; i < tau_s.size(); ++i) {
      if (duration_s / tau_s[i] < kMinClustersForFit || !(adev[i] > 0) || !std::isfinite(adev[i]))
        continue;
      const double bound = factor(tau_s[i]) * adev[i] * interval(noise, tau_s[i]).second;
      if (std::isnan(out->value) || bound < out->value) {
        *out = AllanReading{bound, tau_s[i], kNaN, bound, true};
      }
    }
  };
  AxisReadings r;
  read(
      f.noise_density, f.noise_density_tau_s, [](double tau) { return std::sqrt(tau); },
      AllanNoise::kWhite, &r.noise_density);
  read(
      f.bias_instability, f.bias_instability_tau_s, [](double) { return 1 / kFlickerFloor; },
      AllanNoise::kFlicker, &r.bias_instability);
  read(
      f.random_walk, f.random_walk_tau_s, [](double tau) { return std::sqrt(3 / tau); },
      AllanNoise::kRandomWalk, &r.random_walk);
  return r;
}

absl::StatusOr<NoiseAnalysis> ComputeNoise(const Capture& capture, size_t begin, size_t end,
                                           const AccelParams& accel, const GyroParams& gyro) {
  return ComputeNoise(capture, begin, end, SampleCorrection(accel, gyro, {}, 0.0));
}

absl::StatusOr<NoiseAnalysis> ComputeNoise(const Capture& capture, size_t begin, size_t end,
                                           const SampleCorrection& correction) {
  // Both sensors' figures read every sample's gyro: refused rather than read past an empty one.
  if (!capture.has_gyro) {
    return absl::FailedPreconditionError(
        "the capture has no gyroscope (noise figures are computed for both sensors; an "
        "accelerometer-only capture's accelerometer figures are in `imucal calibrate`'s noise "
        "block)");
  }
  if (begin >= end || end > capture.size()) {
    return absl::InvalidArgumentError(Cat("noise interval [", begin, ", ", end,
                                          ") outside the capture of ", capture.size(), " samples"));
  }
  return ComputeNoiseOfSegments(capture, {SampleRange{begin, end}}, correction);
}

namespace {

// The rate of the segments' samples: that of the median interval inside them (uniform sampling
// is assumed), rounded to a micro-hertz: the median of float time stamps is a nominal rate plus
// noise (200.00000000000426 Hz), and the rate is written into files robots read. NaN when time
// does not increase.
double SegmentsRateHz(const Capture& capture, const std::vector<SampleRange>& segments) {
  std::vector<double> dt;
  for (const SampleRange& r : segments)
    for (size_t i = r.begin + 1; i < r.end; ++i) dt.push_back(capture.t_s[i] - capture.t_s[i - 1]);
  if (dt.empty()) return kNaN;
  std::nth_element(dt.begin(), dt.begin() + static_cast<std::ptrdiff_t>(dt.size() / 2), dt.end());
  const double median_dt = dt[dt.size() / 2];
  return median_dt > 0 ? std::round(1e6 / median_dt) / 1e6 : kNaN;
}

absl::Status CheckSegments(const Capture& capture, const std::vector<SampleRange>& segments) {
  size_t previous_end = 0, longest = 0;
  for (const SampleRange& r : segments) {
    if (r.begin >= r.end || r.end > capture.size() || r.begin < previous_end) {
      return absl::InvalidArgumentError(Cat("noise interval [", r.begin, ", ", r.end,
                                            ") outside the capture of ", capture.size(),
                                            " samples, or not after the previous one"));
    }
    previous_end = r.end;
    longest = std::max(longest, r.size());
  }
  if (longest < kMinSamples) {
    return absl::FailedPreconditionError(Cat("noise interval of ", longest,
                                             " samples is too short for an Allan deviation (at "
                                             "least ",
                                             kMinSamples, ")"));
  }
  return absl::OkStatus();
}

// One axis' pooled deviation over the segments (k: accel x, y, z, gyro x, y, z), calibrated by
// `correction` one sample at a time: memory is one segment's series (and its integral).
std::vector<double> PooledAxisDeviation(const Capture& capture,
                                        const std::vector<SampleRange>& segments,
                                        const SampleCorrection& correction, int k, double rate_hz,
                                        const std::vector<size_t>& m) {
  std::vector<double> sums(m.size(), 0.0), terms(m.size(), 0.0), series;
  for (const SampleRange& r : segments) {
    series.clear();
    series.reserve(r.size());
    for (size_t i = r.begin; i < r.end; ++i) {
      const CorrectedSample corrected = correction.Apply(
          capture.accel[i], capture.gyro[i],
          capture.has_temp() ? capture.temp[i] : std::numeric_limits<double>::quiet_NaN(),
          capture.t_s[i]);
      series.push_back(k < 3 ? corrected.accel_m_s2(k) : corrected.gyro_rad_s(k - 3));
    }
    AccumulateAllanSums(series, rate_hz, m, &sums, &terms);
  }
  std::vector<double> adev(m.size(), kNaN);
  for (size_t j = 0; j < m.size(); ++j) {
    // Pieces: only the segments long enough for this cluster size hold its clusters.
    size_t contributing = 0;
    for (const SampleRange& r : segments) contributing += 2 * m[j] <= r.size() ? r.size() : 0;
    if (segments.size() > 1 &&
        static_cast<double>(contributing) / static_cast<double>(m[j]) < kMinClustersForFit)
      continue;
    const double tau = static_cast<double>(m[j]) * (1.0 / rate_hz);
    if (terms[j] > 0) adev[j] = std::sqrt(sums[j] / (2.0 * tau * tau * terms[j]));
  }
  return adev;
}

}  // namespace

absl::StatusOr<NoiseAnalysis> ComputeNoiseOfSegments(const Capture& capture,
                                                     const std::vector<SampleRange>& segments,
                                                     const SampleCorrection& correction) {
  if (segments.empty()) return absl::InvalidArgumentError("noise: no interval to analyse");
  if (absl::Status s = CheckSegments(capture, segments); !s.ok()) return s;
  const double rate_hz = SegmentsRateHz(capture, segments);
  if (!(rate_hz > 0)) return absl::InvalidArgumentError("noise interval: time does not increase");
  size_t n = 0, longest = 0;
  for (const SampleRange& r : segments) n += r.size(), longest = std::max(longest, r.size());

  const std::vector<size_t> m = LogSpacedClusterSizes(longest);
  NoiseAnalysis out;
  out.segments = segments;
  NoiseFigures& nf = out.figures;
  nf.t_start_s = capture.t_s[segments.front().begin];
  nf.t_end_s = capture.t_s[segments.back().end - 1];
  nf.samples = static_cast<int64_t>(n);
  nf.rate_hz = rate_hz;
  AllanCurves& c = out.curves;
  for (size_t mi : m) c.tau_s.push_back(static_cast<double>(mi) / rate_hz);
  c.accel_m_s2.assign(m.size(), Eigen::Vector3d::Zero());
  c.gyro_rad_s.assign(m.size(), Eigen::Vector3d::Zero());
  const double duration_s = static_cast<double>(n) / rate_hz;
  double tau_max_s = 0;
  for (int k = 0; k < 6; ++k) {
    const std::vector<double> adev =
        PooledAxisDeviation(capture, segments, correction, k, rate_hz, m);
    out.readings[static_cast<size_t>(k)] = ReadAllanFigures(c.tau_s, adev, n, rate_hz);
    for (size_t j = 0; j < m.size(); ++j) (k < 3 ? c.accel_m_s2 : c.gyro_rad_s)[j](k % 3) = adev[j];
    const AxisFigures f = FitAllanFigures(c.tau_s, adev, duration_s);
    SensorNoise& s = k < 3 ? nf.accel : nf.gyro;
    s.noise_density(k % 3) = f.noise_density;
    s.bias_instability(k % 3) = f.bias_instability;
    s.random_walk(k % 3) = f.random_walk;
    s.random_walk_bound(k % 3) = f.random_walk_bound;
    tau_max_s = std::max(tau_max_s, f.tau_max_fit_s);
  }
  AddNotes("accel", nf.accel, tau_max_s, &nf.notes);
  AddNotes("gyro", nf.gyro, tau_max_s, &nf.notes);
  return out;
}

absl::StatusOr<NoiseAnalysis> NoiseFromLongestInterval(const Capture& capture,
                                                       const std::vector<StaticInterval>& intervals,
                                                       const ParamSet& params) {
  const StaticInterval* longest = nullptr;
  for (const StaticInterval& iv : intervals) {
    if (iv.used && (longest == nullptr || iv.samples() > longest->samples())) longest = &iv;
  }
  if (longest == nullptr) return absl::FailedPreconditionError("no used static interval");
  absl::StatusOr<NoiseAnalysis> out =
      ComputeNoise(capture, longest->begin, longest->end,
                   SampleCorrection(params, capture.t_s.empty() ? 0.0 : capture.t_s.front()));
  if (out.ok() && !params.gyro_calibrated && params.gyro_unit == GyroUnit::kCounts) {
    // A nominal matrix on raw counts gives no rad/s: the gyro figures would be in counts.
    out->figures.gyro = SensorNoise{};
    out->figures.notes.push_back(
        "gyro noise not stated: the gyroscope's scale (counts to rad/s) "
        "was not determined");
  }
  return out;
}

}  // namespace imucal::core
