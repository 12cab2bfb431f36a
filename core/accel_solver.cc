#include "core/accel_solver.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>

#include "Eigen/Cholesky"
#include "Eigen/Dense"
#include "absl/strings/str_format.h"
#include "ceres/ceres.h"
#include "core/accel_problem.h"
#include "core/bsas.h"
#include "core/robust_covariance.h"

namespace imucal::core {
namespace {

// Lower-triangular M with positive diagonal and M^T M = Q (Cholesky of the index-reversed Q).
std::optional<Eigen::Matrix3d> ReversedCholesky(const Eigen::Matrix3d& q) {
  const Eigen::Matrix3d j = Eigen::Matrix3d::Identity().rowwise().reverse();
  Eigen::LLT<Eigen::Matrix3d> llt(j * q * j);
  if (llt.info() != Eigen::Success) return std::nullopt;
  const Eigen::Matrix3d l = llt.matrixL();
  return Eigen::Matrix3d(j * l * j).transpose();
}

// Splits a lower-triangular M = L * diag(scale) into the model's scale and tri_angles.
void SetFromLower(const Eigen::Matrix3d& lower, AccelParams* p) {
  p->scale = lower.diagonal();
  const Eigen::Matrix3d l = lower * p->scale.cwiseInverse().asDiagonal();
  p->tri_angles = Eigen::Vector3d(l(1, 0), l(2, 0), l(2, 1));
}

double Seconds(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

// Weighted Jacobian rows (d r_i / d theta with r_i = (|a_i| - g)/sigma_i) restricted to `free`,
// then one row per active prior ((theta_c - value) / sigma).
Eigen::MatrixXd WeightedJacobian(const AccelParams& p, const std::vector<AccelPose>& poses,
                                 const std::vector<double>& sigma, const AccelMask& free,
                                 const AccelPriors& priors = {}) {
  const Eigen::MatrixXd j = MagnitudeJacobian(p, poses);
  const std::vector<AccelPrior> active = ActivePriors(free, priors);
  int n_free = 0;
  for (bool f : free) n_free += f;
  Eigen::MatrixXd out =
      Eigen::MatrixXd::Zero(j.rows() + static_cast<Eigen::Index>(active.size()), n_free);
  std::array<int, kAccelParams> column{};
  for (int c = 0, k = 0; c < kAccelParams; ++c)
    if (free[c]) column[static_cast<size_t>(c)] = k, out.col(k++).head(j.rows()) = j.col(c);
  for (Eigen::Index i = 0; i < j.rows(); ++i) out.row(i) /= sigma[static_cast<size_t>(i)];
  for (size_t m = 0; m < active.size(); ++m)
    out(j.rows() + static_cast<Eigen::Index>(m), column[static_cast<size_t>(active[m].index)]) =
        1.0 / active[m].sigma;
  return out;
}

Eigen::VectorXd WeightedResiduals(const AccelParams& p, const std::vector<AccelPose>& poses,
                                  const std::vector<double>& sigma, double g,
                                  const AccelMask& free = {}, const AccelPriors& priors = {}) {
  const std::vector<double> r = MagnitudeResiduals(p, poses, g);
  const std::vector<AccelPrior> active = ActivePriors(free, priors);
  Eigen::VectorXd out(static_cast<Eigen::Index>(r.size() + active.size()));
  for (size_t i = 0; i < r.size(); ++i) out(static_cast<Eigen::Index>(i)) = r[i] / sigma[i];
  const AccelVector theta = PackAccel(p);
  for (size_t m = 0; m < active.size(); ++m)
    out(static_cast<Eigen::Index>(r.size() + m)) =
        (theta(active[m].index) - active[m].value) / active[m].sigma;
  return out;
}

const char* kGroupNames[4] = {"bias", "scale", "tri", "quadratic"};

// |a| - g of one pose, with l = LowerMisalignment(p.tri_angles) computed once by the caller.
double MagnitudeResidual(const Eigen::Matrix3d& l, const AccelParams& p, const AccelPose& pose,
                         double gravity_m_s2) {
  return (l * p.PerAxis(pose.mean) - pose.offset_m_s2).norm() - gravity_m_s2;
}

}  // namespace

std::vector<AccelPrior> ActivePriors(const AccelMask& free, const AccelPriors& priors) {
  std::vector<AccelPrior> out;
  for (const AccelPrior& q : priors)
    if (q.index >= 0 && q.index < kAccelParams && free[static_cast<size_t>(q.index)] && q.sigma > 0)
      out.push_back(q);
  return out;
}

int PosesPayFor(const AccelMask& free, const AccelPriors& priors) {
  int n = 0;
  for (bool f : free) n += f;
  return n - static_cast<int>(ActivePriors(free, priors).size());
}

AccelVector PackAccel(const AccelParams& p) {
  AccelVector v;
  v << p.bias, p.scale, p.tri_angles, p.quadratic;
  return v;
}

AccelParams UnpackAccel(const AccelVector& v, const Eigen::Vector3d& frame_angles) {
  AccelParams p;
  p.bias = v.segment<3>(0);
  p.scale = v.segment<3>(3);
  p.tri_angles = v.segment<3>(6);
  p.quadratic = v.segment<3>(9);
  p.frame_angles = frame_angles;
  return p;
}

std::string AccelParamName(int index) {
  static const char* kTri[3] = {"t_yx", "t_zx", "t_zy"};
  const int group = index / 3, axis = index % 3;
  if (group == 2) return kTri[axis];
  return absl::StrFormat("%s_%c", kGroupNames[group], "xyz"[axis]);
}

std::vector<double> MagnitudeResiduals(const AccelParams& p, const std::vector<AccelPose>& poses,
                                       double gravity_m_s2) {
  std::vector<double> r;
  r.reserve(poses.size());
  const Eigen::Matrix3d l = LowerMisalignment<double>(p.tri_angles);
  for (const AccelPose& pose : poses) r.push_back(MagnitudeResidual(l, p, pose, gravity_m_s2));
  return r;
}

double Rms(const std::vector<double>& v) {
  if (v.empty()) return 0.0;
  double s = 0;
  for (double x : v) s += x * x;
  return std::sqrt(s / static_cast<double>(v.size()));
}

namespace {

// The poses' means centred and scaled, v = scale (u - centre), so that raw counts (~32768) and
// m/s^2 condition the ellipsoid fits the same.
struct Normalised {
  Eigen::Vector3d centre;
  double scale;
};

absl::StatusOr<Normalised> Normalise(const std::vector<AccelPose>& poses) {
  const auto n = static_cast<double>(poses.size());
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (const auto& p : poses) c += p.mean;
  c /= n;
  double spread = 0;
  for (const auto& p : poses) spread += (p.mean - c).squaredNorm();
  spread = std::sqrt(spread / n);
  if (!(spread > 0)) return absl::FailedPreconditionError("all static poses read the same value");
  return Normalised{c, 1.0 / spread};
}

}  // namespace

absl::StatusOr<AccelParams> FitEllipsoid(const std::vector<AccelPose>& poses, double gravity_m_s2) {
  const size_t n = poses.size();
  if (n < 9) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "too few static poses: %d found, the accelerometer needs at least 9 (12 or more spread "
        "over the sphere recommended)",
        static_cast<int>(n)));
  }
  absl::StatusOr<Normalised> norm = Normalise(poses);
  if (!norm.ok()) return norm.status();
  const Eigen::Vector3d& c = norm->centre;
  const double k = norm->scale;
  // Quadric v^T A v + beta^T v = 1 in the normalised coordinates v = k (u - c).
  Eigen::MatrixXd x(static_cast<Eigen::Index>(n), 9);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d v = k * (poses[i].mean - c);
    x.row(static_cast<Eigen::Index>(i)) << v.x() * v.x(), v.y() * v.y(), v.z() * v.z(),
        2 * v.x() * v.y(), 2 * v.x() * v.z(), 2 * v.y() * v.z(), v.x(), v.y(), v.z();
  }
  const Eigen::VectorXd theta =
      x.colPivHouseholderQr().solve(Eigen::VectorXd::Ones(static_cast<Eigen::Index>(n)));
  Eigen::Matrix3d a;
  a << theta(0), theta(3), theta(4), theta(3), theta(1), theta(5), theta(4), theta(5), theta(2);
  const Eigen::Vector3d beta = theta.segment<3>(6);
  const Eigen::Vector3d v0 = -0.5 * a.ldlt().solve(beta);
  const double rho = 1.0 + v0.dot(a * v0);
  const auto lower = ReversedCholesky(a / rho);
  if (!(rho > 0) || !lower) {
    return absl::FailedPreconditionError(
        "the static poses do not determine the accelerometer: their readings do not lie on an "
        "ellipsoid (poses too similar, or all in one plane); add poses with each axis up and down");
  }
  AccelParams p;
  p.bias = c + v0 / k;
  SetFromLower(gravity_m_s2 * k * *lower, &p);
  return p;
}

