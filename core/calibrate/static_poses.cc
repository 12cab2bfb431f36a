#include "core/calibrate/static_poses.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_format.h"
#include "core/protocol.h"

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
  } else if (poses.size() >= kBiasScalePoses) {
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
    for (double m : multipliers) {
      SweepResult r = ScoreMultiplier(cap, motion, noise, opt, m);
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

}  // namespace

long TimeGaps::In(size_t begin, size_t end) const {
  for (size_t i : after)
    if (i > begin && i <= end) return static_cast<long>(i);
  return -1;
}

std::string TimeGaps::Describe(const Capture& cap, size_t i) {
  return absl::StrFormat("a time gap of %.3f s at %.3f s", cap.t_s[i] - cap.t_s[i - 1],
                         cap.t_s[i - 1]);
}

TimeGaps FindTimeGaps(const Capture& cap) {
  TimeGaps out;
  const double limit = kGapFactor * cap.MedianDt();
  if (!(limit > 0)) return out;
  for (size_t i = 1; i < cap.size(); ++i)
    if (cap.t_s[i] - cap.t_s[i - 1] > limit) out.after.push_back(i);
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
    p.mean_std =
        s.accel_std.cwiseMax(noise.accel_std) / std::sqrt(static_cast<double>(s.samples()));
    out.push_back(p);
  }
  return out;
}

absl::StatusOr<StaticPoses> FindStaticPoses(const Capture& cap, const CalibrateOptions& opt) {
  StaticPoses out;
  out.motion = ComputeMotionSignal(cap, opt.detector);
  out.noise = EstimateNoise(cap, out.motion);
  size_t most_poses = 0;
  SweepResult sweep = SweepThreshold(cap, out.motion, out.noise, opt, &most_poses);
  if (sweep.tier == SweepTier::kNone) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "too few static poses: found at most %d usable, the accelerometer needs at least 10 "
        "distinct orientations held still for %.1f s or more (bias and scale alone: at least %d, "
        "with every axis pointing up and down; or the six faces once each and full turns, the "
        "ferraris protocol)",
        static_cast<int>(most_poses), opt.detector.min_static_s,
        static_cast<int>(kBiasScalePoses)));
  }
  out.multiplier = sweep.multiplier;
  out.escalated = sweep.escalated;
  out.tier = sweep.tier;
  out.intervals = std::move(sweep.intervals);
  out.rough_accel = sweep.accel;
  if (out.escalated) out.warnings.push_back(EscalationWarning(out, opt));
  out.gaps = FindTimeGaps(cap);
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
