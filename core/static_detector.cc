#include "core/static_detector.h"

#include <algorithm>
#include <cmath>

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

bool IntegerValued(const std::vector<Eigen::Vector3d>& x) {
  const size_t step = std::max<size_t>(1, x.size() / 1000);
  for (size_t i = 0; i < x.size(); i += step)
    for (int j = 0; j < 3; ++j)
      if (x[i](j) != std::round(x[i](j))) return false;
  return true;
}

// Per-axis noise std over the longest run of samples whose window variance is at the floor.
Eigen::Vector3d RunStd(const std::vector<Eigen::Vector3d>& x, size_t b, size_t e) {
  return PrefixMoments(std::vector<Eigen::Vector3d>(x.begin() + static_cast<long>(b),
                                                    x.begin() + static_cast<long>(e)))
      .Variance(0, e - b)
      .cwiseSqrt();
}

// Saturation: a rail is the extreme value of an axis over the whole capture; a static interval
// piled up on it (a fifth of its samples or more) reads the rail, not the signal.
bool PiledOnRail(const std::vector<Eigen::Vector3d>& x, size_t b, size_t e,
                 const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, int* axis) {
  for (int j = 0; j < 3; ++j) {
    size_t at_rail = 0;
    for (size_t i = b; i < e; ++i) at_rail += (x[i](j) == lo(j) || x[i](j) == hi(j));
    if (at_rail * 5 >= e - b && at_rail >= 3) {
      *axis = j;
      return true;
    }
  }
  return false;
}

void Extremes(const std::vector<Eigen::Vector3d>& x, Eigen::Vector3d* lo, Eigen::Vector3d* hi) {
  *lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  *hi = -*lo;
  for (const auto& v : x) {
    *lo = lo->cwiseMin(v);
    *hi = hi->cwiseMax(v);
  }
}

}  // namespace

MotionSignal ComputeMotionSignal(const Capture& capture, const StaticDetectorOptions& options) {
  MotionSignal out;
  const size_t n = capture.size();
  const double dt = capture.MedianDt();
  size_t w = dt > 0 ? static_cast<size_t>(std::lround(options.window_s / dt)) : 5;
  w = std::max<size_t>(5, w) | 1;  // odd, centred
  out.window = w;
  Extremes(capture.accel, &out.accel_lo, &out.accel_hi);
  Extremes(capture.gyro, &out.gyro_lo, &out.gyro_hi);
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
  // Quantised readings quieter than one step still carry a step's rounding noise (1/sqrt(12)).
  const double acc_min = IntegerValued(capture.accel) ? std::sqrt(1.0 / 12) : 1e-12;
  const double gyr_min = IntegerValued(capture.gyro) ? std::sqrt(1.0 / 12) : 1e-12;
  noise.accel_std = noise.accel_std.cwiseMax(acc_min);
  noise.gyro_std = noise.gyro_std.cwiseMax(gyr_min);
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
  std::vector<StaticInterval> out;
  const size_t n = capture.size();
  const double acc_threshold = multiplier * noise.accel_std.squaredNorm();
  const double gyr_threshold = multiplier * noise.gyro_std.squaredNorm();
  const double dt = capture.MedianDt();
  const size_t trim = dt > 0 ? static_cast<size_t>(std::lround(options.trim_s / dt)) : 0;
  auto still = [&](size_t i) {
    return motion.accel_var[i] <= acc_threshold && motion.gyro_var[i] <= gyr_threshold;
  };
  for (size_t i = 0; i < n;) {
    if (!still(i)) {
      ++i;
      continue;
    }
    size_t j = i;
    while (j < n && still(j)) ++j;
    const size_t b = i + trim, e = j > trim ? j - trim : 0;
    i = j;
    if (e <= b + 1) continue;  // nothing left after trimming: a pause, not a pose
    StaticInterval s = SummariseInterval(capture, b, e);
    const double duration = s.t_end_s - s.t_start_s;
    int axis = 0;
    if (duration < options.min_static_s) {
      s.used = false;
      s.reason = absl::StrFormat("too short: held %.1f s, needs %.1f s; hold the pose longer",
                                 duration, options.min_static_s);
    } else if (PiledOnRail(capture.accel, b, e, motion.accel_lo, motion.accel_hi, &axis) ||
               PiledOnRail(capture.gyro, b, e, motion.gyro_lo, motion.gyro_hi, &axis)) {
      s.used = false;
      s.reason = absl::StrFormat(
          "saturated: axis %c sits on the sensor's range limit; use a larger range setting",
          "xyz"[axis]);
    } else {
      // Moved during capture: the two halves' means differ by more than the noise of the means
      // AND by more than the per-sample noise (slow thermal drift of a long rest stays below).
      const size_t mid = (b + e) / 2;
      const StaticInterval h1 = SummariseInterval(capture, b, mid);
      const StaticInterval h2 = SummariseInterval(capture, mid, e);
      const Eigen::Vector3d shift = (h2.accel_mean - h1.accel_mean).cwiseAbs();
      const Eigen::Vector3d sigma_means =
          noise.accel_std *
          std::sqrt(1.0 / static_cast<double>(mid - b) + 1.0 / static_cast<double>(e - mid));
      for (int k = 0; k < 3; ++k) {
        if (shift(k) > options.moved_sigma * sigma_means(k) && shift(k) > 3 * noise.accel_std(k)) {
          s.used = false;
          s.reason = absl::StrFormat(
              "moved during capture: axis %c shifted by %.1f noise std between the first and "
              "second half; keep the robot still",
              "xyz"[k], shift(k) / noise.accel_std(k));
          break;
        }
      }
    }
    out.push_back(std::move(s));
  }
  return out;
}

}  // namespace imucal::core