absl::StatusOr<AccelParams> FitAxisEllipsoid(const std::vector<AccelPose>& poses,
                                             double gravity_m_s2) {
  const size_t n = poses.size();
  if (n < 6) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "too few static poses: %d found, bias and scale alone need at least 6 (7 or more with "
        "every axis pointing up and down)",
        static_cast<int>(n)));
  }
  absl::StatusOr<Normalised> norm = Normalise(poses);
  if (!norm.ok()) return norm.status();
  const Eigen::Vector3d& c = norm->centre;
  const double k = norm->scale;
  // a_j v_j^2 + beta_j v_j = 1 in the normalised coordinates v = k (u - c).
  Eigen::MatrixXd x(static_cast<Eigen::Index>(n), 6);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Vector3d v = k * (poses[i].mean - c);
    x.row(static_cast<Eigen::Index>(i)) << v.x() * v.x(), v.y() * v.y(), v.z() * v.z(), v.x(),
        v.y(), v.z();
  }
  const Eigen::VectorXd theta =
      x.colPivHouseholderQr().solve(Eigen::VectorXd::Ones(static_cast<Eigen::Index>(n)));
  const Eigen::Vector3d a = theta.head<3>(), beta = theta.tail<3>();
  if (!(a.minCoeff() > 0)) {
    return absl::FailedPreconditionError(
        "the static poses do not determine bias and scale: add poses with each axis up and down");
  }
  const Eigen::Vector3d v0 = -0.5 * beta.cwiseQuotient(a);
  const double rho = 1.0 + (a.array() * v0.array().square()).sum();
  if (!(rho > 0)) {
    return absl::FailedPreconditionError(
        "the static poses do not lie on an ellipsoid: add poses with each axis up and down");
  }
  AccelParams p;
  p.bias = c + v0 / k;
  // s_j^2 (u_j - b_j)^2 summed = g^2  <=>  (a_j / rho) v_j^2 summed = 1, v = k (u - b).
  p.scale = gravity_m_s2 * k * (a / rho).cwiseSqrt();
  return p;
}

