// The driver of the calibration pipeline: the stages of calibrate.h in order, each one's result
// handed to the next, the report filled in as they finish, the wall time of each phase. No math
// here: each stage's file holds its own.
#include "core/calibrate/calibrate.h"

#include <chrono>
#include <vector>

#include "core/allan.h"
#include "core/calibrate/accel_stage.h"
#include "core/calibrate/effects_stage.h"
#include "core/calibrate/gyro_stage.h"
#include "core/calibrate/protocol_checks.h"
#include "core/calibrate/residuals.h"
#include "core/calibrate/static_poses.h"
#include "core/calibrate/verdict.h"

namespace imucal::core {
namespace {

using namespace pipeline;  // NOLINT(build/namespaces): the stages of this pipeline

// Appends the time since the previous mark to report->phase_ms.
class PhaseTimer {
 public:
  explicit PhaseTimer(CalibrationReport* report) : report_(report) {}
  void Mark(const char* name) {
    const auto now = std::chrono::steady_clock::now();
    report_->phase_ms.emplace_back(name, 1e3 * std::chrono::duration<double>(now - last_).count());
    last_ = now;
  }

 private:
  CalibrationReport* report_;
  std::chrono::steady_clock::time_point last_ = std::chrono::steady_clock::now();
};

template <typename T>
void Append(std::vector<T>* to, const std::vector<T>& from) {
  to->insert(to->end(), from.begin(), from.end());
}

}  // namespace

absl::StatusOr<CalibrationReport> Calibrate(const Capture& cap, const CalibrateOptions& opt) {
  const auto t0 = std::chrono::steady_clock::now();
  if (absl::Status s = ValidateCapture(cap); !s.ok()) return s;
  CalibrationReport rep;
  PhaseTimer timer(&rep);
  rep.device = cap.device;
  rep.gravity_m_s2 = cap.gravity_m_s2;

  // capture -> static poses
  absl::StatusOr<StaticPoses> still = FindStaticPoses(cap, opt);
  if (!still.ok()) return still.status();
  rep.noise = still->noise;
  rep.threshold_multiplier = still->multiplier;
  Append(&rep.warnings, still->warnings);
  timer.Mark("static");

  // -> rough gyroscope and full turns
  const RoughGyro rough = EstimateRoughGyro(cap, opt, *still);
  rep.turns = rough.turn_reports;
  timer.Mark("gyro_rough");

  // -> protocol and its checks
  const ProtocolChecks checks = CheckProtocol(cap, opt, *still, rough);
  rep.protocol = checks.protocol;
  rep.protocol_detected = checks.detected;
  rep.pairs = checks.pairs;
  Append(&rep.warnings, checks.warnings);
  const std::vector<StaticInterval>& intervals = checks.intervals;
  timer.Mark("protocol");

  // -> accelerometer: ls, bsas, lm
  absl::StatusOr<AccelStage> accel = SolveAccel(cap, opt, rep.noise, checks);
  if (!accel.ok()) return accel.status();
  Append(&rep.stages, accel->stages);
  Append(&rep.warnings, accel->warnings);
  rep.accel_chi2_reduced = accel->chi2_reduced;
  timer.Mark("accel");

  // -> final gyroscope; the pairs' turns measured with it; the six-face case frame from the axes
  //    the pairs were turned about (the gyroscope, fitted in the faces' frame, turns with it)
  FinalGyro gyro = SolveFinalGyro(cap, intervals, accel->used, accel->params, still->gaps, rough);
  Append(&rep.warnings, gyro.warnings);
  timer.Mark("gyro");
  MeasurePairTurns(cap, intervals, gyro.fit, &rep.pairs);
  if (rep.protocol == ProtocolKind::kSixFace && accel->from_faces && gyro.fit.calibrated) {
    AccelParams frame_free = accel->params;
    frame_free.frame_angles.setZero();
    const Eigen::Matrix3d R_new_old = SetCaseFrameFromPairAxes(
        rep.pairs, cap.gravity_m_s2,
        [&](int i) { return frame_free.Apply(intervals[static_cast<size_t>(i)].accel_mean); },
        &accel->params);
    TurnGyroFrame(R_new_old, &gyro.fit, &gyro.planned);
  }

  // -> residuals, poses, parameter set
  const AccelResiduals accel_residuals = ComputeAccelResiduals(
      *accel, rep.protocol, checks.ups, cap.gravity_m_s2, opt.heldout, &rep.residual);
  timer.Mark("heldout");
  rep.residual.gyro_static_rms_rad_s = GyroStaticRms(intervals, accel->used, gyro.fit.params);
  rep.poses = MakePoseReports(intervals, accel->params, accel_residuals);
  rep.params = MakeParamSet(cap, *accel, gyro.fit, intervals, rep.residual);
  ReportGyroFit(cap, gyro.planned, rough.turns, gyro.fit, &rep);
  timer.Mark("report");
  if (auto noise = NoiseFromLongestInterval(cap, intervals, rep.params); noise.ok()) {
    rep.params.noise = std::move(noise->figures);
    rep.allan = std::move(noise->curves);
  }

  // -> effects: close the loop
  if (opt.effects.enabled) {
    const absl::Status s = RunEffectsStage(cap, opt, {checks, *accel, rough, gyro}, &rep);
    if (!s.ok()) return s;
    timer.Mark("effects");
  }

  // -> verdict. Undetermined first-order parameters degrade it; undetermined second-order terms
  //    do not (six-face determines seeds/000's 12-parameter model completely), but are warned of.
  bool degraded = !gyro.fit.calibrated || accel->FirstOrderUndetermined();
  for (const PairCheck& p : rep.pairs) degraded |= !p.ok;
  rep.verdict = JudgeVerdict({.accel_rms_m_s2 = rep.residual.accel_rms_m_s2,
                              .move_rms_deg = rep.residual.move_rms_deg,
                              .degraded = degraded});
  rep.total_ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

}  // namespace imucal::core
