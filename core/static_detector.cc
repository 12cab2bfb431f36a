#include "core/static_detector.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "absl/strings/str_format.h"

namespace imucal::core {
namespace {

// Prefix sums of x - x0 and (x - x0)^2 per axis. The offset x0 (the first sample) keeps the
// sums well conditioned for raw counts around 32768.
struct PrefixMoments {
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector3d> s1, s2;

  explicit PrefixMoments(const std::vector<Eigen::Vector3d>& x) {
    if (!x.empty()) offset = x.front();
    s1.assign(x.size() + 1, Eigen::Vector3d::Zero());
    s2.assign(x.size() + 1, Eigen::Vector3d::Zero());
    for (size_t i = 0; i < x.size(); ++i) {
      const Eigen::Vector3d d = x[i] - offset;
      s1[i + 1] = s1[i] + d;
      s2[i + 1] = s2[i] + d.cwiseProduct(d);
    }
  }
  // Per-axis mean over [b, e) (b < e).
  Eigen::Vector3d Mean(size_t b, size_t e) const {
    return offset + (s1[e] - s1[b]) / static_cast<double>(e - b);
  }
  // Unbiased per-axis variance over [b, e).
  Eigen::Vector3d Variance(size_t b, size_t e) const {
    const double n = static_cast<double>(e - b);
    if (n < 2) return Eigen::Vector3d::Zero();
    const Eigen::Vector3d m1 = s1[e] - s1[b];
    const Eigen::Vector3d m2 = s2[e] - s2[b];
    return ((m2 - m1.cwiseProduct(m1) / n) / (n - 1)).cwiseMax(0.0);
  }
};

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

// The step of the grid axis `j` of the readings sits on (input units), or 0 when it sits on none:
// the smallest difference between distinct values, when every difference between neighbouring
// distinct values is a whole multiple of it (to 1e-6 of the step: the readings are decimal text,
// so 0.07 - 0.06 is not exactly 0.01). At most 65536 readings, evenly spread, are looked at.
double GridStep(const std::vector<Eigen::Vector3d>& x, int j) {
  const size_t stride = std::max<size_t>(1, x.size() / 65536);
  std::vector<double> v;
  for (size_t i = 0; i < x.size(); i += stride) v.push_back(x[i](j));
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
  if (v.size() < 2) return 0.0;
  const double magnitude = std::max(std::abs(v.front()), std::abs(v.back()));
  // Differences at the readings' own rounding are not a grid.
  const double tiny = 1e-12 * magnitude;
  double step = std::numeric_limits<double>::infinity();
  for (size_t i = 1; i < v.size(); ++i)
    if (v[i] - v[i - 1] > tiny) step = std::min(step, v[i] - v[i - 1]);
  if (!std::isfinite(step)) return 0.0;
  for (size_t i = 1; i < v.size(); ++i) {
    const double k = (v[i] - v[i - 1]) / step;
    if (std::abs(k - std::round(k)) > 1e-6 * std::max(1.0, k) + tiny / step) return 0.0;
  }
  return step;
}

Eigen::Vector3d GridSteps(const std::vector<Eigen::Vector3d>& x) {
  return Eigen::Vector3d(GridStep(x, 0), GridStep(x, 1), GridStep(x, 2));
}

// The floor of a sensor's per-axis noise std: a grid step's rounding (step / sqrt(12)), and
// 1e-6 of the largest reading (readings a noiseless rest leaves constant).
Eigen::Vector3d NoiseFloor(const std::vector<Eigen::Vector3d>& x, const Eigen::Vector3d& step) {
  double magnitude = 0;
  for (const Eigen::Vector3d& v : x) magnitude = std::max(magnitude, v.cwiseAbs().maxCoeff());
  return (step / std::sqrt(12.0)).cwiseMax(1e-6 * magnitude).cwiseMax(1e-12);
}

// Per-axis noise std over the longest run of samples whose window variance is at the floor.
Eigen::Vector3d RunStd(const std::vector<Eigen::Vector3d>& x, size_t b, size_t e) {
  return PrefixMoments(std::vector<Eigen::Vector3d>(x.begin() + static_cast<long>(b),
                                                    x.begin() + static_cast<long>(e)))
      .Variance(0, e - b)
      .cwiseSqrt();
}

// Saturation: a rail is the extreme value of an axis over the whole capture; a static interval
// piled up on it (a fifth of its samples or more) reads the rail, not the signal. A rail also
// flattens the noise: an axis whose sensor shows noise (its noise std over 1.5 x the floor of
// its grid) and reads the same value through a fifth of a rest does not. A sensor that shows no
// noise (readings constant at rest: noise-free, or quieter than its grid) reads its extreme at
// rest legitimately; nothing tells a rail there, and the fit's residuals judge it.
bool PiledOnRail(const std::array<std::vector<uint32_t>, 3>& at_rail, size_t b, size_t e,
                 const Eigen::Vector3d& noise_std, const Eigen::Vector3d& noise_floor, int* axis) {
  for (int j = 0; j < 3; ++j) {
    if (!(noise_std(j) > 1.5 * noise_floor(j))) continue;
    const std::vector<uint32_t>& v = at_rail[static_cast<size_t>(j)];
    const size_t count = static_cast<size_t>(std::lower_bound(v.begin(), v.end(), e) -
                                             std::lower_bound(v.begin(), v.end(), b));
    if (count * 5 >= e - b && count >= 3) {
      *axis = j;
      return true;
    }
  }
  return false;
}

// The samples of each axis that read its extreme (`lo` or `hi`).
std::array<std::vector<uint32_t>, 3> AtRail(const std::vector<Eigen::Vector3d>& x,
                                            const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  std::array<std::vector<uint32_t>, 3> out;
  for (size_t i = 0; i < x.size(); ++i)
    for (int j = 0; j < 3; ++j)
      if (x[i](j) == lo(j) || x[i](j) == hi(j))
        out[static_cast<size_t>(j)].push_back(static_cast<uint32_t>(i));
  return out;
}

void Extremes(const std::vector<Eigen::Vector3d>& x, Eigen::Vector3d* lo, Eigen::Vector3d* hi) {
  *lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  *hi = -*lo;
  for (const auto& v : x) {
    *lo = lo->cwiseMin(v);
    *hi = hi->cwiseMax(v);
  }
}

// A run of samples whose window variances are under both thresholds: [begin, end).
struct Run {
  size_t begin = 0, end = 0;
};

// The maximal runs of samples where `still(i)` holds.
template <typename Still>
std::vector<Run> RunsWhere(size_t n, Still still) {
  std::vector<Run> out;
  for (size_t i = 0; i < n;) {
    if (!still(i)) {
      ++i;
      continue;
    }
    size_t j = i;
    while (j < n && still(j)) ++j;
    out.push_back({i, j});
    i = j;
  }
  return out;
}

// Runs under both variance thresholds, and the steady runs (MotionSignal::mean_shift) that no
// variance run touches: a rest too noisy for the variance test at any multiplier (a motor
// running). A steady run beside a variance run is the same rest's edge, where a hand's slow
// start of the next move shifts the mean less than its noise: the variance test sees that start
// earlier, so there it decides. A steady run loses half a window at each end for the same reason.
std::vector<Run> StillRuns(const MotionSignal& motion, double acc_threshold, double gyr_threshold) {
  const size_t n = motion.accel_var.size();
  std::vector<Run> out = RunsWhere(n, [&](size_t i) {
    return motion.accel_var[i] <= acc_threshold && motion.gyro_var[i] <= gyr_threshold;
  });
  if (motion.mean_shift.empty()) return out;
  const size_t half = motion.window / 2;
  std::vector<bool> in_variance_run(n, false);
  for (const Run& r : out)
    for (size_t i = r.begin; i < r.end; ++i) in_variance_run[i] = true;
  for (const Run& r :
       RunsWhere(n, [&](size_t i) { return motion.mean_shift[i] <= kSteadyMeanShift; })) {
    bool touches = false;
    for (size_t i = r.begin; i < r.end && !touches; ++i) touches = in_variance_run[i];
    if (touches || r.end - r.begin <= 2 * half) continue;
    out.push_back({r.begin + half, r.end - half});
  }
  std::sort(out.begin(), out.end(), [](const Run& a, const Run& b) { return a.begin < b.begin; });
  return out;
}

// The gyroscope's rate at rest: the duration-weighted median over the intervals of each axis'
// mean (a steady turn is a short minority of a capture), and how far a rest may read from it.
struct RateReference {
  Eigen::Vector3d bias = Eigen::Vector3d::Zero();
  Eigen::Vector3d tolerance = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
};

constexpr double kTurningNoiseStd = 5.0;
constexpr double kTurningSpreads = 5.0;

double WeightedMedian(std::vector<std::pair<double, double>> value_weight) {
  std::sort(value_weight.begin(), value_weight.end());
  double total = 0;
  for (const auto& [v, w] : value_weight) total += w;
  double sum = 0;
  for (const auto& [v, w] : value_weight) {
    sum += w;
    if (sum >= 0.5 * total) return v;
  }
  return value_weight.empty() ? 0.0 : value_weight.back().first;
}

RateReference GyroRateReference(const Capture& capture, const std::vector<Run>& runs,
                                const NoiseLevel& noise, const StaticDetectorOptions& options) {
  RateReference out;
  // The runs long enough to be poses, else all of them.
  std::vector<StaticInterval> rests;
  for (const Run& r : runs) {
    if (r.end <= r.begin + 1) continue;
    StaticInterval s = SummariseInterval(capture, r.begin, r.end);
    if (s.t_end_s - s.t_start_s >= options.min_static_s) rests.push_back(s);
  }
  if (rests.empty()) {
    for (const Run& r : runs)
      if (r.end > r.begin + 1) rests.push_back(SummariseInterval(capture, r.begin, r.end));
  }
  if (rests.empty()) return out;
  for (int j = 0; j < 3; ++j) {
    std::vector<std::pair<double, double>> mean_samples;
    for (const StaticInterval& s : rests)
      mean_samples.emplace_back(s.gyro_mean(j), static_cast<double>(s.samples()));
    out.bias(j) = WeightedMedian(mean_samples);
    std::vector<std::pair<double, double>> deviation;
    for (const StaticInterval& s : rests)
      deviation.emplace_back(std::abs(s.gyro_mean(j) - out.bias(j)), 1.0);
    const double spread = 1.4826 * WeightedMedian(deviation);  // MAD, as a std
    out.tolerance(j) = std::max(kTurningNoiseStd * noise.gyro_std(j), kTurningSpreads * spread);
  }
  return out;
}

// True when the gyroscope's mean over `s` is off its rest by more than the tolerance; `axis`
// and `rate` say where and how much.
bool Turning(const StaticInterval& s, const RateReference& rate, int* axis, double* off) {
  for (int j = 0; j < 3; ++j) {
    *off = s.gyro_mean(j) - rate.bias(j);
    if (std::abs(*off) > rate.tolerance(j)) {
      *axis = j;
      return true;
    }
  }
  return false;
}

// The "moved" test between two sets of samples of one pose: their accelerometer means differ by
// more than the noise of the means AND by more than the per-sample noise (slow thermal drift of a
// long rest stays below). Sets `axis` and `shift` (in noise std) when they do.
bool MeansDiffer(const StaticInterval& a, const StaticInterval& b, const NoiseLevel& noise,
                 const StaticDetectorOptions& options, int* axis, double* shift_std) {
  const Eigen::Vector3d shift = (b.accel_mean - a.accel_mean).cwiseAbs();
  const Eigen::Vector3d sigma_means =
      noise.accel_std.cwiseMax(0.5 * (a.accel_std + b.accel_std)) *
      std::sqrt(1.0 / static_cast<double>(a.samples()) + 1.0 / static_cast<double>(b.samples()));
  for (int k = 0; k < 3; ++k) {
    if (shift(k) > options.moved_sigma * sigma_means(k) && shift(k) > 3 * noise.accel_std(k)) {
      *axis = k;
      *shift_std = shift(k) / noise.accel_std(k);
      return true;
    }
  }
  return false;
}

// Joins neighbouring runs of one rest (see DetectStatic): two runs whose accelerometer means do
// not differ, with the samples between them (no longer than the two runs together) reading the
// same orientation, and the gyroscope at its rest there (mean rate within the tolerance of the
// rest's reference). Runs of one or two samples are too short to judge.
std::vector<Run> JoinRunsOfOneRest(const Capture& capture, const NoiseLevel& noise,
                                   const StaticDetectorOptions& options, const RateReference& rate,
                                   std::vector<Run> runs) {
  if (runs.size() < 2) return runs;
  std::vector<Run> out;
  out.push_back(runs.front());
  for (size_t k = 1; k < runs.size(); ++k) {
    Run& last = out.back();
    const Run& next = runs[k];
    const size_t gap = next.begin - last.end;
    const size_t held = (last.end - last.begin) + (next.end - next.begin);
    bool join = gap <= held && last.end - last.begin > 2 && next.end - next.begin > 2;
    if (join) {
      const StaticInterval a = SummariseInterval(capture, last.begin, last.end);
      const StaticInterval b = SummariseInterval(capture, next.begin, next.end);
      const StaticInterval between = SummariseInterval(capture, last.end, next.begin);
      int axis = 0;
      double shift = 0, off = 0;
      join = !MeansDiffer(a, b, noise, options, &axis, &shift) &&
             (gap < 2 || (!MeansDiffer(a, between, noise, options, &axis, &shift) &&
                          !MeansDiffer(between, b, noise, options, &axis, &shift))) &&
             !Turning(between, rate, &axis, &off) && !Turning(a, rate, &axis, &off) &&
             !Turning(b, rate, &axis, &off);
    }
    if (join) {
      last.end = next.end;
    } else {
      out.push_back(next);
    }
  }
  return out;
}

// Sets used/issue/reason of `s`: turning, too short, saturated or moved.
void Classify(const Capture& capture, const MotionSignal& motion, const NoiseLevel& noise,
              const StaticDetectorOptions& options, const RateReference& rate, StaticInterval* s) {
  const double duration = s->t_end_s - s->t_start_s;
  int axis = 0;
  double value = 0;
  auto reject = [&](IntervalIssue issue, std::string reason) {
    s->used = false;
    s->issue = issue;
    s->reason = std::move(reason);
  };
  if (Turning(*s, rate, &axis, &value)) {
    reject(IntervalIssue::kTurning,
           absl::StrFormat("turning: steady, but gyro %c reads %.3g (input units) off its rest "
                           "(%.0f x the tolerance); a rest is still, not a steady turn",
                           "xyz"[axis], value, std::abs(value) / rate.tolerance(axis)));
  } else if (duration < options.min_static_s) {
    reject(IntervalIssue::kTooShort,
           absl::StrFormat("too short: held %.1f s, needs %.1f s; hold the pose longer", duration,
                           options.min_static_s));
  } else if (PiledOnRail(motion.accel_at_rail, s->begin, s->end, noise.accel_std,
                         noise.accel_floor, &axis) ||
             PiledOnRail(motion.gyro_at_rail, s->begin, s->end, noise.gyro_std,
                         noise.gyro_floor, &axis)) {
    reject(IntervalIssue::kSaturated,
           absl::StrFormat(
               "saturated: axis %c sits on the sensor's range limit; use a larger range setting",
               "xyz"[axis]));
  } else {
    const size_t mid = (s->begin + s->end) / 2;
    const StaticInterval h1 = SummariseInterval(capture, s->begin, mid);
    const StaticInterval h2 = SummariseInterval(capture, mid, s->end);
    if (MeansDiffer(h1, h2, noise, options, &axis, &value)) {
      reject(IntervalIssue::kMoved,
             absl::StrFormat(
                 "moved during capture: axis %c shifted by %.1f noise std between the first and "
                 "second half; keep the robot still",
                 "xyz"[axis], value));
    }
  }
}
}  // namespace

std::string_view IntervalIssueName(IntervalIssue issue) {
  switch (issue) {
    case IntervalIssue::kNone:
      return "";
    case IntervalIssue::kTooShort:
      return "too_short";
    case IntervalIssue::kSaturated:
      return "saturated";
    case IntervalIssue::kMoved:
      return "moved";
    case IntervalIssue::kTurning:
      return "turning";
    case IntervalIssue::kDuplicate:
      return "duplicate";
  }
  return "";
}

MotionSignal ComputeMotionSignal(const Capture& capture, const StaticDetectorOptions& options) {
  MotionSignal out;
  const size_t n = capture.size();
  const double dt = capture.MedianDt();
  size_t w = dt > 0 ? static_cast<size_t>(std::lround(options.window_s / dt)) : 5;
  w = std::max<size_t>(5, w) | 1;  // odd, centred
  out.window = w;
  Extremes(capture.accel, &out.accel_lo, &out.accel_hi);
  Extremes(capture.gyro, &out.gyro_lo, &out.gyro_hi);
  out.accel_at_rail = AtRail(capture.accel, out.accel_lo, out.accel_hi);
  out.gyro_at_rail = AtRail(capture.gyro, out.gyro_lo, out.gyro_hi);
  const PrefixMoments acc(capture.accel), gyr(capture.gyro);
  out.accel_var.resize(n);
  out.gyro_var.resize(n);
  const size_t h = w / 2;
  for (size_t i = 0; i < n; ++i) {
    const size_t b = i >= h ? i - h : 0;
    const size_t e = std::min(n, i + h + 1);
    out.accel_var[i] = acc.Variance(b, e).sum();
    out.gyro_var[i] = gyr.Variance(b, e).sum();
  }
  // Half-windows [i - h, i) and [i, i + h): the mean's shift across sample i.
  out.mean_shift.assign(n, std::numeric_limits<double>::infinity());
  for (size_t i = h; i + h <= n; ++i) {
    double worst = 0;
    for (const PrefixMoments* m : {&acc, &gyr}) {
      const Eigen::Vector3d shift = (m->Mean(i, i + h) - m->Mean(i - h, i)).cwiseAbs();
      const Eigen::Vector3d sigma =
          ((m->Variance(i - h, i) + m->Variance(i, i + h)) / static_cast<double>(h)).cwiseSqrt();
      for (int k = 0; k < 3; ++k)
        worst = std::max(
            worst, sigma(k) > 0 ? shift(k) / sigma(k) : std::numeric_limits<double>::infinity());
    }
    out.mean_shift[i] = worst;
  }
  // A file's start is an unmeasured gap (core/capture.h): no window reaches across it.
  for (size_t start : capture.FileStarts()) {
    for (size_t i = start >= h ? start - h : 0; i < std::min(n, start + h + 1); ++i) {
      out.accel_var[i] = out.gyro_var[i] = out.mean_shift[i] =
          std::numeric_limits<double>::infinity();
    }
  }
  return out;
}

NoiseLevel EstimateNoise(const Capture& capture, const MotionSignal& motion) {
  NoiseLevel noise;
  const size_t n = capture.size();
  if (n < motion.window) return noise;
  // A calibration capture is mostly at rest: the 10th percentile of window variances is rest.
  const double acc_floor = Quantile(motion.accel_var, 0.10);
  const double gyr_floor = Quantile(motion.gyro_var, 0.10);
  // The longest run at (twice) that floor is the cleanest rest: measure per-axis noise there.
  size_t best_b = 0, best_e = 0;
  for (size_t i = 0; i < n;) {
    if (motion.accel_var[i] <= 2 * acc_floor && motion.gyro_var[i] <= 2 * gyr_floor) {
      size_t j = i;
      while (j < n && motion.accel_var[j] <= 2 * acc_floor && motion.gyro_var[j] <= 2 * gyr_floor)
        ++j;
      if (j - i > best_e - best_b) best_b = i, best_e = j;
      i = j;
    } else {
      ++i;
    }
  }
  if (best_e - best_b >= motion.window) {
    noise.accel_std = RunStd(capture.accel, best_b, best_e);
    noise.gyro_std = RunStd(capture.gyro, best_b, best_e);
    noise.source = absl::StrFormat("rest at %.1f-%.1f s (the longest quiet run)",
                                   capture.t_s[best_b], capture.t_s[best_e - 1]);
  } else {
    noise.accel_std = Eigen::Vector3d::Constant(std::sqrt(acc_floor / 3));
    noise.gyro_std = Eigen::Vector3d::Constant(std::sqrt(gyr_floor / 3));
    noise.source = "10th percentile of window variances (no long rest found)";
  }
  // Quantised readings quieter than one step still carry a step's rounding noise.
  noise.accel_step = GridSteps(capture.accel);
  noise.gyro_step = GridSteps(capture.gyro);
  noise.accel_floor = NoiseFloor(capture.accel, noise.accel_step);
  noise.gyro_floor = NoiseFloor(capture.gyro, noise.gyro_step);
  noise.accel_std = noise.accel_std.cwiseMax(noise.accel_floor);
  noise.gyro_std = noise.gyro_std.cwiseMax(noise.gyro_floor);
  return noise;
}

StaticInterval SummariseInterval(const Capture& capture, size_t begin, size_t end) {
  StaticInterval s;
  s.begin = begin;
  s.end = end;
  if (end <= begin) return s;
  s.t_start_s = capture.t_s[begin];
  s.t_end_s = capture.t_s[end - 1];
  const double n = static_cast<double>(end - begin);
  Eigen::Vector3d a1 = Eigen::Vector3d::Zero(), g1 = Eigen::Vector3d::Zero();
  for (size_t i = begin; i < end; ++i) {
    a1 += capture.accel[i];
    g1 += capture.gyro[i];
  }
  s.accel_mean = a1 / n;
  s.gyro_mean = g1 / n;
  Eigen::Vector3d a2 = Eigen::Vector3d::Zero(), g2 = Eigen::Vector3d::Zero();
  for (size_t i = begin; i < end; ++i) {
    a2 += (capture.accel[i] - s.accel_mean).cwiseAbs2();
    g2 += (capture.gyro[i] - s.gyro_mean).cwiseAbs2();
  }
  if (n > 1) {
    s.accel_std = (a2 / (n - 1)).cwiseSqrt();
    s.gyro_std = (g2 / (n - 1)).cwiseSqrt();
  }
  if (capture.has_temp()) {
    double t = 0;
    for (size_t i = begin; i < end; ++i) t += capture.temp[i];
    s.temp_mean = t / n;
  }
  return s;
}

std::vector<StaticInterval> DetectStatic(const Capture& capture, const MotionSignal& motion,
                                         const NoiseLevel& noise, double multiplier,
                                         const StaticDetectorOptions& options) {
  const double acc_threshold = multiplier * noise.accel_std.squaredNorm();
  const double gyr_threshold = multiplier * noise.gyro_std.squaredNorm();
  const double dt = capture.MedianDt();
  const size_t trim = dt > 0 ? static_cast<size_t>(std::lround(options.trim_s / dt)) : 0;
  const std::vector<Run> still = StillRuns(motion, acc_threshold, gyr_threshold);
  const RateReference rate = GyroRateReference(capture, still, noise, options);
  const std::vector<Run> runs = JoinRunsOfOneRest(capture, noise, options, rate, still);
  std::vector<StaticInterval> out;
  for (const Run& run : runs) {
    const size_t b = run.begin + trim, e = run.end > trim ? run.end - trim : 0;
    if (e <= b + 1) continue;  // nothing left after trimming: a pause, not a pose
    StaticInterval s = SummariseInterval(capture, b, e);
    Classify(capture, motion, noise, options, rate, &s);
    out.push_back(std::move(s));
  }
  return out;
}

}  // namespace imucal::core
