#include "core/calibrate/accel_stage.h"

#include <chrono>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_format.h"

namespace imucal::core::pipeline {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

double MsSince(std::chrono::steady_clock::time_point t0) {
  return 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// ---- The warnings this stage raises.

std::string FacesNotPossibleWarning(ProtocolKind protocol, const absl::Status& why) {
  return absl::StrFormat(
      "%s least squares not possible (%s); used the ellipsoid fit instead, frame alignment "
      "unknown",
      protocol == ProtocolKind::kSixFace ? "six-face" : "ferraris: face", why.message());
}

constexpr const char* kFerrarisTiltWarning =
    "ferraris: each face was held once, without the 180-degree pair, so the floor's tilt "
    "is not cancelled: it stays in the misalignment and frame angles (about 17 mrad per "
    "degree of tilt), while bias and scale err only by 1 - cos(tilt) (0.015 % at 1 "
    "degree). Hold each face again turned 180 degrees about the vertical (six-face) to "
    "cancel it";

std::string BiasScaleOnlyWarning(size_t poses) {
  return absl::StrFormat(
      "accelerometer: only bias and scale were calibrated (6 of 12 parameters): %d poses "
      "cannot determine the misalignment angles t_yx, t_zx, t_zy and the second-order terms, "
      "held at 0. Add poses to reach at least 10 distinct orientations, some with gravity "
      "between two axes (45 degrees)",
      static_cast<int>(poses));
}

std::string HeldByFacesWarning(int c, bool determined, double faces_sigma, double obs_sigma) {
  if (!determined) {
    return absl::StrFormat(
        "accel %s: set by the six-face references (stage 1); |a| = g alone does not "
        "determine it, so later stages hold it",
        AccelParamName(c));
  }
  return absl::StrFormat(
      "accel %s: set by the six-face references (stage 1, +-%.2g rad), which determine "
      "it far better than |a| = g on these poses (+-%.2g rad); later stages hold it. "
      "Poses with gravity between two axes would let |a| = g refine it",
      AccelParamName(c), faces_sigma, obs_sigma);
}

std::string QuadraticHeldNote(int c) {
  return absl::StrFormat(
      "accel %s: held at 0; it is within two standard errors of zero and leaving it out "
      "predicts held-out poses better "
      "(add poses with that axis about 45 degrees from vertical to resolve it)",
      AccelParamName(c));
}

std::string AffineOnlyWarning(size_t poses) {
  return absl::StrFormat(
      "accelerometer: %d poses leave nothing to refine |a| = g on; the result is the face "
      "references' least-squares fit (seeds/000), its standard errors from the faces' residual",
      static_cast<int>(poses));
}

// ---- The math.

// The covariance of the affine face fit's 12 magnitude parameters, when the poses are too few
// for the |a| = g refinement: the residual of the 3 n face equations (n faces, 12 unknowns) gives
// their variance, mapped through the fit by finite differences of the references.
AccelMatrix AffineFitCovariance(const FaceReferences& faces, const AccelParams& fit,
                                double* chi2_per_dof) {
  AccelMatrix cov = AccelMatrix::Constant(kNaN);
  const int n = static_cast<int>(faces.means.size());
  const int dof = 3 * n - 12;
  double ss = 0;
  for (int i = 0; i < n; ++i)
    ss += (fit.Apply(faces.means[static_cast<size_t>(i)]) - faces.refs[static_cast<size_t>(i)])
              .squaredNorm();
  *chi2_per_dof = dof > 0 ? ss / dof : kNaN;
  if (dof <= 0) return cov;
  const double h = 1e-4;
  Eigen::MatrixXd jac(kAccelParams, 3 * n);
  const AccelVector base = PackAccel(fit);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < 3; ++j) {
      FaceReferences plus = faces;
      plus.refs[static_cast<size_t>(i)](j) += h;
      auto p = FitKnownReferences(plus.means, plus.refs);
      if (!p.ok()) return cov;
      jac.col(3 * i + j) = (PackAccel(*p) - base) / h;
    }
  }
  cov = *chi2_per_dof * jac * jac.transpose();
  return cov;
}

