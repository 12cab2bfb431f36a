#include "core/calibrate/static_poses.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "core/calibrate/orientations.h"
#include "core/protocol.h"
#include "core/quantisation.h"
#include "util/parallel.h"

namespace imucal::core::pipeline {
namespace {

// A time gap: an interval between samples over this many median intervals.
constexpr double kGapFactor = 3.0;
// Fewer poses than this cannot determine the full model on |a| = g (9 + 1 spare).
constexpr size_t kFullModelPoses = 10;

// One threshold multiplier of the sweep, scored by its leave-one-pose-out (PRESS) error within
// the best tier any multiplier reaches.
struct SweepResult {
  double multiplier = 0;
  std::vector<StaticInterval> intervals;
  AccelParams accel;
  double press = std::numeric_limits<double>::infinity();
  size_t poses = 0;
  SweepTier tier = SweepTier::kNone;
  bool escalated = false;
};

// Bias and scale of an axis need it pointing up in one pose and down in another (within 60
// degrees of the vertical): otherwise the two trade off along that axis. With a spare pose the
// fit's own conditioning tells; with none (6 poses for 6 parameters) nothing would.
bool EveryAxisUpAndDown(const std::vector<Eigen::Vector3d>& ups) {
  for (int j = 0; j < 3; ++j) {
    bool up = false, down = false;
    for (const Eigen::Vector3d& u : ups) up |= u(j) > 0.5, down |= u(j) < -0.5;
    if (!up || !down) return false;
  }
  return true;
}

SweepResult ScoreMultiplier(const Capture& cap, const MotionSignal& motion, const NoiseLevel& noise,
                            const CalibrateOptions& opt, double m) {
  SweepResult out;
  out.multiplier = m;
  const double g = cap.gravity_m_s2;
  std::vector<StaticInterval> ivs = DetectStatic(cap, motion, noise, m, opt.detector);
  const std::vector<AccelPose> poses = ToAccelPoses(ivs, UsedIndices(ivs), noise);
  out.poses = poses.size();
  if (poses.size() >= kFullModelPoses) {
    const auto e = FitEllipsoid(poses, g);
    if (e.ok()) {
      const AccelMask linear = MaskOf(kAccelFirstOrder);
      out.accel = RefineAccelGaussNewton(*e, poses, g, linear, 10);
      out.press = PressRms(out.accel, poses, g, linear);
      out.tier = SweepTier::kFull;
      out.intervals = std::move(ivs);
      return out;
    }
  }
  const auto a = FitAxisEllipsoid(poses, g);
  if (!a.ok()) return out;
  const AccelMask bias_scale = MaskOf(kAccelBiasScale);
  out.accel = RefineAccelGaussNewton(*a, poses, g, bias_scale, 10);
  std::vector<Eigen::Vector3d> ups;
  for (const AccelPose& p : poses) ups.push_back(out.accel.Apply(p.mean).normalized());
  if (CoversSixFaces(ups)) {
    out.tier = SweepTier::kFaces;
  } else if (poses.size() > kBiasScaleNeeds.count ||
             (poses.size() == kBiasScaleNeeds.count && EveryAxisUpAndDown(ups))) {
    out.tier = SweepTier::kBiasScale;
  } else {
    return out;
  }
  // With as many poses as parameters PRESS is undefined: the lowest such multiplier is kept.
  out.press = poses.size() > 6 ? PressRms(out.accel, poses, g, bias_scale)
                               : std::numeric_limits<double>::max();
  if (!std::isfinite(out.press)) out.press = std::numeric_limits<double>::max();
  out.intervals = std::move(ivs);
  return out;
}

SweepResult SweepThreshold(const Capture& cap, const MotionSignal& motion, const NoiseLevel& noise,
                           const CalibrateOptions& opt, size_t* most_poses) {
  SweepResult best;
  auto consider = [&](const std::vector<double>& multipliers, bool escalated) {
    // Each multiplier is scored on its own (on up to opt.threads threads), then judged in order.
    std::vector<SweepResult> scored(multipliers.size());
    ParallelFor(multipliers.size(), opt.threads, [&](size_t i) {
      scored[i] = ScoreMultiplier(cap, motion, noise, opt, multipliers[i]);
    });
    for (SweepResult& r : scored) {
      *most_poses = std::max(*most_poses, r.poses);
      r.escalated = escalated;
      if (r.tier > best.tier ||
          (r.tier == best.tier && r.tier != SweepTier::kNone && r.press < best.press)) {
        best = std::move(r);
      }
    }
  };
  consider(opt.multipliers, false);
  if (best.tier < SweepTier::kFaces) consider(opt.escalation_multipliers, true);
  return best;
}

std::string EscalationWarning(const StaticPoses& s, const CalibrateOptions& opt) {
  double ratio = 0;
  for (const StaticInterval& iv : s.intervals)
    if (iv.used) ratio = std::max(ratio, iv.gyro_std.norm() / s.noise.gyro_std.norm());
  return absl::StrFormat(
      "static poses: the usual thresholds (up to %g x the rest's noise variance) found too few "
      "still poses, so the threshold was raised to %g x: the poses shake more than the rest "
      "(gyro std up to %.0f x the rest's), as when the robot is held by hand. Their means are "
      "still used; place the robot on a support for a tighter calibration",
      opt.multipliers.empty() ? 0.0 : opt.multipliers.back(), s.multiplier, ratio);
}

// The stops of a capture as they are, for a refusal: still intervals of any length at the loosest
// usual threshold (not the steady turns), and the distinct orientations among them.
struct StopCount {
  std::vector<StaticInterval> intervals;
  int stops = 0, too_short = 0, orientations = 0, turning = 0;
  double longest_s = 0, still_s = 0, span_s = 0;
  std::vector<std::string> repeated;  // orientations held twice, faces missing
};

StopCount CountStops(const Capture& cap, const StaticPoses& s, const CalibrateOptions& opt) {
  StopCount out;
  const double m = opt.multipliers.empty() ? s.multiplier : opt.multipliers.back();
  out.intervals = DetectStatic(cap, s.motion, s.noise, m, opt.detector);
  std::vector<StaticInterval> stops;
  for (const StaticInterval& iv : out.intervals) {
    if (iv.issue != IntervalIssue::kTurning) stops.push_back(iv);
    out.turning += iv.issue == IntervalIssue::kTurning;
  }
  out.stops = static_cast<int>(stops.size());
  out.span_s = cap.size() > 1 ? cap.t_s.back() - cap.t_s.front() : 0;
  for (const StaticInterval& iv : stops) {
    out.too_short += iv.issue == IntervalIssue::kTooShort;
    const double d = iv.t_end_s - iv.t_start_s;
    out.longest_s = std::max(out.longest_s, d);
    out.still_s += d;
  }
  out.orientations = DistinctOrientations(RawUps(cap, stops));
  out.repeated = RepeatedOrientations(cap, out.intervals, RawUps(cap, out.intervals));
  return out;
}

// What a refused capture holds, what the models need, and what to record instead. The first
// sentence names the problem (a duplicated orientation, a missing face, stops too short, a rest,
// turns taken for stops, too few orientations); what was found and what each model needs follow.
Refusal DescribeRefusal(const StopCount& c, size_t most_used, const CalibrateOptions& opt) {
  Refusal out;
  const double hold_s = opt.detector.min_static_s;
  const std::string found = absl::StrFormat(
      "Found at most %d usable poses; the capture holds %d still stops (%.0f s still of %.0f s, "
      "the longest %.1f s) in %d distinct orientations, counted from stops of any length%s",
      static_cast<int>(most_used), c.stops, c.still_s, c.span_s, c.longest_s, c.orientations,
      c.turning > 0 ? absl::StrFormat(", and %d steady turns that are not rests", c.turning)
                    : "");
  auto message = [&](const std::string& first) {
    return absl::StrFormat("too few static poses: %s. %s. %s", first, found, RequirementsText());
  };
  if (!c.repeated.empty()) {
    // The orientation held twice (or the face no stop has up) is the problem: say it first.
    out.reason = RefusalReason::kTooFewOrientations;
    out.message = message(absl::StrJoin(c.repeated, "; "));
  } else if (c.stops > 0 && 2 * c.too_short >= c.stops &&
             c.orientations >= static_cast<int>(kBiasScaleNeeds.count)) {
    out.reason = RefusalReason::kStopsTooShort;
    out.message = message(absl::StrFormat(
        "%d of %d stops were too short, under the %.1f s hold: hold each pose %.0f s",
        c.too_short, c.stops, hold_s, 2 * std::ceil(hold_s)));
  } else if (c.orientations == 1) {
    out.reason = RefusalReason::kRestOnly;
    out.message = message(
        "a rest recording, in one orientation. It cannot calibrate: the scales and cross-axis "
        "terms need the sensor turned. A rest gives the noise (Allan deviation: white noise "
        "from seconds of rest, bias instability from minutes; `imucal noise`) and the bias drift");
  } else if (c.orientations > 1 && c.orientations <= 3) {
    out.reason = RefusalReason::kRestOnly;
    out.message = message(absl::StrFormat(
        "only %d orientations. A rest, a known move and a rest checks a calibration (the "
        "gyroscope's turn against the change of the gravity direction), it cannot make one: "
        "calibrate a multi-pose capture of the same unit, then apply its parameters to this one",
        c.orientations));
  } else if (c.turning > 0 && c.turning >= c.stops) {
    out.reason = RefusalReason::kTooFewOrientations;
    out.message = message(absl::StrFormat(
        "%d of the still-looking stretches were steady turns (the gyroscope turned through "
        "them), not rests: put the unit down and let go of it for each pose",
        c.turning));
  } else {
    out.reason = RefusalReason::kTooFewOrientations;
    out.message = message(absl::StrFormat(
        "only %d distinct orientations, the models need at least %d", c.orientations,
        static_cast<int>(kBiasScaleNeeds.count)));
  }
  return out;
}

}  // namespace

std::string RequirementsText() {
  std::string out = "Needs: ";
  bool first = true;
  for (const PoseRequirement* r :
       {&kSixFaceNeeds, &kFullModelNeeds, &kFacesOnceNeeds, &kBiasScaleNeeds}) {
    absl::StrAppendFormat(&out, "%s%s: %d %s", first ? "" : "; ", r->model,
                          static_cast<int>(r->count), r->what);
    first = false;
  }
  return out;
}

long TimeGaps::In(size_t begin, size_t end) const {
  for (size_t i : after)
    if (i > begin && i <= end) return static_cast<long>(i);
  return -1;
}

std::string TimeGaps::Describe(const Capture& cap, size_t i) {
  for (size_t k = 1; k < cap.files.size(); ++k) {
    if (cap.files[k].first_sample == i) {
      return absl::StrFormat(
          "the start of file %s (after %s; the time between files is not "
          "recorded)",
          cap.files[k].path, cap.files[k - 1].path);
    }
  }
  return absl::StrFormat("a time gap of %.3f s at %.3f s", cap.t_s[i] - cap.t_s[i - 1],
                         cap.t_s[i - 1]);
}

TimeGaps FindTimeGaps(const Capture& cap) {
  TimeGaps out;
  out.after = cap.FileStarts();
  const double limit = kGapFactor * cap.MedianDt();
  if (limit > 0) {
    for (size_t i = 1; i < cap.size(); ++i)
      if (cap.t_s[i] - cap.t_s[i - 1] > limit) out.after.push_back(i);
  }
  std::sort(out.after.begin(), out.after.end());
  out.after.erase(std::unique(out.after.begin(), out.after.end()), out.after.end());
  return out;
}

std::vector<int> UsedIndices(const std::vector<StaticInterval>& ivs) {
  std::vector<int> out;
  for (size_t i = 0; i < ivs.size(); ++i)
    if (ivs[i].used) out.push_back(static_cast<int>(i));
  return out;
}

std::vector<AccelPose> ToAccelPoses(const std::vector<StaticInterval>& ivs,
                                    const std::vector<int>& used, const NoiseLevel& noise) {
  std::vector<AccelPose> out;
  out.reserve(used.size());
  for (int i : used) {
    const StaticInterval& s = ivs[static_cast<size_t>(i)];
    AccelPose p;
    p.mean = s.accel_mean;
    // Never below the noise of the pose's own file (its thresholds were learnt there).
    const Eigen::Vector3d floor = s.accel_noise_std.isZero() ? noise.accel_std : s.accel_noise_std;
    p.mean_std = s.accel_std.cwiseMax(floor) / std::sqrt(static_cast<double>(s.samples()));
    // Readings on a grid whose step the noise does not dither keep a rounding error in their
    // mean that does not average down (core/quantisation.h); sigma is the pose's own scatter,
    // not the floored noise level, since it is the noise below the step that leaves it whole.
    for (int j = 0; j < 3; ++j)
      p.mean_std(j) = WithRoundingError(p.mean_std(j), noise.accel_step(j), s.accel_std(j));
    out.push_back(p);
  }
  return out;
}

StaticPoses FindStaticPoses(const Capture& cap, const CalibrateOptions& opt) {
  StaticPoses out;
  out.motion = ComputeMotionSignal(cap, opt.detector);
  out.noise = EstimateNoise(cap, out.motion);
  out.gaps = FindTimeGaps(cap);
  size_t most_poses = 0;
  SweepResult sweep = SweepThreshold(cap, out.motion, out.noise, opt, &most_poses);
  if (sweep.tier == SweepTier::kNone) {
    out.multiplier = opt.multipliers.empty() ? 0.0 : opt.multipliers.back();
    StopCount stops = CountStops(cap, out, opt);
    out.refusal = DescribeRefusal(stops, most_poses, opt);
    out.intervals = std::move(stops.intervals);
    return out;
  }
  out.multiplier = sweep.multiplier;
  out.escalated = sweep.escalated;
  out.tier = sweep.tier;
  out.intervals = std::move(sweep.intervals);
  out.rough_accel = sweep.accel;
  if (out.escalated) out.warnings.push_back(EscalationWarning(out, opt));
  for (size_t i = 0; i < out.intervals.size(); ++i) {
    const StaticInterval& iv = out.intervals[i];
    const long gap = out.gaps.In(iv.begin, iv.end - 1);
    if (gap >= 0 && iv.used) {
      out.warnings.push_back(absl::StrFormat(
          "pose %d (%.2f-%.2f s) spans %s: its means stay valid, nothing is integrated across it",
          static_cast<int>(i), iv.t_start_s, iv.t_end_s,
          TimeGaps::Describe(cap, static_cast<size_t>(gap))));
    }
  }
  return out;
}

}  // namespace imucal::core::pipeline