absl::StatusOr<AccelParams> FitKnownReferences(const std::vector<Eigen::Vector3d>& means,
                                               const std::vector<Eigen::Vector3d>& references) {
  const size_t n = means.size();
  if (n < 4 || references.size() != n) {
    return absl::FailedPreconditionError(
        absl::StrFormat("the affine least-squares fit needs at least 4 reference poses, got %d",
                        static_cast<int>(n)));
  }
  Eigen::MatrixXd x(static_cast<Eigen::Index>(n), 4), y(static_cast<Eigen::Index>(n), 3);
  for (size_t i = 0; i < n; ++i) {
    x.row(static_cast<Eigen::Index>(i)) << means[i].transpose(), 1.0;
    y.row(static_cast<Eigen::Index>(i)) = references[i].transpose();
  }
  // P = (X^T X)^-1 X^T Y (seeds/000), via QR for conditioning.
  const Eigen::Matrix<double, 4, 3> pm = x.colPivHouseholderQr().solve(y);
  const Eigen::Matrix3d m = pm.topRows<3>().transpose();
  const auto lower = ReversedCholesky(m.transpose() * m);
  if (!lower || std::abs(m.determinant()) < 1e-300) {
    return absl::FailedPreconditionError("the reference poses do not determine the 3x3 matrix");
  }
  Eigen::Matrix3d r = m * lower->inverse();  // rotation (frame) part: M = R * Lower
  if (r.determinant() < 0) {
    return absl::FailedPreconditionError(
        "the face readings imply a mirrored axis: check the axis signs of the capture");
  }
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(r, Eigen::ComputeFullU | Eigen::ComputeFullV);
  r = svd.matrixU() * svd.matrixV().transpose();
  AccelParams p;
  p.bias = -m.inverse() * pm.row(3).transpose();
  SetFromLower(*lower, &p);
  const Eigen::AngleAxisd aa(r);
  p.frame_angles = aa.angle() * aa.axis();
  return p;
}

