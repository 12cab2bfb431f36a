#include "core/calibrate/residuals.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>

#include "absl/strings/str_format.h"
#include "core/calibrate/protocol_checks.h"
#include "core/correction.h"
#include "core/gyro_solver.h"
#include "core/quantisation.h"
#include "util/units.h"

namespace imucal::core::pipeline {
namespace {

std::vector<double> ToDeg(const std::vector<double>& rad) {
  std::vector<double> out;
  for (double x : rad) out.push_back(x * kRadToDeg);
  return out;
}

}  // namespace

double MaxAbsFinite(const std::vector<double>& v) {
  double m = 0;
  for (double x : v)
    if (std::isfinite(x)) m = std::max(m, std::abs(x));
  return m;
}

double RmsFinite(const std::vector<double>& v) {
  std::vector<double> f;
  for (double x : v)
    if (std::isfinite(x)) f.push_back(x);
  return f.empty() ? kNaN : Rms(f);
}

AccelResiduals ComputeAccelResiduals(const AccelStage& accel, ProtocolKind protocol,
                                     const std::vector<Eigen::Vector3d>& ups, double g,
                                     bool heldout, Residuals* out) {
  AccelResiduals r;
  r.in_sample = MagnitudeResiduals(accel.params, accel.poses, g);
  out->accel_rms_m_s2 = Rms(r.in_sample);
  out->accel_max_m_s2 = MaxAbsFinite(r.in_sample);
  // The noise floor: each pose's |a| noise from its measured scatter alone (no model error).
  std::vector<AccelPose> noise_only = accel.poses;
  for (AccelPose& p : noise_only) p.model_sigma_m_s2 = 0;
  out->accel_noise_floor_m_s2 = Rms(MagnitudeSigmas(accel.params, noise_only));
  r.heldout.assign(accel.poses.size(), kNaN);
  if (!heldout || accel.affine_only) return r;
  r.heldout = HeldOutMagnitudeResiduals(accel.params, accel.poses, g, accel.free, accel.priors);
  if (protocol == ProtocolKind::kFerraris || protocol == ProtocolKind::kFaces) {
    // A face placed once cannot be predicted without it (its axis' bias and scale go with it).
    std::vector<Eigen::Vector3d> used_ups;
    for (int i : accel.used) used_ups.push_back(ups[static_cast<size_t>(i)]);
    for (const auto& p : FacePlacements(used_ups))
      if (p.size() == 1) r.heldout[static_cast<size_t>(p.front())] = kNaN;
  }
  out->accel_heldout_rms_m_s2 = RmsFinite(r.heldout);
  // None predictable (too few poses beyond the model): both n/a, not a max of 0.
  out->accel_heldout_max_m_s2 =
      std::isfinite(out->accel_heldout_rms_m_s2) ? MaxAbsFinite(r.heldout) : kNaN;
  return r;
}

double GyroStaticRms(const std::vector<StaticInterval>& ivs, const std::vector<int>& used,
                     const GyroParams& gyro) {
  double ss = 0;
  for (int i : used) {
    const StaticInterval& s = ivs[static_cast<size_t>(i)];
    ss += (gyro.matrix * (s.gyro_mean - gyro.bias)).squaredNorm();
  }
  return used.empty() ? 0 : std::sqrt(ss / used.size());
}

void ReportGyroFit(const Capture& cap, const std::vector<PlannedMove>& planned,
                   const std::vector<TurnCandidate>& turns, const GyroFit& gyro,
                   CalibrationReport* rep) {
  rep->moves.clear();
  rep->residual.move_rms_deg = rep->residual.move_max_deg = rep->residual.move_fit_rms_deg = kNaN;
  rep->residual.move_heldout_rms_deg = rep->residual.move_heldout_max_deg = kNaN;
  for (TurnReport& t : rep->turns) t.error_deg = kNaN;
  if (gyro.result) {
    const auto& gr = *gyro.result;
    rep->residual.move_rms_deg = Rms(gr.move_error_rad) * kRadToDeg;
    rep->residual.move_fit_rms_deg = rep->residual.move_rms_deg;
    rep->residual.move_max_deg = MaxAbsFinite(gr.move_error_rad) * kRadToDeg;
    if (!gr.heldout_error_rad.empty()) {
      rep->residual.move_heldout_rms_deg = RmsFinite(gr.heldout_error_rad) * kRadToDeg;
      rep->residual.move_heldout_max_deg = MaxAbsFinite(gr.heldout_error_rad) * kRadToDeg;
    }
    const std::vector<double> in = ToDeg(gr.move_error_rad), out = ToDeg(gr.heldout_error_rad);
    for (size_t k = 0; k < planned.size() && k < in.size(); ++k) {
      MoveReport m;
      m.from_pose = planned[k].from_pose;
      m.to_pose = planned[k].to_pose;
      m.error_deg = in[k];
      if (k < out.size()) m.heldout_error_deg = out[k];
      m.rotation_deg =
          IntegrateRotation(cap, planned[k].move.begin, planned[k].move.end, gyro.params).norm() *
          kRadToDeg;
      rep->moves.push_back(m);
    }
    for (size_t k = 0; k < rep->turns.size() && k < gr.turn_error_rad.size(); ++k)
      rep->turns[k].error_deg = gr.turn_error_rad[k] * kRadToDeg;
    for (int c = 0; c < 9; ++c)
      rep->params.stderrs.gyro_matrix(c % 3, c / 3) = std::sqrt(gr.covariance(c, c));
  } else {
    rep->params.stderrs.gyro_matrix.setConstant(kNaN);
  }
  // Each turn's integrated angle with the final gyroscope (only when its output is in rad/s).
  if (gyro.calibrated || !std::isnan(NominalGyroToSi(cap.gyro_unit))) {
    for (size_t k = 0; k < rep->turns.size() && k < turns.size(); ++k)
      rep->turns[k].angle_deg = (gyro.params.matrix * turns[k].raw_integral).norm() * kRadToDeg;
  }
}

std::vector<PoseReport> MakePoseReports(const std::vector<StaticInterval>& ivs,
                                        const AccelParams& accel, const AccelResiduals& res) {
  std::vector<PoseReport> out;
  for (size_t i = 0, k = 0; i < ivs.size(); ++i) {
    PoseReport pr;
    pr.index = static_cast<int>(i);
    pr.interval = ivs[i];
    pr.up = accel.Apply(ivs[i].accel_mean).normalized();
    const Face f = ClassifyFace(pr.up);
    if (f.off_axis_deg <= kFaceToleranceDeg) pr.face = f.Label();
    if (ivs[i].used) {
      pr.residual_m_s2 = res.in_sample[k];
      pr.heldout_m_s2 = res.heldout[k];
      ++k;
    }
    out.push_back(pr);
  }
  return out;
}

void AttachSources(const Capture& cap, std::vector<PoseReport>* poses) {
  for (PoseReport& p : *poses) {
    const StaticInterval& s = p.interval;
    if (s.end <= s.begin || s.end > cap.size()) continue;
    const int file = cap.FileOf(s.begin);
    if (file >= 0) p.file = cap.files[static_cast<size_t>(file)].path;
    if (cap.line.size() == cap.size()) {
      p.first_line = cap.line[s.begin];
      p.last_line = cap.line[s.end - 1];
    }
  }
}

ParamSet MakeParamSet(const Capture& cap, const AccelStage& accel, const GyroFit& gyro,
                      const std::vector<StaticInterval>& ivs, const Residuals& residual,
                      const NoiseLevel& noise) {
  ParamSet ps;
  ps.device = cap.device;
  ps.accel_unit = cap.accel_unit;
  ps.gyro_unit = cap.gyro_unit;
  ps.gravity_m_s2 = cap.gravity_m_s2;
  ps.accel = accel.params;
  ps.gyro = gyro.params;
  ps.gyro_calibrated = gyro.calibrated;
  AccelVector se = accel.covariance.diagonal().cwiseSqrt();
  for (int c = 0; c < kAccelParams; ++c)
    if (!accel.free[static_cast<size_t>(c)]) se(c) = kNaN;
  // The case frame's standard error is not estimated (NaN) when the faces set it, and 0 (a
  // convention, not an estimate) when no orientation was known.
  ps.stderrs.accel = UnpackAccel(se, Eigen::Vector3d::Constant(accel.from_faces ? kNaN : 0.0));
  // Gyro bias standard error from the scatter of the pose means (includes slow drift).
  const std::vector<int>& used = accel.used;
  if (used.size() >= 2) {
    Eigen::Vector3d ss = Eigen::Vector3d::Zero();
    for (int i : used) ss += (ivs[static_cast<size_t>(i)].gyro_mean - gyro.params.bias).cwiseAbs2();
    ps.stderrs.gyro_bias =
        (ss / static_cast<double>(used.size() - 1) / static_cast<double>(used.size())).cwiseSqrt();
  }
  // A channel on a grid its noise does not dither rounds the same way in every pose: the pose
  // means share that rounding error, their scatter does not show it, and the bias keeps it
  // (core/quantisation.h). sigma: the median over the poses of the channel's scatter.
  if (!used.empty()) {
    for (int j = 0; j < 3; ++j) {
      std::vector<double> sigma;
      for (int i : used) sigma.push_back(ivs[static_cast<size_t>(i)].gyro_std(j));
      std::nth_element(sigma.begin(), sigma.begin() + static_cast<long>(sigma.size() / 2),
                       sigma.end());
      const double se = std::isfinite(ps.stderrs.gyro_bias(j)) ? ps.stderrs.gyro_bias(j) : 0.0;
      ps.stderrs.gyro_bias(j) = WithRoundingError(se, noise.gyro_step(j), sigma[sigma.size() / 2]);
    }
  }
  ps.quality_accel_rms_m_s2 = residual.accel_rms_m_s2;
  ps.quality_gyro_static_rms_rad_s = residual.gyro_static_rms_rad_s;
  return ps;
}

std::vector<ParameterSpread> ParameterSpreads(const ParamSet& ps, const AccelMask& free) {
  std::vector<ParameterSpread> out;
  const AccelVector se = PackAccel(ps.stderrs.accel);
  const AccelVector range = AccelPlausibleRange(ps.accel, ps.gravity_m_s2);
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)])
      out.push_back({"accel " + AccelParamName(c), se(c), range(c)});
  if (ps.gyro_calibrated) {
    const double scale = ps.gyro.matrix.diagonal().cwiseAbs().mean();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        out.push_back({absl::StrFormat("gyro matrix (%c,%c)", "xyz"[r], "xyz"[c]),
                       ps.stderrs.gyro_matrix(r, c), kGyroPlausibleRelative * scale});
  }
  return out;
}

