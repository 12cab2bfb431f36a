#include "core/calibrate/accel_stage.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/robust_covariance.h"
#include "util/units.h"

namespace imucal::core::pipeline {
namespace {

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

// The face references of ferraris and faces: each face held once, no pair.
bool FacesHeldOnce(ProtocolKind protocol) {
  return protocol == ProtocolKind::kFerraris || protocol == ProtocolKind::kFaces;
}

// How far a floor tilted by `tilt_deg` moves each parameter of the face references' fit, at most:
// each placement's tilt in its own unknown direction (the floor's tilt seen from each face), the
// first-order worst case summed over the faces.
AccelVector TiltSensitivity(const FaceReferences& faces, double tilt_deg) {
  AccelVector out = AccelVector::Zero();
  const absl::StatusOr<AccelParams> base = FitKnownReferences(faces.means, faces.refs);
  if (!base.ok()) return AccelVector::Constant(kNaN);
  const double t = tilt_deg * kDegToRad;
  for (size_t i = 0; i < faces.refs.size(); ++i) {
    const Eigen::Vector3d& ref = faces.refs[i];
    int axis = 0;
    ref.cwiseAbs().maxCoeff(&axis);
    AccelVector squared = AccelVector::Zero();
    for (int k = 1; k <= 2; ++k) {
      FaceReferences tilted = faces;
      Eigen::Vector3d side = Eigen::Vector3d::Zero();
      side((axis + k) % 3) = ref.norm();
      tilted.refs[i] = std::cos(t) * ref + std::sin(t) * side;
      const absl::StatusOr<AccelParams> p = FitKnownReferences(tilted.means, tilted.refs);
      if (!p.ok()) return AccelVector::Constant(kNaN);
      squared += (PackAccel(*p) - PackAccel(*base)).cwiseAbs2();
    }
    out += squared.cwiseSqrt();
  }
  return out;
}

std::string FacesOnceWarning(ProtocolKind protocol, const FaceReferences& faces,
                             const AccelParams& fit, double g) {
  constexpr double kTiltDeg = 1.0;
  const AccelVector d = TiltSensitivity(faces, kTiltDeg);
  double bias = 0, scale = 0, angle = 0;
  for (int j = 0; j < 3; ++j) {
    bias = std::max(bias, std::abs(d(kAccelBias.begin + j) * fit.scale(j)));
    scale = std::max(scale, std::abs(d(kAccelScale.begin + j) / fit.scale(j)));
    angle = std::max(angle, std::abs(d(kAccelTri.begin + j)));
  }
  return absl::StrFormat(
      "%s: each face was held once, without the 180-degree pair, so the floor is assumed level: "
      "its tilt is not cancelled. A tilt of %.0f degree moves the bias by up to %.2f mg, the "
      "scale by up to %.0f ppm and the misalignment angles by up to %.1f mrad (the frame angles "
      "by about the tilt itself). Hold each face again turned 180 degrees about the vertical "
      "(six-face, the recommended protocol) to cancel it",
      protocol == ProtocolKind::kFaces ? "faces" : "ferraris", kTiltDeg, 1e3 * bias / g,
      1e6 * scale, 1e3 * angle);
}

std::string NothingToCheckWarning(size_t poses, int n_free) {
  return absl::StrFormat(
      "accelerometer: %d poses for %d parameters: nothing is left to check the fit (no residual, "
      "no held-out error; the standard errors come from the poses' noise alone); add poses",
      static_cast<int>(poses), n_free);
}

std::string BiasScaleOnlyWarning(size_t poses) {
  return absl::StrFormat(
      "accelerometer: only bias and scale were calibrated (6 of 12 parameters): %d poses "
      "cannot determine the misalignment angles t_yx, t_zx, t_zy and the second-order terms, "
      "held at 0. Add poses to reach at least %d distinct orientations, some with gravity "
      "between two axes (45 degrees)",
      static_cast<int>(poses), static_cast<int>(kFullModelNeeds.count));
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
  if (FacesHeldOnce(protocol) && faces.means.size() != 6) {
    return absl::FailedPreconditionError(
        absl::StrFormat("only %d of the 6 faces placed", static_cast<int>(faces.means.size())));
  }
  return FitKnownReferences(faces.means, faces.refs);
}

// The error the pair means leave in the face references' angles: a turn of 180 + e degrees on a
// floor tilted by t puts a pair's mean t * e / 2 off its face axis (core/protocol.h
// PairTurnAxis), and the affine fit's angles err by as much. Measured with the rough gyroscope,
// whose scale may be 3 % off (5.4 degrees of a half turn), hence e is taken that much larger.
// The largest over the verified pairs, rad.
double PairMeanAngleError(const std::vector<PairCheck>& pairs) {
  constexpr double kRoughTurnErrorDeg = 0.03 * 180.0;
  double out = 0;
  for (const PairCheck& p : pairs) {
    if (!p.ok || !std::isfinite(p.rotation_deg)) continue;
    const double e_deg = std::abs(std::abs(p.rotation_deg) - 180.0) + kRoughTurnErrorDeg;
    out = std::max(out, std::sin(p.tilt_deg * kDegToRad) * e_deg * kDegToRad / 2);
  }
  return out;
}

// The face references measure the non-orthogonality angles at first order; at axis-aligned
// poses |a| = g sees them only through the floor's tilt, and off-axis poses bring it more. Both
// are used: the faces' angles enter the |a| = g fit as priors (accel_solver.h AccelPrior), with
// their fit's standard error and the systematic error of the references together:
//   six-face  the pair means' t * e / 2 (PairMeanAngleError);
//   faces held once (ferraris, faces)  the floor's tilt itself, unknown, taken as 1 degree: it
//             moves the angles by about 17 mrad per degree.
// A plain six-face capture then keeps the faces' angles (|a| = g knows them 100 times worse and
// refining on it alone fitted noise, up to a degree on an independent writer's capture); off-axis
// poses refine them where they know better. Holding them at the faces' value instead (as before)
// pushed the pair means' error into quadratic terms and biases with low noise (biases off by
// 2e-3 m/s^2, 4-7 standard errors, on an independent writer's capture with 4 extra poses).
AccelPriors FaceAnglePriors(ProtocolKind protocol, const std::vector<PairCheck>& pairs,
                            const FaceReferences& faces, const AccelParams& stage_one,
                            std::vector<std::string>* warnings) {
  constexpr double kFacesOnceTiltRad = 1.0 * kDegToRad;
  const double systematic =
      protocol == ProtocolKind::kSixFace ? PairMeanAngleError(pairs) : kFacesOnceTiltRad;
  double chi2 = kNaN;
  const AccelMatrix cov = AffineFitCovariance(faces, stage_one, &chi2);
  AccelPriors out;
  std::string sigmas;
  for (int c : kAccelTri.Indices()) {
    const double fit = std::sqrt(cov(c, c));
    const double sigma = std::hypot(std::isfinite(fit) ? fit : 0.0, systematic);
    if (!(sigma > 0)) continue;
    out.push_back({c, PackAccel(stage_one)(c), sigma, "face references"});
    absl::StrAppendFormat(&sigmas, "%s%s %.2g", sigmas.empty() ? "" : ", ", AccelParamName(c),
                          sigma);
  }
  warnings->push_back(absl::StrFormat(
      "accel angles: the face references measure them to +- %s rad (their fit and the %s), "
      "joined to what |a| = g on the poses says",
      sigmas,
      protocol == ProtocolKind::kSixFace ? "pairs' turn error" : "floor's tilt, taken as 1 deg"));
  return out;
}

// The second-order terms' prior width by the capture's own evidence (empirical Bayes, type-II
// maximum likelihood over a grid): the sensor class's width is the widest tried, down to 1/50
// of it. The class says what a unit may have; the poses say how large this unit's terms are.
// A unit whose poses show them small gets them shrunk hard (on a plain six-face capture, where
// the poses know them only through the floor's tilt, the class's width let noise into them and
// through them into the biases: 1.1-2.5 mg against 0.8 held at 0); one whose terms are large
// keeps them. Sets the width chosen in `priors`.
//
// The width is itself uncertain: two captures of one unit can choose neighbouring widths and
// then shrink the terms, and the biases they trade against, differently. Returns what that
// uncertainty adds to the covariance at the chosen width: the positive part of the covariance
// averaged over the widths (each weighted by its evidence, a uniform prior over the grid; each
// width's posterior covariance plus its fit's distance from the chosen one) less the chosen
// width's own.
AccelMatrix ChooseQuadraticWidth(const AccelParams& start, const std::vector<AccelPose>& poses,
                                 double g, const AccelMask& free, double class_width,
                                 AccelPriors* priors) {
  const auto set_width = [priors](double w) {
    for (AccelPrior& q : *priors)
      if (q.index >= kAccelQuadratic.begin && q.index < kAccelQuadratic.end) q.sigma = w;
  };
  struct Tried {
    double width, evidence;
    AccelVector theta;
    AccelMatrix covariance;
  };
  std::vector<Tried> tried;
  size_t best = 0;
  for (double f : {1.0, 0.5, 0.2, 0.1, 0.05, 0.02}) {
    set_width(f * class_width);
    const AccelParams fit = RefineAccelGaussNewton(start, poses, g, free, 10, *priors);
    tried.push_back({f * class_width, AccelLogEvidence(fit, poses, g, free, *priors),
                     PackAccel(fit), AccelCovariance(fit, poses, free, *priors)});
    if (tried.back().evidence > tried[best].evidence) best = tried.size() - 1;
  }
  set_width(tried[best].width);
  AccelMatrix averaged = AccelMatrix::Zero();
  double total = 0;
  for (const Tried& t : tried) {
    const double weight = std::exp(t.evidence - tried[best].evidence);
    if (!std::isfinite(weight) || !t.covariance.allFinite()) continue;
    const AccelVector d = t.theta - tried[best].theta;
    averaged += weight * (t.covariance + d * d.transpose());
    total += weight;
  }
  if (!(total > 0)) return AccelMatrix::Zero();
  const AccelMatrix extra =
      LoewnerUpperBound(tried[best].covariance, averaged / total) - tried[best].covariance;
  return extra.allFinite() ? extra : AccelMatrix::Zero();
}

}  // namespace

AccelVector StageOneUnits(const AccelParams& p, const std::vector<AccelPose>& poses,
                          const AccelMask& free, const AccelPriors& priors) {
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
  for (const AccelPrior& q : priors)
    for (size_t a = 0; a < idx.size(); ++a)
      if (idx[a] == q.index)
        info(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(a)) +=
            1.0 / (q.sigma * q.sigma);
  const Eigen::MatrixXd cov =
      info.ldlt().solve(Eigen::MatrixXd::Identity(info.rows(), info.cols()));
  for (size_t a = 0; a < idx.size(); ++a) {
    const double s =
        std::sqrt(std::abs(cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(a))));
    if (std::isfinite(s) && s > 0) unit(idx[a]) = s;
  }
  return unit;
}