Eigen::MatrixXd MagnitudeJacobian(const AccelParams& p, const std::vector<AccelPose>& poses) {
  // r = |a| - g with a = L z - offset, z = y + q.*y.^2, y = s.*(u - b). With n = a/|a| and
  // c = L^T n:
  //   dr/db_j = -c_j (1 + 2 q_j y_j) s_j     dr/ds_j = c_j (1 + 2 q_j y_j) (u_j - b_j)
  //   dr/dq_j = c_j y_j^2                    dr/dt_yx = n_y z_x, dr/dt_zx = n_z z_x,
  //                                          dr/dt_zy = n_z z_y
  // (checked against the autodiff functor that the LM stage uses, in accel_solver_test).
  Eigen::MatrixXd j(static_cast<Eigen::Index>(poses.size()), kAccelParams);
  const Eigen::Matrix3d l = LowerMisalignment<double>(p.tri_angles);
  for (size_t i = 0; i < poses.size(); ++i) {
    const Eigen::Vector3d d = poses[i].mean - p.bias;
    const Eigen::Vector3d y = p.scale.cwiseProduct(d);
    const Eigen::Vector3d z = y + p.quadratic.cwiseProduct(y.cwiseProduct(y));
    const Eigen::Vector3d n = (l * z - poses[i].offset_m_s2).normalized();
    const Eigen::Vector3d c = l.transpose() * n;
    const Eigen::Vector3d dz_dy = Eigen::Vector3d::Ones() + 2 * p.quadratic.cwiseProduct(y);
    const auto row = static_cast<Eigen::Index>(i);
    for (int k = 0; k < 3; ++k) {
      j(row, k) = -c(k) * dz_dy(k) * p.scale(k);
      j(row, 3 + k) = c(k) * dz_dy(k) * d(k);
      j(row, 9 + k) = c(k) * y(k) * y(k);
    }
    j(row, 6) = n.y() * z.x();
    j(row, 7) = n.z() * z.x();
    j(row, 8) = n.z() * z.y();
  }
  return j;
}

std::vector<double> MagnitudeSigmas(const AccelParams& p, const std::vector<AccelPose>& poses) {
  // d|a|/du = (a/|a|)^T L diag(1 + 2 q y) diag(scale); the mean's per-axis std propagates.
  std::vector<double> out;
  out.reserve(poses.size());
  const Eigen::Matrix3d l = LowerMisalignment<double>(p.tri_angles);
  for (const AccelPose& pose : poses) {
    const Eigen::Vector3d y = p.scale.cwiseProduct(pose.mean - p.bias);
    const Eigen::Vector3d a =
        l * (y + p.quadratic.cwiseProduct(y.cwiseProduct(y))) - pose.offset_m_s2;
    const Eigen::Vector3d d = Eigen::Vector3d(
        (a.normalized().transpose() * l)
            .transpose()
            .cwiseProduct(
                (Eigen::Vector3d::Ones() + 2 * p.quadratic.cwiseProduct(y)).cwiseProduct(p.scale)));
    out.push_back(
        std::max(1e-12, std::hypot(d.cwiseProduct(pose.mean_std).norm(), pose.model_sigma_m_s2)));
  }
  return out;
}

double EffectiveParameters(const AccelParams& p, const std::vector<AccelPose>& poses,
                           const AccelMask& free, const AccelPriors& priors) {
  const std::vector<double> sigma = MagnitudeSigmas(p, poses);
  const Eigen::MatrixXd jw = WeightedJacobian(p, poses, sigma, free);
  const Eigen::MatrixXd with_priors = WeightedJacobian(p, poses, sigma, free, priors);
  const Eigen::MatrixXd data = jw.transpose() * jw;
  const Eigen::MatrixXd share = (with_priors.transpose() * with_priors).ldlt().solve(data);
  return share.allFinite() ? share.trace() : static_cast<double>(data.rows());
}

