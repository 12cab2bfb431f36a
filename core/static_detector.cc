#include "core/static_detector.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/prefix_moments.h"
#include "core/rest_rotation.h"

namespace imucal::core {
namespace {

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

// The maximal runs of samples in [b, e) where `still(i)` holds.
template <typename Still>
std::vector<Run> RunsWhere(size_t b, size_t e, Still still) {
  std::vector<Run> out;
  for (size_t i = b; i < e;) {
    if (!still(i)) {
      ++i;
      continue;
    }
    size_t j = i;
    while (j < e && still(j)) ++j;
    out.push_back({i, j});
    i = j;
  }
  return out;
}

// Runs of [b, e) under both variance thresholds, and the steady runs (MotionSignal::mean_shift)
// that no variance run touches: a rest too noisy for the variance test at any multiplier (a
// motor running). A steady run beside a variance run is the same rest's edge, where a hand's slow
// start of the next move shifts the mean less than its noise: the variance test sees that start
// earlier, so there it decides. A steady run loses half a window at each end for the same reason.
std::vector<Run> StillRuns(const MotionSignal& motion, size_t b, size_t e, double acc_threshold,
                           double gyr_threshold) {
  std::vector<Run> out = RunsWhere(b, e, [&](size_t i) {
    return motion.accel_var[i] <= acc_threshold && motion.gyro_var[i] <= gyr_threshold;
  });
  if (motion.mean_shift.empty()) return out;
  const size_t half = motion.window / 2;
  std::vector<bool> in_variance_run(e - b, false);
  for (const Run& r : out)
    for (size_t i = r.begin; i < r.end; ++i) in_variance_run[i - b] = true;
  for (const Run& r :
       RunsWhere(b, e, [&](size_t i) { return motion.mean_shift[i] <= kSteadyMeanShift; })) {
    bool touches = false;
    for (size_t i = r.begin; i < r.end && !touches; ++i) touches = in_variance_run[i - b];
    if (touches || r.end - r.begin <= 2 * half) continue;
    out.push_back({r.begin + half, r.end - half});
  }
  std::sort(out.begin(), out.end(), [](const Run& x, const Run& y) { return x.begin < y.begin; });
  return out;
}

// What the rotation test knows of one file: its noise, its rest rate (input units) and how far
// a rest's rate may sit from it (rad/s).
struct FileRest {
  NoiseLevel::Segment noise;
  std::vector<Run> runs;
  Eigen::Vector3d rate = Eigen::Vector3d::Zero();
  double bias_bound_rad_s = 0;
};

// The capture's rotation test: the gyroscope's integral, its unit in radians (0 when unknown:
// raw counts with no move that tilts the unit, where no rotation is measured), and each file's
// rest.
struct RestContext {
  const GyroIntegral* integral = nullptr;  // the motion signal's (MotionSignal::integral)
  double rad_per_unit = 0;
  std::vector<FileRest> files;
  const StaticDetectorOptions* options = nullptr;