// Stage 1 from the protocol's face references: six-face from the verified pairs (all six
// needed), ferraris from each face's placements. Not OK (with the reason) when the faces do not
// give it or the protocol has none.
absl::StatusOr<AccelParams> FitFaces(ProtocolKind protocol, const FaceReferences& faces) {
  if (protocol == ProtocolKind::kSixFace && faces.means.size() < 6) {
    return absl::FailedPreconditionError(
        absl::StrFormat("only %d of 6 faces have a verified 180-degree pair",
                        static_cast<int>(faces.means.size())));
  }
  if (protocol == ProtocolKind::kFerraris && faces.means.size() != 6) {
    return absl::FailedPreconditionError(
        absl::StrFormat("only %d of the 6 faces placed", static_cast<int>(faces.means.size())));
  }
  return FitKnownReferences(faces.means, faces.refs);
}

// Backward elimination of the quadratic terms by leave-one-pose-out (PRESS) error: the full
// 15-parameter model is the default, and a term is dropped only where leaving it out predicts
// held-out poses better. With few poses at intermediate angles a second-order term fits noise
// (the Xsens capture's quadratic_x does); where it is real, dropping it biases that axis' bias.
AccelMask SelectQuadratics(const AccelParams& start, const std::vector<AccelPose>& poses, double g,
                           const AccelMask& determined, std::vector<std::string>* notes) {
  AccelMask mask = determined;
  auto press = [&](const AccelMask& m) {
    return PressRms(RefineAccelGaussNewton(start, poses, g, m, 10), poses, g, m);
  };
  // Only a term within two standard errors of zero may go: a significant one is kept even if
  // PRESS, itself noisy with a few dozen poses, would prefer the smaller model.
  const AccelParams full = RefineAccelGaussNewton(start, poses, g, mask, 10);
  const AccelVector se = AccelStdErrors(full, poses, mask);
  double best = press(mask);
  for (;;) {
    int drop = -1;
    double drop_press = best;
    for (int c : kAccelQuadratic.Indices()) {
      if (!mask[static_cast<size_t>(c)]) continue;
      if (std::abs(PackAccel(full)(c)) > 2 * se(c)) continue;
      AccelMask trial = mask;
      trial[static_cast<size_t>(c)] = false;
      const double p = press(trial);
      if (p < drop_press) drop = c, drop_press = p;
    }
    if (drop < 0) break;
    mask[static_cast<size_t>(drop)] = false;
    best = drop_press;
  }
  for (int c : kAccelQuadratic.Indices())
    if (determined[static_cast<size_t>(c)] && !mask[static_cast<size_t>(c)])
      notes->push_back(QuadraticHeldNote(c));
  return mask;
}

// Six-face: at axis-aligned poses the non-orthogonality angles reach |a| only at second order
// (through the floor's tilt), but the face references of stage 1 (seeds/000) determine them
// at first order. An angle stays at its stage-1 value, held fixed, when |a| = g on these
// poses is nearly blind to it: less than a hundredth of the faces' information (its standard
// error over ten times theirs). On a plain six-face capture |a| = g may "determine" an angle
// to 0.015 rad (15 mg across the axis) where the faces give 1e-4 rad (a ratio near 100), and
// refining on it only fits noise. A few extra poses between the axes bring the ratio to 2-5:
// then holding the angle against what |a| = g says pushes the misfit into the weakly
// determined second-order terms, which trade off against the biases (k g^2 on a face), so
// the angle is refined as before.
AccelMask HoldAnglesTheFacesDetermine(const FaceReferences& faces, const AccelParams& stage_one,
                                      const AccelObservability& obs,
                                      std::vector<std::string>* warnings) {
  AccelMask held{};
  double faces_chi2 = kNaN;
  const AccelMatrix faces_cov = AffineFitCovariance(faces, stage_one, &faces_chi2);
  for (int c : kAccelTri.Indices()) {
    const size_t k = static_cast<size_t>(c);
    const double faces_sigma = std::sqrt(faces_cov(c, c));
    const bool faces_better = std::isfinite(faces_sigma) && 10 * faces_sigma < obs.sigma(c);
    held[k] = !obs.determined[k] || faces_better;
    if (held[k])
      warnings->push_back(HeldByFacesWarning(c, obs.determined[k], faces_sigma, obs.sigma(c)));
  }
  return held;
}

}  // namespace