void ReportFinalFigures(const Capture& cap, const std::vector<StaticInterval>& ivs,
                        const std::vector<PlannedMove>& planned, CalibrationReport* rep) {
  const ParamSet& ps = rep->params;
  if (!ps.gyro_calibrated && std::isnan(NominalGyroToSi(cap.gyro_unit))) return;
  if (cap.t_s.empty()) return;
  constexpr double kNoTemp = std::numeric_limits<double>::quiet_NaN();
  const SampleCorrection correct(ps, cap.t_s.front());
  const auto at = [&](size_t i) {
    return correct.Apply(cap.accel[i], cap.gyro[i], cap.has_temp() ? cap.temp[i] : kNoTemp,
                         cap.t_s[i]);
  };
  // A pose's up: the mean of its corrected samples (the SDK corrects each sample, not the
  // mean), once per pose (a pose ends one move and starts the next).
  std::map<int, Eigen::Vector3d> ups;
  const auto up = [&](int pose) -> const Eigen::Vector3d& {
    auto [it, inserted] = ups.try_emplace(pose, Eigen::Vector3d::Zero());
    if (!inserted) return it->second;
    const StaticInterval& s = ivs[static_cast<size_t>(pose)];
    for (size_t i = s.begin; i < s.end; ++i) it->second += at(i).accel_m_s2;
    it->second.normalize();
    return it->second;
  };
  std::vector<double> errors_deg;
  for (const PlannedMove& pm : planned) {
    // The move's samples on their own, rates already in rad/s in the body frame.
    const size_t first = pm.move.begin, last = pm.move.end;
    std::vector<double> t_s(cap.t_s.begin() + static_cast<long>(first),
                            cap.t_s.begin() + static_cast<long>(last) + 1);
    std::vector<Eigen::Vector3d> rate;
    rate.reserve(t_s.size());
    for (size_t i = first; i <= last; ++i) rate.push_back(at(i).gyro_rad_s);
    GyroMove m;
    m.begin = 0;
    m.end = last - first;
    m.up_before = up(pm.from_pose);
    m.up_after = up(pm.to_pose);
    const Eigen::Vector3d predicted =
        PredictUpAfterMove(t_s, rate, m, Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero(),
                           /*interpolate_bias=*/false);
    const double error_deg =
        std::atan2(predicted.cross(m.up_after).norm(), predicted.dot(m.up_after)) * kRadToDeg;
    errors_deg.push_back(error_deg);
    for (MoveReport& r : rep->moves)
      if (r.from_pose == pm.from_pose && r.to_pose == pm.to_pose) r.error_deg = error_deg;
  }
  if (!errors_deg.empty()) {
    rep->residual.move_rms_deg = RmsFinite(errors_deg);
    rep->residual.move_max_deg = MaxAbsFinite(errors_deg);
  }
}

