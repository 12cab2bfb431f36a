// The noise level of a capture (core/static_detector.h's NoiseLevel and EstimateNoise): the
// grid its readings sit on, the floor that grid puts under the noise, and the quietest rest of
// each file, where the still thresholds are learnt.
#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/prefix_moments.h"
#include "core/static_detector.h"

namespace imucal::core {
namespace {

double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size())));
  std::nth_element(v.begin(), v.begin() + static_cast<long>(k), v.end());
  return v[k];
}

// The grid step of sorted distinct values (input units), or 0 when they sit on none: the smallest
// difference between them, when every difference between neighbours is a whole multiple of it
// (to 1e-6 of the step: the readings are decimal text, so 0.07 - 0.06 is not exactly 0.01).
double SortedGridStep(const std::vector<double>& v) {
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

// Every `stride`-th reading of axis `j` from the first, sorted, each value once.
std::vector<double> SortedDistinct(const std::vector<Eigen::Vector3d>& x, int j, size_t stride) {
  std::vector<double> v;
  v.reserve(x.size() / stride + 1);
  for (size_t i = 0; i < x.size(); i += stride) v.push_back(x[i](j));
  std::sort(v.begin(), v.end());
  v.erase(std::unique(v.begin(), v.end()), v.end());
  return v;
}

// Whether every `stride`-th reading of axis `j` sits on the grid origin + k step, each within
// half of SortedGridStep's tolerance for one step (so any two neighbours pass its test: a grid
// accepted here is one the full sort accepts, never a looser one).
bool OnGrid(const std::vector<Eigen::Vector3d>& x, int j, size_t stride, double origin, double step,
            double tiny) {
  const double tolerance = 0.5 * (1e-6 + tiny / step);
  for (size_t i = 0; i < x.size(); i += stride) {
    const double k = (x[i](j) - origin) / step;
    if (std::abs(k - std::round(k)) > tolerance) {
      return false;
    }
  }
  return true;
}

// The step of the grid axis `j` of the readings sits on (SortedGridStep over all of them). At
// most 65536 readings, evenly spread, are looked at. Sorting them all is the cost, so a sample
// of about 4096 proposes the step first: when every reading sits on the grid it proposes, that
// is the step (the sample holds two neighbours that far apart, and no two readings on the grid
// are closer). Otherwise (a sample may skip grid lines) all the readings are sorted.
double GridStep(const std::vector<Eigen::Vector3d>& x, int j) {
  const size_t stride = std::max<size_t>(1, x.size() / 65536);
  const size_t sample_stride = std::max<size_t>(stride, x.size() / 4096);
  if (sample_stride > stride) {
    const std::vector<double> v = SortedDistinct(x, j, sample_stride);
    const double step = SortedGridStep(v);
    const double tiny = v.empty() ? 0.0 : 1e-12 * std::max(std::abs(v.front()), std::abs(v.back()));
    if (step > 0 && OnGrid(x, j, stride, v.front(), step, tiny)) return step;
  }
  return SortedGridStep(SortedDistinct(x, j, stride));
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

// The noise std of samples [b, e): the 10th percentile of their window variances is rest (a
// calibration capture is mostly at rest), and the longest run at (twice) that floor is the
// cleanest rest, where the per-axis noise is measured.
NoiseLevel::Segment SegmentNoise(const Capture& capture, const MotionSignal& motion, size_t b,
                                 size_t e) {
  NoiseLevel::Segment out;
  out.begin = b;
  out.end = e;
  std::vector<double> acc_var, gyr_var;
  for (size_t i = b; i < e; ++i) {
    if (!std::isfinite(motion.accel_var[i]) || !std::isfinite(motion.gyro_var[i])) continue;
    acc_var.push_back(motion.accel_var[i]);
    gyr_var.push_back(motion.gyro_var[i]);
  }
  if (acc_var.empty()) return out;
  const double acc_floor = Quantile(std::move(acc_var), 0.10);
  const double gyr_floor = Quantile(std::move(gyr_var), 0.10);
  size_t best_b = 0, best_e = 0;
  auto quiet = [&](size_t i) {
    return motion.accel_var[i] <= 2 * acc_floor && motion.gyro_var[i] <= 2 * gyr_floor;
  };
  for (size_t i = b; i < e;) {
    if (!quiet(i)) {
      ++i;
      continue;
    }
    size_t j = i;
    while (j < e && quiet(j)) ++j;
    if (j - i > best_e - best_b) best_b = i, best_e = j;
    i = j;
  }
  if (best_e - best_b >= motion.window) {
    out.accel_std = RunStd(capture.accel, best_b, best_e);
    out.gyro_std = RunStd(capture.gyro, best_b, best_e);
    out.source = absl::StrFormat("rest at %.1f-%.1f s (the longest quiet run)", capture.t_s[best_b],
                                 capture.t_s[best_e - 1]);
  } else {
    out.accel_std = Eigen::Vector3d::Constant(std::sqrt(acc_floor / 3));
    out.gyro_std = Eigen::Vector3d::Constant(std::sqrt(gyr_floor / 3));
    out.source = "10th percentile of window variances (no long rest found)";
  }
  return out;
}

}  // namespace

NoiseLevel EstimateNoise(const Capture& capture, const MotionSignal& motion) {
  NoiseLevel noise;
  const size_t n = capture.size();
  if (n < motion.window) return noise;
  // Quantised readings quieter than one step still carry a step's rounding noise.
  noise.accel_step = GridSteps(capture.accel);
  noise.gyro_step = GridSteps(capture.gyro);
  noise.accel_floor = NoiseFloor(capture.accel, noise.accel_step);
  noise.gyro_floor = NoiseFloor(capture.gyro, noise.gyro_step);
  const NoiseLevel::Segment all = SegmentNoise(capture, motion, 0, n);
  noise.accel_std = all.accel_std.cwiseMax(noise.accel_floor);
  noise.gyro_std = all.gyro_std.cwiseMax(noise.gyro_floor);
  noise.source = all.source;
  std::vector<size_t> bounds = {0};
  for (size_t start : capture.FileStarts())
    if (start > bounds.back() && start < n) bounds.push_back(start);
  bounds.push_back(n);
  for (size_t k = 0; k + 1 < bounds.size(); ++k) {
    NoiseLevel::Segment seg =
        bounds.size() == 2 ? all : SegmentNoise(capture, motion, bounds[k], bounds[k + 1]);
    seg.begin = bounds[k];
    seg.end = bounds[k + 1];
    // A file too short to measure (under one window of finite variances) takes the capture's.
    if (seg.source.empty()) {
      seg.accel_std = noise.accel_std;
      seg.gyro_std = noise.gyro_std;
      seg.source = "the capture's (the file is too short to measure its own)";
    }
    seg.accel_std = seg.accel_std.cwiseMax(noise.accel_floor);
    seg.gyro_std = seg.gyro_std.cwiseMax(noise.gyro_floor);
    noise.segments.push_back(std::move(seg));
  }
  if (noise.segments.size() > 1) {
    absl::StrAppend(&noise.source, "; the still thresholds are learnt per file");
  }
  return noise;
}

}  // namespace imucal::core
