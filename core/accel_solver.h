// Accelerometer calibration from static poses, in the stages of the issue:
//   1. linear least squares: with known orientations (six-face, seeds/000) the 12-parameter
//      affine fit against +-g; otherwise an ellipsoid fit of |a| = g (9 parameters);
//   2. BSAS refinement (seeds/002) of the 12 magnitude parameters on the |a| = g cost, staged
//      (scale, bias, angles, quadratic) in units of the stage-1 standard errors;
//   3. Levenberg-Marquardt (Ceres) on the same cost, weighted by each pose's measured noise, with
//      the parameter covariance.
// The model is AccelModel of core/model.h. |a| does not depend on frame_angles, so stages 2-3
// keep the frame angles of stage 1 (zero when no orientation was known).
//
// The 12 "magnitude" parameters, in this order everywhere (vectors, covariance, masks):
//   0-2 bias (input units), 3-5 scale (m/s^2 per input unit), 6-8 tri_angles (rad),
//   9-11 quadratic (1/(m/s^2)).
#ifndef IMUCAL_CORE_ACCEL_SOLVER_H_
#define IMUCAL_CORE_ACCEL_SOLVER_H_

#include <array>
#include <limits>
#include <optional>
#include <ranges>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "core/model.h"

namespace ceres {
class CostFunction;
}  // namespace ceres