Eigen::Vector3d CorrectedSpecificForce(const AccelParams& accel, const std::vector<Effect>& effects,
                                       const StaticInterval& s, double t0_s) {
  // The gyroscope left out (zero rate): only the accelerometer's output is read.
  return SampleCorrection(accel, GyroParams(), effects, t0_s)
      .Apply(s.accel_mean, Eigen::Vector3d::Zero(), s.temp_mean, 0.5 * (s.t_start_s + s.t_end_s))
      .accel_m_s2;
}

std::vector<FaceResidual> FaceResiduals(const Capture& cap, const std::vector<StaticInterval>& ivs,
                                        const std::vector<PairCheck>& pairs,
                                        const ParamSet& params) {
  std::vector<FaceResidual> out;
  const double t0 = cap.t_s.empty() ? 0.0 : cap.t_s.front();
  for (const PairCheck& p : pairs) {
    if (!p.ok) continue;
    const Eigen::Vector3d a = CorrectedSpecificForce(params.accel, params.effects,
                                                     ivs[static_cast<size_t>(p.pose_a)], t0);
    const Eigen::Vector3d b = CorrectedSpecificForce(params.accel, params.effects,
                                                     ivs[static_cast<size_t>(p.pose_b)], t0);
    // The mean of the two sizes: the mean vector is shorter by cos(tilt), 0.15 mg at 1 degree.
    const Eigen::Vector3d axis = PairFaceAxis(p, a, b);
    const Eigen::Vector3d face = 0.5 * (a.norm() + b.norm()) * axis;
    const Face f = ClassifyFace(axis);
    out.push_back({f.Label(), face - f.Reference(cap.gravity_m_s2)});
  }
  return out;
}