  // The rotation of [b, e) in file `f` and the most a rest could turn, radians.
  std::pair<double, double> Rotation(size_t f, size_t b, size_t e) const {
    const FileRest& file = files[f];
    const double turned = integral->Excursion(b, e, file.rate) * rad_per_unit;
    const double bound = RestRotationBound(file.noise.gyro_std * rad_per_unit, e - b,
                                           integral->median_dt_s, integral->Duration(b, e),
                                           file.bias_bound_rad_s, options->rotation_sigmas);
    return {turned, bound};
  }
  bool Turns(size_t f, size_t b, size_t e) const {
    if (!(rad_per_unit > 0)) return false;
    const auto [turned, bound] = Rotation(f, b, e);
    return turned > bound;
  }
};

constexpr double kDegPerRad = 180.0 / std::numbers::pi;

// A gyroscope at rest reads its bias, and no MEMS gyroscope's bias is this large (the
// MPU-6050's zero-rate output is specified within 20 deg/s, most are within a few): a run whose
// mean rate is larger turned, whatever else it looks like. Nominal units only (raw counts
// carry an offset).
constexpr double kMostBiasDegS = 25.0;

// The samples a rest rate may come from: those within kMostBiasDegS (`rad_per_unit` radians per
// input unit), or all of them when the readings have no known zero (raw counts).
std::vector<RateSample> PlausibleRests(std::vector<RateSample> runs, double rad_per_unit,
                                       bool zero_known) {
  if (!zero_known) return runs;
  const double most = kMostBiasDegS * std::numbers::pi / 180 / rad_per_unit;
  std::erase_if(runs, [&](const RateSample& r) { return r.mean.norm() > most; });
  return runs;
}

// A run's rate sample, and whether it is held long enough to be a pose.
struct RunRate {
  RateSample rate;
  bool held = false;
};

std::vector<RunRate> RunRates(const Capture& capture, const std::vector<Run>& runs,
                              const StaticDetectorOptions& options) {
  std::vector<RunRate> out;
  for (const Run& r : runs) {
    if (r.end <= r.begin + 1) continue;
    const StaticInterval s = SummariseInterval(capture, r.begin, r.end);
    out.push_back({{s.gyro_mean, static_cast<double>(s.samples())},
                   s.t_end_s - s.t_start_s >= options.min_static_s});
  }
  return out;
}

// The runs a rest rate may come from: the plausible ones (PlausibleRests), and of those the ones
// held long enough to be poses when there are any (a turn's piece between two bursts of motion
// is short; a rest is held).
std::vector<RateSample> RestCandidates(const std::vector<RunRate>& runs, double rad_per_unit,
                                       bool zero_known) {
  std::vector<RateSample> held, all;
  for (const RunRate& r : runs) {
    if (PlausibleRests({r.rate}, rad_per_unit, zero_known).empty()) continue;
    all.push_back(r.rate);
    if (r.held) held.push_back(r.rate);
  }
  return held.empty() ? all : held;
}

// With no rest to learn from, the rest rate is zero and a rest may read up to this: the turn-on
// bias of most MEMS gyroscopes is within a few deg/s.
constexpr double kUnknownBiasDegS = 5.0;

// The gyroscope's radians per input unit for the rotation test. Its nominal unit's, unless the
// moves say it is the other nominal unit (a deg/s gyroscope read as rad/s turns gravity 57 times
// less than it says): within 3x of the other and not of its own, the other's, so that a wrong
// unit does not make every rest a turn (the calibration's unit check then refuses it by name,
// core/calibrate/unit_check.h). A figure near neither (a gyroscope that recorded no rotation)
// changes nothing. Raw counts, or a unit the caller does not know
// (StaticDetectorOptions::gyro_unit_known), have only the moves' figure.
double GyroRadPerUnit(const Capture& capture, const RestContext& ctx,
                      const StaticDetectorOptions& options, const Eigen::Vector3d& provisional) {
  std::vector<std::pair<size_t, size_t>> rests;
  for (const FileRest& f : ctx.files)
    for (const Run& r : f.runs) rests.emplace_back(r.begin, r.end);
  const double moves = RoughRadPerGyroUnit(capture, *ctx.integral, rests, provisional);
  if (capture.gyro_unit == GyroUnit::kCounts || !options.gyro_unit_known) return moves;
  const double nominal = NominalGyroToSi(capture.gyro_unit);
  const double other = NominalGyroToSi(capture.gyro_unit == GyroUnit::kRadPerSecond
                                           ? GyroUnit::kDegPerSecond
                                           : GyroUnit::kRadPerSecond);
  const double near = std::log(3.0);
  if (moves > 0 && std::abs(std::log(moves / other)) < near &&
      std::abs(std::log(moves / nominal)) > near)
    return other;
  return nominal;
}

// Each file's rest rate: the densest cluster (by duration) of its own runs, when two or more
// agree on it (one run cannot vouch for itself: a slow steady turn reads like a bias). Else (a
// file holding one pose) the densest cluster of all files' runs, when two or more agree, with the
// power-up bound. Else (no two rests agree anywhere: a single rest, a hand-held walk) zero, with
// kUnknownBiasDegS; raw counts have no zero, so there the provisional rate of all runs.
void SetRestRates(const Capture& capture, const StaticDetectorOptions& options,
                  RestContext* ctx) {
  std::vector<std::vector<RunRate>> runs;
  std::vector<RateSample> every;
  for (const FileRest& f : ctx->files) {
    runs.push_back(RunRates(capture, f.runs, options));
    for (const RunRate& r : runs.back()) every.push_back(r.rate);
  }
  const Eigen::Vector3d provisional = DenseRestRate(every, INFINITY).rate;
  ctx->rad_per_unit = GyroRadPerUnit(capture, *ctx, options, provisional);
  if (!(ctx->rad_per_unit > 0)) return;
  const bool zero_known = capture.gyro_unit != GyroUnit::kCounts;
  std::vector<std::vector<RateSample>> own;
  std::vector<RateSample> all;
  for (const std::vector<RunRate>& r : runs) {
    own.push_back(RestCandidates(r, ctx->rad_per_unit, zero_known));
    all.insert(all.end(), own.back().begin(), own.back().end());
  }
  const double rest_bound = options.rest_rate_bound_deg_s / kDegPerRad;
  const double power_up_bound = options.power_up_rate_bound_deg_s / kDegPerRad;
  const RestRate across = DenseRestRate(all, power_up_bound / ctx->rad_per_unit);
  for (size_t k = 0; k < ctx->files.size(); ++k) {
    FileRest& f = ctx->files[k];
    const RestRate mine = DenseRestRate(own[k], rest_bound / ctx->rad_per_unit);
    if (mine.members >= 2) {
      f.rate = mine.rate;
      f.bias_bound_rad_s = rest_bound;
    } else if (across.members >= 2 || !zero_known) {
      f.rate = across.members >= 2 ? across.rate : provisional;
      f.bias_bound_rad_s = power_up_bound;
    } else {
      f.rate.setZero();
      f.bias_bound_rad_s = kUnknownBiasDegS / kDegPerRad;
    }
  }
}

// A window whose mean rate is off the rest rate by this much turns: a hand drifts by a degree
// or two per second while it holds a pose, a slow turn goes at tens. (Slower drifts are the
// interval's rotation test's to judge, over the whole interval.)
constexpr double kWindowTurnDegS = 5.0;

// Cuts file `f`'s still runs where the gyroscope turns: a sample whose centred window's mean
// rate is off the rest rate by more than `rotation_sigmas` noise std of a window mean plus
// kWindowTurnDegS. A hand-held capture's learnt threshold can take a slow turn and the rests on
// either side as one run; the rotation test would then refuse the whole run, rests included.
void SplitAtTurns(const MotionSignal& motion, RestContext* ctx, size_t f) {
  if (!(ctx->rad_per_unit > 0)) return;
  FileRest& file = ctx->files[f];
  const GyroIntegral& g = *ctx->integral;
  const size_t h = motion.window / 2;
  const size_t n = g.time_s.size() - 1;
  const double limit =
      ctx->options->rotation_sigmas * file.noise.gyro_std.norm() * ctx->rad_per_unit /
          std::sqrt(static_cast<double>(2 * h + 1)) +
      std::max(file.bias_bound_rad_s, kWindowTurnDegS * std::numbers::pi / 180);
  auto turning = [&](size_t i) {
    const size_t b = i >= h ? i - h : 0, e = std::min(n, i + h + 1);
    const double span = g.time_s[e] - g.time_s[b];
    if (!(span > 0)) return false;
    const Eigen::Vector3d mean = (g.angle[e] - g.angle[b]) / span;
    return (mean - file.rate).norm() * ctx->rad_per_unit > limit;
  };
  std::vector<Run> out;
  for (const Run& r : file.runs) {
    for (const Run& piece : RunsWhere(r.begin, r.end, [&](size_t i) { return !turning(i); }))
      out.push_back(piece);
  }
  file.runs = std::move(out);
}

// The "moved" test between two sets of samples of one pose: their accelerometer means differ by
// more than the noise of the means AND by more than the per-sample noise (slow thermal drift of a
// long rest stays below). Sets `axis` and `shift` (in noise std) when they do.
bool MeansDiffer(const StaticInterval& a, const StaticInterval& b, const Eigen::Vector3d& noise,
                 const StaticDetectorOptions& options, int* axis, double* shift_std) {
  const Eigen::Vector3d shift = (b.accel_mean - a.accel_mean).cwiseAbs();
  const Eigen::Vector3d sigma_means =
      noise.cwiseMax(0.5 * (a.accel_std + b.accel_std)) *
      std::sqrt(1.0 / static_cast<double>(a.samples()) + 1.0 / static_cast<double>(b.samples()));
  for (int k = 0; k < 3; ++k) {
    if (shift(k) > options.moved_sigma * sigma_means(k) && shift(k) > 3 * noise(k)) {
      *axis = k;
      *shift_std = shift(k) / noise(k);
      return true;
    }
  }
  return false;
}

// A time gap (an interval over 3 median intervals) between samples `from` and `to`.
bool GapBetween(const Capture& capture, size_t from, size_t to, double median_dt) {
  for (size_t i = from + 1; i <= to && i < capture.size(); ++i)
    if (capture.t_s[i] - capture.t_s[i - 1] > 3 * median_dt) return true;
  return false;
}

// Joins neighbouring runs of one rest (see DetectStatic): no time gap between them, the
// gyroscope not turning over the whole span, and the accelerometer's means agreeing before,
// between and after. Runs of one or two samples are too short to judge.
std::vector<Run> JoinRunsOfOneRest(const Capture& capture, const RestContext& ctx, size_t f,
                                   const StaticDetectorOptions& options, std::vector<Run> runs) {
  if (runs.size() < 2) return runs;
  const Eigen::Vector3d& noise = ctx.files[f].noise.accel_std;
  std::vector<Run> out;
  out.push_back(runs.front());
  for (size_t k = 1; k < runs.size(); ++k) {
    Run& last = out.back();
    const Run& next = runs[k];
    bool join = last.end - last.begin > 2 && next.end - next.begin > 2 &&
                !GapBetween(capture, last.end - 1, next.begin, ctx.integral->median_dt_s) &&
                ctx.rad_per_unit > 0 && !ctx.Turns(f, last.begin, next.end);
    if (join) {
      const StaticInterval a = SummariseInterval(capture, last.begin, last.end);
      const StaticInterval b = SummariseInterval(capture, next.begin, next.end);
      const StaticInterval between = SummariseInterval(capture, last.end, next.begin);
      int axis = 0;
      double shift = 0;
      join = !MeansDiffer(a, b, noise, options, &axis, &shift) &&
             (next.begin - last.end < 2 ||
              (!MeansDiffer(a, between, noise, options, &axis, &shift) &&
               !MeansDiffer(between, b, noise, options, &axis, &shift)));
    }
    if (join) {
      last.end = next.end;
    } else {
      out.push_back(next);
    }
  }
  return out;
}

// Sets used/issue/reason of `s` (in file `f`): turning, too short, saturated or moved.
void Classify(const Capture& capture, const MotionSignal& motion, const NoiseLevel& noise,
              const RestContext& ctx, size_t f, StaticInterval* s) {
  const StaticDetectorOptions& options = *ctx.options;
  const double duration = s->t_end_s - s->t_start_s;
  int axis = 0;
  double value = 0;
  auto reject = [&](IntervalIssue issue, std::string reason) {
    s->used = false;
    s->issue = issue;
    s->reason = std::move(reason);
  };
  if (ctx.rad_per_unit > 0) {
    const auto [turned, bound] = ctx.Rotation(f, s->begin, s->end);
    s->rotation_deg = turned * kDegPerRad;
    s->rotation_bound_deg = bound * kDegPerRad;
  }
  if (s->rotation_deg > s->rotation_bound_deg) {
    reject(IntervalIssue::kTurning,
           absl::StrFormat("turning: the gyroscope turned %.1f deg over these %.1f s (%.2g deg/s "
                           "on average), more than a rest can (%.2f deg: its noise and a %.2g "
                           "deg/s bound on its bias); a rest is still, not a steady turn",
                           s->rotation_deg, duration,
                           duration > 0 ? s->rotation_deg / duration : 0.0, s->rotation_bound_deg,
                           ctx.files[f].bias_bound_rad_s * kDegPerRad));
  } else if (duration < options.min_static_s) {
    reject(IntervalIssue::kTooShort,
           absl::StrFormat("too short: held %.1f s, needs %.1f s; hold the pose longer", duration,
                           options.min_static_s));
  } else if (PiledOnRail(motion.accel_at_rail, s->begin, s->end, s->accel_noise_std,
                         noise.accel_floor, &axis) ||
             PiledOnRail(motion.gyro_at_rail, s->begin, s->end, s->gyro_noise_std,
                         noise.gyro_floor, &axis)) {
    reject(IntervalIssue::kSaturated,
           absl::StrFormat(
               "saturated: axis %c sits on the sensor's range limit; use a larger range setting",
               "xyz"[axis]));
  } else {
    const size_t mid = (s->begin + s->end) / 2;
    const StaticInterval h1 = SummariseInterval(capture, s->begin, mid);
    const StaticInterval h2 = SummariseInterval(capture, mid, s->end);
    if (MeansDiffer(h1, h2, s->accel_noise_std, options, &axis, &value)) {
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
  out.integral = GyroIntegral(capture, dt);
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
  RestContext ctx;
  ctx.options = &options;
  // A motion signal made by hand (not by ComputeMotionSignal) has no integral yet.
  GyroIntegral own;
  ctx.integral = &motion.integral;
  if (motion.integral.time_s.size() != capture.size() + 1) {
    own = GyroIntegral(capture);
    ctx.integral = &own;
  }
  std::vector<NoiseLevel::Segment> segments = noise.segments;
  if (segments.empty()) {
    segments.push_back({0, capture.size(), noise.accel_std, noise.gyro_std, noise.source});
  }
  for (const NoiseLevel::Segment& seg : segments) {
    FileRest f;
    f.noise = seg;
    f.runs = StillRuns(motion, seg.begin, std::min(seg.end, capture.size()),
                       multiplier * seg.accel_std.squaredNorm(),
                       multiplier * seg.gyro_std.squaredNorm());
    ctx.files.push_back(std::move(f));
  }
  SetRestRates(capture, options, &ctx);
  // Cut the runs where the gyroscope turns, then learn the rest rates again from the pieces
  // (the runs that held a turn no longer pull them).
  for (size_t f = 0; f < ctx.files.size(); ++f) SplitAtTurns(motion, &ctx, f);
  SetRestRates(capture, options, &ctx);
  const double dt = ctx.integral->median_dt_s;
  const size_t trim = dt > 0 ? static_cast<size_t>(std::lround(options.trim_s / dt)) : 0;
  std::vector<StaticInterval> out;
  for (size_t f = 0; f < ctx.files.size(); ++f) {
    for (const Run& run : JoinRunsOfOneRest(capture, ctx, f, options, ctx.files[f].runs)) {
      const size_t b = run.begin + trim, e = run.end > trim ? run.end - trim : 0;
      if (e <= b + 1) continue;  // nothing left after trimming: a pause, not a pose
      StaticInterval s = SummariseInterval(capture, b, e);
      s.accel_noise_std = ctx.files[f].noise.accel_std;
      s.gyro_noise_std = ctx.files[f].noise.gyro_std;
      Classify(capture, motion, noise, ctx, f, &s);
      out.push_back(std::move(s));
    }
  }
  return out;
}

}  // namespace imucal::core
