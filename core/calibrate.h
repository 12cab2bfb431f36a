// The offline calibration pipeline: a capture in, a verified parameter set and its report out.
//
//   capture -> noise level -> static intervals (threshold multiplier swept, the one whose
//   calibration predicts held-out poses best is kept) -> rough accelerometer -> gyroscope from
//   the rotations between poses -> protocol (detected or declared) and its checks (six-face
//   pairs, duplicates) -> accelerometer stages ls, bsas, lm -> final gyroscope -> residuals
//   in-sample and held-out -> observability -> effects the residual shows (core/effects.h),
//   refitted jointly -> verdict.
#ifndef IMUCAL_CORE_CALIBRATE_H_
#define IMUCAL_CORE_CALIBRATE_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/accel_solver.h"
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
};

struct PoseReport {
  int index = 0;
  StaticInterval interval;  // times, means (input units), used/reason
  std::string face;         // "Z+" when on a face, else ""
  Eigen::Vector3d up = Eigen::Vector3d::Zero();  // calibrated up direction, body frame
  double residual_m_s2 = std::numeric_limits<double>::quiet_NaN();  // |a| - g, in-sample
  double heldout_m_s2 = std::numeric_limits<double>::quiet_NaN();   // |a| - g, pose left out
};

struct MoveReport {
  int from_pose = 0, to_pose = 0;
  double error_deg = 0;          // predicted vs measured gravity direction, in-sample
  double heldout_error_deg = std::numeric_limits<double>::quiet_NaN();
  double rotation_deg = 0;       // total rotation of the move
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
  std::vector<StageReport> stages;
  Residuals residual;
  ParamSet params;
  double accel_chi2_reduced = 0;
  std::string verdict;  // pass | warn | fail
  std::vector<std::string> warnings;
  // What the residual search examined and found; its effects are in params.effects.
  EffectDiagnostics effect_diagnostics;
  double total_ms = 0;
  // Wall time of each phase of the pipeline, in order: {"static", ms}, {"gyro_rough", ms}, ...
  std::vector<std::pair<std::string, double>> phase_ms;
};

// Errors: FailedPrecondition when the capture cannot determine the model (too few poses, poses
// too alike), naming what to add; InvalidArgument for a capture that fails ValidateCapture.
absl::StatusOr<CalibrationReport> Calibrate(const Capture& capture,
                                            const CalibrateOptions& options);

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CALIBRATE_H_