BiasWander GyroWanderOf(const Capture& cap, const std::vector<StaticInterval>& ivs,
                        const std::vector<int>& used, const ParamSet& ps, const NoiseLevel& noise) {
  if (!ps.gyro_calibrated && std::isnan(NominalGyroToSi(cap.gyro_unit))) return {};
  if (cap.t_s.empty()) return {};
  const SampleCorrection correct(ps, cap.t_s.front());
  std::vector<WanderPose> poses;
  for (int i : used) {
    const StaticInterval& s = ivs[static_cast<size_t>(i)];
    if (s.end <= s.begin + 3 || s.end > cap.size()) continue;
    const size_t n = s.end - s.begin, mid = s.begin + n / 2;
    Eigen::Vector3d sum = Eigen::Vector3d::Zero(), sq = Eigen::Vector3d::Zero();
    Eigen::Vector3d first = Eigen::Vector3d::Zero();
    for (size_t k = s.begin; k < s.end; ++k) {
      const Eigen::Vector3d w =
          correct.Apply(cap.accel[k], cap.gyro[k], cap.has_temp() ? cap.temp[k] : kNaN, cap.t_s[k])
              .gyro_rad_s;
      sum += w;
      sq += w.cwiseAbs2();
      if (k < mid) first += w;
    }
    const double dn = static_cast<double>(n), n1 = static_cast<double>(mid - s.begin);
    const double n2 = dn - n1;
    const Eigen::Vector3d mean = sum / dn;
    const Eigen::Vector3d sd =
        ((sq - dn * mean.cwiseAbs2()) / (dn - 1)).cwiseMax(0.0).cwiseSqrt();
    WanderPose p;
    p.t_s = 0.5 * (s.t_start_s + s.t_end_s) - cap.t_s.front();
    p.duration_s = s.t_end_s - s.t_start_s;
    p.rate_rad_s = mean;
    p.sigma_rad_s = sd / std::sqrt(dn);
    // A channel stuck on one quantisation step reads sd = 0: its mean is known to the grid's
    // rounding (core/quantisation.h), not exactly. A step of input axis j moves output j by
    // |matrix(j, j)| times it.
    for (int j = 0; j < 3; ++j) {
      const double step_rad_s = noise.gyro_step(j) * std::abs(ps.gyro.matrix(j, j));
      p.sigma_rad_s(j) = WithRoundingError(p.sigma_rad_s(j), step_rad_s, sd(j));
    }
    p.half_diff_rad_s = (sum - first) / n2 - first / n1;
    p.half_diff_sigma_rad_s = sd * std::sqrt(1 / n1 + 1 / n2);
    poses.push_back(p);
  }
  const Eigen::Vector3d none = Eigen::Vector3d::Constant(kNaN);
  return AnalyseBiasWander(poses, ps.noise ? ps.noise->gyro.random_walk : none,
                           ps.noise ? ps.noise->gyro.random_walk_bound : none);
}

}  // namespace imucal::core::pipeline