double EstimateModelSigma(const AccelParams& p, const std::vector<AccelPose>& poses,
                          double gravity_m_s2, double n_free) {
  std::vector<AccelPose> bare = poses;
  for (auto& pose : bare) pose.model_sigma_m_s2 = 0;
  const std::vector<double> r = MagnitudeResiduals(p, bare, gravity_m_s2);
  const std::vector<double> sigma = MagnitudeSigmas(p, bare);
  const double dof = static_cast<double>(poses.size()) - n_free;
  auto chi2 = [&](double tau) {
    double s = 0;
    for (size_t i = 0; i < r.size(); ++i) s += r[i] * r[i] / (sigma[i] * sigma[i] + tau * tau);
    return s;
  };
  if (dof <= 0 || chi2(0) <= dof) return 0.0;
  double lo = 0, hi = 10 * (Rms(r) + 1e-12);  // chi2 decreases in tau
  for (int it = 0; it < 60; ++it) {
    const double mid = 0.5 * (lo + hi);
    (chi2(mid) > dof ? lo : hi) = mid;
  }
  return hi;
}

AccelVector AccelPlausibleRange(const AccelParams& p, double gravity_m_s2) {
  AccelVector range;
  for (int k = 0; k < 3; ++k) {
    range(k) = 0.2 * gravity_m_s2 / std::abs(p.scale(k));
    range(3 + k) = 0.1 * std::abs(p.scale(k));
    range(6 + k) = 0.03;
    range(9 + k) = 1e-3;
  }
  return range;
}

AccelObservability AnalyseAccelObservability(const AccelParams& p,
                                             const std::vector<AccelPose>& poses,
                                             double gravity_m_s2, const AccelMask& candidates,
                                             const AccelPriors& priors) {
  AccelObservability out;
  out.determined = candidates;
  const AccelVector prior = AccelPlausibleRange(p, gravity_m_s2);
  const std::vector<double> sigma = MagnitudeSigmas(p, poses);
  static const char* kFix[12] = {
      "add poses with the x axis pointing up and pointing down",
      "add poses with the y axis pointing up and pointing down",
      "add poses with the z axis pointing up and pointing down",
      "add poses with the x axis pointing up and pointing down",
      "add poses with the y axis pointing up and pointing down",
      "add poses with the z axis pointing up and pointing down",
      "add poses with gravity between the x and y axes (45 degrees in the x-y plane)",
      "add poses with gravity between the x and z axes (45 degrees in the x-z plane)",
      "add poses with gravity between the y and z axes (45 degrees in the y-z plane)",
      "add poses with the x axis about 45 degrees from vertical",
      "add poses with the y axis about 45 degrees from vertical",
      "add poses with the z axis about 45 degrees from vertical"};
  // A parameter with a prior is measured (by the prior's source) whatever the poses add.
  const auto has_prior = [&priors](int c) {
    for (const AccelPrior& q : priors)
      if (q.index == c) return true;
    return false;
  };
  // Release undetermined parameters from the highest order down, re-checking after each group.
  for (int group = 3; group >= 0; --group) {
    AccelMask free = out.determined;
    int n_free = 0;
    for (bool f : free) n_free += f;
    if (n_free == 0) break;
    const Eigen::MatrixXd jw = WeightedJacobian(p, poses, sigma, free, priors);
    Eigen::VectorXd d(n_free);
    for (int c = 0, k = 0; c < kAccelParams; ++c)
      if (free[c]) d(k++) = prior(c);
    const Eigen::MatrixXd info = d.asDiagonal() * (jw.transpose() * jw) * d.asDiagonal();
    const Eigen::MatrixXd post = (info + Eigen::MatrixXd::Identity(n_free, n_free))
                                     .ldlt()
                                     .solve(Eigen::MatrixXd::Identity(n_free, n_free));
    bool released = false;
    for (int c = 0, k = 0; c < kAccelParams; ++c) {
      if (!free[c]) continue;
      const double ratio = std::sqrt(post(k, k));
      out.sigma(c) = ratio * prior(c);
      ++k;
      if (c / 3 == group && ratio > 0.5 && !has_prior(c)) {
        out.determined[c] = false;
        out.sigma(c) = std::numeric_limits<double>::infinity();
        released = true;
        out.warnings.push_back(absl::StrFormat(
            "accel %s: not determined by these poses (the data leaves %.0f%% of the prior "
            "uncertainty); held at its %s value. To determine it, %s",
            AccelParamName(c), 100 * ratio, group >= 2 ? "neutral (0)" : "stage-1", kFix[c]));
      }
    }
    if (!released && group == 0) break;
  }
  return out;
}

