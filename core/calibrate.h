// The offline calibration pipeline: a capture in, a verified parameter set and its report out.
//
//   capture -> noise level -> static intervals (threshold multiplier swept, the one whose
//   calibration predicts held-out poses best is kept) -> rough accelerometer -> gyroscope from
//   the rotations between poses -> protocol (detected or declared) and its checks (six-face
//   pairs, duplicates) -> accelerometer stages ls, bsas, lm -> final gyroscope -> six-face case
//   frame from the axes the pairs were turned about (core/protocol.h PairTurnAxis, with the
//   turns that gyroscope measured; the gyroscope turns with the frame) -> residuals in-sample
//   and held-out -> observability -> effects the residual shows (core/effects.h), refitted
//   jointly; with an applied accelerometer effect, the case frame and the gyroscope fitted
//   again to the pose directions it corrects -> verdict.
//
// Captures that cannot determine everything still calibrate what they can, with a warning and a
// "warn" verdict: fewer than 10 poses give bias and scale only (7 or more, every axis up and
// down); the six faces held once each (ferraris) give the 12-parameter affine model from the
// face references. Moves across a time gap (an interval over 3x the median) or whose gravity
// change the gyroscope cannot explain (a cut in the data) are left out of the gyroscope fit and
// the pair checks, with a warning naming them.
#ifndef IMUCAL_CORE_CALIBRATE_H_
#define IMUCAL_CORE_CALIBRATE_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/accel_solver.h"
#include "core/allan.h"
#include "core/capture.h"
#include "core/effects.h"
#include "core/params.h"
#include "core/protocol.h"
#include "core/static_detector.h"

namespace imucal::core {

struct CalibrateOptions {
  ProtocolKind protocol = ProtocolKind::kAuto;
  uint64_t seed = 1;  // BSAS's random seed: the same capture and seed give the same result
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
};

struct PoseReport {
  int index = 0;
  StaticInterval interval;                       // times, means (input units), used/reason
  std::string face;                              // "Z+" when on a face, else ""
  Eigen::Vector3d up = Eigen::Vector3d::Zero();  // calibrated up direction, body frame
  double residual_m_s2 = std::numeric_limits<double>::quiet_NaN();  // |a| - g, in-sample
  double heldout_m_s2 = std::numeric_limits<double>::quiet_NaN();   // |a| - g, pose left out
};

struct MoveReport {
  int from_pose = 0, to_pose = 0;
  double error_deg = 0;  // predicted vs measured gravity direction, in-sample
  double heldout_error_deg = std::numeric_limits<double>::quiet_NaN();
  double rotation_deg = 0;  // total rotation of the move
};

// A full turn (Ferraris et al. 1995) found in the capture: from a still orientation about one
// axis back to it, whole turns; its known angle constrains the gyroscope's scale.
struct TurnReport {
  double t_start_s = 0, t_end_s = 0;
  int turns = 1;                                        // whole turns (360 degrees each)
  Eigen::Vector3d axis_body = Eigen::Vector3d::Zero();  // unit, body frame; zero when unknown
  std::string axis;                                     // "z (vertical)", "unknown (not vertical)"
  double angle_deg = std::numeric_limits<double>::quiet_NaN();  // with the final gyroscope
  double error_deg = std::numeric_limits<double>::quiet_NaN();  // |constraint residual|
};

struct Residuals {
  double accel_rms_m_s2 = 0, accel_max_m_s2 = 0;
  double accel_heldout_rms_m_s2 = std::numeric_limits<double>::quiet_NaN();
  double accel_heldout_max_m_s2 = std::numeric_limits<double>::quiet_NaN();
  double gyro_static_rms_rad_s = 0;  // |calibrated rate| over the static poses
  double move_rms_deg = std::numeric_limits<double>::quiet_NaN();
  double move_max_deg = std::numeric_limits<double>::quiet_NaN();
  double move_heldout_rms_deg = std::numeric_limits<double>::quiet_NaN();
  double move_heldout_max_deg = std::numeric_limits<double>::quiet_NaN();
};

struct CalibrationReport {
  std::string device;
  double gravity_m_s2 = kStandardGravity;
  ProtocolKind protocol = ProtocolKind::kFree;
  bool protocol_detected = false;
  NoiseLevel noise;
  double threshold_multiplier = 0;
  std::vector<PoseReport> poses;
  std::vector<PairCheck> pairs;
  std::vector<MoveReport> moves;
  std::vector<TurnReport> turns;
  std::vector<StageReport> stages;
  Residuals residual;
  ParamSet params;
  double accel_chi2_reduced = 0;
  std::string verdict;  // pass | warn | fail
  std::vector<std::string> warnings;
  // What the residual search examined and found; its effects are in params.effects.
  EffectDiagnostics effect_diagnostics;
  // Allan deviation curves of the interval params.noise was measured on (core/allan.h), for the
  // plot; empty when no used interval was long enough.
  AllanCurves allan;
  double total_ms = 0;
  // Wall time of each phase of the pipeline, in order: {"static", ms}, {"gyro_rough", ms}, ...
  std::vector<std::pair<std::string, double>> phase_ms;
};

// Errors: FailedPrecondition when the capture cannot determine even bias and scale (fewer than
// 7 usable poses and not the six faces, poses too alike), naming what to add; InvalidArgument for a
// capture that fails ValidateCapture.
absl::StatusOr<CalibrationReport> Calibrate(const Capture& capture,
                                            const CalibrateOptions& options);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CALIBRATE_H_
