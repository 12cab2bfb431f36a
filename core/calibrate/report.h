// The report of a calibration: what each stage found, the residuals, the parameter set, the
// verdict and the warnings. Written as "imucal-report v1" (../shared/spec/report.md).
#ifndef IMUCAL_CORE_CALIBRATE_REPORT_H_
#define IMUCAL_CORE_CALIBRATE_REPORT_H_

#include <limits>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "core/accel_solver.h"
#include "core/allan.h"
#include "core/bias_wander.h"
#include "core/calibrate/term_priors.h"
#include "core/calibrate/verdict.h"
#include "core/effects.h"
#include "core/params.h"
#include "core/protocol.h"
#include "core/static_detector.h"

namespace imucal::core {

struct PoseReport {
  int index = 0;
  StaticInterval interval;                       // times, means (input units), used/reason
  std::string face;                              // "Z+" when on a face, else ""
  Eigen::Vector3d up = Eigen::Vector3d::Zero();  // calibrated up direction, body frame
  double residual_m_s2 = std::numeric_limits<double>::quiet_NaN();  // |a| - g, in-sample
  double heldout_m_s2 = std::numeric_limits<double>::quiet_NaN();   // |a| - g, pose left out
  // Where it came from: the file and its first and last line (empty and 0 when the capture does
  // not say; for a bag, message ordinals).
  std::string file;
  uint32_t first_line = 0, last_line = 0;
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
  // The RMS |a| - g would have if the model were perfect: the pose means' noise, m/s^2.
  double accel_noise_floor_m_s2 = std::numeric_limits<double>::quiet_NaN();
  double accel_heldout_rms_m_s2 = std::numeric_limits<double>::quiet_NaN();
  double accel_heldout_max_m_s2 = std::numeric_limits<double>::quiet_NaN();
  double gyro_static_rms_rad_s = 0;  // |calibrated rate| over the static poses
  // The gravity direction after the moves with the final parameter set as the SDK applies it
  // (ReportFinalFigures), and as the gyroscope's fit left it (bias interpolated between each
  // move's poses, the ups before the effects): the held-out figures compare with the fit's.
  double move_rms_deg = std::numeric_limits<double>::quiet_NaN();
  double move_max_deg = std::numeric_limits<double>::quiet_NaN();
  double move_fit_rms_deg = std::numeric_limits<double>::quiet_NaN();
  double move_heldout_rms_deg = std::numeric_limits<double>::quiet_NaN();
  double move_heldout_max_deg = std::numeric_limits<double>::quiet_NaN();
};

// Why a capture was refused (verdict refused): it cannot determine even bias and scale.
enum class RefusalReason {
  kStopsTooShort,       // still stops found, but too short to hold a pose
  kTooFewOrientations,  // too few distinct orientations for any model
  kRestOnly,            // one orientation (or two or three): a rest or a check, not a calibration
  kPosesTooAlike,       // the poses do not spread over the sphere (all in one plane, ...)
  kUnitMismatch,        // a fitted scale is far from its unit's: the unit is wrong (unit_check.h)
};
// "stops_too_short", "too_few_orientations", "rest_only", "poses_too_alike", "unit_mismatch".
std::string_view RefusalReasonName(RefusalReason reason);

struct Refusal {
  RefusalReason reason = RefusalReason::kTooFewOrientations;
  std::string message;  // what the capture holds, what the models need, what to record
};

// The units the capture was read in and how each was decided ("declared", "file", "inferred";
// empty: unstated, e.g. a capture made in memory or a device's registered units).
struct InputUnits {
  AccelUnit accel = AccelUnit::kMetersPerSecond2;
  GyroUnit gyro = GyroUnit::kRadPerSecond;
  std::string accel_source;
  std::string gyro_source;
};

struct CalibrationReport {
  std::string device;
  InputUnits input_units;
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
  // What each prior did to its term (core/calibrate/term_priors.h): the faces' angles, the
  // sensor class's second-order terms.
  std::vector<TermPriorEffect> term_priors;
  Verdict verdict = Verdict::kFail;
  // The gates that failed or warned and what the capture left incomplete (verdict.h).
  std::vector<std::string> verdict_reasons;
  // Set exactly when verdict is refused; the report then holds the poses found and no
  // parameters.
  std::optional<Refusal> refusal;
  std::vector<std::string> warnings;
  // What the residual search examined and found; its effects are in params.effects.
  EffectDiagnostics effect_diagnostics;
  // Allan deviation curves of the interval params.noise was measured on (core/allan.h), for the
  // plot; empty when no used interval was long enough.
  AllanCurves allan;
  // The gyroscope's static rate as a sequence over the poses, with the final parameter set
  // (core/bias_wander.h): how its bias moves between poses. Not run when the gyroscope's output
  // is not in rad/s or the capture has fewer than 6 used poses.
  BiasWander gyro_wander;
  double total_ms = 0;
  // Wall time of each phase of the pipeline, in order: {"static", ms}, {"gyro_rough", ms}, ...
  std::vector<std::pair<std::string, double>> phase_ms;
};

}  // namespace imucal::core

#endif  // IMUCAL_CORE_CALIBRATE_REPORT_H_
