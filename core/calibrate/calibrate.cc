// The driver of the calibration pipeline: the stages of calibrate.h in order, each one's result
// handed to the next, the report filled in as they finish, the wall time of each phase. No math
// here: each stage's file holds its own.
#include "core/calibrate/calibrate.h"

#include <algorithm>
#include <chrono>
#include <optional>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/allan.h"
#include "core/calibrate/accel_stage.h"
#include "core/calibrate/effects_stage.h"
#include "core/calibrate/gyro_stage.h"
#include "core/calibrate/protocol_checks.h"
#include "core/calibrate/residuals.h"
#include "core/calibrate/static_poses.h"
#include "core/calibrate/unit_check.h"
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

// The report of a refused capture: every interval found, with why it is not usable, and the
// refusal; no parameters.
CalibrationReport Refuse(const Capture& cap, CalibrationReport rep, Refusal refusal,
                         const std::vector<StaticInterval>& intervals) {
  rep.poses.clear();
  for (size_t i = 0; i < intervals.size(); ++i) {
    PoseReport pr;
    pr.index = static_cast<int>(i);
    pr.interval = intervals[i];
    rep.poses.push_back(pr);
  }
  AttachSources(cap, &rep.poses);
  rep.verdict = Verdict::kRefused;
  rep.verdict_reasons = {refusal.message};
  rep.refusal = std::move(refusal);
  return rep;
}

// The used poses that alone determine part of the model (VerdictInputs::lone_poses) and the
// held-out figures with and without them. A least-squares fit's held-out residual is its
// in-sample one over 1 - h (h the pose's leverage, PRESS): h near 1 means the fit bends to the
// pose whatever it reads, and leaving it out leaves that part undetermined.
void SetLonePoses(const std::vector<PoseReport>& poses, VerdictInputs* in) {
  constexpr double kSelfDetermined = 0.95;  // leverage
  double ss_all = 0, ss_lone = 0;
  size_t n_all = 0, n_lone = 0;
  for (const PoseReport& p : poses) {
    if (!p.interval.used || !std::isfinite(p.heldout_m_s2)) continue;
    const double r2 = p.heldout_m_s2 * p.heldout_m_s2;
    ss_all += r2;
    ++n_all;
    const double leverage =
        p.heldout_m_s2 != 0 && std::isfinite(p.residual_m_s2) ? 1 - p.residual_m_s2 / p.heldout_m_s2
                                                              : 0.0;
    if (leverage < kSelfDetermined) continue;
    ss_lone += r2;
    ++n_lone;
    in->lone_faces += !p.face.empty();
    in->lone_poses.push_back(
        p.face.empty() ? absl::StrFormat("pose %d (up %.2f %.2f %.2f)", p.index, p.up(0), p.up(1),
                                         p.up(2))
                       : absl::StrFormat("%s (pose %d)", p.face, p.index));
  }
  // With every pose self-determined (six faces once) there is nothing to compare: the capture's
  // own warnings say so (the 12-parameter model), and the gate reads the figure as it is.
  if (n_lone == 0 || n_lone == n_all || ss_all <= 0) {
    in->lone_poses.clear();
    in->lone_faces = 0;
    return;
  }
  const double rms_all = std::sqrt(ss_all / static_cast<double>(n_all));
  const double rms_checked = std::sqrt((ss_all - ss_lone) / static_cast<double>(n_all - n_lone));
  in->accel_heldout_checked_rms_m_s2 = in->accel_heldout_rms_m_s2 * rms_checked / rms_all;
  in->accel_heldout_lone_rms_m_s2 =
      in->accel_heldout_rms_m_s2 * std::sqrt(ss_lone / static_cast<double>(n_lone)) / rms_all;
}

// A fitted scale far from its unit's (core/calibrate/unit_check.h): the unit is wrong, and
// nothing after the fit is meaningful. Sets the refusal and returns true.
bool RefuseWrongUnit(const Capture& cap, const std::vector<StaticInterval>& intervals,
                     const std::vector<int>& used, CalibrationReport* rep) {
  std::vector<StaticInterval> used_poses;
  for (int i : used) used_poses.push_back(intervals[static_cast<size_t>(i)]);
  std::optional<Refusal> wrong_unit = CheckFittedUnits(cap, rep->params, used_poses);
  if (!wrong_unit) return false;
  rep->verdict = Verdict::kRefused;
  rep->verdict_reasons = {wrong_unit->message};
  rep->refusal = std::move(wrong_unit);
  return true;
}