bool AccelStage::FirstOrderUndetermined() const {
  for (int c : kAccelFirstOrder.Indices()) {
    const size_t k = static_cast<size_t>(c);
    if (!observability.determined[k] && !held_by_faces[k]) return true;
  }
  return false;
}

AccelVector StageOneUnits(const AccelParams& p, const std::vector<AccelPose>& poses,
                          const AccelMask& free) {
  const Eigen::MatrixXd j = MagnitudeJacobian(p, poses);
  const std::vector<double> sigma = MagnitudeSigmas(p, poses);
  Eigen::MatrixXd jw = j;
  for (Eigen::Index i = 0; i < jw.rows(); ++i) jw.row(i) /= sigma[static_cast<size_t>(i)];
  AccelVector unit = AccelVector::Ones();
  std::vector<int> idx;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)]) idx.push_back(c);
  Eigen::MatrixXd info(idx.size(), idx.size());
  for (size_t a = 0; a < idx.size(); ++a)
    for (size_t b = 0; b < idx.size(); ++b)
      info(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b)) =
          jw.col(idx[a]).dot(jw.col(idx[b]));
  const Eigen::MatrixXd cov =
      info.ldlt().solve(Eigen::MatrixXd::Identity(info.rows(), info.cols()));
  for (size_t a = 0; a < idx.size(); ++a) {
    const double s =
        std::sqrt(std::abs(cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(a))));
    if (std::isfinite(s) && s > 0) unit(idx[a]) = s;
  }
  return unit;
}

void SetModelSigma(const AccelParams& p, double g, const AccelMask& free,
                   std::vector<AccelPose>* poses) {
  int n_free = 0;
  for (bool f : free) n_free += f;
  const double tau = EstimateModelSigma(p, *poses, g, n_free);
  for (auto& pose : *poses) pose.model_sigma_m_s2 = tau;
}