AccelParams RefineAccelBsas(const AccelParams& start, const std::vector<AccelPose>& poses,
                            double gravity_m_s2, const AccelMask& free, const AccelVector& unit,
                            const BsasStageOptions& options, StageReport* report,
                            const AccelPriors& priors) {
  const auto t0 = std::chrono::steady_clock::now();
  const std::vector<AccelPrior> active = ActivePriors(free, priors);
  const AccelVector theta0 = PackAccel(start);
  std::vector<int> index;  // free parameter indices
  for (int c = 0; c < kAccelParams; ++c)
    if (free[c]) index.push_back(c);
  const std::vector<double> sigma = MagnitudeSigmas(start, poses);
  auto to_params = [&](const Eigen::VectorXd& x) {
    AccelVector theta = theta0;
    for (size_t k = 0; k < index.size(); ++k)
      theta(index[k]) += unit(index[k]) * x(static_cast<Eigen::Index>(k));
    return UnpackAccel(theta, start.frame_angles);
  };
  // Evaluated thousands of times: no allocation per call.
  auto cost = [&](const Eigen::VectorXd& x) {
    const AccelParams p = to_params(x);
    const Eigen::Matrix3d l = LowerMisalignment<double>(p.tri_angles);
    double s = 0;
    for (size_t i = 0; i < poses.size(); ++i) {
      const double r = MagnitudeResidual(l, p, poses[i], gravity_m_s2);
      s += (r / sigma[i]) * (r / sigma[i]);
    }
    if (!active.empty()) {
      const AccelVector theta = PackAccel(p);
      for (const AccelPrior& q : active)
        s += ((theta(q.index) - q.value) / q.sigma) * ((theta(q.index) - q.value) / q.sigma);
    }
    return s;
  };
  // seeds/002's schedule: scale, bias, installation angles, second-order terms, repeated.
  std::vector<std::vector<int>> groups;
  for (int group : {1, 0, 2, 3}) {
    std::vector<int> g;
    for (size_t k = 0; k < index.size(); ++k)
      if (index[k] / 3 == group) g.push_back(static_cast<int>(k));
    if (!g.empty()) groups.push_back(g);
  }
  const auto n = static_cast<Eigen::Index>(index.size());
  BsasOptions bo;
  bo.seed = options.seed;
  bo.max_iterations = options.iterations_per_stage;
  const BsasResult r =
      MinimizeBsasStaged(cost, Eigen::VectorXd::Zero(n), Eigen::VectorXd::Constant(n, -50.0),
                         Eigen::VectorXd::Constant(n, 50.0), groups, options.max_rounds, 1e-4, bo);
  const AccelParams out = to_params(r.x);
  if (report) {
    report->name = "bsas";
    report->accel_rms_m_s2 = Rms(MagnitudeResiduals(out, poses, gravity_m_s2));
    report->iterations = r.iterations;
    report->evaluations = r.evaluations;
    report->ms = 1e3 * Seconds(t0);
  }
  return out;
}