namespace imucal::core {

inline constexpr int kAccelParams = 12;
using AccelVector = Eigen::Matrix<double, kAccelParams, 1>;
using AccelMatrix = Eigen::Matrix<double, kAccelParams, kAccelParams>;
using AccelMask = std::array<bool, kAccelParams>;  // true = estimated, false = held fixed

// The parameter groups of the 12-vector, as index ranges [begin, end).
struct AccelParamRange {
  int begin = 0, end = 0;
  // The indices of the range, for `for (int c : kAccelTri.Indices())`.
  constexpr auto Indices() const { return std::views::iota(begin, end); }
};
inline constexpr AccelParamRange kAccelBias{0, 3};
inline constexpr AccelParamRange kAccelScale{3, 6};
inline constexpr AccelParamRange kAccelTri{6, 9};         // t_yx, t_zx, t_zy
inline constexpr AccelParamRange kAccelQuadratic{9, 12};  // the second-order terms
inline constexpr AccelParamRange kAccelFirstOrder{0, 9};  // bias, scale and angles
inline constexpr AccelParamRange kAccelBiasScale{0, 6};

// The mask that frees exactly `range`.
constexpr AccelMask MaskOf(AccelParamRange range) {
  AccelMask m{};
  for (int c : range.Indices()) m[static_cast<size_t>(c)] = true;
  return m;
}

// A Gaussian prior on one of the 12 magnitude parameters: an independent measurement of it,
// `value` +- `sigma` (parameter units), joined to |a| = g as one more weighted residual
// (theta[index] - value) / sigma. The six-face references measure the non-orthogonality angles
// at first order where |a| = g sees them only through off-axis poses: the two combine, neither
// replaces the other. A prior on a fixed parameter is ignored.
struct AccelPrior {
  int index = 0;
  double value = 0;
  double sigma = 1;
  std::string
      source;  // where it comes from, for the report: "face references", "sensor class mems"
};
using AccelPriors = std::vector<AccelPrior>;
// The number of free parameters less those a prior constrains: what the poses' residual pays
// for (the model error's degrees of freedom).
int PosesPayFor(const AccelMask& free, const AccelPriors& priors);
// The priors on free parameters (sigma > 0), in the order their rows follow the poses' rows in
// every weighted design of the magnitude fit.
std::vector<AccelPrior> ActivePriors(const AccelMask& free, const AccelPriors& priors);
// One prior as a Ceres residual (theta[index] - value) / sigma on the parameter block of its
// index's group (3 components: bias, scale, tri_angles or quadratic). The caller owns it.
ceres::CostFunction* NewAccelPriorCost(const AccelPrior& prior);

// A static pose as the accelerometer solver sees it.
struct AccelPose {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();      // mean raw reading, input units
  Eigen::Vector3d mean_std = Eigen::Vector3d::Ones();  // std of that mean per axis, input units
  // Error of |a| that the model leaves, common to all poses, m/s^2 (see EstimateModelSigma).
  double model_sigma_m_s2 = 0.0;
  // A known additive term of this pose's output, removed before the magnitude: the effects the
  // diagnostics found (core/effects.h), rotated into the frame-free axes R(frame_angles)^T, m/s^2.
  // |a| is then |L z - offset|. Zero in the plain model.
  Eigen::Vector3d offset_m_s2 = Eigen::Vector3d::Zero();
};

AccelVector PackAccel(const AccelParams& p);
AccelParams UnpackAccel(const AccelVector& v, const Eigen::Vector3d& frame_angles);
std::string AccelParamName(int index);  // "bias_x", "scale_y", "t_zx", "quadratic_z", ...

// |a_i| - g for every pose.
std::vector<double> MagnitudeResiduals(const AccelParams& p, const std::vector<AccelPose>& poses,
                                       double gravity_m_s2);
double Rms(const std::vector<double>& v);

// Stage 1 without orientations: the ellipsoid through the pose means, in the triangular gauge.
// Needs at least 9 poses spread over the sphere. Data-driven start: no nominal scale needed.
absl::StatusOr<AccelParams> FitEllipsoid(const std::vector<AccelPose>& poses, double gravity_m_s2);

// Stage 1 of the reduced model (bias and scale only, angles and quadratic 0) for captures with
// too few poses for the ellipsoid: sum_j s_j^2 (u_j - b_j)^2 = g^2, linear in 6 unknowns.
// Needs at least 6 poses with every axis both up and down (7 or more for any redundancy).
absl::StatusOr<AccelParams> FitAxisEllipsoid(const std::vector<AccelPose>& poses,
                                             double gravity_m_s2);

// Stage 1 with known orientations (seeds/000): a = P^T [u; 1] by least squares against the
// reference specific forces (m/s^2). Returns the full 12-parameter affine model, decomposed into
// frame rotation * lower-triangular * scale (quadratic 0).
absl::StatusOr<AccelParams> FitKnownReferences(const std::vector<Eigen::Vector3d>& means,
                                               const std::vector<Eigen::Vector3d>& references);

// Jacobian d(|a_i| - g)/d(params), one row per pose.
Eigen::MatrixXd MagnitudeJacobian(const AccelParams& p, const std::vector<AccelPose>& poses);
// Standard deviation of |a_i| from the pose's mean_std and model_sigma_m_s2, m/s^2.
std::vector<double> MagnitudeSigmas(const AccelParams& p, const std::vector<AccelPose>& poses);

// The common model error tau (m/s^2) with sum_i r_i^2 / (sigma_i^2 + tau^2) = N - free: the
// scatter the residual shows beyond each pose's measured noise (0 when the noise explains it).
// Weighting by noise alone lets a 50 s rest outweigh every 4 s pose tenfold, although on real
// data the model, not the noise, limits the fit; with tau each pose counts as what it is worth.
double EstimateModelSigma(const AccelParams& p, const std::vector<AccelPose>& poses,
                          double gravity_m_s2, double n_free);

// The parameters the poses pay for, trace((J'WJ + P)^-1 J'WJ) over the free ones: a parameter the
// poses determine counts 1, one its prior decides 0, a shrunk one between (P: the priors'
// precisions). The model error's degrees of freedom are the poses less this.
double EffectiveParameters(const AccelParams& p, const std::vector<AccelPose>& poses,
                           const AccelMask& free, const AccelPriors& priors);

// The range a MEMS accelerometer's parameters plausibly have, in parameter units: bias 0.2 g,
// scale 10 %, angles 30 mrad, quadratic 1e-3 per m/s^2 (datasheet tolerances with room).
AccelVector AccelPlausibleRange(const AccelParams& p, double gravity_m_s2);

// Which parameters the poses determine. Information is compared with the plausible range as a
// broad physical prior: a parameter whose posterior std is not at least halved by the data is
// undetermined. `priors` join the data's information; a parameter with one is never released.
// Higher-order parameters are released first (quadratic, then angles), so a confounded pair keeps
// its lower-order member.
struct AccelObservability {
  AccelMask determined{};
  // Posterior standard deviation of each determined parameter from |a| = g on these poses
  // (parameter units: m/s^2, scale, rad, 1/(m/s^2)); infinity for the undetermined.
  AccelVector sigma = AccelVector::Constant(std::numeric_limits<double>::infinity());
  std::vector<std::string> warnings;  // "quadratic_x: not determined by these poses; ..."
};
AccelObservability AnalyseAccelObservability(const AccelParams& p,
                                             const std::vector<AccelPose>& poses,
                                             double gravity_m_s2, const AccelMask& candidates,
                                             const AccelPriors& priors = {});

struct StageReport {
  std::string name;  // "ls", "bsas", "lm"
  double accel_rms_m_s2 = 0;
  int iterations = 0;
  int evaluations = 0;
  double ms = 0;
  // |a| - g per used pose after this stage (m/s^2), in the order of `pose_indices` (report pose
  // indices); the per-pose picture of what the stage changed. Filled by Calibrate.
  std::vector<int> pose_indices;
  std::vector<double> pose_residual_m_s2;
};

struct BsasStageOptions {
  uint64_t seed = 1;
  int max_rounds = 4;
  int iterations_per_stage = 200;
};
// Stage 2. `unit` is the normalisation (one unit per parameter), typically stage-1 std errors.
AccelParams RefineAccelBsas(const AccelParams& start, const std::vector<AccelPose>& poses,
                            double gravity_m_s2, const AccelMask& free, const AccelVector& unit,
                            const BsasStageOptions& options, StageReport* report,
                            const AccelPriors& priors = {});

struct LmResult {
  AccelParams params;
  AccelMatrix covariance = AccelMatrix::Zero();  // zero rows/cols for fixed parameters
  double chi2_reduced = 0;         // weighted residual^2 / dof; >1: model misfit beyond noise
  bool covariance_scaled = false;  // covariance multiplied by chi2_reduced (> 1)
};
// Stage 3. Fails (FailedPrecondition) when there are fewer poses than free parameters, and
// (Internal) when Ceres reports an unusable solution.
absl::StatusOr<LmResult> RefineAccelLm(const AccelParams& start,
                                       const std::vector<AccelPose>& poses, double gravity_m_s2,
                                       const AccelMask& free, StageReport* report,
                                       const AccelPriors& priors = {});

// Gauss-Newton on the weighted magnitude residuals over the `free` parameters, from a nearby
// start, until the step is below 1e-10 of the parameters or after `max_iterations`. For the many
// small refits (threshold sweep, term selection, leave-one-out), where the setup of a Ceres
// problem would cost more than the solve; the reported "lm" stage stays on Ceres.
AccelParams RefineAccelGaussNewton(const AccelParams& start, const std::vector<AccelPose>& poses,
                                   double gravity_m_s2, const AccelMask& free, int max_iterations,
                                   const AccelPriors& priors = {});

// The covariance (J^T W J)^-1 over the free parameters at `p` (weights from each pose's noise
// and model_sigma_m_s2, not scaled by the fit's chi^2); zero rows and columns for fixed ones.
AccelMatrix AccelCovariance(const AccelParams& p, const std::vector<AccelPose>& poses,
                            const AccelMask& free, const AccelPriors& priors = {});
// The log marginal likelihood of the priors' widths (Laplace, at a converged fit `p` with these
// priors), up to a constant: -1/2 |r_w|^2 (priors' rows included) - 1/2 log det(J'WJ + P)
// - sum log sigma. Compares prior widths on one capture (empirical Bayes, accel_stage.cc).
double AccelLogEvidence(const AccelParams& p, const std::vector<AccelPose>& poses,
                        double gravity_m_s2, const AccelMask& free, const AccelPriors& priors);
// Its diagonal's square root: one-sigma standard errors, 0 for fixed parameters.
AccelVector AccelStdErrors(const AccelParams& p, const std::vector<AccelPose>& poses,
                           const AccelMask& free, const AccelPriors& priors = {});

// Leave-one-pose-out: for each pose, refit without it (Gauss-Newton from `fit`, which is a
// converged full fit, so the refit converges in a few steps) and return its |a| - g.
std::vector<double> HeldOutMagnitudeResiduals(const AccelParams& fit,
                                              const std::vector<AccelPose>& poses,
                                              double gravity_m_s2, const AccelMask& free,
                                              const AccelPriors& priors = {});
// The same, to first order (PRESS: r_i / (1 - h_ii)); cheap enough for a parameter sweep.
double PressRms(const AccelParams& fit, const std::vector<AccelPose>& poses, double gravity_m_s2,
                const AccelMask& free, const AccelPriors& priors = {});

}  // namespace imucal::core

#endif  // IMUCAL_CORE_ACCEL_SOLVER_H_
