// The offline calibration pipeline: a capture in, a verified parameter set and its report out.
// Each stage lives in a file of its own in this folder; Calibrate() (calibrate.cc) runs them in
// this order:
//
//   capture
//     -> static_poses     noise at rest; static intervals, the threshold multiplier swept and the
//                         one whose calibration predicts held-out poses best kept; time gaps
//     -> gyro_stage       rough gyroscope (for the checks) and the full turns (Ferraris)
//     -> protocol_checks  protocol (detected or declared) and its checks: six-face pairs,
//                         ferraris turns, duplicate poses
//     -> accel_stage      ls (face references, or the ellipsoid), observability, second-order
//                         terms, bsas, lm
//     -> gyro_stage       final gyroscope from the rotations between poses and the full turns;
//                         the pairs' turns measured with it; the six-face case frame from the
//                         axes the pairs were turned about (the gyroscope turns with it)
//     -> residuals        in-sample and held-out residuals, pose reports, the parameter set with
//                         its standard errors, Allan noise figures
//     -> effects_stage    effects the residual shows (core/effects.h), refitted jointly; with an
//                         applied accelerometer effect, the case frame and the gyroscope fitted
//                         again to the pose directions it corrects
//     -> verdict          the quality gates (verdict.h)
//   -> report (report.h)
//
// Captures that cannot determine everything still calibrate what they can, with a warning and a
// "warn" verdict: fewer than 10 poses give bias and scale only (7 or more, every axis up and
// down); the six faces held once each (ferraris) give the 12-parameter affine model from the
// face references. Moves across a time gap (an interval over 3x the median) or whose gravity
// change the gyroscope cannot explain (a cut in the data) are left out of the gyroscope fit and
// the pair checks, with a warning naming them.
#ifndef IMUCAL_CORE_CALIBRATE_CALIBRATE_H_
#define IMUCAL_CORE_CALIBRATE_CALIBRATE_H_

#include <cstdint>
#include <vector>

#include "absl/status/statusor.h"
#include "core/calibrate/report.h"
#include "core/capture.h"
#include "core/effects.h"
#include "core/protocol.h"
#include "core/static_detector.h"

namespace imucal::core {

struct CalibrateOptions {
  ProtocolKind protocol = ProtocolKind::kAuto;
  uint64_t seed = 1;  // BSAS's random seed: the same capture and seed give the same result
  // Threads the independent steps may use (the still-threshold sweep's multipliers); the result
  // is the same for any count. 1 in the server, whose solve pool runs solves side by side.
  int threads = 1;
  bool use_bsas = true;
  bool heldout = true;  // leave-one-pose-out accelerometer refits (the held-out figures)
  StaticDetectorOptions detector;
  // The search for effects the model misses (core/effects.h), after the solve.
  EffectSearchOptions effects;
  // Threshold multipliers tried (times the learnt noise variance).
  std::vector<double> multipliers = {2, 3, 4, 6, 8, 12, 16, 24, 32, 48};
  // Tried only when `multipliers` find too few poses for the full model: poses held by hand
  // shake more than a rest on a table (the noise is learnt there), up to 16x its std.
  std::vector<double> escalation_multipliers = {64, 96, 128, 192, 256};
  // The prior widths of the model's own terms (core/params.h; TermPriorsFor in
  // core/calibrate/term_priors.h gives a class's).
  TermPriors term_priors;
};

// A capture that cannot determine even bias and scale is not an error: the report's verdict is
// refused, with the refusal (what the capture holds, what the models need) and every interval
// found. Errors: InvalidArgument for a capture that fails ValidateCapture; Internal when a solver
// fails on data it accepted.
// A capture without a gyroscope (Capture::has_gyro false) gets the accelerometer stages alone:
// the still poses from the accelerometer, the protocol's checks that need no gyroscope (a
// six-face pair's turn is PairCheck::turn_checked false), ls/bsas/lm, held-out figures and the
// accelerometer's noise; no gyroscope stage, moves, turns or effects search, and the parameter
// set has has_gyro false.
absl::StatusOr<CalibrationReport> Calibrate(const Capture& capture,
                                            const CalibrateOptions& options);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CALIBRATE_CALIBRATE_H_