void SetModelSigma(const AccelParams& p, double g, const AccelMask& free, const AccelPriors& priors,
                   std::vector<AccelPose>* poses) {
  const double tau = EstimateModelSigma(p, *poses, g, EffectiveParameters(p, *poses, free, priors));
  for (auto& pose : *poses) pose.model_sigma_m_s2 = tau;
}

namespace {

// 1. Linear least squares: the face references when the protocol has them, else the ellipsoid;
// with too few poses for either, the per-axis ellipsoid (bias and scale only).
absl::StatusOr<AccelParams> LinearStage(const ProtocolChecks& checks, double g,
                                        FaceReferences* faces, bool* bias_scale_only,
                                        AccelStage* out) {
  const auto start = std::chrono::steady_clock::now();
  const std::vector<StaticInterval>& ivs = checks.intervals;
  const std::vector<AccelPose>& poses = out->poses;
  absl::StatusOr<AccelParams> s1 = absl::FailedPreconditionError("no face references");
  if (checks.protocol == ProtocolKind::kSixFace) {
    *faces = VerifiedFaces(ivs, checks.pairs, checks.ups, g);
  } else if (FacesHeldOnce(checks.protocol)) {
    *faces = SingleFaces(ivs, out->used, checks.ups, g);
  }
  if (checks.protocol == ProtocolKind::kSixFace || FacesHeldOnce(checks.protocol)) {
    s1 = FitFaces(checks.protocol, *faces);
    if (!s1.ok()) {
      out->warnings.push_back(FacesNotPossibleWarning(checks.protocol, s1.status()));
    } else if (FacesHeldOnce(checks.protocol)) {
      out->warnings.push_back(FacesOnceWarning(checks.protocol, *faces, *s1, g));
      if (checks.protocol == ProtocolKind::kFaces)
        out->incomplete.push_back("faces held once each: the floor was assumed level");
    }
  }
  out->from_faces = s1.ok();
  *bias_scale_only = false;
  if (!s1.ok()) s1 = FitEllipsoid(poses, g);
  if (!s1.ok() && poses.size() >= kBiasScaleNeeds.count) {
    // Too few poses for the full model: the largest one they determine.
    s1 = FitAxisEllipsoid(poses, g);
    if (s1.ok()) {
      *bias_scale_only = true;
      *s1 = RefineAccelGaussNewton(*s1, poses, g, MaskOf(kAccelBiasScale), 20);
      out->warnings.push_back(BiasScaleOnlyWarning(poses.size()));
      out->incomplete.push_back(
          "accelerometer: only bias and scale were calibrated (too few orientations)");
    }
  }
  if (!s1.ok()) return s1.status();
  StageReport ls;
  ls.name = "ls";
  ls.iterations = 1;
  ls.pose_indices = out->used;
  ls.pose_residual_m_s2 = MagnitudeResiduals(*s1, poses, g);
  ls.accel_rms_m_s2 = Rms(ls.pose_residual_m_s2);
  ls.ms = MsSince(start);
  out->stages.push_back(ls);
  return s1;
}

// 2. What the poses (and the face references' angles) determine; undetermined parameters stay
// at neutral values. The priors: the faces' angles, and the model's own second-order terms (and
// the angles where no face measures them) by their evidence: a prior of the sensor class, never
// a switch (issue 25; term_priors.h).
void PriorsAndObservability(const ProtocolChecks& checks, const CalibrateOptions& opt,
                            const FaceReferences& faces, const AccelParams& s1, double g,
                            bool bias_scale_only, AccelStage* out) {
  std::vector<AccelPose>& poses = out->poses;
  if (out->from_faces)
    out->priors = FaceAnglePriors(checks.protocol, checks.pairs, faces, s1, &out->warnings);
  // Model error beyond each pose's noise joins the weights (accel_solver.h). Stage 1 lacks the
  // second-order terms, so its misfit overstates it: it is measured again at each refit. Stage
  // 1's misfit, over the first-order model, is the first model error.
  SetModelSigma(s1, g, MaskOf(kAccelFirstOrder), out->priors, &poses);
  for (AccelPrior& q : ClassAccelPriors(opt.term_priors, out->from_faces))
    out->priors.push_back(std::move(q));
  AccelMask all{};
  all.fill(true);
  if (bias_scale_only) all = MaskOf(kAccelBiasScale);
  // An angle the face references measure is free whatever |a| = g adds: it is not neutral (0)
  // but the faces' value, with their error (the warnings say what was assumed).
  out->observability = AnalyseAccelObservability(s1, poses, g, all, out->priors);
  const AccelObservability& obs = out->observability;
  for (const auto& w : obs.warnings) out->warnings.push_back(w);
  if (!bias_scale_only) {
    for (int c : kAccelFirstOrder.Indices())
      if (!obs.determined[static_cast<size_t>(c)])
        out->incomplete.push_back("accel " + AccelParamName(c) + " is not determined by the poses");
  }
  // The face references alone, when the poses are too few to refine |a| = g on (the six faces
  // once each: 6 poses for the 6 parameters the angles' priors leave): the affine fit is the
  // result.
  out->affine_only =
      out->from_faces && static_cast<int>(poses.size()) <= PosesPayFor(obs.determined, out->priors);
  out->free = obs.determined;
}

// 3. Every determined term is estimated; those with a prior are shrunk by it as far as the poses
// leave them to it. Returns what the prior width's doubt adds to the covariance.
AccelMatrix ChooseWidths(const CalibrateOptions& opt, const AccelParams& s1, double g,
                         AccelStage* out) {
  if (out->affine_only) return AccelMatrix::Zero();
  const AccelMask& determined = out->observability.determined;
  SetModelSigma(RefineAccelGaussNewton(s1, out->poses, g, determined, 10, out->priors), g,
                determined, out->priors, &out->poses);
  const AccelMatrix width_uncertainty = ChooseQuadraticWidth(
      s1, out->poses, g, determined, opt.term_priors.accel_quadratic_per_m_s2, &out->priors);
  for (AccelPrior& q : out->priors) {
    if (q.index < kAccelQuadratic.begin) continue;
    q.source += absl::StrFormat(" (its %.1e, the widest, narrowed to the capture's evidence)",
                                opt.term_priors.accel_quadratic_per_m_s2);
  }
  return width_uncertainty;
}

// 4. BSAS, then LM, from `s1`; or `s1` itself when nothing is left to refine it on.
absl::Status Refine(const CalibrateOptions& opt, const FaceReferences& faces, AccelParams s1,
                    double g, const AccelMatrix& width_uncertainty, AccelStage* out) {
  std::vector<AccelPose>& poses = out->poses;
  const AccelPriors& priors = out->priors;
  // Undetermined second-order terms and angles are held at their neutral value, 0: a stage-1
  // value the data does not support would be a confident number it cannot back.
  AccelVector s1_vector = PackAccel(s1);
  for (int c = kAccelTri.begin; c < kAccelParams; ++c)
    if (!out->observability.determined[static_cast<size_t>(c)]) s1_vector(c) = 0;
  s1 = UnpackAccel(s1_vector, s1.frame_angles);
  const double pays_for = EffectiveParameters(s1, poses, out->free, priors);
  if (!out->affine_only && static_cast<double>(poses.size()) - pays_for < 0.5) {
    // As many poses as parameters: the solution fits every pose exactly, nothing checks it.
    const int n_free = static_cast<int>(std::lround(pays_for));
    out->params = s1;
    out->covariance = AccelCovariance(s1, poses, out->free, priors);
    out->chi2_reduced = kNaN;
    out->warnings.push_back(NothingToCheckWarning(poses.size(), n_free));
    out->incomplete.push_back("nothing is left to check the accelerometer's fit");
    return absl::OkStatus();
  }
  if (out->affine_only) {
    out->params = s1;
    out->covariance = AffineFitCovariance(faces, s1, &out->chi2_reduced);
    out->warnings.push_back(AffineOnlyWarning(poses.size()));
    return absl::OkStatus();
  }
  AccelParams start = s1;
  if (opt.use_bsas) {
    StageReport bs;
    start = RefineAccelBsas(s1, poses, g, out->free, StageOneUnits(s1, poses, out->free, priors),
                            BsasStageOptions{.seed = opt.seed}, &bs, priors);
    bs.pose_indices = out->used;
    bs.pose_residual_m_s2 = MagnitudeResiduals(start, poses, g);
    out->stages.push_back(bs);
  }
  StageReport lm_report;
  absl::StatusOr<LmResult> lm = RefineAccelLm(start, poses, g, out->free, &lm_report, priors);
  if (!lm.ok()) return lm.status();
  // The weights and the covariance with the model error of the final fit.
  SetModelSigma(lm->params, g, out->free, priors, &poses);
  lm = RefineAccelLm(lm->params, poses, g, out->free, nullptr, priors);
  if (!lm.ok()) return lm.status();
  lm_report.pose_indices = out->used;
  lm_report.pose_residual_m_s2 = MagnitudeResiduals(lm->params, poses, g);
  lm_report.accel_rms_m_s2 = Rms(lm_report.pose_residual_m_s2);
  out->stages.push_back(lm_report);
  out->params = lm->params;
  out->covariance = lm->covariance + width_uncertainty;
  out->chi2_reduced = lm->chi2_reduced;
  return absl::OkStatus();
}

// What each prior did. A first-order term (a non-orthogonality angle) the poses know no better
// than the class does is an assumption, not a measurement: at best a warn, as when it was held
// at 0 (the faces' angles are the faces' measurement). The second-order terms' shrinkage is
// said in the warnings and term_priors; a capture that leaves them to the prior (six faces)
// passes.
void DescribeTermPriors(const CalibrateOptions& opt, AccelStage* out) {
  out->term_priors = DescribePriors(out->priors, out->params, out->covariance);
  std::string assumed;
  for (size_t k = 0; k < out->term_priors.size(); ++k) {
    const TermPriorEffect& e = out->term_priors[k];
    if (e.data_weight < 0.5) out->warnings.push_back(DescribePriorEffect(e));
    const int c = out->priors[k].index;
    const bool class_angle = !out->from_faces && c >= kAccelTri.begin && c < kAccelTri.end;
    if (class_angle && !(e.data_sigma < opt.term_priors.accel_angle_rad))
      absl::StrAppend(&assumed, assumed.empty() ? "" : ", ", AccelParamName(c));
  }
  if (!assumed.empty()) {
    out->incomplete.push_back("accel " + assumed +
                              ": the poses do not determine them; the sensor class's prior "
                              "holds them near 0");
  }
}

}  // namespace

absl::StatusOr<AccelStage> SolveAccel(const Capture& cap, const CalibrateOptions& opt,
                                      const NoiseLevel& noise, const ProtocolChecks& checks) {
  AccelStage out;
  const double g = cap.gravity_m_s2;
  out.used = UsedIndices(checks.intervals);
  out.poses = ToAccelPoses(checks.intervals, out.used, noise);
  FaceReferences faces;
  bool bias_scale_only = false;
  absl::StatusOr<AccelParams> s1 = LinearStage(checks, g, &faces, &bias_scale_only, &out);
  if (!s1.ok()) return s1.status();
  PriorsAndObservability(checks, opt, faces, *s1, g, bias_scale_only, &out);
  const AccelMatrix width_uncertainty = ChooseWidths(opt, *s1, g, &out);
  if (absl::Status s = Refine(opt, faces, *s1, g, width_uncertainty, &out); !s.ok()) return s;
  if (out.from_faces) out.params.frame_angles = FrameAngles(out.params, faces);
  DescribeTermPriors(opt, &out);
  return out;
}

}  // namespace imucal::core::pipeline