absl::StatusOr<LmResult> RefineAccelLm(const AccelParams& start,
                                       const std::vector<AccelPose>& poses, double gravity_m_s2,
                                       const AccelMask& free, StageReport* report,
                                       const AccelPriors& priors) {
  const auto t0 = std::chrono::steady_clock::now();
  int n_free = 0;
  for (bool f : free) n_free += f;
  const std::vector<AccelPrior> active = ActivePriors(free, priors);
  const int n_observations = static_cast<int>(poses.size() + active.size());
  if (n_observations <= n_free) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%d static poses cannot determine %d accelerometer parameters; add poses",
                        static_cast<int>(poses.size()), n_free));
  }
  LmResult out;
  out.params = start;
  AccelParams& p = out.params;
  const std::vector<double> sigma = MagnitudeSigmas(start, poses);
  const AccelBlocks blocks = AccelParamBlocks(&p);
  ceres::Problem problem;
  for (size_t i = 0; i < poses.size(); ++i) {
    problem.AddResidualBlock(NewAccelMagnitudeCost(poses[i], gravity_m_s2, 1.0 / sigma[i]), nullptr,
                             blocks[0], blocks[1], blocks[2], blocks[3]);
  }
  const absl::StatusOr<AccelProblemSummary> summary =
      SolveAccelProblem(free, priors, blocks, "accelerometer LM", &problem);
  if (!summary.ok()) return summary.status();
  // Covariance = (J^T W J)^-1 over the free parameters, scaled by chi^2/dof when the residual
  // exceeds the noise (model misfit), so standard errors never claim more than the data shows.
  const Eigen::MatrixXd jw = WeightedJacobian(p, poses, MagnitudeSigmas(p, poses), free, priors);
  const Eigen::VectorXd rw =
      WeightedResiduals(p, poses, MagnitudeSigmas(p, poses), gravity_m_s2, free, priors);
  const int dof = n_observations - n_free;
  out.chi2_reduced = rw.squaredNorm() / dof;
  const Eigen::MatrixXd bread =
      (jw.transpose() * jw).ldlt().solve(Eigen::MatrixXd::Identity(n_free, n_free));
  Eigen::MatrixXd cov = bread;
  if (out.chi2_reduced > 1) {
    cov *= out.chi2_reduced;
    out.covariance_scaled = true;
  }
  // Poses in time order share a floor, a drift, a rest's neighbour: the sandwich over them
  // (core/robust_covariance.h), never below the scaled estimate; the priors as information.
  std::vector<ObservationBlock> pose_blocks;
  pose_blocks.reserve(poses.size());
  const auto n_poses = static_cast<Eigen::Index>(poses.size());
  for (Eigen::Index i = 0; i < n_poses; ++i) pose_blocks.push_back({jw.row(i), rw.segment(i, 1)});
  const Eigen::MatrixXd prior_rows = jw.bottomRows(jw.rows() - n_poses);
  cov = RobustCovariance(bread, pose_blocks, prior_rows.transpose() * prior_rows, cov);
  std::vector<int> index;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[c]) index.push_back(c);
  for (size_t a = 0; a < index.size(); ++a)
    for (size_t b = 0; b < index.size(); ++b)
      out.covariance(index[a], index[b]) =
          cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b));
  if (report) {
    report->name = "lm";
    report->accel_rms_m_s2 = Rms(MagnitudeResiduals(p, poses, gravity_m_s2));
    report->iterations = summary->iterations;
    report->evaluations = summary->evaluations;
    report->ms = 1e3 * Seconds(t0);
  }
  return out;
}

AccelParams RefineAccelGaussNewton(const AccelParams& start, const std::vector<AccelPose>& poses,
                                   double gravity_m_s2, const AccelMask& free, int max_iterations,
                                   const AccelPriors& priors) {
  std::vector<int> index;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)]) index.push_back(c);
  if (poses.size() + ActivePriors(free, priors).size() <= index.size()) return start;
  const std::vector<double> sigma = MagnitudeSigmas(start, poses);
  AccelVector theta = PackAccel(start);
  for (int it = 0; it < max_iterations; ++it) {
    const AccelParams p = UnpackAccel(theta, start.frame_angles);
    const Eigen::MatrixXd jw = WeightedJacobian(p, poses, sigma, free, priors);
    const Eigen::VectorXd rw = WeightedResiduals(p, poses, sigma, gravity_m_s2, free, priors);
    const Eigen::VectorXd step = (jw.transpose() * jw).ldlt().solve(-jw.transpose() * rw);
    if (!step.allFinite()) break;
    double rel = 0;
    for (size_t k = 0; k < index.size(); ++k) {
      const auto kk = static_cast<Eigen::Index>(k);
      theta(index[k]) += step(kk);
      rel = std::max(rel, std::abs(step(kk)) / std::max(1e-300, std::abs(theta(index[k]))));
    }
    if (rel < 1e-10) break;
  }
  return UnpackAccel(theta, start.frame_angles);
}

AccelMatrix AccelCovariance(const AccelParams& p, const std::vector<AccelPose>& poses,
                            const AccelMask& free, const AccelPriors& priors) {
  AccelMatrix out = AccelMatrix::Zero();
  const Eigen::MatrixXd jw = WeightedJacobian(p, poses, MagnitudeSigmas(p, poses), free, priors);
  const Eigen::MatrixXd cov =
      (jw.transpose() * jw).ldlt().solve(Eigen::MatrixXd::Identity(jw.cols(), jw.cols()));
  std::vector<int> index;
  for (int c = 0; c < kAccelParams; ++c)
    if (free[static_cast<size_t>(c)]) index.push_back(c);
  for (size_t a = 0; a < index.size(); ++a)
    for (size_t b = 0; b < index.size(); ++b)
      out(index[a], index[b]) = cov(static_cast<Eigen::Index>(a), static_cast<Eigen::Index>(b));
  return out;
}