// What the verdict reads: the final figures, the parameters' spreads, what the model lacks.
// `gyro` is null for a capture without a gyroscope (nothing is missing from its model).
VerdictInputs VerdictInputsOf(const CalibrationReport& rep, const AccelStage& accel,
                              const GyroFit* gyro) {
  VerdictInputs in;
  in.accel_rms_m_s2 = rep.residual.accel_rms_m_s2;
  in.accel_heldout_rms_m_s2 = rep.residual.accel_heldout_rms_m_s2;
  in.accel_noise_floor_m_s2 = rep.residual.accel_noise_floor_m_s2;
  const double n = static_cast<double>(accel.poses.size());
  const double p = static_cast<double>(std::count(accel.free.begin(), accel.free.end(), true));
  if (n > p) in.accel_heldout_inflation = n / (n - p);
  in.move_rms_deg = rep.residual.move_rms_deg;
  in.move_fit_rms_deg = rep.residual.move_fit_rms_deg;
  in.move_heldout_rms_deg = rep.residual.move_heldout_rms_deg;
  in.parameters = ParameterSpreads(rep.params, accel.free);
  SetLonePoses(rep.poses, &in);
  in.incomplete = accel.incomplete;
  if (gyro != nullptr && !gyro->calibrated)
    in.incomplete.push_back("gyroscope: only the bias was calibrated (the warnings say why)");
  for (const PairCheck& pair : rep.pairs)
    if (!pair.ok)
      in.incomplete.push_back(absl::StrFormat("six-face pair of poses %d and %d (%s) rejected",
                                              pair.pose_a, pair.pose_b, pair.face));
  return in;
}

// The report's start: the capture's units, for a report that ends before the parameter set (a
// refusal).
void StartReport(const Capture& cap, CalibrationReport* rep) {
  rep->device = cap.device;
  rep->input_units = {cap.accel_unit, cap.gyro_unit, cap.accel_unit_source, cap.gyro_unit_source};
  rep->gravity_m_s2 = cap.gravity_m_s2;
  // The capture's units, for a report that ends before the parameter set (a refusal).
  rep->params.device = cap.device;
  rep->params.accel_unit = cap.accel_unit;
  rep->params.gyro_unit = cap.gyro_unit;
  rep->params.gravity_m_s2 = cap.gravity_m_s2;
  rep->params.has_gyro = cap.has_gyro;
}

// What the static detector and the noise analysis read for a capture without a gyroscope: the
// same samples with a gyroscope that reads exactly zero, so that the accelerometer alone decides
// what is still (both read the gyro of every sample). Nothing else sees it: every stage that
// would believe a gyro reading is skipped, and the gyro figures they return are dropped.
Capture WithStillGyro(const Capture& cap) {
  Capture view = cap;
  view.has_gyro = true;
  view.gyro.assign(cap.size(), Eigen::Vector3d::Zero());
  return view;
}

// The noise block of an accelerometer-only parameter set: the accelerometer's figures only.
void AttachAccelNoise(const Capture& still_view, const std::vector<StaticInterval>& intervals,
                      CalibrationReport* rep) {
  absl::StatusOr<NoiseAnalysis> noise =
      NoiseFromLongestInterval(still_view, intervals, rep->params);
  if (!noise.ok()) return;
  noise->figures.gyro = SensorNoise{};
  std::erase_if(noise->figures.notes, [](const std::string& n) { return n.starts_with("gyro"); });
  noise->curves.gyro_rad_s.clear();
  rep->params.noise = std::move(noise->figures);
  rep->allan = std::move(noise->curves);
}

// The stages a capture with or without a gyroscope shares: the protocol and its checks, then
// the accelerometer (ls, bsas, lm). The accelerometer stage, or nullopt with `rep` made the
// refusal when the poses determine not even bias and scale, or an error.
absl::StatusOr<std::optional<AccelStage>> ProtocolAndAccel(const Capture& cap,
                                                           const CalibrateOptions& opt,
                                                           const StaticPoses& still,
                                                           const RoughGyro& rough,
                                                           PhaseTimer* timer,
                                                           CalibrationReport* rep,
                                                           ProtocolChecks* checks) {
  *checks = CheckProtocol(cap, opt, still, rough);
  rep->protocol = checks->protocol;
  rep->protocol_detected = checks->detected;
  rep->pairs = checks->pairs;
  Append(&rep->warnings, checks->warnings);
  timer->Mark("protocol");
  absl::StatusOr<AccelStage> accel = SolveAccel(cap, opt, rep->noise, *checks);
  if (absl::IsFailedPrecondition(accel.status())) {
    *rep = Refuse(cap, std::move(*rep),
                  {RefusalReason::kPosesTooAlike,
                   absl::StrCat(accel.status().message(), ". ", RequirementsText())},
                  checks->intervals);
    return std::nullopt;
  }
  if (!accel.ok()) return accel.status();
  Append(&rep->stages, accel->stages);
  Append(&rep->warnings, accel->warnings);
  rep->accel_chi2_reduced = accel->chi2_reduced;
  rep->term_priors = accel->term_priors;
  timer->Mark("accel");
  return std::optional<AccelStage>(*std::move(accel));
}

