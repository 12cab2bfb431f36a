#include "core/calibrate/effects_stage.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <utility>

#include "absl/strings/str_format.h"
#include "core/calibrate/residuals.h"
#include "core/effects.h"
#include "core/move_effects.h"
#include "util/units.h"

namespace imucal::core::pipeline {
namespace {

std::string NotSearchedNote(size_t poses) {
  return absl::StrFormat(
      "effects not searched: the %d poses all go into the face references' fit, none is spare "
      "to test an effect on. Place each face twice (six-face) or add poses between the faces",
      static_cast<int>(poses));
}

// The gravity-direction error after each reported move with its signals, for the effects'
// examination of the rotation residuals (core/effects.h ExamineMoveResiduals).
std::vector<EffectMoveResidual> MoveResiduals(const Capture& cap,
                                              const std::vector<StaticInterval>& ivs,
                                              const std::vector<MoveReport>& moves,
                                              const std::vector<PoseReport>& poses) {
  const double t0 = cap.t_s.empty() ? 0.0 : cap.t_s.front();
  std::vector<EffectMoveResidual> out;
  for (const MoveReport& m : moves) {
    if (!std::isfinite(m.error_deg)) continue;
    const StaticInterval& a = ivs[static_cast<size_t>(m.from_pose)];
    const StaticInterval& b = ivs[static_cast<size_t>(m.to_pose)];
    EffectMoveResidual mr;
    mr.error_rad = m.error_deg / kRadToDeg;
    mr.rotation_rad = m.rotation_deg / kRadToDeg;
    mr.time_s = 0.5 * (a.t_end_s + b.t_start_s) - t0;
    mr.temp_c = 0.5 * (a.temp_mean + b.temp_mean);
    const auto up = [&](int pose) -> Eigen::Vector3d {
      for (const PoseReport& p : poses)
        if (p.index == pose) return p.up;
      return Eigen::Vector3d::Zero();
    };
    const Eigen::Vector3d ua = up(m.from_pose), ub = up(m.to_pose);
    if (ua.norm() > 0 && ub.norm() > 0) mr.tilt_rad = std::atan2(ua.cross(ub).norm(), ua.dot(ub));
    out.push_back(mr);
  }
  return out;
}

// The search's input: every used pose with its signals, the model, and the rotations between
// poses as a second view of the accelerometer candidates (|a| - g cannot tell every one apart):
// the gyroscope refitted, as the final gyroscope was, to the pose directions each candidate
// gives (core/effects.h, THE MOVES).
absl::StatusOr<EffectSearchInput> SearchInput(const Capture& cap, const EffectsStageInput& in,
                                              const CalibrationReport& rep) {
  const std::vector<StaticInterval>& ivs = in.checks.intervals;
  const std::vector<int>& used = in.accel.used;
  const GyroFit& gyro = in.gyro.fit;
  const std::vector<PlannedMove>& planned = in.gyro.planned;
  EffectSearchInput out;
  out.gravity_m_s2 = cap.gravity_m_s2;
  out.accel = rep.params.accel;
  // The search refits the model as the accelerometer stage estimated it: the same free terms
  // with the same priors (a maximum a posteriori fit), the effects' coefficients beside them.
  out.accel_free = in.accel.free;
  out.accel_priors = in.accel.priors;
  // Held, though the data determine them: tested again once an effect is in.
  for (int c = 0; c < kAccelParams; ++c) {
    const auto k = static_cast<size_t>(c);
    out.accel_held[k] = in.accel.observability.determined[k] && !out.accel_free[k];
  }
  out.gyro = rep.params.gyro;
  out.gyro_output_si = gyro.calibrated || !std::isnan(NominalGyroToSi(cap.gyro_unit));
  const double t0 = cap.t_s.empty() ? 0.0 : cap.t_s.front();
  for (size_t k = 0; k < used.size(); ++k) {
    const StaticInterval& s = ivs[static_cast<size_t>(used[k])];
    EffectPose p;
    p.pose_index = used[k];
    p.accel = in.accel.poses[k];
    p.gyro_mean = s.gyro_mean;
    p.gyro_mean_std = s.gyro_std / std::sqrt(static_cast<double>(std::max<size_t>(1, s.samples())));
    p.temp_c = s.temp_mean;
    p.time_s = 0.5 * (s.t_start_s + s.t_end_s) - t0;
    out.poses.push_back(p);
  }
  out.moves = MoveResiduals(cap, ivs, rep.moves, rep.poses);
  if (!gyro.calibrated || planned.size() < 3) return out;
  std::vector<std::pair<size_t, size_t>> ends;  // per planned move: its poses' index in `used`
  for (const PlannedMove& m : planned) {
    const auto from = std::find(used.begin(), used.end(), m.from_pose);
    const auto to = std::find(used.begin(), used.end(), m.to_pose);
    if (from == used.end() || to == used.end())
      return absl::InternalError("move off the used poses");
    ends.emplace_back(from - used.begin(), to - used.begin());
  }
  out.move_fit = [&cap, &planned, &gyro,
                  ends](const std::vector<Eigen::Vector3d>& up) -> std::optional<MoveFit> {
    std::vector<GyroMove> moves;
    for (size_t k = 0; k < planned.size(); ++k) {
      GyroMove m = planned[k].move;
      m.up_before = up[ends[k].first];
      m.up_after = up[ends[k].second];
      moves.push_back(m);
    }
    GyroSolveOptions go;
    go.bias = gyro.params.bias;
    go.interpolate_bias = true;
    go.initial_matrix = gyro.params.matrix;
    go.compute_heldout = false;
    const absl::StatusOr<GyroSolveResult> r = SolveGyroFromMoves(cap.t_s, cap.gyro, moves, go);
    if (!r.ok() || r->rank_deficient) return std::nullopt;
    return MoveFit{r->move_error_rad};
  };
  return out;
}

// Puts the search's refitted model, effects and residuals into the report (when it added any).
void TakeSearchResult(EffectSearchResult res, const AccelMask& searched, const AccelMask& free,
                      CalibrationReport* rep) {
  rep->effect_diagnostics = std::move(res.diagnostics);
  if (res.effects.empty()) return;
  ParamSet& ps = rep->params;
  ps.accel = res.accel;
  ps.gyro = res.gyro;
  ps.effects = std::move(res.effects);
  ps.effect_reference = res.reference;
  AccelVector se = res.accel_covariance.diagonal().cwiseSqrt();
  const AccelVector before = PackAccel(ps.stderrs.accel);
  for (int c = 0; c < kAccelParams; ++c) {
    const size_t k = static_cast<size_t>(c);
    if (res.accel_free[k]) {
      // Estimated by the search (a held one freed included), with the stage's priors. The
      // stage's covariance also carries what the choice of the second-order prior's width leaves
      // uncertain (accel_stage.cc ChooseQuadraticWidth), which the search does not choose again:
      // the stage's standard error is the floor.
      if (free[k] && std::isfinite(before(c))) se(c) = std::max(se(c), before(c));
      continue;
    }
    // Estimated before and held by the search, or never estimated.
    se(c) = free[k] && !searched[k] ? before(c) : kNaN;
  }
  ps.stderrs.accel = UnpackAccel(se, ps.stderrs.accel.frame_angles);
  // Residuals of the model as stored (with its applied effects).
  std::vector<double> after;
  double gyro_ss = 0;
  for (const EffectPoseRow& row : rep->effect_diagnostics.rows) {
    after.push_back(row.accel_after_m_s2);
    gyro_ss += row.gyro_after_rad_s.squaredNorm();
    for (PoseReport& pr : rep->poses)
      if (pr.index == row.pose_index) pr.residual_m_s2 = row.accel_after_m_s2;
  }
  rep->residual.accel_rms_m_s2 = Rms(after);
  rep->residual.accel_max_m_s2 = MaxAbsFinite(after);
  rep->residual.gyro_static_rms_rad_s = std::sqrt(gyro_ss / std::max<size_t>(1, after.size()));
  if (std::isfinite(rep->effect_diagnostics.accel_heldout_after_m_s2))
    rep->residual.accel_heldout_rms_m_s2 = rep->effect_diagnostics.accel_heldout_after_m_s2;
  ps.quality_accel_rms_m_s2 = rep->residual.accel_rms_m_s2;
  ps.quality_gyro_static_rms_rad_s = rep->residual.gyro_static_rms_rad_s;
  StageReport st;
  st.name = "effects";
  st.accel_rms_m_s2 = rep->residual.accel_rms_m_s2;
  st.iterations = rep->effect_diagnostics.rounds;
  for (const EffectPoseRow& row : rep->effect_diagnostics.rows) {
    st.pose_indices.push_back(row.pose_index);
    st.pose_residual_m_s2.push_back(row.accel_after_m_s2);
  }
  rep->stages.push_back(st);
}

// Applied accelerometer effects move the pose directions that the final gyroscope and (six-face)
// the case frame were fitted to: both are fitted again to the corrected directions.
void RefitToCorrectedDirections(const Capture& cap, const EffectsStageInput& in,
                                CalibrationReport* rep) {
  const std::vector<StaticInterval>& ivs = in.checks.intervals;
  const double t0_s = cap.t_s.front();
  const auto corrected = [&](int i) {
    return CorrectedSpecificForce(rep->params.accel, rep->params.effects,
                                  ivs[static_cast<size_t>(i)], t0_s);
  };
  Eigen::Matrix3d R_new_old = Eigen::Matrix3d::Identity();
  if (rep->protocol == ProtocolKind::kSixFace && in.accel.from_faces) {
    const Eigen::Matrix3d frame = ExpSo3<double>(rep->params.accel.frame_angles);
    R_new_old = SetCaseFrameFromPairAxes(
        rep->pairs, cap.gravity_m_s2,
        [&](int i) -> Eigen::Vector3d { return frame.transpose() * corrected(i); },
        &rep->params.accel);
  }
  std::vector<PlannedMove> replanned = in.gyro.planned;
  for (PlannedMove& m : replanned) {
    m.move.up_before = corrected(m.from_pose).normalized();
    m.move.up_after = corrected(m.to_pose).normalized();
  }
  GyroParams initial = rep->params.gyro;
  TurnGyroParams(R_new_old, &initial);
  const GyroFit refit = FitGyro(cap, replanned, in.rough.turns, initial);
  if (refit.calibrated) {
    rep->params.gyro.matrix = refit.params.matrix;
    rep->params.gyro.accel_coupling = refit.params.accel_coupling;
    ReportGyroFit(cap, replanned, in.rough.turns, refit, rep);
  } else {  // keep the final gyroscope's fit, in the new frame (the moves' ups are not reported)
    GyroFit turned = in.gyro.fit;
    TurnGyroFrame(R_new_old, &turned, nullptr);
    rep->params.gyro.matrix = turned.params.matrix;
    rep->params.gyro.accel_coupling = turned.params.accel_coupling;
    ReportGyroFit(cap, in.gyro.planned, in.rough.turns, turned, rep);
  }
  // The rotation residuals' trends as the refitted model leaves them: what the effect
  // explained no longer shows as a trend.
  ExamineMoveResiduals(MoveResiduals(cap, ivs, rep->moves, rep->poses), &rep->effect_diagnostics);
}

// True when the regressor reads a rate (gx, gy, gz): a term only the moves can test.
bool ReadsRate(const std::string& regressor) {
  const std::optional<Regressor> r = ParseRegressor(regressor);
  if (!r) return false;
  for (int i = 0; i < r->num_factors; ++i)
    if (r->factors[static_cast<size_t>(i)] >= static_cast<int>(Signal::kGx)) return true;
  return false;
}

// The moves' detection bounds in a note: "none found" said with what would have been found.
std::string RateBoundsNote(const std::vector<DetectionBound>& bounds) {
  std::string text;
  for (const DetectionBound& b : bounds)
    absl::StrAppendFormat(
        &text, "%s %s (%s)", text.empty() ? "" : ";",
        std::isfinite(b.coefficient)
            ? absl::StrFormat("gyro %c %s", "xyz"[b.axis],
                              HumanValue(b.sensor, b.regressor, b.coefficient))
            : absl::StrFormat("gyro %c none: the moves do not excite it", "xyz"[b.axis]),
        b.from);
  return "rate-dependent gyro scale (a scale that grows with the rate, gk*|gk| on k): where none "
         "was found, these moves would have found one 9 times in 10 at:" +
         text + ". A smaller one may be there; faster turns about an axis see smaller ones";
}

// The rates' terms the rotations between poses can show (core/move_effects.h), on the final
// model: its gyroscope and the pose directions of the stored accelerometer (its applied effects
// included). What it finds joins the parameter set, the gyroscope matrix refitted with it, and
// the report's moves become the joint fit's.
absl::Status SearchMoves(const Capture& cap, const CalibrateOptions& opt,
                         const EffectsStageInput& in, CalibrationReport* rep) {
  EffectDiagnostics& diag = rep->effect_diagnostics;
  if (!rep->params.gyro_calibrated) return absl::OkStatus();
  const std::vector<StaticInterval>& ivs = in.checks.intervals;
  const double t0_s = cap.t_s.front();
  std::vector<PlannedMove> planned = in.gyro.planned;
  for (PlannedMove& m : planned) {
    m.move.up_before = CorrectedSpecificForce(rep->params.accel, rep->params.effects,
                                              ivs[static_cast<size_t>(m.from_pose)], t0_s)
                           .normalized();
    m.move.up_after = CorrectedSpecificForce(rep->params.accel, rep->params.effects,
                                             ivs[static_cast<size_t>(m.to_pose)], t0_s)
                          .normalized();
  }
  MoveSearchInput mi;
  mi.t_s = &cap.t_s;
  mi.gyro_raw = &cap.gyro;
  mi.moves = OnlyMoves(planned);
  for (const TurnCandidate& c : in.rough.turns) mi.turns.push_back(c.turn);
  mi.matrix = rep->params.gyro.matrix;
  mi.bias = rep->params.gyro.bias;
  mi.interpolate_bias = true;
  // The noise floor: the rest's per-sample noise through the model, and each used pose's
  // direction from its mean specific force.
  const Eigen::Vector3d gyro_noise =
      (rep->params.gyro.matrix * rep->noise.gyro_std.asDiagonal()).rowwise().norm();
  mi.gyro_noise_rad_s = gyro_noise.norm() / std::sqrt(3.0);
  double up_var = 0;
  int poses = 0;
  for (const StaticInterval& s : ivs) {
    if (!s.used || s.samples() == 0) continue;
    const Eigen::Vector3d a = rep->params.accel.scale.cwiseProduct(s.accel_std);
    up_var += a.squaredNorm() / 3 / (cap.gravity_m_s2 * cap.gravity_m_s2) /
              static_cast<double>(s.samples());
    ++poses;
  }
  mi.up_noise_rad = poses > 0 ? std::sqrt(up_var / poses) : 0.0;
  MoveSearchOptions mo;
  mo.family_alpha = opt.effects.family_alpha;
  for (const GivenEffect& g : opt.effects.given)
    if (g.sensor == Sensor::kGyro && ReadsRate(g.regressor))
      mo.given.push_back({g.axis, g.regressor});
  if (opt.effects.max_effects <= 0) mo.max_terms = 0;
  absl::StatusOr<MoveSearchResult> res = SearchMoveEffects(mi, mo);
  if (!res.ok()) return res.status();
  diag.move_search = res->Diagnostics();
  diag.notes.insert(diag.notes.end(), res->notes.begin(), res->notes.end());
  if (!res->detection_bounds.empty()) diag.notes.push_back(RateBoundsNote(res->detection_bounds));
  if (res->effects.empty()) return absl::OkStatus();
  ParamSet& ps = rep->params;
  ps.effects.insert(ps.effects.end(), res->effects.begin(), res->effects.end());
  const MoveModelFit& fit = res->after;
  ps.gyro.matrix = fit.matrix;
  for (int c = 0; c < 9; ++c)
    ps.stderrs.gyro_matrix(c % 3, c / 3) = std::sqrt(std::max(0.0, fit.covariance(c, c)));
  // The report's moves as the joint fit leaves them (ReportFinalFigures then puts in the
  // in-sample figures of the parameter set as the SDK applies it).
  for (size_t k = 0; k < planned.size() && k < fit.move_error_rad.size(); ++k) {
    for (MoveReport& r : rep->moves) {
      if (r.from_pose != planned[k].from_pose || r.to_pose != planned[k].to_pose) continue;
      r.error_deg = fit.move_error_rad[k] * kRadToDeg;
      r.heldout_error_deg = fit.heldout_error_rad[k] * kRadToDeg;
    }
  }
  rep->residual.move_rms_deg = rep->residual.move_fit_rms_deg = fit.RmsMoveError() * kRadToDeg;
  rep->residual.move_max_deg = MaxAbsFinite(fit.move_error_rad) * kRadToDeg;
  rep->residual.move_heldout_rms_deg = fit.RmsHeldOut() * kRadToDeg;
  rep->residual.move_heldout_max_deg = MaxAbsFinite(fit.heldout_error_rad) * kRadToDeg;
  for (size_t k = 0; k < rep->turns.size() && k < in.rough.turns.size(); ++k)
    rep->turns[k].angle_deg = fit.turn_angle_rad[k] * kRadToDeg;
  // What the terms explained no longer shows as a trend.
  ExamineMoveResiduals(MoveResiduals(cap, ivs, rep->moves, rep->poses), &diag);
  return absl::OkStatus();
}

}  // namespace

absl::Status RunEffectsStage(const Capture& cap, const CalibrateOptions& opt,
                             const EffectsStageInput& in, CalibrationReport* rep) {
  if (in.accel.affine_only) {
    rep->effect_diagnostics.notes.push_back(NotSearchedNote(in.accel.poses.size()));
    return absl::OkStatus();
  }
  absl::StatusOr<EffectSearchInput> search = SearchInput(cap, in, *rep);
  if (!search.ok()) return search.status();
  // Terms in the rates are the moves' to fit (SearchMoves); the static search sees the rest.
  EffectSearchOptions static_options = opt.effects;
  std::erase_if(static_options.given, [](const GivenEffect& g) { return ReadsRate(g.regressor); });
  absl::StatusOr<EffectSearchResult> res = FindEffects(*search, static_options);
  if (!res.ok()) return res.status();
  TakeSearchResult(*std::move(res), search->accel_free, in.accel.free, rep);

  bool accel_effect = false;
  for (const Effect& e : rep->params.effects)
    accel_effect |= e.sensor == Sensor::kAccel && e.applied;
  if (accel_effect && in.gyro.fit.calibrated) RefitToCorrectedDirections(cap, in, rep);
  if (accel_effect) {
    for (PoseReport& pr : rep->poses) {
      pr.up = CorrectedSpecificForce(rep->params.accel, rep->params.effects, pr.interval,
                                     cap.t_s.front())
                  .normalized();
      const Face f = ClassifyFace(pr.up);
      pr.face = f.off_axis_deg <= kFaceToleranceDeg ? f.Label() : "";
    }
  }
  rep->effect_diagnostics.faces = FaceResiduals(cap, in.checks.intervals, rep->pairs, rep->params);
  return SearchMoves(cap, opt, in, rep);
}

}  // namespace imucal::core::pipeline