AccelVector AccelStdErrors(const AccelParams& p, const std::vector<AccelPose>& poses,
                           const AccelMask& free, const AccelPriors& priors) {
  return AccelCovariance(p, poses, free, priors).diagonal().cwiseMax(0.0).cwiseSqrt();
}

double AccelLogEvidence(const AccelParams& p, const std::vector<AccelPose>& poses,
                        double gravity_m_s2, const AccelMask& free, const AccelPriors& priors) {
  const std::vector<double> sigma = MagnitudeSigmas(p, poses);
  const Eigen::MatrixXd jw = WeightedJacobian(p, poses, sigma, free, priors);
  const Eigen::VectorXd rw = WeightedResiduals(p, poses, sigma, gravity_m_s2, free, priors);
  const Eigen::LDLT<Eigen::MatrixXd> h(jw.transpose() * jw);
  double log_det = 0;
  for (Eigen::Index i = 0; i < h.vectorD().size(); ++i)
    log_det += std::log(std::max(h.vectorD()(i), 1e-300));
  double log_prior_norm = 0;
  for (const AccelPrior& q : ActivePriors(free, priors)) log_prior_norm -= std::log(q.sigma);
  return -0.5 * rw.squaredNorm() - 0.5 * log_det + log_prior_norm;
}

namespace {

// Pose i's |a| - g with the model refitted without it (Gauss-Newton from `fit`); NaN when the
// other poses are too few to refit.
double ExactHeldOutResidual(const AccelParams& fit, const std::vector<AccelPose>& poses,
                            double gravity_m_s2, const AccelMask& free, const AccelPriors& priors,
                            size_t i) {
  std::vector<AccelPose> rest = poses;
  rest.erase(rest.begin() + static_cast<long>(i));
  int n_free = 0;
  for (bool f : free) n_free += f;
  if (static_cast<int>(rest.size() + ActivePriors(free, priors).size()) <= n_free)
    return std::numeric_limits<double>::quiet_NaN();
  const AccelParams refit = RefineAccelGaussNewton(fit, rest, gravity_m_s2, free, 10, priors);
  return MagnitudeResiduals(refit, {poses[i]}, gravity_m_s2)[0];
}

}  // namespace

std::vector<double> HeldOutMagnitudeResiduals(const AccelParams& fit,
                                              const std::vector<AccelPose>& poses,
                                              double gravity_m_s2, const AccelMask& free,
                                              const AccelPriors& priors) {
  std::vector<double> out(poses.size(), std::numeric_limits<double>::quiet_NaN());
  for (size_t i = 0; i < poses.size(); ++i) {
    out[i] = ExactHeldOutResidual(fit, poses, gravity_m_s2, free, priors, i);
  }
  return out;
}

double PressRms(const AccelParams& fit, const std::vector<AccelPose>& poses, double gravity_m_s2,
                const AccelMask& free, const AccelPriors& priors) {
  const std::vector<double> sigma = MagnitudeSigmas(fit, poses);
  const Eigen::MatrixXd jw = WeightedJacobian(fit, poses, sigma, free, priors);
  const Eigen::MatrixXd jtj = jw.transpose() * jw;
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(jtj);
  const std::vector<double> r = MagnitudeResiduals(fit, poses, gravity_m_s2);
  // Near h = 1 the first order fails: a pose that alone pins a parameter has r ~ 0 and a tiny
  // 1 - h, and their quotient says nothing of how badly the fit without it predicts it. Those
  // poses are refitted without themselves, exactly (HeldOutMagnitudeResiduals' way).
  constexpr double kExactAboveLeverage = 0.9;
  double s = 0;
  const auto n_poses = static_cast<Eigen::Index>(poses.size());
  for (Eigen::Index i = 0; i < n_poses; ++i) {
    const double h = jw.row(i).dot(ldlt.solve(jw.row(i).transpose()));
    double loo = r[static_cast<size_t>(i)] / std::max(1e-6, 1.0 - h);
    if (h > kExactAboveLeverage) {
      loo = ExactHeldOutResidual(fit, poses, gravity_m_s2, free, priors, static_cast<size_t>(i));
      // Not predictable at all without itself: this model cannot be scored by held-out poses.
      if (!std::isfinite(loo)) return std::numeric_limits<double>::infinity();
    }
    s += loo * loo;
  }
  return std::sqrt(s / static_cast<double>(n_poses));
}

}  // namespace imucal::core