// Calibrate for a capture without a gyroscope: the accelerometer stages alone. No gyroscope
// stage, no turn checks (six-face pairs are checked on their faces only), no moves, no effects
// search (it reads the gyroscope's moves); the parameter set has no gyro part.
absl::StatusOr<CalibrationReport> CalibrateAccelOnly(const Capture& cap,
                                                     const CalibrateOptions& opt) {
  const auto t0 = std::chrono::steady_clock::now();
  CalibrationReport rep;
  PhaseTimer timer(&rep);
  StartReport(cap, &rep);
  const Capture still_view = WithStillGyro(cap);
  const StaticPoses still = FindStaticPoses(still_view, opt);
  rep.noise = still.noise;
  rep.threshold_multiplier = still.multiplier;
  Append(&rep.warnings, still.warnings);
  timer.Mark("static");
  if (still.refusal) return Refuse(cap, std::move(rep), *still.refusal, still.intervals);

  ProtocolChecks checks;
  absl::StatusOr<std::optional<AccelStage>> solved =
      ProtocolAndAccel(cap, opt, still, RoughGyro{}, &timer, &rep, &checks);
  if (!solved.ok()) return solved.status();
  std::optional<AccelStage>& accel = *solved;
  if (!accel) return rep;  // refused: the poses are too alike
  const std::vector<StaticInterval>& intervals = checks.intervals;

  const AccelResiduals accel_residuals = ComputeAccelResiduals(
      *accel, rep.protocol, checks.ups, cap.gravity_m_s2, opt.heldout, &rep.residual);
  rep.poses = MakePoseReports(intervals, accel->params, accel_residuals);
  AttachSources(cap, &rep.poses);
  rep.params = MakeParamSet(cap, *accel, GyroFit{}, intervals, rep.residual, rep.noise);
  rep.params.term_priors = opt.term_priors;
  rep.params.has_gyro = false;
  if (RefuseWrongUnit(cap, intervals, accel->used, &rep)) return rep;
  rep.warnings.push_back(
      "accelerometer only: the capture has no gyroscope, so the parameter set has no gyro part "
      "and nothing was checked with one (pair turns, gravity direction after the moves)");
  if (opt.effects.enabled) {
    rep.effect_diagnostics.notes.push_back(
        "effects search skipped: it needs the gyroscope (the capture has none)");
  }
  AttachAccelNoise(still_view, intervals, &rep);
  timer.Mark("report");

  VerdictResult verdict = JudgeVerdict(VerdictInputsOf(rep, *accel, nullptr));
  rep.verdict = verdict.verdict;
  rep.verdict_reasons = std::move(verdict.reasons);
  rep.total_ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

}  // namespace

std::string_view RefusalReasonName(RefusalReason reason) {
  switch (reason) {
    case RefusalReason::kStopsTooShort:
      return "stops_too_short";
    case RefusalReason::kTooFewOrientations:
      return "too_few_orientations";
    case RefusalReason::kRestOnly:
      return "rest_only";
    case RefusalReason::kPosesTooAlike:
      return "poses_too_alike";
    case RefusalReason::kUnitMismatch:
      return "unit_mismatch";
  }
  return "too_few_orientations";
}