absl::StatusOr<AccelStage> SolveAccel(const Capture& cap, const CalibrateOptions& opt,
                                      const NoiseLevel& noise, const ProtocolChecks& checks) {
  AccelStage out;
  const double g = cap.gravity_m_s2;
  const std::vector<StaticInterval>& ivs = checks.intervals;
  out.used = UsedIndices(ivs);
  out.poses = ToAccelPoses(ivs, out.used, noise);
  std::vector<AccelPose>& poses = out.poses;

  // 1. Linear least squares.
  const auto ls_start = std::chrono::steady_clock::now();
  absl::StatusOr<AccelParams> s1 = absl::FailedPreconditionError("no face references");
  FaceReferences faces;
  if (checks.protocol == ProtocolKind::kSixFace) {
    faces = VerifiedFaces(ivs, checks.pairs, checks.ups, g);
  } else if (checks.protocol == ProtocolKind::kFerraris) {
    faces = SingleFaces(ivs, out.used, checks.ups, g);
  }
  if (checks.protocol == ProtocolKind::kSixFace || checks.protocol == ProtocolKind::kFerraris) {
    s1 = FitFaces(checks.protocol, faces);
    if (!s1.ok()) {
      out.warnings.push_back(FacesNotPossibleWarning(checks.protocol, s1.status()));
    } else if (checks.protocol == ProtocolKind::kFerraris) {
      out.warnings.push_back(kFerrarisTiltWarning);
    }
  }
  out.from_faces = s1.ok();
  bool bias_scale_only = false;
  if (!s1.ok()) s1 = FitEllipsoid(poses, g);
  if (!s1.ok() && poses.size() >= kBiasScalePoses) {
    // Too few poses for the full model: the largest one they determine.
    s1 = FitAxisEllipsoid(poses, g);
    if (s1.ok()) {
      bias_scale_only = true;
      *s1 = RefineAccelGaussNewton(*s1, poses, g, MaskOf(kAccelBiasScale), 20);
      out.warnings.push_back(BiasScaleOnlyWarning(poses.size()));
    }
  }
  if (!s1.ok()) return s1.status();
  StageReport ls;
  ls.name = "ls";
  ls.iterations = 1;
  ls.pose_indices = out.used;
  ls.pose_residual_m_s2 = MagnitudeResiduals(*s1, poses, g);
  ls.accel_rms_m_s2 = Rms(ls.pose_residual_m_s2);
  ls.ms = MsSince(ls_start);
  out.stages.push_back(ls);
  // Model error beyond each pose's noise joins the weights (accel_solver.h). Stage 1 lacks
  // the second-order terms, so its misfit overstates it: it is measured again at each refit.
  SetModelSigma(*s1, g, MaskOf(kAccelFirstOrder), &poses);

  // 2. What the poses determine; undetermined parameters stay at neutral values.
  AccelMask all{};
  all.fill(true);
  if (bias_scale_only) all = MaskOf(kAccelBiasScale);
  out.observability = AnalyseAccelObservability(*s1, poses, g, all);
  if (out.from_faces) {
    out.held_by_faces = HoldAnglesTheFacesDetermine(faces, *s1, out.observability, &out.warnings);
    AccelMask candidates = all;
    for (int c : kAccelTri.Indices())
      candidates[static_cast<size_t>(c)] = !out.held_by_faces[static_cast<size_t>(c)];
    out.observability = AnalyseAccelObservability(*s1, poses, g, candidates);
  }
  const AccelObservability& obs = out.observability;
  for (const auto& w : obs.warnings) out.warnings.push_back(w);

  // The face references alone, when the poses are too few to refine |a| = g on (ferraris with
  // each face once: 6 poses for 6 parameters): the affine fit is the result.
  int n_determined = 0;
  for (bool d : obs.determined) n_determined += d;
  out.affine_only = out.from_faces && static_cast<int>(poses.size()) <= n_determined;

  // 3. Second-order terms stay unless leaving them out predicts held-out poses better.
  out.free = obs.determined;
  if (!out.affine_only) {
    SetModelSigma(RefineAccelGaussNewton(*s1, poses, g, obs.determined, 10), g, obs.determined,
                  &poses);
    out.free = SelectQuadratics(*s1, poses, g, obs.determined, &out.warnings);
  }

  // 4. BSAS, then LM.
  // Undetermined second-order terms and angles are held at their neutral value, 0: a stage-1
  // value the data does not support would be a confident number it cannot back.
  AccelVector s1_vector = PackAccel(*s1);
  for (int c = kAccelTri.begin; c < kAccelParams; ++c)
    if (!obs.determined[static_cast<size_t>(c)] && !out.held_by_faces[static_cast<size_t>(c)])
      s1_vector(c) = 0;
  *s1 = UnpackAccel(s1_vector, s1->frame_angles);
  if (out.affine_only) {
    out.params = *s1;
    out.covariance = AffineFitCovariance(faces, *s1, &out.chi2_reduced);
    // Its standard errors cover the face-set angles too.
    for (int c : kAccelTri.Indices())
      out.free[static_cast<size_t>(c)] |= out.held_by_faces[static_cast<size_t>(c)];
    out.warnings.push_back(AffineOnlyWarning(poses.size()));
  } else {
    AccelParams start = *s1;
    if (opt.use_bsas) {
      StageReport bs;
      start = RefineAccelBsas(*s1, poses, g, out.free, StageOneUnits(*s1, poses, out.free),
                              BsasStageOptions{.seed = opt.seed}, &bs);
      bs.pose_indices = out.used;
      bs.pose_residual_m_s2 = MagnitudeResiduals(start, poses, g);
      out.stages.push_back(bs);
    }
    StageReport lm_report;
    absl::StatusOr<LmResult> lm = RefineAccelLm(start, poses, g, out.free, &lm_report);
    if (!lm.ok()) return lm.status();
    // The weights and the covariance with the model error of the final fit.
    SetModelSigma(lm->params, g, out.free, &poses);
    lm = RefineAccelLm(lm->params, poses, g, out.free, nullptr);
    if (!lm.ok()) return lm.status();
    lm_report.pose_indices = out.used;
    lm_report.pose_residual_m_s2 = MagnitudeResiduals(lm->params, poses, g);
    lm_report.accel_rms_m_s2 = Rms(lm_report.pose_residual_m_s2);
    out.stages.push_back(lm_report);
    out.params = lm->params;
    out.covariance = lm->covariance;
    out.chi2_reduced = lm->chi2_reduced;
  }
  if (out.from_faces) out.params.frame_angles = FrameAngles(out.params, faces);
  return out;
}

}  // namespace imucal::core::pipeline
