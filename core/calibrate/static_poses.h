// Calibration stage "static": the capture's noise at rest, its static poses and its time gaps.
//
// The detector (core/static_detector.h) compares window variances against a multiple of the
// noise variance learnt from the capture. The multiple is not a constant to tune: each one of
// CalibrateOptions::multipliers is tried, and the one whose accelerometer fit predicts held-out
// poses best (PRESS) is kept, within the best tier any multiple reaches (SweepTier). Captures
// held by hand shake more than the rest the noise is learnt on: the escalation multipliers are
// tried only when the usual ones find too few poses for the full model.
#ifndef IMUCAL_CORE_CALIBRATE_STATIC_POSES_H_
#define IMUCAL_CORE_CALIBRATE_STATIC_POSES_H_

#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/accel_solver.h"
#include "core/calibrate/calibrate.h"
#include "core/calibrate/report.h"
#include "core/capture.h"
#include "core/static_detector.h"

namespace imucal::core::pipeline {

// What each model needs from a capture: the one table every refusal and warning quotes.
struct PoseRequirement {
  std::string_view model;
  size_t count;
  std::string_view what;
};
inline constexpr PoseRequirement kFullModelNeeds{
    "the full model (bias, scale, misalignment, second-order terms)", 10,
    "distinct orientations spread over the sphere, some with gravity between two axes"};
inline constexpr PoseRequirement kSixFaceNeeds{
    "six-face, the recommended protocol (each pair's 180-degree turn cancels the floor's tilt)", 12,
    "poses: each face up twice, turned 180 degrees about the vertical between the two"};
inline constexpr PoseRequirement kFacesOnceNeeds{
    "the 12-parameter model of the face references (seeds/000), the floor assumed level", 6,
    "orientations: the six faces, each held once"};
inline constexpr PoseRequirement kBiasScaleNeeds{
    "bias and scale alone", 6,
    "orientations with every axis pointing up and down (a 7th leaves one to check the fit)"};
// "needs: the full model (...) 10 distinct orientations ...; six-face ...; ...".
std::string RequirementsText();

// What the poses of one threshold can determine, best first.
enum class SweepTier {
  kNone = 0,
  kBiasScale = 1,  // 7+ poses, every axis up and down: bias and scale (6 parameters)
  kFaces = 2,      // the six faces: the affine model from the face references (ferraris)
  kFull = 3,       // 10+ poses on an ellipsoid: the full model
};

// The capture's time gaps: an interval between samples over 3x the median interval (as the
// importers note it). The gyroscope was not recorded across a gap.
struct TimeGaps {
  std::vector<size_t> after;  // the sample index after each gap

  // The first gap inside samples [begin, end] (between samples i-1 and i with begin < i <= end),
  // or -1.
  long In(size_t begin, size_t end) const;
  // "a time gap of 0.500 s at 12.250 s" for the gap before sample `i`.
  static std::string Describe(const Capture& capture, size_t i);
};
TimeGaps FindTimeGaps(const Capture& capture);

struct StaticPoses {
  MotionSignal motion;
  NoiseLevel noise;
  double multiplier = 0;   // the threshold multiplier kept
  bool escalated = false;  // found only above the usual multipliers
  SweepTier tier = SweepTier::kNone;
  std::vector<StaticInterval> intervals;  // every interval found, used or not (and why)
  // The accelerometer the sweep fitted at that multiplier (bias and scale, or the linear model):
  // good to a few mrad, enough for pose directions in the checks.
  AccelParams rough_accel;
  TimeGaps gaps;
  std::vector<std::string> warnings;
  // Set when no multiplier finds poses that determine even bias and scale: `intervals` are then
  // the stops at the loosest usual multiplier, each with why it is not usable.
  std::optional<Refusal> refusal;
};

StaticPoses FindStaticPoses(const Capture& capture, const CalibrateOptions& options);

// The indices of the used intervals, in time order.
std::vector<int> UsedIndices(const std::vector<StaticInterval>& intervals);

// The used intervals as the accelerometer solver sees them: the mean and its standard error (the
// interval's scatter, never below the capture's noise level).
std::vector<AccelPose> ToAccelPoses(const std::vector<StaticInterval>& intervals,
                                    const std::vector<int>& used, const NoiseLevel& noise);

}  // namespace imucal::core::pipeline

#endif  // IMUCAL_CORE_CALIBRATE_STATIC_POSES_H_