namespace {

// The final gyroscope, the pairs' turns measured with it, and the six-face case frame from the
// axes the pairs were turned about (the gyroscope, fitted in the faces' frame, turns with it).
FinalGyro GyroAndCaseFrame(const Capture& cap, const std::vector<StaticInterval>& intervals,
                           const StaticPoses& still, const RoughGyro& rough, PhaseTimer* timer,
                           AccelStage* accel, CalibrationReport* rep) {
  FinalGyro gyro = SolveFinalGyro(cap, intervals, accel->used, accel->params, still.gaps, rough);
  Append(&rep->warnings, gyro.warnings);
  timer->Mark("gyro");
  MeasurePairTurns(cap, intervals, gyro.fit, &rep->pairs);
  if (rep->protocol == ProtocolKind::kSixFace && accel->from_faces && gyro.fit.calibrated) {
    AccelParams frame_free = accel->params;
    frame_free.frame_angles.setZero();
    const Eigen::Matrix3d R_new_old = SetCaseFrameFromPairAxes(
        rep->pairs, cap.gravity_m_s2,
        [&](int i) { return frame_free.Apply(intervals[static_cast<size_t>(i)].accel_mean); },
        &accel->params);
    TurnGyroFrame(R_new_old, &gyro.fit, &gyro.planned);
  }
  return gyro;
}

// The figures a robot will see: the final parameter set applied as the SDK applies it, the
// noise figures of the longest rest, and the gyroscope's bias between poses (what the static
// residual is made of).
void FinalFigures(const Capture& cap, const std::vector<StaticInterval>& intervals,
                  const FinalGyro& gyro, const AccelStage& accel, CalibrationReport* rep) {
  ReportFinalFigures(cap, intervals, gyro.planned, rep);
  if (auto noise = NoiseFromLongestInterval(cap, intervals, rep->params); noise.ok()) {
    rep->params.noise = std::move(noise->figures);
    rep->allan = std::move(noise->curves);
  }
  rep->gyro_wander = GyroWanderOf(cap, intervals, accel.used, rep->params, rep->noise);
  if (rep->gyro_wander.ran) rep->effect_diagnostics.notes.push_back(rep->gyro_wander.note);
}

}  // namespace

absl::StatusOr<CalibrationReport> Calibrate(const Capture& cap, const CalibrateOptions& opt) {
  const auto t0 = std::chrono::steady_clock::now();
  if (absl::Status s = ValidateCapture(cap); !s.ok()) return s;
  if (!cap.has_gyro) return CalibrateAccelOnly(cap, opt);
  CalibrationReport rep;
  PhaseTimer timer(&rep);
  StartReport(cap, &rep);

  // capture -> static poses
  const StaticPoses still = FindStaticPoses(cap, opt);
  rep.noise = still.noise;
  rep.threshold_multiplier = still.multiplier;
  Append(&rep.warnings, still.warnings);
  timer.Mark("static");
  if (still.refusal) return Refuse(cap, std::move(rep), *still.refusal, still.intervals);

  // -> rough gyroscope and full turns
  const RoughGyro rough = EstimateRoughGyro(cap, opt, still);
  rep.turns = rough.turn_reports;
  timer.Mark("gyro_rough");

  // -> protocol and its checks; accelerometer: ls, bsas, lm
  ProtocolChecks checks;
  absl::StatusOr<std::optional<AccelStage>> solved =
      ProtocolAndAccel(cap, opt, still, rough, &timer, &rep, &checks);
  if (!solved.ok()) return solved.status();
  std::optional<AccelStage>& accel = *solved;
  if (!accel) return rep;  // refused: the poses are too alike
  const std::vector<StaticInterval>& intervals = checks.intervals;

  // -> final gyroscope; the pairs' turns measured with it; the six-face case frame
  FinalGyro gyro = GyroAndCaseFrame(cap, intervals, still, rough, &timer, &*accel, &rep);

  // -> residuals, poses, parameter set
  const AccelResiduals accel_residuals = ComputeAccelResiduals(
      *accel, rep.protocol, checks.ups, cap.gravity_m_s2, opt.heldout, &rep.residual);
  timer.Mark("heldout");
  rep.residual.gyro_static_rms_rad_s = GyroStaticRms(intervals, accel->used, gyro.fit.params);
  rep.poses = MakePoseReports(intervals, accel->params, accel_residuals);
  AttachSources(cap, &rep.poses);
  rep.params = MakeParamSet(cap, *accel, gyro.fit, intervals, rep.residual, rep.noise);
  rep.params.term_priors = opt.term_priors;
  ReportGyroFit(cap, gyro.planned, rough.turns, gyro.fit, &rep);
  timer.Mark("report");
  if (RefuseWrongUnit(cap, intervals, accel->used, &rep)) return rep;

  // -> effects: close the loop
  if (opt.effects.enabled) {
    const absl::Status s = RunEffectsStage(cap, opt, {checks, *accel, rough, gyro}, &rep);
    if (!s.ok()) return s;
    timer.Mark("effects");
  }

  // -> the figures a robot will see
  FinalFigures(cap, intervals, gyro, *accel, &rep);
  timer.Mark("final");

  // -> verdict. Undetermined first-order parameters make it warn at best; undetermined
  //    second-order terms do not (six-face determines seeds/000's 12-parameter model
  //    completely), but are warned of.
  VerdictResult verdict = JudgeVerdict(VerdictInputsOf(rep, *accel, &gyro.fit));
  rep.verdict = verdict.verdict;
  rep.verdict_reasons = std::move(verdict.reasons);
  rep.total_ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return rep;
}

}  // namespace imucal::core
